"""Policies trained in MJX, evaluated in MJX and in Gymnasium's v5 environments (MuJoCo C engine).

    python experiments/engine_transfer.py [--envs hopper halfcheetah walker2d] [--steps 20000]
        [--alphas 0 1] [--seed 0] [--episodes 10] [--runs runs/engine_transfer]

Trains (or resumes) one SAC run per (environment, alpha) with the cpu preset, then evaluates its
final policy with ``runner.evaluate_run`` in both engines on the nominal task and on one
perturbation per environment, with the same episodes' reset seeds. Writes
``experiments/results/engine_transfer.{json,md}``.
"""

from __future__ import annotations

import argparse
import os
import time

from minatt_jax import runner
from minatt_jax.config import PRESETS, with_overrides

RESULTS = os.path.join(os.path.dirname(__file__), "results")
PERTURBATION = {
    "hopper": "mass=1.25",
    "halfcheetah": "crippled=bthigh",
    "walker2d": "slope=0.05",
    "humanoid": "mass=1.1",
}
COLUMNS = ("return", "length", "feedback_norm", "energy")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=["hopper", "halfcheetah", "walker2d"])
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--alphas", type=float, nargs="+", default=[0.0, 1.0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--runs", default="runs/engine_transfer")
    args = parser.parse_args()
    rows = []
    for env in args.envs:
        for alpha in args.alphas:
            config = with_overrides(PRESETS["cpu"], env=env, total_steps=args.steps,
                                    seed=args.seed, ma_alpha=alpha)  # fmt: skip
            run_dir = os.path.join(args.runs, f"{env}_sac_alpha{alpha:g}_seed{args.seed}")
            os.makedirs(run_dir, exist_ok=True)
            resume = os.path.exists(os.path.join(run_dir, "config.json"))
            runner.train(config, run_dir, resume=resume)
            for task in ((), (PERTURBATION[env],)):
                for engine in ("mjx", "mujoco"):
                    start = time.perf_counter()
                    m = runner.evaluate_run(run_dir, None, args.episodes, 0, task, engine)
                    m.update(
                        env=env, alpha=alpha, seed=args.seed, seconds=time.perf_counter() - start
                    )
                    rows.append(m)
                    print(f"{env} alpha={alpha:g} {m['variant']} {engine}: "
                          f"return {m['return']:.1f} +- {m['return_std']:.1f}")  # fmt: skip
    os.makedirs(RESULTS, exist_ok=True)
    runner.write_json_atomic(os.path.join(RESULTS, "engine_transfer.json"), rows)
    lines = ["| env | alpha | task | " + " | ".join(f"{c} MJX | {c} C" for c in COLUMNS) + " |",
             "|---" * (3 + 2 * len(COLUMNS)) + "|"]  # fmt: skip
    for mjx_row, c_row in zip(rows[::2], rows[1::2], strict=True):
        cells = " | ".join(
            f"{r[c]:.3g} +- {r[c + '_std']:.2g}" for c in COLUMNS for r in (mjx_row, c_row)
        )
        lines.append(
            f"| {mjx_row['env']} | {mjx_row['alpha']:g} | {mjx_row['variant']} | {cells} |"
        )
    runner.write_text_atomic(
        os.path.join(RESULTS, "engine_transfer.md"),
        "# MJX against the MuJoCo C engine (Gymnasium v5)\n\n"
        f"`python experiments/engine_transfer.py --steps {args.steps}`: SAC, cpu preset, seed "
        f"{args.seed}, the final policy; mean +- std over {args.episodes} deterministic episodes "
        "(reset seeds 0..n-1 in the C engine; the run's evaluation keys in MJX). MJX runs our "
        "Gym-v3 environments with the `fast` solver settings; the C engine runs Gymnasium's "
        "v5 environments with Gym's own (see `minatt_jax/mujoco_engine.py`).\n\n"
        + "\n".join(lines)
        + "\n",
    )
    print("\n".join(lines))


if __name__ == "__main__":
    main()
