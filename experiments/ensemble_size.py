"""HalfCheetah's dependency on the ensemble size M and the imagined trajectories N (Fig. 4).

    python experiments/ensemble_size.py [--scale smoke|cpu|paper] [--steps N] [--envs halfcheetah]
        [--seeds 0-4] [--alpha 1] [--sizes 1 5 15 20] [--trajectories 16 128 256 512]
        [--collect-only] [--runs runs/ensemble_size]

Members: MB-MPO + MA (``--alpha``) with the ensemble size M in ``--sizes`` (N at the preset's
value) and with N in ``--trajectories`` (M at the preset's 7), every seed, one population (one
compiled program per M and per N: they are shapes), trained to the paper's stages that the scale
reaches (resumable). N is read as the imagined trajectories started per model rollout
(``mb.rollout_batch``), as ``benchmarks/meta_step.py`` does; elites are min(5, M). The paper's
claim: the reward grows with M up to 20; N helps up to 128 and less at 256. Writes
``experiments/results/ensemble_size_<tag>.{json,md,png}`` (the return over training per arm).
"""

from __future__ import annotations

import argparse
import os
from typing import Any

import numpy as np
import paper_numbers
import study as xt

from minatt_jax import population
from minatt_jax.analysis import plots
from minatt_jax.config import resolve, with_overrides

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")
SWEPT = ["env", "model.ensemble_size", "mb.rollout_batch"]


def members(args: argparse.Namespace, base: Any) -> list[Any]:
    """Every (arm, seed) member from the preset ``base``: each M at the preset's N, each N at
    the preset's M."""
    arms = [(m, None) for m in args.sizes]
    arms += [(None, n) for n in args.trajectories if n != base.mb.rollout_batch]
    out = []
    for env in args.envs:
        for size, trajectories in arms:
            for seed in population.parse_seeds(args.seeds):
                out.append(resolve(with_overrides(
                    base, env=env, algo="mbmpo", seed=seed, ma_alpha=args.alpha,
                    model_ensemble_size=size, mb_rollout_batch=trajectories,
                    model_num_elites=elites(base, size),
                    ma_placement=args.placement, sac_normalize_reward=args.normalize_reward,
                    total_steps=args.steps,
                )))  # fmt: skip
    return out


def elites(base: Any, size: int | None) -> int | None:
    """The preset's elites (min(5, M) when unset), at most M; None keeps the preset's."""
    if size is None:
        return None
    return min(base.model.num_elites or 5, size)


def arm_of(config: Any) -> str:
    return f"M={config.model.ensemble_size} N={config.mb.rollout_batch}"


def plot(result: dict[str, Any], path: str) -> None:
    plt = plots._pyplot()
    envs = list(result["curves"])
    fig, axes = plt.subplots(1, len(envs), figsize=(6 * len(envs), 4), squeeze=False)
    for ax, env in zip(axes[0], envs, strict=True):
        for arm, c in result["curves"][env].items():
            x, mean, std = np.array(c["step"]), np.array(c["mean"]), np.array(c["std"])
            ax.plot(x, mean, label=arm)
            ax.fill_between(x, mean - std, mean + std, alpha=0.15)
        ax.set_title(f"{env}: return over training (mean +- std over seeds)")
        ax.set_xlabel("env steps")
        ax.legend(fontsize=7)
    plots.save_figure(fig, path)


def markdown(result: dict[str, Any]) -> str:
    lines = [
        f"# Ensemble size M and imagined trajectories N ({result['tag']})",
        "",
        f"`{result['command']}` on {result['device']}, {result['date']}. MB-MPO + MA "
        f"(alpha {result['alpha']:g}); deterministic evaluation, mean +- std over seeds "
        "[95% bootstrap interval] n=seeds, each arm against the preset's M and N "
        "(lower/higher where the interval of the difference excludes zero). The paper "
        "shows curves only (Fig. 4): reward grows with M up to 20; N helps up to 128.",
    ]
    for env, by_stage in result["tables"].items():
        lines += ["", f"## {env}", "", "| stage | arm | seeds | " +
                  " | ".join(paper_numbers.METRICS) + " |", "|---" * 7 + "|"]  # fmt: skip
        for step, rows in by_stage.items():
            for arm, row in rows.items():
                lines.append(f"| {xt.stage_label(int(step))} | {arm} | {row['seeds']} | "
                             + " | ".join(xt.cell(row[m]) for m in paper_numbers.METRICS)
                             + " |")  # fmt: skip
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    xt.add_study_arguments(parser, envs=["halfcheetah"], runs="runs/ensemble_size", reuse=True)
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 5, 15, 20])
    parser.add_argument("--trajectories", type=int, nargs="+", default=[16, 128, 256, 512])
    args = parser.parse_args()
    base = xt.study_preset(args)
    configs = members(args, base)
    reused = xt.reused_runs(args, configs)
    steps, tag, out_dir = xt.train_study("ensemble_size", args, configs, SWEPT, reused=reused)
    if args.no_tables:
        return
    baseline = f"M={base.model.ensemble_size} N={base.mb.rollout_batch}"
    tables: dict[str, Any] = {}
    curves: dict[str, Any] = {}
    for env in args.envs:
        dirs = xt.dirs_by_arm(configs, out_dir, SWEPT, env, arm_of, reused)
        known = baseline if baseline in dirs else None
        tables[env] = {str(s): xt.training_rows(dirs, s, baseline=known) for s in steps}
        curves[env] = {arm: xt.curves(d) for arm, d in dirs.items()}
    command = xt.study_command(
        "ensemble_size.py",
        args,
        f" --sizes {' '.join(map(str, args.sizes))}"
        f" --trajectories {' '.join(map(str, args.trajectories))}",
    )
    result = {"tag": tag, **xt.provenance(command), "alpha": args.alpha, "stages": steps,
              "baseline": baseline, "tables": tables, "curves": curves}  # fmt: skip
    name = f"ensemble_size_{tag}"
    text = markdown(result)
    xt.write_study(RESULTS, name, result, text)
    plot(result, os.path.join(RESULTS, f"{name}.png"))
    print(text)


if __name__ == "__main__":
    main()
