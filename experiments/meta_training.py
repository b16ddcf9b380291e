"""The paper's meta-training and meta-testing tables: SAC, MB-MPO and MB-MPO + MA per agent.

    python experiments/meta_training.py [--scale smoke|cpu|paper] [--steps N]
        [--envs hopper halfcheetah walker2d humanoid] [--seeds 0-4] [--alpha 1 [0.01 0.05]]
        [--placement actor_loss] [--normalize-reward] [--variants mass crippled slope]
        [--no-meta-test] [--collect-only] [--runs runs/meta_training]
        [--records experiments/records]

Members: per environment SAC (alpha 0), MB-MPO (alpha 0) and MB-MPO + MA at each ``--alpha``
(the paper's tables use 1, HalfCheetah's Tables S1-S2 also 0.01 and 0.05; ``--placement`` /
``--normalize-reward`` pick the reading of MA), every seed, as one population
(``population.train_population``: one compiled program per environment and algorithm, seeds
and alphas vmapped). Training goes stage by stage: the paper's stages (10K /
100K / 200K) that the scale reaches, and the last step. At each stage every member is
meta-tested (``meta_test.meta_test``: 1 real episode per task, 10 adaptation steps) on each
``--variants`` task set, since only the latest checkpoints are kept. Running the command again
resumes training and skips meta-tests already written
(``<member>/meta_test/<variant>_<step>.json``).

Per environment (one population under ``<runs>/<env>/<tag>``, trained and tabulated in turn, so
each agent's table is written when it finishes) writes
``experiments/results/meta_training_<tag>_<env>.{json,md}``, the adaptation curves
``meta_testing_<tag>_<env>.png`` and an ``analyze`` report of its members
(``meta_training_<tag>_<env>_report/``; ``--no-report`` skips it). With alphas other than 1 alone,
each alpha's table and curves carry ``_alpha<a>`` (SAC and MB-MPO shared by all of them) and the
population lives under ``<runs>/<env>/alpha<a>_<b>/<tag>``. The tables: per stage and
arm, mean +- std over seeds [95% bootstrap interval of the mean], the difference from MB-MPO
(direction when its interval excludes zero), and the paper's numbers beside ours
(``paper_numbers``).

A grid longer than a machine keeps its runs: ``--records experiments/records`` copies each
member's results (config.json, metrics.jsonl, meta-tests; kilobytes) there once it reached
every stage, and the next call reads members kept there instead of training them. So
``--seeds 0-1`` on one machine, ``--seeds 2-4`` on another (commit the records between) and
``--seeds 0-4`` tabulates all ten without training; the analyze report needs checkpoints: it
reads them in the pieces' runs folders where they were trained, and is skipped where some member was
trained elsewhere.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import os
import shutil
import sys
from collections.abc import Callable
from typing import Any

import numpy as np
import paper_numbers
import study as xt

from minatt_jax import checkpoint, meta_test, population, runner
from minatt_jax.analysis import plots
from minatt_jax.config import resolve, with_overrides

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")
METRICS = paper_numbers.METRICS
SWEPT = ["env", "ma.alpha"]
ENV_NAMES = {"hopper": "Hopper", "halfcheetah": "HalfCheetah", "walker2d": "Walker2D",
             "humanoid": "Humanoid"}  # fmt: skip


def arms(alphas: list[float]) -> list[tuple[str, str, float]]:
    """(arm, algo, alpha): the paper's three columns, MA once per alpha."""
    return [("sac", "sac", 0.0), ("mbmpo", "mbmpo", 0.0)] + [
        (ma_arm(a), "mbmpo", a) for a in alphas
    ]


def ma_arm(alpha: float) -> str:
    return f"ma alpha={alpha:g}"


def arm_of(config: Any) -> str:
    if config.algo == "sac":
        return "sac"
    return ma_arm(config.ma.alpha) if config.ma.alpha > 0 else "mbmpo"


def alpha_list(args: argparse.Namespace) -> list[float]:
    """``--alpha`` as a list (one value or several), without repeats; alpha 0 is MB-MPO's arm
    already, so it exits 2."""
    alphas = list(dict.fromkeys(args.alpha if isinstance(args.alpha, list) else [args.alpha]))
    if any(a <= 0 for a in alphas):
        print("meta_training.py: --alpha takes MA weights above 0 (MB-MPO is alpha 0 already)",
              file=sys.stderr)  # fmt: skip
        raise SystemExit(2)
    return alphas


def alpha_suffix(alphas: list[float], alpha: float) -> str:
    """What one alpha's result files add to their name: '' for the paper's alpha 1 alone,
    else '_alpha<a>'."""
    return "" if alphas == [1.0] else f"_alpha{alpha:g}"


def alphas_folder(alphas: list[float]) -> str:
    """The population's folder under ``<runs>/<env>``: '' for alpha 1 alone, else
    'alpha<a>_<b>'."""
    return "" if alphas == [1.0] else "alpha" + "_".join(f"{a:g}" for a in alphas)


def members(args: argparse.Namespace) -> list[Any]:
    out, base = [], xt.study_preset(args)
    for env in args.envs:
        for _, algo, alpha in arms(alpha_list(args)):
            for seed in population.parse_seeds(args.seeds):
                out.append(resolve(with_overrides(
                    base, env=env, algo=algo, seed=seed, ma_alpha=alpha,
                    ma_placement=args.placement, sac_normalize_reward=args.normalize_reward,
                    total_steps=args.steps,
                )))  # fmt: skip
    return out


def meta_test_path(run_dir: str, variant: str, step: int) -> str:
    return os.path.join(run_dir, "meta_test", f"{variant}_{step}.json")


def meta_tested(variants: list[str], steps: list[int]) -> Callable[[str], bool]:
    """Whether a run holds its meta-tests on every variant at every stage: a member read from
    elsewhere has no checkpoints to meta-test again."""
    return lambda d: all(os.path.exists(meta_test_path(d, v, s)) for v in variants for s in steps)


def meta_test_stage(step: int, dirs: list[str], variants: list[str]) -> None:
    """Meta-tests every member at ``step`` (its latest checkpoint) on every variant, once."""
    settings = meta_test.MetaTestConfig()
    for d in dirs:
        for variant in variants:
            path = meta_test_path(d, variant, step)
            if os.path.exists(path):
                continue
            result = meta_test.meta_test(d, variant, settings, log=lambda _: None)
            if result["step"] != step:
                raise runner.RunError(f"{d}: latest checkpoint {result['step']}, expected {step}")
            os.makedirs(os.path.dirname(path), exist_ok=True)
            runner.write_json_atomic(path, result)
            before, after = (result["mean_over_tasks"]["return"][k] for k in ("before", "after"))
            print(f"meta-test {os.path.basename(d)} {variant} @ {step}: return "
                  f"{before:.1f} -> {after:.1f}", flush=True)  # fmt: skip


def collect(configs: list[Any], out_dir: str, steps: list[int], alpha: float,
            variants: list[str],
            reused: dict[int, str] | None = None) -> dict[str, Any]:  # fmt: skip
    """Per environment, stage and arm (sac, mbmpo, ma: MA at ``alpha``): the meta-training and
    meta-testing statistics (``reused`` members read where they were found)."""
    out: dict[str, Any] = {}
    for env in dict.fromkeys(c.env for c in configs):
        env_out: dict[str, Any] = {"meta_training": {}, "meta_testing": {}}
        found = xt.dirs_by_arm(configs, out_dir, SWEPT, env, arm_of, reused)
        dirs = {arm: found.get(arm, []) for arm in ("sac", "mbmpo")}
        dirs["ma"] = found.get(ma_arm(alpha), [])
        for step in steps:
            train_rows, test_rows = xt.training_rows(dirs, step, baseline="mbmpo"), {}
            tests = {arm: [[_read(p) for v in variants
                            if os.path.exists(p := meta_test_path(d, v, step))]
                           for d in arm_dirs]
                     for arm, arm_dirs in dirs.items()}  # fmt: skip
            for arm in dirs:
                test_rows[arm] = xt.meta_test_rows(tests[arm], tests["mbmpo"] if arm == "ma"
                                                 else None, variants)  # fmt: skip
            env_out["meta_training"][str(step)] = train_rows
            env_out["meta_testing"][str(step)] = test_rows
        out[env] = env_out
    return out


def _read(path: str) -> dict[str, Any]:
    with open(path) as f:
        return json.load(f)


def task_sets(variants: list[str]) -> list[str]:
    """The variants, and their average where there are several (one is its own average)."""
    return [*variants, "average"] if len(variants) > 1 else list(variants)


def markdown(result: dict[str, Any], alpha: float, variants: list[str]) -> str:
    lines = [
        f"# Meta-training and meta-testing tables ({result['tag']}, MA alpha {alpha:g})",
        "",
        f"`{result['command']}` on {result['device']}, {result['date']}. Deterministic "
        "evaluation of each member at each stage; mean +- std over seeds [95% bootstrap "
        "interval of the mean] n=seeds; SAC and MA say (lower/higher) where the interval "
        "of its difference from MB-MPO excludes zero. The paper's columns: mean +- std "
        "over its seeds (energy on the paper's own scale, which differs between its "
        "tables: compare directions; the feedforward norm's scale differs too). SAC has no "
        "numbers in the paper (figures only).",
    ]
    for env, env_out in result["tables"].items():
        title = ENV_NAMES.get(env, env)
        lines += ["", f"## {title}: meta-training", "",
                  "| stage | metric | SAC | MB-MPO | MB-MPO + MA | paper MB-MPO | paper MA |",
                  "|---|---|---|---|---|---|---|"]  # fmt: skip
        for step, rows in env_out["meta_training"].items():
            for m in METRICS:
                ours = [xt.cell(rows[a][m]) for a in ("sac", "mbmpo", "ma")]
                paper = [paper_numbers.reported(env, "meta_training", int(step), a, alpha)
                         for a in ("mbmpo", "ma")]  # fmt: skip
                cells = [xt.paper_cell(p and p[m]) for p in paper]
                lines.append(f"| {xt.stage_label(int(step))} | {m} | " + " | ".join(ours + cells)
                             + " |")  # fmt: skip
        if not variants:
            continue
        lines += ["", f"## {title}: meta-testing (before -> after 10 adaptation steps)", "",
                  "| stage | tasks | metric | SAC | MB-MPO | MB-MPO + MA | paper MB-MPO | "
                  "paper MA |", "|---|---|---|---|---|---|---|---|"]  # fmt: skip
        for step, rows in env_out["meta_testing"].items():
            for name in task_sets(variants):
                for m in METRICS:
                    ours = []
                    for a in ("sac", "mbmpo", "ma"):
                        row = rows[a].get(name, {})
                        ours.append(f"{xt.cell(row.get(f'{m}_before'))} -> "
                                    f"{xt.cell(row.get(f'{m}_after'))}")  # fmt: skip
                    paper = [paper_numbers.reported(env, "meta_testing", int(step), a, alpha)
                             for a in ("mbmpo", "ma")]  # fmt: skip
                    cells = [xt.paper_cell(p and p[m]) for p in paper]
                    lines.append(f"| {xt.stage_label(int(step))} | {name} | {m} | "
                                 + " | ".join(ours + cells) + " |")  # fmt: skip
    return "\n".join(lines) + "\n"


def plot_adaptation(result: dict[str, Any], env: str, variants: list[str], path: str) -> None:
    """Return over adaptation steps (mean +- std over seeds), one panel per task set."""
    plt = plots._pyplot()
    names = task_sets(variants)
    fig, axes = plt.subplots(1, len(names), figsize=(4 * len(names), 3.2), squeeze=False)
    tests = result["tables"][env]["meta_testing"]
    last = max(tests, key=int)
    for ax, name in zip(axes[0], names, strict=True):
        for arm, label in (("sac", "SAC"), ("mbmpo", "MB-MPO"), ("ma", "MB-MPO + MA")):
            row = tests[last][arm].get(name, {})
            if "return_curve_mean" not in row:
                continue
            mean, std = np.array(row["return_curve_mean"]), np.array(row["return_curve_std"])
            x = np.arange(len(mean))
            ax.plot(x, mean, label=label)
            ax.fill_between(x, mean - std, mean + std, alpha=0.2)
        ax.set_title(f"{ENV_NAMES.get(env, env)} {name} @ {xt.stage_label(int(last))}")
        ax.set_xlabel("adaptation step")
    axes[0][0].set_ylabel("return")
    axes[0][0].legend()
    plots.save_figure(fig, path)


def write_reports(configs: list[Any], out_dir: str, steps: list[int], tag: str,
                  suffix: str = "", reused: dict[int, str] | None = None) -> None:  # fmt: skip
    """``minatt-jax analyze`` on every member of each environment (K(t)x + v(t), heatmaps,
    failure grid, maturation at the stages); its figures and tables are copied beside the
    tables (``report.html`` stays under the runs). A member read from records is analyzed in
    the piece folder that trained it on the same machine (``checkpointed_run``); skipped, said
    once, where some member has no checkpoint on that machine."""
    from minatt_jax.cli import main as cli

    for env in dict.fromkeys(c.env for c in configs):
        dirs = [xt.checkpointed_run(d, os.path.dirname(out_dir), steps[-1])
                for arm in xt.dirs_by_arm(configs, out_dir, SWEPT, env, arm_of, reused).values()
                for d in arm]  # fmt: skip
        if missing := [d for d in dirs if checkpoint.latest_step(d) is None]:
            print(f"meta_training: no analyze report for {env}: {len(missing)} members have no "
                  f"checkpoint here (e.g. {missing[0]})", flush=True)  # fmt: skip
            continue
        report = os.path.join(out_dir, "reports", env)
        argv = ["analyze", *dirs, "--out", report, "--maturation-steps", *map(str, steps)]
        if cli(argv) != 0:
            raise SystemExit(f"meta_training: analyze failed for {env}")
        target = os.path.join(RESULTS, f"meta_training_{tag}_{env}{suffix}_report")
        os.makedirs(target, exist_ok=True)
        for name in os.listdir(report):
            if name.endswith((".png", ".md", ".json")):
                shutil.copy(os.path.join(report, name), os.path.join(target, name))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    xt.add_study_arguments(parser, envs=list(ENV_NAMES), runs="runs/meta_training",
                           several_alphas=True)  # fmt: skip
    parser.add_argument("--variants", nargs="*", default=["mass", "crippled", "slope"])
    parser.add_argument("--no-meta-test", action="store_true")
    parser.add_argument("--no-report", action="store_true", help="skip the analyze reports")
    args = parser.parse_args()
    alphas = alpha_list(args)
    variants = [] if args.no_meta_test else args.variants
    at_stage = functools.partial(meta_test_stage, variants=variants) if variants else None
    for env in args.envs:  # one population, table and report per agent, written as it finishes
        runs = os.path.join(args.runs, env, alphas_folder(alphas))
        one = argparse.Namespace(**{**vars(args), "envs": [env], "runs": runs})
        configs = members(one)
        steps = xt.stages(configs[0].total_steps, configs[0].eval_every)
        reused = xt.reused_runs(one, configs, meta_tested(variants, steps))
        _, tag, out_dir = xt.train_study("meta_training", one, configs, SWEPT, at_stage,
                                         reused)  # fmt: skip
        if args.no_tables:
            continue
        command = xt.study_command("meta_training.py", one, f" --variants {' '.join(variants)}"
                                   if variants else " --no-meta-test")  # fmt: skip
        for alpha in alphas:  # one table per alpha, each against the same SAC and MB-MPO
            result = {"tag": tag, **xt.provenance(command), "stages": steps,
                      "alpha": alpha, "placement": configs[-1].ma.placement,
                      "normalize_reward": configs[-1].sac.normalize_reward, "variants": variants,
                      "meta_test_settings": dataclasses.asdict(meta_test.MetaTestConfig()),
                      "tables": collect(configs, out_dir, steps, alpha, variants,
                                        reused)}  # fmt: skip
            text = markdown(result, alpha, variants)
            name = f"{tag}_{env}{alpha_suffix(alphas, alpha)}"
            xt.write_study(RESULTS, f"meta_training_{name}", result, text)
            if variants:
                plot_adaptation(result, env, variants,
                                os.path.join(RESULTS, f"meta_testing_{name}.png"))  # fmt: skip
            print(text, flush=True)
        if not args.no_report:
            folder = alphas_folder(alphas)
            write_reports(configs, out_dir, steps, tag, f"_{folder}" if folder else "", reused)


if __name__ == "__main__":
    main()
