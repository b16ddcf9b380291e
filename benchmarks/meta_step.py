"""Throughput of the model-based loop: the full jitted step, its parts, scaling, and mbrl-lib.

    python benchmarks/meta_step.py [--steps 1000] [--sections loop mbrl scaling_m scaling_n]

* ``loop``: mbmpo (alpha 1) on hopper with the ``cpu`` preset: compile time of the whole training
  chunk, env steps/s of the full loop over ``--steps`` steps right after the 5,000 warm-up steps,
  and a time breakdown from the loop's own parts (model fit, imagination, agent update) and env
  steps, each jitted and timed alone at the same shapes, scaled to their counts per step;
* ``mbrl``: our ``mbpo`` against mbrl-lib's MBPO (``benchmarks/mbrl_mbpo.py``) on the same
  schedule and sizes (7/5 ensemble of 4 x 200, 20 full epochs per refit every 250 steps,
  100,000-state rollouts of length 1, 2 SAC updates of batch 256 per step, 256 x 256 SAC), in the
  same run; skipped with the reason when mbrl-lib cannot be imported;
* ``scaling_m``: mbmpo loop cost per env step for ensemble sizes M in {1, 5, 15, 20} (all members
  elites, so M tasks per meta step);
* ``scaling_n``: the same for N in {16, 128, 256, 512} imagined trajectories per rollout.

Writes ``benchmarks/results/meta_step.json`` after every measurement and prints short tables.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import time

import jax
import jax.numpy as jnp

from minatt_jax.config import PRESETS, TrainConfig, resolve, with_overrides
from minatt_jax.training import hyper_of, make_train

RESULTS = os.path.join(os.path.dirname(__file__), "results", "meta_step.json")


def _save(results: dict) -> None:
    os.makedirs(os.path.dirname(RESULTS), exist_ok=True)
    tmp = RESULTS + ".tmp"
    with open(tmp, "w") as f:
        json.dump(results, f, indent=2)
    os.replace(tmp, RESULTS)


def _timed(fn, *args, repeat: int = 3) -> float:
    """Median seconds of ``fn(*args)`` after one warm-up call."""
    jax.block_until_ready(fn(*args))
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t)
    return sorted(times)[len(times) // 2]


def _timed_state_fn(fn, state, key, repeat: int = 3) -> float:
    """Median seconds of ``state = fn(state, key)`` jitted with the state donated (in place, as
    inside the loop; without donation each call would copy the buffers in the state)."""

    def only_state(ts, k):
        out = fn(ts, k)
        return out[0] if isinstance(out, tuple) else out

    step = jax.jit(only_state, donate_argnums=0)
    state = jax.tree.map(lambda x: jnp.array(x, copy=True), state)
    state = jax.block_until_ready(step(state, key))
    times = []
    for i in range(repeat):
        t = time.perf_counter()
        state = jax.block_until_ready(step(state, jax.random.fold_in(key, i)))
        times.append(time.perf_counter() - t)
    return sorted(times)[len(times) // 2]


def measure_loop(config: TrainConfig, steps: int, breakdown: bool = False) -> dict:
    """Compile time and env steps/s of ``steps`` loop steps after the warm-up."""
    config = resolve(dataclasses.replace(config, eval_every=steps))
    trainer = make_train(config)
    state = trainer.init(jax.random.PRNGKey(0), hyper_of(trainer.config))
    t = time.perf_counter()
    chunk = trainer.train_chunk.lower(state).compile()
    compile_s = time.perf_counter() - t
    while int(state.env_steps) < config.warmup_steps:
        state, _ = chunk(state)
    jax.block_until_ready(state)
    t = time.perf_counter()
    state, metrics = chunk(state)
    jax.block_until_ready(state)
    loop_s = time.perf_counter() - t
    metrics = jax.device_get(metrics)
    out = {
        "compile_s": compile_s,
        "loop_s": loop_s,
        "env_steps_per_s": steps / loop_s,
        "model_fits": float(metrics["model_fits"]),
        "model_epochs_last_fit": float(metrics["model_epochs"]),
        "imagined_transitions": float(metrics["imagined_transitions"]),
        "agent_updates": float(metrics["updates"]),
    }
    if breakdown:
        key = jax.random.PRNGKey(1)
        parts = trainer.agent.parts
        fit_s = _timed_state_fn(parts["refit"], state, key)
        imagine_s = _timed_state_fn(parts["imagine"], state, key)
        update_s = _timed_state_fn(parts["agent_update"], state, key, repeat=20)
        env = trainer.env

        def env_steps(env_state, k):
            def body(s, kk):
                a = jax.random.uniform(kk, (1, env.action_size), minval=-1.0, maxval=1.0)
                return jax.vmap(env.step)(s, a), None

            return jax.lax.scan(body, env_state, jax.random.split(k, steps))[0]

        env_s = _timed(jax.jit(env_steps), state.collector.env_state, key)
        fits = out["model_fits"]
        parts_s = {
            "model_training_s": fit_s * fits,
            "imagination_s": imagine_s * fits,
            "agent_updates_s": update_s * out["agent_updates"],
            "env_s": env_s,
        }
        parts_s["sum_of_parts_s"] = sum(parts_s.values())
        out["breakdown"] = parts_s
        out["per_call_ms"] = {"model_fit": 1e3 * fit_s, "imagine": 1e3 * imagine_s,
                              "agent_update": 1e3 * update_s}  # fmt: skip
    return out


def mbpo_schedule(steps: int) -> TrainConfig:
    """Our mbpo on mbrl-lib's schedule (see the module docstring)."""
    return with_overrides(
        PRESETS["cpu"], env="hopper", algo="mbpo", ma_alpha=0.0, updates_per_step=2,
        model_max_epochs=20, model_patience=10**6, model_max_batches_per_epoch=0,
        mb_rollout_batch=100_000,
    )  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--sections", nargs="+", default=["loop", "mbrl", "scaling_m", "scaling_n"])
    args = parser.parse_args()
    results: dict = {
        "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
        "jax": jax.__version__,
        "steps_timed": args.steps,
        "command": "python benchmarks/meta_step.py " + " ".join(
            [f"--steps {args.steps}", "--sections", *args.sections]
        ),
    }  # fmt: skip
    if os.path.exists(RESULTS):
        with open(RESULTS) as f:
            previous = json.load(f)
        results = {**previous, **results}
    mbmpo = with_overrides(PRESETS["cpu"], env="hopper", algo="mbmpo", ma_alpha=1.0,
                           task_set="train")  # fmt: skip

    if "loop" in args.sections:
        r = measure_loop(mbmpo, args.steps, breakdown=True)
        results["loop_mbmpo_cpu"] = r
        _save(results)
        print(
            f"\nmbmpo cpu preset: compile {r['compile_s']:.1f} s, "
            f"{r['env_steps_per_s']:.1f} env steps/s ({r['loop_s']:.1f} s per {args.steps})"
        )
        print(f"{'part':22s} {'s per ' + str(args.steps) + ' steps':>18s} {'share':>7s}")
        total = r["breakdown"]["sum_of_parts_s"]
        for k, v in r["breakdown"].items():
            print(f"{k:22s} {v:18.2f} {v / total:7.1%}")
        print(f"(the loop itself took {r['loop_s']:.2f} s)")

    if "mbrl" in args.sections:
        import mbrl_mbpo

        ours = measure_loop(mbpo_schedule(args.steps), args.steps, breakdown=True)
        results["mbpo_ours"] = ours
        _save(results)
        reason = mbrl_mbpo.available()
        if reason is None:
            theirs = mbrl_mbpo.run(steps=args.steps, model_epochs=20)
            results["mbpo_mbrl_lib"] = theirs
            results["mbpo_speedup"] = ours["env_steps_per_s"] / theirs["env_steps_per_s"]
        else:
            results["mbpo_mbrl_lib"] = {"skipped": reason}
        _save(results)
        print(f"\n{'mbpo, same schedule':24s} {'env steps/s':>12s}")
        print(f"{'minatt-jax':24s} {ours['env_steps_per_s']:12.2f}")
        if reason is None:
            print(f"{'mbrl-lib':24s} {theirs['env_steps_per_s']:12.2f}")
            print(f"speedup {results['mbpo_speedup']:.2f}x")
        else:
            print(f"mbrl-lib skipped: {reason}")

    for section, field, values in (
        ("scaling_m", "M", (1, 5, 15, 20)),
        ("scaling_n", "N", (16, 128, 256, 512)),
    ):
        if section not in args.sections:
            continue
        rows = {}
        for v in values:
            if field == "M":
                config = with_overrides(mbmpo, model_ensemble_size=v, model_num_elites=v)
            else:
                config = with_overrides(mbmpo, mb_rollout_batch=v)
            r = measure_loop(config, args.steps)
            rows[str(v)] = {**r, "s_per_1000_steps": 1000 * r["loop_s"] / args.steps}
            results[section] = rows
            _save(results)
        if field == "M" and "5" in rows and "20" in rows:
            results["cost_m20_over_m5"] = rows["20"]["loop_s"] / rows["5"]["loop_s"]
            _save(results)
        print(f"\n{field:>4s} {'s/1000 steps':>13s} {'compile s':>10s}")
        for v, r in rows.items():
            print(f"{v:>4s} {r['s_per_1000_steps']:13.2f} {r['compile_s']:10.1f}")
    print(f"\nwrote {RESULTS}")


if __name__ == "__main__":
    jnp.zeros(())  # initialize the backend before timing
    main()
