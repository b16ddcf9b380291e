"""Full SAC updates/s (actor, twin critics, entropy) at batch 256, with and without MA.

Every variant runs the same jitted ``lax.scan`` of ``--updates`` SAC updates on a fixed replay
batch source (Hopper dimensions, 11 obs / 3 act, 256x256 networks); variants are timed interleaved
(A B C ... A B C ...) for ``--rounds`` rounds and the median is reported, with the cost relative to
plain SAC measured in the same run. For each feedback estimator, its relative error against the
exact full-batch ||du/dx||_F^2 is measured over ``--error-draws`` draws at the same parameters.
Stable-Baselines3's SAC (PyTorch) with the same settings runs as an optional extra.

    python benchmarks/sac_update.py [--updates 200] [--rounds 5]

Writes ``benchmarks/results/sac_update.json`` and prints a table.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

from minatt_jax import min_attention as ma
from minatt_jax.config import TrainConfig
from minatt_jax.replay import Transitions
from minatt_jax.sac import SACConfig, make_sac
from minatt_jax.training import hyper_of

OBS, ACT, BATCH = 11, 3, 256
RESULTS = os.path.join(os.path.dirname(__file__), "results")

VARIANTS: dict[str, ma.MAConfig] = {
    "plain SAC (alpha=0)": ma.MAConfig(alpha=0.0),
    "MA default: jacrev on 32 states + temporal": ma.MAConfig(alpha=1.0),
    "MA default, feedback every 10 updates": ma.MAConfig(alpha=1.0, interval=10),
    "MA in the actor loss alone: jacrev on 32 states + temporal": ma.MAConfig(
        alpha=1.0, placement="actor_loss"
    ),
    "MA in the actor loss alone, feedback every 10 updates": ma.MAConfig(
        alpha=1.0, placement="actor_loss", interval=10
    ),
    "hutchinson 1 probe, 64 states": ma.MAConfig(alpha=1.0, estimator="hutchinson", subsample=64),
    "hutchinson 1 probe, full batch": ma.MAConfig(alpha=1.0, estimator="hutchinson", subsample=0),
    "jacfwd exact, 32 states": ma.MAConfig(alpha=1.0, estimator="jacfwd", subsample=32),
    "jacfwd exact, full batch": ma.MAConfig(alpha=1.0, estimator="jacfwd", subsample=0),
    "temporal term only": ma.MAConfig(alpha=1.0, mode="temporal"),
}


def make_runner(ma_config: ma.MAConfig, updates: int):
    """A jitted function running ``updates`` SAC updates; returns (init_state, run)."""
    sac = make_sac(OBS, ACT, SACConfig(), ma_config)
    data = Transitions(
        obs=jax.random.normal(jax.random.PRNGKey(1), (4096, OBS)),
        action=jax.random.uniform(jax.random.PRNGKey(2), (4096, ACT), minval=-1, maxval=1),
        reward=jax.random.normal(jax.random.PRNGKey(3), (4096,)),
        next_obs=jax.random.normal(jax.random.PRNGKey(4), (4096, OBS)),
        terminal=jnp.zeros((4096,)),
    )

    @jax.jit
    def run(state, key):
        def one(state, k):
            k_idx, k_up = jax.random.split(k)
            idx = jax.random.randint(k_idx, (BATCH,), 0, 4096)
            batch = jax.tree.map(lambda x: x[idx], data)
            return sac.update(state, batch, k_up)[0], None

        state, _ = jax.lax.scan(one, state, jax.random.split(key, updates))
        return state

    hyper = hyper_of(TrainConfig(ma=ma_config))
    return sac, sac.init(jax.random.PRNGKey(0), hyper), run


def estimator_error(sac, params, config: ma.MAConfig, draws: int) -> dict[str, float]:
    """Relative error of the configured feedback estimate against the exact full-batch value."""
    obs = jax.random.normal(jax.random.PRNGKey(7), (BATCH, OBS))
    exact = float(jnp.mean(ma.feedback_exact(sac.control, params, obs, "jacfwd")))

    def draw(k: jax.Array) -> jax.Array:
        # A fresh random order per draw, as each replay batch is: the subsample (the leading
        # states) then varies from draw to draw as it does from update to update.
        k_perm, k_est = jax.random.split(k)
        shuffled = obs[jax.random.permutation(k_perm, obs.shape[0])]
        return ma.feedback_term(config, sac.control, params, shuffled, k_est)

    estimates = jax.jit(jax.vmap(draw))(jax.random.split(jax.random.PRNGKey(8), draws))
    estimates = np.asarray(estimates)
    rel = (estimates - exact) / exact
    return {
        "exact_feedback": exact,
        "relative_bias": float(np.mean(rel)),
        "relative_rms_error": float(np.sqrt(np.mean(rel**2))),
    }


def sb3_updates_per_s(updates: int) -> float | None:
    """Stable-Baselines3 SAC updates/s with the same settings, or None when not installed."""
    try:
        import gymnasium as gym
        import torch
        from stable_baselines3 import SAC
    except ImportError:
        return None
    torch.set_num_threads(os.cpu_count() or 1)

    class Dummy(gym.Env):
        observation_space = gym.spaces.Box(-np.inf, np.inf, (OBS,), np.float32)
        action_space = gym.spaces.Box(-1, 1, (ACT,), np.float32)

        def reset(self, seed=None, options=None):
            return np.zeros(OBS, np.float32), {}

        def step(self, action):
            return np.random.randn(OBS).astype(np.float32), 0.0, False, False, {}

    model = SAC(
        "MlpPolicy", Dummy(), batch_size=BATCH, learning_starts=0, buffer_size=10_000,
        policy_kwargs={"net_arch": [256, 256]}, device="cpu", verbose=0,
    )  # fmt: skip
    model.learn(total_timesteps=BATCH + 10)  # fills the buffer
    model.train(gradient_steps=20, batch_size=BATCH)  # warm-up
    t0 = time.perf_counter()
    model.train(gradient_steps=updates, batch_size=BATCH)
    return updates / (time.perf_counter() - t0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--updates", type=int, default=200)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--error-draws", type=int, default=2000)
    parser.add_argument("--only", nargs="*", default=None, help="variant name prefixes to run")
    parser.add_argument("--out", default=os.path.join(RESULTS, "sac_update.json"))
    args = parser.parse_args()
    variants = {
        k: v
        for k, v in VARIANTS.items()
        if args.only is None or k.startswith("plain") or any(k.startswith(p) for p in args.only)
    }

    runners, compile_s = {}, {}
    for name, cfg in variants.items():
        sac, state, run = make_runner(cfg, args.updates)
        t0 = time.perf_counter()
        state = jax.block_until_ready(run(state, jax.random.PRNGKey(0)))
        compile_s[name] = time.perf_counter() - t0
        runners[name] = (sac, state, run)
    times: dict[str, list[float]] = {name: [] for name in variants}
    for r in range(args.rounds):
        for name, (_, state, run) in runners.items():
            t0 = time.perf_counter()
            jax.block_until_ready(run(state, jax.random.PRNGKey(r + 1)))
            times[name].append(time.perf_counter() - t0)
    plain = statistics.median(times["plain SAC (alpha=0)"])
    rows = []
    for name, cfg in variants.items():
        median = statistics.median(times[name])
        row = {
            "variant": name,
            "config": dataclasses.asdict(cfg),
            "updates_per_s": args.updates / median,
            "cost_vs_plain": median / plain,
            "compile_s": compile_s[name],
            "round_times_s": times[name],
        }
        if cfg.uses_feedback:
            sac, state, _ = runners[name]
            row.update(estimator_error(sac, state.actor_params, cfg, args.error_draws))
        rows.append(row)
    sb3 = sb3_updates_per_s(args.updates)

    print(f"\nSAC updates/s, batch {BATCH}, 256x256, {args.updates} updates x {args.rounds} rounds")
    print(f"{'variant':55s} {'upd/s':>7s} {'cost':>6s} {'rel.err':>8s}")
    for row in rows:
        err = f"{row['relative_rms_error']:8.3f}" if "relative_rms_error" in row else f"{'-':>8s}"
        print(f"{row['variant']:55s} {row['updates_per_s']:7.1f} {row['cost_vs_plain']:6.3f} {err}")
    if sb3 is None:
        print("Stable-Baselines3 not installed: skipped (pip install torch stable-baselines3)")
    else:
        print(f"{'Stable-Baselines3 SAC (PyTorch)':55s} {sb3:7.1f}")
        print(f"plain SAC / SB3 = {rows[0]['updates_per_s'] / sb3:.2f}x")
    out = {
        "benchmark": "sac_update",
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform()},
        "versions": {"jax": jax.__version__},
        "batch": BATCH,
        "updates_per_round": args.updates,
        "rounds": args.rounds,
        "rows": rows,
        "sb3_updates_per_s": sb3,
        "plain_over_sb3": None if sb3 is None else rows[0]["updates_per_s"] / sb3,
    }
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    tmp = args.out + ".tmp"
    with open(tmp, "w") as f:
        json.dump(out, f, indent=2)
    os.replace(tmp, args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
