"""Hopper SAC with and without minimum attention: same seed, same steps, same settings.

    python experiments/hopper_sac_alpha.py [--steps 20000] [--seeds 0] [--alphas 0 1]

Each run is a normal run directory under ``--runs`` (resumable with ``minatt-jax train --resume``);
the evaluation records at every ``eval_every`` steps are collected into
``experiments/results/hopper_sac_alpha.json`` and a markdown table beside it.
"""

from __future__ import annotations

import argparse
import os

from minatt_jax import runner
from minatt_jax.config import PRESETS, with_overrides

RESULTS = os.path.join(os.path.dirname(__file__), "results")
COLUMNS = ("return", "feedback_norm", "feedforward_norm", "energy", "jerk", "smoothness")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--alphas", type=float, nargs="+", default=[0.0, 1.0])
    parser.add_argument("--runs", default="runs/experiments")
    args = parser.parse_args()
    results = []
    for seed in args.seeds:
        for alpha in args.alphas:
            config = with_overrides(
                PRESETS["cpu"], env="hopper", total_steps=args.steps, seed=seed, ma_alpha=alpha
            )
            run_dir = os.path.join(args.runs, f"hopper_sac_alpha{alpha:g}_seed{seed}")
            os.makedirs(run_dir, exist_ok=True)
            resume = os.path.exists(os.path.join(run_dir, "config.json"))
            runner.train(config, run_dir, resume=resume)
            for record in runner.read_metrics(run_dir):
                results.append({"alpha": alpha, "seed": seed, **record})
    os.makedirs(RESULTS, exist_ok=True)
    runner.write_json_atomic(os.path.join(RESULTS, "hopper_sac_alpha.json"), results)
    lines = [
        "| alpha | seed | step | " + " | ".join(COLUMNS) + " | updates/s |",
        "|---" * (len(COLUMNS) + 4) + "|",
    ]
    for r in results:
        values = " | ".join(f"{r[c]:.4g} +- {r[c + '_std']:.2g}" for c in COLUMNS)
        lines.append(
            f"| {r['alpha']:g} | {r['seed']} | {r['step']} | {values} | {r['updates_per_s']:.0f} |"
        )
    runner.write_text_atomic(
        os.path.join(RESULTS, "hopper_sac_alpha.md"),
        "# Hopper SAC, alpha = 0 against alpha = 1\n\n"
        f"`python experiments/hopper_sac_alpha.py --steps {args.steps}` (cpu preset; "
        "deterministic evaluation, mean +- std over 5 episodes).\n\n" + "\n".join(lines) + "\n",
    )
    print("\n".join(lines))


if __name__ == "__main__":
    main()
