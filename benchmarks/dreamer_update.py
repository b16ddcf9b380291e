"""DreamerV3 (cheetah_run) or MAMBA (point_robot) updates/s and env steps/s, with and without
minimum attention.

Two measurements per model size, each compiled once and timed after a warm-up call:

* **update**: a jitted ``lax.scan`` of ``--updates`` learner updates (world model, imagination,
  actor, critic) on batches sampled from a filled sequence replay (random data: the cost does not
  depend on the values);
* **training chunk**: the whole training program (collection in MJX, replay, updates at the size's
  train ratio) for one chunk after two chunks that fill the replay (updates run throughout the
  timed one), as ``minatt-jax train`` runs it; env steps/s is the chunk's steps over its time.

Variants MA off (alpha 0: no MA terms in the program) and on (alpha 0.05) are timed interleaved
for ``--rounds`` rounds; the median is reported, with the MA cost measured in the same run. Sizes:
``cpu`` and ``paper`` are the presets' settings (``minatt_jax.config.preset_config``: DreamerV3's
in ``PRESETS``, MAMBA's in ``agents.mamba``). MAMBA replays whole meta-episodes
(``--algo mamba``: 3 x 50 steps at cpu size, with its world-model horizon's mask).

    python benchmarks/dreamer_update.py [--algo dreamer|mamba] [--sizes cpu paper]
        [--updates 20] [--rounds 3]

Writes ``benchmarks/results/<algo>_update_<device>.json`` and prints a table.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time

import jax

from minatt_jax.config import preset_config, replace_fields, resolve
from minatt_jax.training import hyper_of, make_train

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")


ENVS = {"dreamer": "cheetah_run", "mamba": "point_robot"}


def build(algo: str, size: str, alpha: float, updates: int, chunk_steps: int):
    """(config, timed update scan, its agent state, trainer, initial state)."""
    preset = preset_config(size, fields={"algo": algo, "env": ENVS[algo]})
    # one chunk holds two whole sequences (MAMBA: meta-episodes)
    chunk_steps = max(chunk_steps, 2 * preset.episode_limit if algo == "mamba" else 0)
    config = resolve(replace_fields(preset, {
        "ma.alpha": alpha, "warmup_steps": 0, "eval_every": chunk_steps * preset.num_envs,
        "total_steps": chunk_steps * preset.num_envs,
        "buffer_size": max(4096, 2 * chunk_steps * preset.num_envs),
    }))  # fmt: skip
    trainer = make_train(config)
    agent, source = trainer.agent.parts["agent"], trainer.agent.parts["source"]
    state = trainer.init(jax.random.PRNGKey(0), hyper_of(config))
    d = config.dreamer

    # A replay filled with one chunk of random-policy steps (enough for whole sequences).
    filled, _ = trainer.train_chunk(trainer.init(jax.random.PRNGKey(1), hyper_of(config)))
    mask = source.valid(filled.env_steps)  # MAMBA: the horizon at the filled replay's steps
    valid = None if mask is None else jax.numpy.broadcast_to(mask, (d.batch_size, source.length))

    @jax.jit
    def run_updates(agent_state, key):
        def one(s, k):
            k_sample, k_update = jax.random.split(k)
            batch = source.sample(filled.replay, k_sample)
            return agent.update(s, batch, k_update, valid)[0], None

        return jax.lax.scan(one, agent_state, jax.random.split(key, updates))[0]

    return config, run_updates, filled.agent, trainer, state


def timed(fn, *args) -> float:
    t = time.perf_counter()
    jax.block_until_ready(fn(*args))
    return time.perf_counter() - t


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--algo", default="dreamer", choices=sorted(ENVS))
    parser.add_argument("--sizes", nargs="+", default=["cpu", "paper"])
    parser.add_argument("--updates", type=int, default=20)
    parser.add_argument("--chunk-steps", type=int, default=64,
                        help="iterations per timed chunk (>= the batch length)")  # fmt: skip
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    device = jax.devices()[0]
    rows = []
    for size in args.sizes:
        built = {}
        for label, alpha in (("MA off", 0.0), ("MA on (alpha 0.05)", 0.05)):
            config, run_updates, agent_state, trainer, state = build(
                args.algo, size, alpha, args.updates, args.chunk_steps
            )
            chunk = trainer.train_chunk.lower(state).compile()
            timed(run_updates, agent_state, jax.random.PRNGKey(0))  # compile and warm up
            built[label] = (config, run_updates, agent_state, trainer, chunk)
        times: dict[str, dict[str, list[float]]] = {k: {"update": [], "chunk": []} for k in built}
        for _ in range(args.rounds):
            for label, (_, run_updates, agent_state, trainer, chunk) in built.items():
                times[label]["update"].append(
                    timed(run_updates, agent_state, jax.random.PRNGKey(1)) / args.updates
                )
                # Two chunks fill the rings past one sequence; the third updates throughout.
                state = chunk(chunk(trainer.init(jax.random.PRNGKey(2), hyper_of(config)))[0])[0]
                times[label]["chunk"].append(timed(chunk, state))
        base = statistics.median(times["MA off"]["update"])
        for label, (config, _, _, trainer, _) in built.items():
            update_s = statistics.median(times[label]["update"])
            chunk_s = statistics.median(times[label]["chunk"])
            d = config.dreamer
            rows.append({
                "size": size, "variant": label,
                "model": f"deter {d.deter}, hidden {d.hidden}, {d.stoch}x{d.classes}, "
                         f"units {d.units}x{d.layers}",
                "batch": f"{d.batch_size}x{trainer.agent.parts['source'].length}",
                "env": config.env, "num_envs": config.num_envs,
                "train_ratio": d.train_ratio, "updates_per_s": 1.0 / update_s,
                "update_cost_vs_ma_off": update_s / base,
                "env_steps_per_s": trainer.steps_per_chunk / chunk_s,
            })  # fmt: skip
    result = {
        "device": f"{device.platform} ({device.device_kind})",
        "machine": f"{platform.machine()}, {os.cpu_count()} cores",
        "jax": jax.__version__,
        "command": "python benchmarks/dreamer_update.py "
        + " ".join(
            f"--{k.replace('_', '-')} {' '.join(map(str, v)) if isinstance(v, list) else v}"
            for k, v in vars(args).items()
        ),  # fmt: skip
        "rows": rows,
    }
    os.makedirs(RESULTS, exist_ok=True)
    path = os.path.join(RESULTS, f"{args.algo}_update_{device.platform}.json")
    with open(path, "w") as f:
        json.dump(result, f, indent=2)
    print(f"{'size':6s} {'variant':20s} {'updates/s':>10s} {'x MA off':>9s} {'env steps/s':>12s}")
    for r in rows:
        print(f"{r['size']:6s} {r['variant']:20s} {r['updates_per_s']:10.2f} "
              f"{r['update_cost_vs_ma_off']:9.2f} {r['env_steps_per_s']:12.1f}")  # fmt: skip
    print(f"device: {result['device']}; written to {path}")


if __name__ == "__main__":
    main()
