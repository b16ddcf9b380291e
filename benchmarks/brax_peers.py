"""minatt-jax's PPO and SAC side by side with brax's own trainers (``brax.training.agents``),
in one process, on the same machine and threads.

* PPO: brax's ``ppo.train`` on brax's ``hopper`` (MJX backend) against ``--algo ppo`` (alpha 0)
  on minatt-jax's hopper, with the same number of environments, unroll length, batch,
  minibatches, epochs, discount, learning rate, entropy cost, reward scale and observation
  normalization; env steps/s of the training after compilation, and the return at the same env
  steps. MA's cost: ``--algo ppo`` at ``--alpha`` against alpha 0, the same seed.
* SAC: brax's ``sac.train`` against ``--algo sac`` (alpha 0): one environment, one update per env
  step, batch 256, 256 x 256 networks, Adam 3e-4, discount 0.99, ``--sac-warmup`` random steps;
  env steps/s and updates/s after compilation, and the return.
* One simulator for the returns: each final policy also acts deterministically in Gymnasium's
  Hopper-v5 on the MuJoCo C engine (brax's policy through its own inference function on the
  C engine's observations, which have the same layout).

The two hoppers are not one model: brax's ``hopper`` is Gym v2-like (its own MJCF and
``reset_noise_scale`` 5e-3, healthy range and reward weights of Gym's v2/v3 hopper), minatt-jax's
is Gymnasium's v5 model and rules (``minatt_jax/envs/hopper.py``); throughput compares each
program on its own environment, returns meet on the C engine.

brax 0.14.2's trainers call ``jax.device_put_replicated``, which jax 0.10.2 removed; this script
alone defines it (``x`` stacked once per device, then ``jax.device_put``) so that they run.

    python benchmarks/brax_peers.py --seeds 0 1 2 --ppo-steps 1024000 --sac-steps 20000

Writes ``benchmarks/results/brax_peers_<device>.json`` and prints a table.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")


def shim_device_put_replicated() -> None:
    """brax 0.14.2 calls ``jax.device_put_replicated`` (removed in jax 0.10): define it here."""
    if hasattr(jax, "device_put_replicated"):
        return

    def device_put_replicated(x, devices):
        stacked = jax.tree.map(lambda a: jnp.stack([jnp.asarray(a)] * len(devices)), x)
        return jax.device_put(stacked, devices[0] if len(devices) == 1 else None)

    jax.device_put_replicated = device_put_replicated


def c_engine_return(act, episodes: int, seed: int) -> dict:
    """Mean and std of the return of ``act`` (observation -> action, numpy) in Hopper-v5."""
    from minatt_jax import envs
    from minatt_jax.mujoco_engine import make_gym_env

    env = make_gym_env("hopper", 1000, envs.make("hopper").nominal_task())
    returns = []
    for i in range(episodes):
        obs, _ = env.reset(seed=seed * 1000 + i)
        total, done = 0.0, False
        while not done:
            obs, reward, terminated, truncated, _ = env.step(np.asarray(act(obs), np.float64))
            total += reward
            done = terminated or truncated
        returns.append(total)
    env.close()
    return {"mean": float(np.mean(returns)), "std": float(np.std(returns)), "episodes": episodes}


def _brax_run(train: Any, episodes: int, seed: int, **kwargs: Any) -> dict:
    """One brax training run on brax's MJX hopper (3 evaluations, 8 episodes each) and its
    record (``_brax_record``)."""
    from brax import envs as brax_envs

    marks: list[tuple[int, float, float]] = []

    def progress(step, metrics):
        marks.append((step, float(metrics.get("training/sps", 0)),
                      float(metrics.get("eval/episode_reward", 0))))  # fmt: skip

    t0 = time.perf_counter()
    make_inference, params, _ = train(
        environment=brax_envs.get_environment("hopper", backend="mjx"), num_evals=3,
        episode_length=1000, num_eval_envs=8, seed=seed, progress_fn=progress, **kwargs,
    )  # fmt: skip
    return _brax_record(marks, make_inference, params, time.perf_counter() - t0, episodes, seed)


def brax_ppo(seed: int, steps: int, s: dict, episodes: int) -> dict:
    """brax's PPO; its own evaluation samples actions (its default), the C engine's does not."""
    from brax.training.agents.ppo import train as ppo

    return _brax_run(
        ppo.train, episodes, seed, num_timesteps=steps, num_envs=s["num_envs"],
        unroll_length=s["unroll_length"], batch_size=s["batch_size"],
        num_minibatches=s["minibatches"], num_updates_per_batch=s["epochs"],
        discounting=s["gamma"], learning_rate=s["lr"], entropy_cost=s["entropy_cost"],
        reward_scaling=s["reward_scaling"], normalize_observations=True,
    )  # fmt: skip


def _brax_record(marks, make_inference, params, total_s, episodes, seed) -> dict:
    """progress_fn runs after each of the 3 evaluations (at 0, half way, the end): brax's own
    ``training/sps`` of the second half (the first half compiles the training step), which
    times the training alone, as minatt-jax's ``env_steps_per_s`` does."""
    (_, _, _), (mid, _, _), (last, rate, reward) = marks[-3:]
    policy = jax.jit(make_inference(params, deterministic=True))

    def act(obs):
        return np.asarray(policy(jnp.asarray(obs, jnp.float32), jax.random.PRNGKey(0))[0])

    return {"env_steps": last, "timed_env_steps": last - mid,
            "env_steps_per_s": rate, "total_s": total_s, "return_own_env": reward,
            "return_c_engine": c_engine_return(act, episodes, seed)}  # fmt: skip


def brax_sac(seed: int, steps: int, warmup: int, episodes: int) -> dict:
    from brax.training.agents.sac import train as sac

    record = _brax_run(
        sac.train, episodes, seed, num_timesteps=steps, num_envs=1, learning_rate=3e-4,
        discounting=0.99, batch_size=256, reward_scaling=1.0, tau=0.005,
        min_replay_size=warmup, max_replay_size=steps, grad_updates_per_step=1,
        deterministic_eval=True,
    )  # fmt: skip
    return {**record, "updates_per_s": record["env_steps_per_s"]}  # one update per env step


def ours(algo: str, seed: int, steps: int, fields: dict, episodes: int, out: str) -> dict:
    from minatt_jax import api, checkpoint

    t0 = time.perf_counter()
    # Two chunks: the second one's rate is the training alone, compiled (as brax's below).
    run = api.train(preset="cpu", algo=algo, env="hopper", seed=seed, total_steps=steps,
                    eval_every=steps // 2, out=out, log=lambda m: None, **fields)  # fmt: skip
    end = time.perf_counter()
    record = run.metrics[-1]
    policy = checkpoint.load_policy(out)
    control = jax.jit(policy.control)
    return {"env_steps": record["step"], "env_steps_per_s": record["env_steps_per_s"],
            "updates_per_s": record["updates_per_s"], "total_s": end - t0,
            "return_own_env": record["return"], "feedback_norm": record["feedback_norm"],
            "return_c_engine": c_engine_return(lambda o: np.asarray(control(jnp.asarray(
                o, jnp.float32))), episodes, seed)}  # fmt: skip


def summary_rows(rows: dict[str, list[dict]]) -> list[dict]:
    """One row per program: mean and spread over seeds of the rate and the returns."""
    out = []
    for name, runs in rows.items():
        if not runs:
            continue
        rate = [r["env_steps_per_s"] for r in runs]
        own = [r["return_own_env"] for r in runs]
        c = [r["return_c_engine"]["mean"] for r in runs]
        out.append({"program": name, "seeds": len(runs), "env_steps": runs[0]["env_steps"],
                    "env_steps_per_s": float(np.mean(rate)),
                    "env_steps_per_s_std": float(np.std(rate, ddof=1)) if len(rate) > 1 else 0.0,
                    "return_own_env": float(np.mean(own)),
                    "return_own_env_std": float(np.std(own, ddof=1)) if len(own) > 1 else 0.0,
                    "return_c_engine": float(np.mean(c)),
                    "return_c_engine_std": float(np.std(c, ddof=1)) if len(c) > 1 else 0.0,
                    **({"feedback_norm": float(np.mean([r["feedback_norm"] for r in runs]))}
                       if "feedback_norm" in runs[0] else {})})  # fmt: skip
    return out


PPO = {"num_envs": 16, "unroll_length": 5, "batch_size": 64, "minibatches": 8, "epochs": 4,
       "gamma": 0.97, "lr": 3e-4, "entropy_cost": 1e-2, "reward_scaling": 10.0}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--ppo-steps", type=int, default=1_024_000)
    parser.add_argument("--sac-steps", type=int, default=20_000)
    parser.add_argument("--sac-warmup", type=int, default=5_000)
    parser.add_argument("--alpha", type=float, default=0.05, help="MA's cost: ppo at this alpha")
    parser.add_argument("--episodes", type=int, default=5, help="C-engine episodes per policy")
    parser.add_argument("--runs", default="runs/brax_peers")
    parser.add_argument("--skip", nargs="*", default=[], choices=("ppo", "sac", "ma"))
    parser.add_argument("--summarize", metavar="JSON", default=None,
                        help="rewrite the summary of an earlier result file and stop")  # fmt: skip
    args = parser.parse_args()
    if args.summarize:
        with open(args.summarize) as f:
            result = json.load(f)
        result["summary"] = summary_rows(result["rows"])
        with open(args.summarize, "w") as f:
            json.dump(result, f, indent=1)
        return
    shim_device_put_replicated()
    ppo_fields = {"num_envs": PPO["num_envs"], "ppo_unroll_length": PPO["unroll_length"],
                  "ppo_batch_size": PPO["batch_size"], "ppo_minibatches": PPO["minibatches"],
                  "ppo_epochs": PPO["epochs"], "ppo_gamma": PPO["gamma"], "ppo_lr": PPO["lr"],
                  "ppo_entropy_cost": PPO["entropy_cost"],
                  "ppo_reward_scaling": PPO["reward_scaling"]}  # fmt: skip
    sac_fields = {"warmup_steps": args.sac_warmup, "buffer_size": args.sac_steps}
    rows: dict[str, list] = {"brax_ppo": [], "minatt_ppo": [], "minatt_ppo_ma": [],
                             "brax_sac": [], "minatt_sac": []}  # fmt: skip
    for seed in args.seeds:
        if "ppo" not in args.skip:
            rows["minatt_ppo"].append(ours("ppo", seed, args.ppo_steps, ppo_fields, args.episodes,
                                           f"{args.runs}/ppo_alpha0_seed{seed}"))  # fmt: skip
            rows["brax_ppo"].append(brax_ppo(seed, args.ppo_steps, PPO, args.episodes))
        if "ma" not in args.skip and seed == args.seeds[0]:
            rows["minatt_ppo_ma"].append(ours(
                "ppo", seed, args.ppo_steps, {**ppo_fields, "ma_alpha": args.alpha},
                args.episodes, f"{args.runs}/ppo_alpha{args.alpha:g}_seed{seed}"))  # fmt: skip
        if "sac" not in args.skip:
            rows["minatt_sac"].append(ours("sac", seed, args.sac_steps, sac_fields, args.episodes,
                                           f"{args.runs}/sac_alpha0_seed{seed}"))  # fmt: skip
            rows["brax_sac"].append(brax_sac(seed, args.sac_steps, args.sac_warmup, args.episodes))
        print(json.dumps({k: v[-1] for k, v in rows.items() if v}, indent=1), flush=True)
    device = f"{jax.devices()[0].platform}-{os.cpu_count()}core-{platform.machine()}"
    result = {"device": device, "cpu_count": os.cpu_count(), "jax": jax.__version__,
              "command": "python benchmarks/brax_peers.py " + " ".join(
                  f"--{k.replace('_', '-')} {' '.join(map(str, v)) if isinstance(v, list) else v}"
                  for k, v in vars(args).items() if k not in ("runs", "skip", "summarize")),
              "ppo_settings": PPO, "alpha": args.alpha, "summary": summary_rows(rows), "rows": rows,
              "note": "brax ran with a jax.device_put_replicated shim (jax 0.10 removed it)",
              }  # fmt: skip
    os.makedirs(RESULTS, exist_ok=True)
    path = os.path.join(RESULTS, f"brax_peers_{jax.devices()[0].platform}.json")
    with open(path, "w") as f:
        json.dump(result, f, indent=1)
    print(
        f"\n{'program':16s} {'env steps/s':>12s} {'return (own env)':>18s} "
        f"{'return (C engine)':>18s}"
    )
    for name, runs in rows.items():
        if runs:
            rate = np.mean([r["env_steps_per_s"] for r in runs])
            own = np.mean([r["return_own_env"] for r in runs])
            c = np.mean([r["return_c_engine"]["mean"] for r in runs])
            print(f"{name:16s} {rate:12.0f} {own:18.1f} {c:18.1f}")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
