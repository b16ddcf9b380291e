"""Hopper learning table: mbmpo alpha = 0 and 1 against model-free SAC alpha = 0 (cpu preset),
plus mbmpo alpha = 0.05 (one of the paper's smaller alphas; alpha = 1 costs return at 50K).

    python experiments/hopper_model_based.py [--steps 50000] [--seeds 0 1 2] [--collect-only]

Runs go one after another (seed 0 of every variant first; SAC, which takes minutes, first),
each a normal run directory under ``--runs``; a killed invocation resumes every unfinished run
from its last checkpoint when started again. After each run (and with ``--collect-only``, from
whatever the run directories hold) the evaluation records at 10K, 25K and 50K steps are written
to ``experiments/results/hopper_model_based.json`` and a markdown table (mean +- std over the
seeds that reached the step, n given).
"""

from __future__ import annotations

import argparse
import os
import re

import numpy as np

from minatt_jax import runner
from minatt_jax.analysis import report
from minatt_jax.config import PRESETS, with_overrides

RESULTS = os.path.join(os.path.dirname(__file__), "results")
# Run order: the cheap one first; the alpha = 0.05 row came after the first three were done.
VARIANTS = (("sac", 0.0), ("mbmpo", 1.0), ("mbmpo", 0.0), ("mbmpo", 0.05))
STEPS = (10_000, 25_000, 50_000)
COLUMNS = ("return", "feedback_norm", "energy", "feedforward_norm")


def run_dir(runs: str, algo: str, alpha: float, seed: int) -> str:
    return os.path.join(runs, f"hopper_{algo}_alpha{alpha:g}_seed{seed}")


def train_or_resume(config, directory: str) -> None:
    """Trains ``config`` in ``directory``, resuming from its last checkpoint if it has one."""
    os.makedirs(directory, exist_ok=True)
    resume = os.path.exists(os.path.join(directory, "config.json"))
    print(f"== {directory} ({'resume' if resume else 'new'})", flush=True)
    runner.train(config, directory, resume=resume)


def seeds_on_disk(runs: str, seeds: list[int]) -> list[int]:
    """``seeds`` plus every seed with a run directory under ``runs``, so that lanes running
    different seeds at once each write the whole table rather than overwriting it with theirs."""
    found = set(seeds)
    if os.path.isdir(runs):
        for name in os.listdir(runs):
            match = re.search(r"_seed(\d+)$", name)
            if match:
                found.add(int(match.group(1)))
    return sorted(found)


def collect(runs: str, seeds: list[int], variants=VARIANTS) -> list[dict]:
    """Every evaluation record of every run directory that exists."""
    out = []
    for algo, alpha in variants:
        for seed in seeds:
            for record in runner.read_metrics(run_dir(runs, algo, alpha, seed)):
                out.append({"algo": algo, "alpha": alpha, "seed": seed, **record})
    return out


def table(records: list[dict], variants=VARIANTS, steps=STEPS) -> list[str]:
    """Markdown rows: mean +- std over seeds per (algo, alpha) and evaluation step."""
    lines = [
        "| algo | alpha | step | seeds | " + " | ".join(COLUMNS) + " | env steps/s |",
        "|---" * (len(COLUMNS) + 5) + "|",
    ]
    for algo, alpha in variants:
        for step in steps:
            rows = [r for r in records
                    if r["algo"] == algo and r["alpha"] == alpha and r["step"] == step]  # fmt: skip
            if not rows:
                continue
            cells = []
            for c in COLUMNS:
                v = np.array([r[c] for r in rows])
                cells.append(f"{v.mean():.4g} +- {v.std():.2g}")
            speed = np.mean([r["env_steps_per_s"] for r in rows])
            lines.append(
                f"| {algo} | {alpha:g} | {step} | {len(rows)} | " + " | ".join(cells)
                + f" | {speed:.0f} |"
            )  # fmt: skip
    return lines


def write(records: list[dict], steps: int, runs: str) -> None:
    os.makedirs(RESULTS, exist_ok=True)
    runner.write_json_atomic(os.path.join(RESULTS, "hopper_model_based.json"), records)
    lines = table(records)
    runner.write_text_atomic(
        os.path.join(RESULTS, "hopper_model_based.md"),
        "# Hopper: mbmpo (alpha 0, 0.05, 1) against SAC (alpha 0), cpu preset\n\n"
        f"`python experiments/hopper_model_based.py --steps {steps}`. Deterministic "
        "evaluation on the run's task set (5 episodes per evaluation); mean +- std over the "
        "seeds that reached the step (std over seeds, population).\n\n"
        + "\n".join(lines) + "\n"
    )  # fmt: skip
    print("\n".join(lines), flush=True)
    figure(runs, sorted({(r["algo"], r["alpha"], r["seed"]) for r in records}))


def figure(runs: str, keys: list[tuple[str, float, int]]) -> None:
    """Learning curves (return, feedback, feedforward, energy; mean +- std over seeds) of the
    table's runs: ``results/hopper_model_based.png``."""
    dirs = [run_dir(runs, *key) for key in keys]
    dirs = [d for d in dirs if os.path.exists(os.path.join(d, "config.json"))]
    if dirs:
        path = os.path.join(RESULTS, "hopper_model_based.png")
        report.profiles_figure(report.load_runs(dirs), path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=50_000)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--runs", default="runs/hopper_model_based")
    parser.add_argument("--collect-only", action="store_true")
    args = parser.parse_args()
    if not args.collect_only:
        for seed in args.seeds:
            for algo, alpha in VARIANTS:
                config = with_overrides(
                    PRESETS["cpu"], env="hopper", algo=algo, total_steps=args.steps, seed=seed,
                    ma_alpha=alpha,
                )  # fmt: skip
                train_or_resume(config, run_dir(args.runs, algo, alpha, seed))
                write_all(args)
    write_all(args)


def write_all(args: argparse.Namespace) -> None:
    """The table and figure over every seed on disk (see ``seeds_on_disk``)."""
    write(collect(args.runs, seeds_on_disk(args.runs, args.seeds)), args.steps, args.runs)


if __name__ == "__main__":
    main()
