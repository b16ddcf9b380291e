"""Population throughput: aggregate env steps/s and updates/s against the number of members N.

For each N, a population of N members (seeds 0..N-1, ``--env``, hopper by default) is built as
one program (``population.Program``), compiled, run through its warm-up, then one chunk of
``--steps`` env steps per member is timed after ``block_until_ready``. N = 1 is the single run's
rate measured in the same process, so the ratio ``aggregate / (N x single)`` is side by side.
Memory is the size of the stacked train state (replay and model buffers dominate).

    python benchmarks/population.py --algo sac --preset smoke --sizes 1 2 4 8 16 32
    python benchmarks/population.py --algo sac --preset cpu --sizes 1 2 4

Writes ``benchmarks/results/population_<algo>_<preset>_<device>.json`` and prints a table.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import jax
import numpy as np

from minatt_jax import population
from minatt_jax.config import PRESETS, with_overrides

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")


def measure(algo: str, preset: str, n: int, steps: int, buffer_size: int, env: str = "hopper",
            alpha: float = 0.0) -> dict:  # fmt: skip
    """Compile time, state bytes and the timed chunk's rates for a population of ``n``."""
    base = PRESETS[preset]
    config = with_overrides(
        base, env=env, algo=algo, eval_every=steps, total_steps=base.warmup_steps + steps,
        buffer_size=buffer_size, ma_alpha=alpha,
    )  # fmt: skip
    members = population.expand(config, list(range(n)), [])
    program = population.Program(members)
    states = program.init()
    state_bytes = sum(x.nbytes for x in jax.tree.leaves(states))
    t = time.perf_counter()
    chunk = program.chunk.lower(states).compile()
    compile_s = time.perf_counter() - t
    while int(states.env_steps[0]) < config.warmup_steps:
        states, _ = chunk(states)
    jax.block_until_ready(states)
    t = time.perf_counter()
    states, metrics = chunk(states)
    jax.block_until_ready(states)
    seconds = time.perf_counter() - t
    updates = float(np.sum(jax.device_get(metrics["updates"])))
    return {
        "members": n,
        "compile_s": compile_s,
        "chunk_s": seconds,
        "aggregate_env_steps_per_s": n * steps / seconds,
        "aggregate_updates_per_s": updates / seconds,
        "state_mb_per_member": state_bytes / n / 2**20,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algo", default="sac", choices=("sac", "mbpo", "mbmpo"))
    parser.add_argument("--preset", default="smoke", choices=tuple(PRESETS))
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 2, 4, 8, 16])
    parser.add_argument("--steps", type=int, default=1000, help="timed env steps per member")
    parser.add_argument("--buffer-size", type=int, default=50_000, help="replay capacity")
    parser.add_argument("--env", default="hopper")
    parser.add_argument("--alpha", type=float, default=0.0, help="MA weight of every member")
    args = parser.parse_args()
    device = jax.devices()[0]
    name = f"{device.platform}" if device.platform != "cpu" else "cpu"
    rows = []
    for n in args.sizes:
        row = measure(args.algo, args.preset, n, args.steps, args.buffer_size, args.env, args.alpha)
        rows.append(row)
        print(f"N={n:4d}: {row['aggregate_env_steps_per_s']:9.1f} env steps/s in all, "
              f"compile {row['compile_s']:.1f} s", flush=True)  # fmt: skip
    single = rows[0]["aggregate_env_steps_per_s"] / rows[0]["members"]
    for row in rows:
        row["speedup_over_one_run"] = row["aggregate_env_steps_per_s"] / single
        row["efficiency"] = row["speedup_over_one_run"] / row["members"]
    result = {
        "device": f"{device.device_kind} ({device.platform}), {len(jax.devices())} device(s)",
        "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
        "jax": jax.__version__,
        "algo": args.algo,
        "preset": args.preset,
        "env": args.env,
        "alpha": args.alpha,
        "steps_timed_per_member": args.steps,
        "buffer_size": args.buffer_size,
        "command": "python benchmarks/population.py "
        + " ".join(
            [
                f"--algo {args.algo}",
                f"--preset {args.preset}",
                f"--steps {args.steps}",
                f"--buffer-size {args.buffer_size}",
                f"--env {args.env}",
                f"--alpha {args.alpha:g}",
                "--sizes",
                *map(str, args.sizes),
            ]
        ),  # fmt: skip
        "rows": rows,
    }
    os.makedirs(RESULTS, exist_ok=True)
    env = "" if args.env == "hopper" else f"_{args.env}"
    path = os.path.join(RESULTS, f"population_{args.algo}_{args.preset}{env}_{name}.json")
    with open(path, "w") as f:
        json.dump(result, f, indent=2)
    print(f"\n{result['device']}, {args.algo}, preset {args.preset}")
    print(f"{'N':>5s} {'env steps/s':>12s} {'x one run':>10s} {'efficiency':>10s} "
          f"{'compile s':>10s} {'MB/member':>10s}")  # fmt: skip
    for r in rows:
        print(f"{r['members']:5d} {r['aggregate_env_steps_per_s']:12.1f} "
              f"{r['speedup_over_one_run']:10.2f} {r['efficiency']:10.2f} {r['compile_s']:10.1f} "
              f"{r['state_mb_per_member']:10.1f}")  # fmt: skip
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
