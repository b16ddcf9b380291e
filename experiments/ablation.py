"""The HalfCheetah ablation (Table 1): full MA against Jacobian-only and temporal-only.

    python experiments/ablation.py [--scale smoke|cpu|paper] [--steps N] [--envs halfcheetah]
        [--seeds 0-4] [--alpha 1] [--arms full jacobian temporal none] [--placement P]
        [--normalize-reward] [--collect-only] [--runs runs/ablation]
        [--reuse runs/meta_training/halfcheetah/cpu_10k]

Members: MB-MPO with MA at ``--alpha`` in each mode (``ma.mode``: full = both terms, jacobian =
the feedback term alone, a state-smoothness regularizer; temporal = the feedforward term alone)
and MB-MPO without MA (arm "none"), every seed, trained to the paper's stages that the scale
reaches (resumable: run it again). The modes are data (0/1 term weights), so all arms are one
population in one compiled program. ``--arms`` keeps some (the paper's Table 1 has the first
three). Each arm is compared with full MA (the paper's claim: full MA has the highest
reward). The full and alpha-0 arms are meta_training's MB-MPO + MA and MB-MPO members:
``--reuse`` its runs folder to read them instead of training them again.
Writes ``experiments/results/ablation_<tag>.{json,md}``.
"""

from __future__ import annotations

import argparse
import os
from typing import Any

import paper_numbers
import study as xt

from minatt_jax import population
from minatt_jax.config import resolve, with_overrides

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")
SWEPT = ["env", "ma.mode", "ma.alpha"]
MODES = ("full", "jacobian", "temporal")


def members(args: argparse.Namespace) -> list[Any]:
    arms = [(mode, args.alpha) for mode in MODES if mode in args.arms]
    arms += [("full", 0.0)] if "none" in args.arms else []
    base = xt.study_preset(args)
    return [resolve(with_overrides(
        base, env=env, algo="mbmpo", seed=seed, ma_mode=mode, ma_alpha=alpha,
        ma_placement=args.placement, sac_normalize_reward=args.normalize_reward,
        total_steps=args.steps,
    )) for env in args.envs for mode, alpha in arms
        for seed in population.parse_seeds(args.seeds)]  # fmt: skip


def arm_of(config: Any) -> str:
    return config.ma.mode if config.ma.alpha > 0 else "none"


def markdown(result: dict[str, Any]) -> str:
    lines = [f"# MA ablation ({result['tag']})", "",
             f"`{result['command']}` on {result['device']}, {result['date']}. MB-MPO with MA "
             f"(alpha {result['alpha']:g}) in each mode and without it; deterministic evaluation "
             "at each stage, mean +- std over seeds [95% bootstrap interval] n=seeds, each arm "
             "against full MA (lower/higher where the interval of the difference excludes "
             "zero). The paper's column: HalfCheetah at 200K."]  # fmt: skip
    for env, by_stage in result["tables"].items():
        lines += ["", f"## {env}", "", "| stage | metric | full | jacobian | temporal | none "
                  "(alpha 0) | paper full | paper jacobian | paper temporal |",
                  "|---" * 9 + "|"]  # fmt: skip
        for step, rows in by_stage.items():
            for m in paper_numbers.METRICS:
                ours = [xt.cell(rows[a][m]) if a in rows else "-"
                        for a in (*MODES, "none")]  # fmt: skip
                final = env == "halfcheetah" and int(step) == max(paper_numbers.STAGES)
                paper = [xt.paper_cell(paper_numbers.ABLATION[a].get(m) if final else None)
                         for a in MODES]  # fmt: skip
                lines.append(f"| {xt.stage_label(int(step))} | {m} | "
                             + " | ".join(ours + paper) + " |")  # fmt: skip
    return "\n".join(lines) + "\n"


def build_parser() -> argparse.ArgumentParser:
    """The study's options and ``--arms``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    xt.add_study_arguments(parser, envs=["halfcheetah"], runs="runs/ablation", reuse=True)
    parser.add_argument("--arms", nargs="+", default=[*MODES, "none"], choices=[*MODES, "none"],
                        help="the arms to train and tabulate (default: all four; each is "
                             "compared with full, which must be among them)")  # fmt: skip
    return parser


def main() -> None:
    parser = build_parser()
    args = parser.parse_args()
    if "full" not in args.arms:
        parser.error("--arms must include full: every arm is compared with it")
    configs = members(args)
    reused = xt.reused_runs(args, configs)
    steps, tag, out_dir = xt.train_study("ablation", args, configs, SWEPT, reused=reused)
    if args.no_tables:
        return
    tables = {}
    for env in args.envs:
        dirs = xt.dirs_by_arm(configs, out_dir, SWEPT, env, arm_of, reused)
        tables[env] = {str(s): xt.training_rows(dirs, s, baseline="full") for s in steps}
    command = xt.study_command("ablation.py", args)
    result = {"tag": tag, **xt.provenance(command), "alpha": args.alpha, "stages": steps,
              "tables": tables}  # fmt: skip
    text = markdown(result)
    xt.write_study(RESULTS, f"ablation_{tag}", result, text)
    print(text)


if __name__ == "__main__":
    main()
