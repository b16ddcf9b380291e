"""Why model-based does not beat SAC here: agent updates per real step (hopper, alpha = 0).

    python experiments/hopper_update_ratio.py [--steps 20000] [--seeds 0] [--variants mbpo:20]
                                              [--collect-only]

MBPO's sample efficiency on Hopper comes with 20 policy updates per real step; the cpu preset
makes 2 (one hour per 50K-step mbmpo run here). This runs mbpo with 2 and 20 updates per step,
and SAC on real data only with 20 (SAC with 1 is the learning table's baseline), cpu preset
otherwise, and writes ``experiments/results/hopper_update_ratio.{json,md}``: return, episode
length and feedback norm at each evaluation (mean +- std over the seeds that reached the step).
``--variants`` picks some of the runs, e.g. one per pinned CPU lane. A killed invocation resumes
its runs.
"""

from __future__ import annotations

import argparse
import os

import numpy as np

# same folder: the scripts run from it
from hopper_model_based import run_dir as table_run_dir
from hopper_model_based import seeds_on_disk, train_or_resume

from minatt_jax import runner
from minatt_jax.config import PRESETS, with_overrides

RESULTS = os.path.join(os.path.dirname(__file__), "results")
# (algo, agent updates per real step), cheapest first.
VARIANTS = (("mbpo", 2), ("sac", 20), ("mbpo", 20))
COLUMNS = ("return", "length", "feedback_norm")


def run_dir(runs: str, algo: str, updates: int, seed: int) -> str:
    return os.path.join(runs, f"hopper_{algo}_utd{updates}_seed{seed}")


def collect(runs: str, seeds: list[int], table_runs: str, steps: int) -> list[dict]:
    """Every evaluation record up to ``steps`` of every run directory that exists, led by the
    learning table's SAC alpha-0 runs (1 update per step) as the reference. A record without a
    ``device`` field ran here, on the CPU."""
    dirs = [("sac", 1, s, table_run_dir(table_runs, "sac", 0.0, s)) for s in seeds]
    dirs += [(a, u, s, run_dir(runs, a, u, s)) for a, u in VARIANTS for s in seeds]
    return [
        {"algo": algo, "updates_per_step": updates, "seed": seed, "device": "cpu", **record}
        for algo, updates, seed, directory in dirs
        for record in runner.read_metrics(directory)
        if record["step"] <= steps
    ]


def _mean_std(values: list[float]) -> str:
    """'mean' for one seed, 'mean +- std' for several."""
    if len(values) == 1:
        return f"{values[0]:.4g}"
    return f"{np.mean(values):.4g} +- {np.std(values):.2g}"


def _variant(text: str) -> tuple[str, int]:
    """Parse 'algo:updates' (e.g. 'mbpo:20') into one of VARIANTS."""
    algo, _, updates = text.partition(":")
    if not updates.isdigit() or (algo, int(updates)) not in VARIANTS:
        known = ", ".join(f"{a}:{u}" for a, u in VARIANTS)
        raise argparse.ArgumentTypeError(f"unknown variant {text!r}; choose from {known}")
    return algo, int(updates)


def write(records: list[dict], steps: int) -> None:
    os.makedirs(RESULTS, exist_ok=True)
    runner.write_json_atomic(os.path.join(RESULTS, "hopper_update_ratio.json"), records)
    lines = [
        "| algo | updates/step | step | seeds | " + " | ".join(COLUMNS) + " | ran on |",
        "|---" * (len(COLUMNS) + 5) + "|",
    ]
    for algo, updates in (("sac", 1), *VARIANTS):
        for step in sorted({r["step"] for r in records}):
            key = (algo, updates, step)
            rows = [r for r in records if (r["algo"], r["updates_per_step"], r["step"]) == key]
            if not rows:
                continue
            cells = [_mean_std([r[c] for r in rows]) for c in COLUMNS]
            devices = ", ".join(r["device"] for r in sorted(rows, key=lambda r: r["seed"]))
            lines.append(f"| {algo} | {updates} | {step} | {len(rows)} | " + " | ".join(cells)
                         + f" | {devices} |")  # fmt: skip
    runner.write_text_atomic(
        os.path.join(RESULTS, "hopper_update_ratio.md"),
        "# Hopper, alpha 0: agent updates per real step\n\n"
        f"`python experiments/hopper_update_ratio.py --steps {steps}` (cpu preset otherwise). "
        "Deterministic evaluation, 5 episodes; mean +- std over the seeds that reached "
        "the step. SAC with 1 update per step is the learning table's SAC alpha 0 "
        "(`hopper_model_based.py`). 'ran on' names each seed's machine: cpu = 2 CPU cores, "
        "jax 0.10.2; h100 = an H100 GPU with its own jax 0.11.2, the run's metrics "
        "copied back.\n\n"
        + "\n".join(lines) + "\n"
    )  # fmt: skip
    print("\n".join(lines), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--runs", default="runs/hopper_update_ratio")
    parser.add_argument(
        "--table-runs",
        default="runs/hopper_model_based",
        help="the learning table's runs: their SAC is the 1-update reference",
    )
    parser.add_argument("--variants", type=_variant, nargs="+", default=list(VARIANTS))
    parser.add_argument("--collect-only", action="store_true")
    args = parser.parse_args()
    if not args.collect_only:
        for seed in args.seeds:
            for algo, updates in args.variants:
                config = with_overrides(
                    PRESETS["cpu"], env="hopper", algo=algo, total_steps=args.steps, seed=seed,
                    ma_alpha=0.0, updates_per_step=updates,
                )  # fmt: skip
                train_or_resume(config, run_dir(args.runs, algo, updates, seed))
                write(collect_all(args), args.steps)
    write(collect_all(args), args.steps)


def collect_all(args: argparse.Namespace) -> list[dict]:
    seeds = seeds_on_disk(args.runs, args.seeds)
    return collect(args.runs, seeds, args.table_runs, args.steps)


if __name__ == "__main__":
    main()
