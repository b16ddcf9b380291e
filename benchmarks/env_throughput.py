"""Env steps/s and compile time of the MJX environments against the MuJoCo C engine.

For each environment and batch size, a vmapped ``lax.scan`` of ``--steps`` env steps (random
actions drawn beforehand, no resets) is timed after compilation (median of ``--repeats``); in the
same run ``mujoco.rollout`` steps the same MjModel from the same initial states with the same
controls for the same number of physics steps, on 1 and on 2 threads. Physics presets ``fast``
(the default), ``gym`` (Gym's own solver settings) and ``fastest`` (one Newton iteration) are
compared side by side for Hopper.

    python benchmarks/env_throughput.py            # all envs, batches 1 8 32 128
    python benchmarks/env_throughput.py --envs hopper --batches 1 32 --compare-presets gym

Writes ``benchmarks/results/env_throughput.json`` and prints a table.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

import minatt_jax.envs as envs

RESULTS = os.path.join(os.path.dirname(__file__), "results")


def time_mjx(env: envs.LocomotionEnv, batch: int, steps: int, repeats: int) -> dict:
    """Compile and run a vmapped scan of ``steps`` env steps; returns timings and the states."""
    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    actions = jax.random.uniform(
        jax.random.PRNGKey(1), (batch, steps, env.action_size), minval=-1.0, maxval=1.0
    )
    task = env.nominal_task()

    def run(key, acts):
        state0 = env.reset(key, task)

        def body(state, a):
            return env.step(state, a), None

        state, _ = jax.lax.scan(body, state0, acts)
        return state0.pipeline_state, state.pipeline_state.qpos

    t0 = time.perf_counter()
    compiled = jax.jit(jax.vmap(run)).lower(keys, actions).compile()
    compile_s = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        data0, _ = jax.block_until_ready(compiled(keys, actions))
        times.append(time.perf_counter() - t0)
    run_s = statistics.median(times)
    return {
        "compile_s": compile_s,
        "run_s": run_s,
        "env_steps_per_s": batch * steps / run_s,
        "physics_steps_per_s": batch * steps * env.frame_skip / run_s,
        "data0": data0,
        "actions": np.asarray(actions),
    }


def time_c_engine(
    env: envs.LocomotionEnv, data0, actions: np.ndarray, nthread: int, repeats: int
) -> float:
    """Physics steps/s of ``mujoco.rollout`` over the same initial states and controls."""
    m = env.mj_model
    batch, steps, nu = actions.shape
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    datas = [mujoco.MjData(m) for _ in range(nthread)]
    state = np.zeros((batch, mujoco.mj_stateSize(m, spec)))
    for b in range(batch):
        d = datas[0]
        d.qpos[:] = np.asarray(data0.qpos[b])
        d.qvel[:] = np.asarray(data0.qvel[b])
        mujoco.mj_getState(m, d, state[b], spec)
    control = np.repeat(actions.astype(np.float64), env.frame_skip, axis=1)  # hold per frame
    times = []
    with mj_rollout.Rollout(nthread=nthread) as pool:
        for _ in range(repeats):
            t0 = time.perf_counter()
            pool.rollout(m, datas, state, control)
            times.append(time.perf_counter() - t0)
    return batch * steps * env.frame_skip / statistics.median(times)


def time_reset_step_compile(env: envs.LocomotionEnv) -> dict:
    """Seconds to jit-compile a single reset and a single step (what a first call costs)."""
    t0 = time.perf_counter()
    reset = jax.jit(env.reset).lower(jax.random.PRNGKey(0)).compile()
    reset_s = time.perf_counter() - t0
    state = reset(jax.random.PRNGKey(0))
    t0 = time.perf_counter()
    jax.jit(env.step).lower(state, jnp.zeros(env.action_size)).compile()
    return {"reset_compile_s": reset_s, "step_compile_s": time.perf_counter() - t0}


def write_results(args: argparse.Namespace, rows: list, compiles: list, final: bool) -> None:
    """Writes the JSON (after every row, so an interrupted run keeps what it measured)."""
    summary = []
    for name in dict.fromkeys(r["env"] for r in rows):
        for preset in dict.fromkeys(r["preset"] for r in rows if r["env"] == name):
            sel = [r for r in rows if r["env"] == name and r["preset"] == preset]
            best = max(sel, key=lambda r: r["mjx_physics_steps_per_s"])
            c_best = max(
                max(r["c_physics_steps_per_s_1thread"], r["c_physics_steps_per_s_2threads"])
                for r in sel
            )
            summary.append(
                {
                    "env": name,
                    "preset": preset,
                    "best_batch": best["batch"],
                    "best_mjx_physics_steps_per_s": best["mjx_physics_steps_per_s"],
                    "best_c_physics_steps_per_s": c_best,
                    "ratio_best_mjx_over_best_c": best["mjx_physics_steps_per_s"] / c_best,
                    "ratio_at_best_batch": best["mjx_over_c_best"],
                }
            )
    if final:
        print("\nbest batch per env (physics steps/s; C = best of 1 and 2 threads, all batches)")
        print(f"{'env':12s} {'preset':8s} {'batch':>5s} {'MJX':>9s} {'C':>9s} {'MJX/C':>6s}")
        for s in summary:
            print(
                f"{s['env']:12s} {s['preset']:8s} {s['best_batch']:5d} "
                f"{s['best_mjx_physics_steps_per_s']:9.0f} {s['best_c_physics_steps_per_s']:9.0f} "
                f"{s['ratio_best_mjx_over_best_c']:6.3f}"
            )
    out = {
        "benchmark": "env_throughput",
        "complete": final,
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform()},
        "versions": {"jax": jax.__version__, "mujoco": mujoco.__version__},
        "steps_per_rollout": args.steps,
        "compile": compiles,
        "rows": rows,
        "summary": summary,
    }
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    tmp = args.out + ".tmp"
    with open(tmp, "w") as f:
        json.dump(out, f, indent=2)
    os.replace(tmp, args.out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=list(envs.ENV_NAMES))
    parser.add_argument("--batches", nargs="+", type=int, default=[1, 8, 32, 128])
    parser.add_argument("--presets", nargs="+", default=["fast"])
    parser.add_argument("--compare-envs", nargs="*", default=["hopper"])
    parser.add_argument("--compare-presets", nargs="*", default=["gym", "fastest"])
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", default=os.path.join(RESULTS, "env_throughput.json"))
    args = parser.parse_args()

    rows = []
    compiles = []
    for name in args.envs:
        presets = list(args.presets)
        if name in args.compare_envs:
            presets += [p for p in args.compare_presets if p not in presets]
        for preset in presets:
            env = envs.make(name, preset)
            compiles.append({"env": name, "preset": preset, **time_reset_step_compile(env)})
            c = compiles[-1]
            print(
                f"{name:12s} {preset:5s} jit reset {c['reset_compile_s']:5.1f} s + step "
                f"{c['step_compile_s']:5.1f} s",
                flush=True,
            )
            for batch in args.batches:
                mjx_t = time_mjx(env, batch, args.steps, args.repeats)
                c1 = time_c_engine(env, mjx_t["data0"], mjx_t["actions"], 1, args.repeats)
                c2 = time_c_engine(env, mjx_t["data0"], mjx_t["actions"], 2, args.repeats)
                row = {
                    "env": name,
                    "preset": preset,
                    "batch": batch,
                    "scan_compile_s": mjx_t["compile_s"],
                    "mjx_env_steps_per_s": mjx_t["env_steps_per_s"],
                    "mjx_physics_steps_per_s": mjx_t["physics_steps_per_s"],
                    "c_physics_steps_per_s_1thread": c1,
                    "c_physics_steps_per_s_2threads": c2,
                    "mjx_over_c_best": mjx_t["physics_steps_per_s"] / max(c1, c2),
                }
                rows.append(row)
                print(
                    f"{name:12s} {preset:5s} B={batch:4d} mjx {row['mjx_env_steps_per_s']:8.0f} "
                    f"env st/s = {row['mjx_physics_steps_per_s']:8.0f} phys | C 1thr {c1:8.0f} "
                    f"2thr {c2:8.0f} | mjx/C {row['mjx_over_c_best']:.3f} | compile "
                    f"{row['scan_compile_s']:.1f} s",
                    flush=True,
                )
                write_results(args, rows, compiles, final=False)  # partial results survive

    write_results(args, rows, compiles, final=True)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
