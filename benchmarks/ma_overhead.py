"""Minimum attention's share of whole-training wall time: MA off, MA every update, the Jacobian
term every 10 updates, the whole attention cost every 10 updates, and the same with the
Hutchinson estimator.

The paper's appendix says the Jacobian term costs 10-12% of an update and, with the attention
cost updated every 10 steps, under 2% of training time, for MB-MPO. ``sac_update.py`` times
updates alone; this benchmark times whole training runs through the library's run loop
(``runner.train``: compile, collection, env steps, model fits, imagination, updates, evaluation
every chunk, checkpoints), the variants interleaved round by round so the machine's drift hits
them alike. A variant's program compiles once, in its first round (the process keeps compiled
programs). Per round, each variant's loop time is divided by MA off's of the same round: the
paired ratios' mean with its 95% t interval over rounds is the verdict's number (``loop_ratio``);
``whole_s`` adds the variant's one compile to its median loop: the wall time of one whole run.

    python benchmarks/ma_overhead.py                                  # SAC, hopper, 5,000 steps
    python benchmarks/ma_overhead.py --algo mbmpo --steps 2000 --rounds 7 \
        --out benchmarks/results/ma_overhead_mbmpo.json             # the paper's setting

Writes ``benchmarks/results/ma_overhead.json`` (``--out``) and prints a table.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import tempfile
from typing import Any

import jax

from minatt_jax import runner
from minatt_jax.config import PRESETS, with_overrides

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")
# name -> overrides of the MA group; "off" is the baseline every ratio divides by.
VARIANTS = {
    "off": {"ma.alpha": 0.0},
    "feedback every update": {"ma.alpha": 1.0, "ma.interval": 1},
    "feedback every 10 updates": {"ma.alpha": 1.0, "ma.interval": 10},
    "whole cost every 10 updates": {"ma.alpha": 1.0, "ma.interval": 10,
                                    "ma.interval_terms": "both"},
    "hutchinson every update": {"ma.alpha": 1.0, "ma.estimator": "hutchinson"},
    "hutchinson, whole cost every 10 updates": {"ma.alpha": 1.0, "ma.estimator": "hutchinson",
                                                "ma.interval": 10, "ma.interval_terms": "both"},
    # A diagnostic: MA on, its whole cost computed on the first update only. What remains over
    # "off" is what the skipped updates still pay (the lax.cond, the state MA keeps).
    "whole cost skipped": {"ma.alpha": 1.0, "ma.interval": 10**9, "ma.interval_terms": "both",
                           "ma.interval_scaling": False},
}  # fmt: skip
# "feedback every update" is MA's default mode: the Jacobian (feedback) and temporal terms.


def paired_ratio(times: list[dict[str, float]], off: list[dict[str, float]]) -> dict[str, Any]:
    """Round-by-round loop time ratios against MA off: each, their mean and its 95% t interval."""
    from scipy import stats as scipy_stats

    ratios = [t["loop_s"] / o["loop_s"] for t, o in zip(times, off, strict=True)]
    mean = statistics.fmean(ratios)
    if len(ratios) < 2:
        return {"ratios": ratios, "mean": mean, "ci": [mean, mean]}
    half = scipy_stats.t.ppf(0.975, len(ratios) - 1) * statistics.stdev(ratios)
    half /= len(ratios) ** 0.5
    return {"ratios": ratios, "mean": mean, "ci": [mean - half, mean + half]}


def timed_run(config, folder: str) -> dict[str, float]:
    """Trains ``config`` into a fresh ``folder``; its compile, loop and whole wall times."""
    shutil.rmtree(folder, ignore_errors=True)
    os.makedirs(folder)
    last = runner.train(config, folder, log=lambda _: None)
    return {"compile_s": last["compile_s"], "loop_s": last["wall_s"],
            "whole_s": last["compile_s"] + last["wall_s"]}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algo", default="sac", choices=("sac", "mbpo", "mbmpo"))
    parser.add_argument("--env", default="hopper")
    parser.add_argument("--preset", default="cpu", choices=tuple(PRESETS))
    parser.add_argument("--steps", type=int, default=5000, help="env steps after the warm-up")
    parser.add_argument("--rounds", type=int, default=3, help="runs of each variant")
    parser.add_argument(
        "--placement",
        default="actor_loss",
        help="MA placement (the paper's: the penalty in the actor loss)",
    )
    parser.add_argument("--out", default=os.path.join(RESULTS, "ma_overhead.json"))
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS),
                        help="variants to time (off is always timed)")  # fmt: skip
    args = parser.parse_args()
    chosen = {n: VARIANTS[n] for n in VARIANTS if n == "off" or n in args.variants}

    base = PRESETS[args.preset]
    total = base.warmup_steps + args.steps
    configs = {
        name: with_overrides(base, env=args.env, algo=args.algo, total_steps=total,
                             eval_every=max(1000, args.steps // 5),
                             **{"ma.placement": args.placement}, **overrides)
        for name, overrides in chosen.items()
    }  # fmt: skip
    times: dict[str, list[dict[str, float]]] = {name: [] for name in chosen}
    with tempfile.TemporaryDirectory() as tmp:
        # The process's one-off costs (XLA start-up, the model's first load) go to an untimed
        # run of another program (a shorter chunk), not to the first variant's compile.
        warm = with_overrides(configs["off"], eval_every=500, total_steps=base.warmup_steps + 500)
        timed_run(warm, os.path.join(tmp, "warm-up"))
        for r in range(args.rounds):
            for name, config in configs.items():
                times[name].append(timed_run(config, os.path.join(tmp, "run")))
                print(f"round {r + 1}/{args.rounds} {name}: {times[name][-1]['whole_s']:.1f} s",
                      flush=True)  # fmt: skip

    def median(name: str, key: str) -> float:
        return statistics.median(t[key] for t in times[name])

    def whole(name: str) -> float:
        """One whole run: the median loop and the variant's one compile (its first round)."""
        return median(name, "loop_s") + times[name][0]["compile_s"]

    rows = []
    for name in chosen:
        rows.append({
            "variant": name, "overrides": chosen[name],
            "whole_s": whole(name), "loop_s": median(name, "loop_s"),
            "compile_s": times[name][0]["compile_s"],
            "whole_vs_off": whole(name) / whole("off"),
            "loop_vs_off": median(name, "loop_s") / median("off", "loop_s"),
            "loop_ratio": paired_ratio(times[name], times["off"]),
            "runs": times[name],
        })  # fmt: skip
    command = (
        "python benchmarks/ma_overhead.py --algo {algo} --env {env} --preset {preset} "
        "--steps {steps} --rounds {rounds} --placement {placement}"
    ).format(**vars(args)) + (f" --out {os.path.relpath(args.out)}" if os.path.abspath(args.out)
                              != os.path.join(RESULTS, "ma_overhead.json") else "")  # fmt: skip
    if set(args.variants) != set(VARIANTS):
        command += " --variants " + " ".join(f'"{n}"' for n in chosen if n != "off")
    out = {"benchmark": "ma_overhead", "command": command,
           "device": f"{jax.devices()[0].platform} ({jax.devices()[0].device_kind})",
           "machine": f"{platform.machine()}, {os.cpu_count()} cores", "jax": jax.__version__,
           "xla_flags": os.environ.get("XLA_FLAGS", ""),
           "cores_used": len(os.sched_getaffinity(0)),
           "algo": args.algo, "env": args.env, "preset": args.preset,
           "env_steps": args.steps, "warmup_steps": base.warmup_steps,
           "placement": args.placement, "rows": rows}  # fmt: skip
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    tmp_path = args.out + ".tmp"
    with open(tmp_path, "w") as f:
        json.dump(out, f, indent=2)
    os.replace(tmp_path, args.out)

    print(f"\n{args.algo} on {args.env}, {args.preset} preset, {args.steps} env steps after "
          f"{base.warmup_steps} warm-up, median of {args.rounds} ({out['device']})")  # fmt: skip
    print(f"{'variant':42s} {'whole s':>9s} {'loop s':>8s} {'whole/off':>10s} "
          f"{'loop/off, paired [95%]':>26s}")  # fmt: skip
    for row in rows:
        r = row["loop_ratio"]
        print(f"{row['variant']:42s} {row['whole_s']:9.1f} {row['loop_s']:8.1f} "
              f"{row['whole_vs_off']:10.3f} {r['mean']:10.3f} [{r['ci'][0]:.3f}, "
              f"{r['ci'][1]:.3f}]")  # fmt: skip
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
