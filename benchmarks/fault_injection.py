"""Kill a training run at random moments, resume it, and tally how often the metrics come out exact.

    python benchmarks/fault_injection.py [--algo sac] [--kills 10] [--steps 1500] [--seed 0]
        [--population]

One uninterrupted smoke run is the reference; a second one, loading its compiled program from
the cache as every later run does, gives the wall time of a run. Then, ``--kills`` times: the
same run starts in a fresh directory, receives SIGKILL after a uniformly random delay (up to that
wall time, so the kill lands in start-up, a chunk, an evaluation or a checkpoint save),
and is resumed with ``--resume`` (again and again until it finishes). Its ``metrics.jsonl``
(timings dropped) must equal the reference's; with ``--population``, a population of 2 seeds x 2
alphas (``--seeds 0-1 --sweep ma.alpha=0,1``), every member's. Writes
``benchmarks/results/fault_injection_<algo>.json`` and prints the tally.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time

from minatt_jax import checkpoint, runner

RESULTS = os.path.join(os.path.dirname(__file__), "results")


def _records(out: str) -> dict[str, list[dict]]:
    """Each member's records without timings (one member, "", for a single run)."""
    if not os.path.exists(os.path.join(out, "population.json")):
        return {"": runner.without_timings(runner.read_metrics(out))}
    members = sorted(d for d in os.listdir(out)
                     if os.path.exists(os.path.join(out, d, "config.json")))  # fmt: skip
    return {d: runner.without_timings(runner.read_metrics(os.path.join(out, d))) for d in members}


def _started(out: str) -> bool:
    return any(os.path.exists(os.path.join(out, f)) for f in ("config.json", "population.json"))


def _train(argv: list[str], env: dict) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "minatt_jax.cli", *argv]
    return subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True)  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algo", default="sac", choices=("sac", "mbpo", "mbmpo"))
    parser.add_argument("--kills", type=int, default=10)
    parser.add_argument("--steps", type=int, default=1500)
    parser.add_argument("--seed", type=int, default=0, help="seed of the kill times")
    parser.add_argument("--earliest", type=float, default=0.0,
                        help="kill no earlier than this (seconds), e.g. past start-up")  # fmt: skip
    parser.add_argument("--tag", default="", help="suffix of the result file's name")
    parser.add_argument("--population", action="store_true",
                        help="a population of 2 seeds x 2 alphas instead of one run")  # fmt: skip
    args = parser.parse_args()
    rng = random.Random(args.seed)
    work = tempfile.mkdtemp(prefix="minatt-fault-")
    env = {**os.environ, "JAX_COMPILATION_CACHE_DIR": os.path.join(work, "xla-cache")}
    base = ["train", "--preset", "smoke", "--algo", args.algo, "--steps", str(args.steps)]
    population_flags = ["--seeds", "0-1", "--sweep", "ma.alpha=0,1"]
    if args.population:
        base += population_flags
    reference_dir = os.path.join(work, "reference")
    start = time.perf_counter()
    proc = _train([*base, "--out", reference_dir], env)
    _, err = proc.communicate()
    if proc.returncode != 0:
        raise SystemExit(f"reference run failed: {err.strip().splitlines()[-1]}")
    compile_wall = time.perf_counter() - start
    reference = _records(reference_dir)
    start = time.perf_counter()
    proc = _train([*base, "--out", os.path.join(work, "again")], env)
    proc.communicate()
    wall = time.perf_counter() - start
    if _records(os.path.join(work, "again")) != reference:
        raise SystemExit("two uninterrupted runs differ: nothing to compare kills against")
    count = sum(map(len, reference.values()))
    print(f"reference: {count} records in {compile_wall:.0f} s, {wall:.0f} s with the "
          f"compiled program cached ({args.algo})", flush=True)  # fmt: skip
    trials = []
    for i in range(args.kills):
        run_dir = os.path.join(work, f"kill{i}")
        delay = rng.uniform(min(args.earliest, wall), wall)
        proc = _train([*base, "--out", run_dir], env)
        time.sleep(delay)
        finished_first = proc.poll() is not None
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        at_kill = (checkpoint.latest_step(run_dir) if os.path.isdir(run_dir)
                   and not args.population else None)  # fmt: skip
        resumes = 0
        while True:
            resumes += 1
            fresh = not _started(run_dir)
            # a population's resume takes its members from population.json
            again = [a for a in base if a not in population_flags] if args.population else base
            argv = [*base, "--out", run_dir] if fresh else [*again, "--out", run_dir, "--resume"]
            proc = _train(argv, env)
            _, err = proc.communicate()
            if proc.returncode == 0 or resumes >= 3:
                break
        exact = proc.returncode == 0 and _records(run_dir) == reference
        trials.append({"kill_after_s": round(delay, 2), "checkpoint_at_kill": at_kill,
                       "finished_before_kill": finished_first, "resumes": resumes,
                       "exit_status": proc.returncode, "exact": exact,
                       "error": "" if proc.returncode == 0 else err.strip()[-300:]})  # fmt: skip
        print(f"kill {i + 1}/{args.kills} after {delay:5.1f} s (checkpoint {at_kill}): "
              f"{'exact' if exact else 'DIFFERENT'}", flush=True)  # fmt: skip
        shutil.rmtree(run_dir, ignore_errors=True)
    tally = {
        "algo": args.algo,
        "population": args.population,
        "steps": args.steps,
        "reference_wall_s": round(compile_wall, 1),
        "cached_run_wall_s": round(wall, 1),
        "kills": args.kills,
        "earliest_s": args.earliest,
        "exact": sum(t["exact"] for t in trials),
        "trials": trials,
        "command": f"python benchmarks/fault_injection.py --algo {args.algo} --kills "
        f"{args.kills} --steps {args.steps} --seed {args.seed} --earliest {args.earliest}"
        + (f" --tag {args.tag}" if args.tag else "")
        + (" --population" if args.population else ""),
    }
    os.makedirs(RESULTS, exist_ok=True)
    kind = "_population" if args.population else ""
    name = f"fault_injection_{args.algo}{kind}{'_' + args.tag if args.tag else ''}.json"
    runner.write_json_atomic(os.path.join(RESULTS, name), tally)
    shutil.rmtree(work, ignore_errors=True)
    print(json.dumps({k: v for k, v in tally.items() if k != "trials"}))


if __name__ == "__main__":
    main()
