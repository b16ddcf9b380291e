"""DreamerV3 with and without minimum attention on cheetah_run, against a random policy.

    python experiments/dreamer_cheetah_run.py [--preset cpu] [--steps 20000] [--alphas 0 0.05]
        [--seeds 0] [--runs runs/dreamer_cheetah_run] [--set dreamer.train_ratio=...]

Trains (or resumes: run it again after a stop) one run per (alpha, seed) with ``minatt-jax
train``'s runner; evaluates a uniform random policy on the same 1000-step episodes; writes
``experiments/results/dreamer_cheetah_run_<preset>.{json,md}`` with each run's learning curve
(deterministic evaluation every ``eval_every`` steps) and the final metrics beside DreamerV3's
published cheetah-run curve (5 seeds: 308 +- 78 at 100K, 596 +- 44 at 500K steps).
"""

from __future__ import annotations

import argparse
import json
import os

import jax
import jax.numpy as jnp
import numpy as np

import minatt_jax.envs as envs
from minatt_jax import acting, runner
from minatt_jax.config import PRESETS, apply_overrides, with_overrides

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")
PUBLISHED = {"100K": "308 +- 78", "250K": "489 +- 57", "500K": "596 +- 44"}  # DreamerV3, 5 seeds


def random_returns(episodes: int, steps: int) -> np.ndarray:
    """Returns of a uniform random policy on cheetah_run episodes of ``steps`` steps."""
    env = envs.make("cheetah_run")
    policy = acting.random_policy(env.action_size)

    def episode(key):
        k_reset, k_act = jax.random.split(key)
        traj = acting.unroll(env, policy, env.reset(k_reset), steps, key=k_act)
        return jnp.sum(traj.reward)

    keys = jax.random.split(jax.random.PRNGKey(123), episodes)
    return np.asarray(jax.jit(jax.vmap(episode))(keys))


def stored_rows(preset: str, trained: set[tuple[float, int]]) -> list[dict]:
    """The rows of the preset's result file for the (alpha, seed) pairs not trained in this
    call, marked ``stored``: runs trained elsewhere stay in the table beside new ones."""
    path = os.path.join(RESULTS, f"dreamer_cheetah_run_{preset}.json")
    if not os.path.exists(path):
        return []
    with open(path) as f:
        old = json.load(f)
    return [{**r, "stored": True} for r in old.get("runs", [])
            if (r["alpha"], r["seed"]) not in trained]  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="cpu", choices=sorted(PRESETS))
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--alphas", type=float, nargs="+", default=[0.0, 0.05])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--runs", default="runs/dreamer_cheetah_run")
    parser.add_argument("--set", action="append", default=[], dest="overrides")
    parser.add_argument("--collect-only", action="store_true",
                        help="tabulate the runs as they stand, without training")  # fmt: skip
    args = parser.parse_args()
    rows = []
    for alpha in args.alphas:
        for seed in args.seeds:
            config = with_overrides(PRESETS[args.preset], env="cheetah_run", algo="dreamer",
                                    total_steps=args.steps, seed=seed, ma_alpha=alpha)  # fmt: skip
            config = apply_overrides(config, args.overrides)
            run_dir = os.path.join(args.runs, f"{args.preset}_alpha{alpha:g}_seed{seed}")
            os.makedirs(run_dir, exist_ok=True)
            resume = os.path.exists(os.path.join(run_dir, "config.json"))
            if not args.collect_only:
                runner.train(config, run_dir, resume=resume)
            curve = runner.read_metrics(run_dir)
            keep = ("step", "return", "return_std", "feedback_norm", "feedforward_norm",
                    "energy", "wm_loss", "train_episode_return", "updates_per_s",
                    "env_steps_per_s")  # fmt: skip
            # the run's directory under --runs (no machine path in the results)
            rows.append({"alpha": alpha, "seed": seed, "run": os.path.basename(run_dir),
                         "config": {"dreamer": config.dreamer.__dict__,
                                    "num_envs": config.num_envs,
                                    "warmup_steps": config.warmup_steps},
                         "curve": [{k: r[k] for k in keep if k in r} for r in curve]})  # fmt: skip
    rows = stored_rows(args.preset, {(r["alpha"], r["seed"]) for r in rows}) + rows
    episodes = PRESETS[args.preset].eval_episodes
    rand = random_returns(max(episodes, 10), PRESETS[args.preset].max_episode_steps)
    result = {
        "command": "python experiments/dreamer_cheetah_run.py --preset "
        f"{args.preset} --steps {args.steps} --alphas {' '.join(map(str, args.alphas))} "
        f"--seeds {' '.join(map(str, args.seeds))}"
        + "".join(f" --set {o}" for o in args.overrides),
        "device": str(jax.devices()[0].device_kind),
        "random_policy_return": {
            "mean": float(rand.mean()),
            "std": float(rand.std()),
            "max": float(rand.max()),
            "episodes": len(rand),
        },  # fmt: skip
        "published_dreamerv3": PUBLISHED,
        "runs": rows,
    }
    os.makedirs(RESULTS, exist_ok=True)
    name = f"dreamer_cheetah_run_{args.preset}"
    runner.write_json_atomic(os.path.join(RESULTS, f"{name}.json"), result)
    lines = [
        f"# DreamerV3 on cheetah_run ({args.preset} preset)\n",
        f"`{result['command']}` on {result['device']}. Deterministic evaluation "
        f"({episodes} episodes of 1000 steps) every chunk; a uniform random policy returns "
        f"{rand.mean():.1f} +- {rand.std():.1f} (max {rand.max():.1f}, {len(rand)} episodes). "
        f"DreamerV3's published curve: {PUBLISHED}. Seeds marked (stored): rows kept from "
        "this file's earlier version, trained by another call of this script with an earlier "
        "version of the code; an arm of stored rows is not compared with an arm trained "
        "anew (retrain both arms in one call to compare them).\n",
        "| alpha | seed | step | return | feedback | feedforward | energy | updates/s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        for r in row["curve"]:
            lines.append(
                f"| {row['alpha']:g} | {row['seed']}{' (stored)' if row.get('stored') else ''} "
                f"| {r['step']} | {r['return']:.1f} +- "
                f"{r['return_std']:.1f} | {r['feedback_norm']:.4g} | {r['feedforward_norm']:.4g} "
                f"| {r['energy']:.3f} | {r['updates_per_s']:.1f} |"
            )
    runner.write_text_atomic(os.path.join(RESULTS, f"{name}.md"), "\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
