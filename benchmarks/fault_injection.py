"""Kill a training run at random moments, resume it, and tally how often the metrics come out exact.

    python benchmarks/fault_injection.py [--algo sac] [--kills 10] [--steps 1500] [--seed 0]
        [--population] [--signal kill|term] [--cut] [--set KEY=VALUE ...]

One uninterrupted smoke run is the reference; a second one, loading its compiled program from
the cache as every later run does, gives the wall time of a run. Then, ``--kills`` times: the
same run starts in a fresh directory, receives SIGKILL (``--signal term``: SIGTERM, which stops
after the chunk in progress, or at once while compiling) after a uniformly random delay (up to
that wall time, so it lands in start-up, compilation, a chunk, an evaluation or a checkpoint
save), and is resumed with ``--resume`` (again and again until it finishes). Its
``metrics.jsonl`` (timings dropped) must equal the reference's; with ``--population``, a
population of 2 seeds x 2 alphas (``--seeds 0-1 --sweep ma.alpha=0,1``), every member's.

``--cut`` damages instead of killing: each trial trains to a random earlier chunk, cuts half of
one random file of the newest checkpoint (of a random member, in a population) and resumes to
the end, which must fall back to the previous checkpoint and still equal the reference.
``--set`` passes settings to every run (``--set meta_episodes=3``: runs in meta-episodes).
Writes ``benchmarks/results/fault_injection_<algo>[_population][_<tag>].json``.
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


def _cut_newest(out: str, rng: random.Random) -> str:
    """Cuts half of one random file of the newest checkpoint (of a random member of a
    population); returns the file's path under ``out``."""
    runs = [out]
    if os.path.exists(os.path.join(out, "population.json")):
        runs = sorted(os.path.join(out, d) for d in os.listdir(out)
                      if os.path.exists(os.path.join(out, d, "config.json")))  # fmt: skip
    run_dir = rng.choice(runs)
    newest = os.path.join(run_dir, "checkpoints", str(checkpoint.latest_step(run_dir)))
    files = sorted(os.path.join(b, f) for b, _, fs in os.walk(newest) for f in fs
                   if os.path.getsize(os.path.join(b, f)) > 64)  # fmt: skip
    path = rng.choice(files)
    os.truncate(path, os.path.getsize(path) // 2)
    return os.path.relpath(path, out)


def _started(out: str) -> bool:
    return any(os.path.exists(os.path.join(out, f)) for f in ("config.json", "population.json"))


def _train(argv: list[str], env: dict) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "minatt_jax.cli", *argv]
    return subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True)  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algo", default="sac",
                        choices=("sac", "mbpo", "mbmpo", "dreamer", "mamba", "ppo"))  # fmt: skip
    parser.add_argument("--kills", type=int, default=10)
    parser.add_argument("--steps", type=int, default=1500)
    parser.add_argument("--seed", type=int, default=0, help="seed of the kill times")
    parser.add_argument("--earliest", type=float, default=0.0,
                        help="kill no earlier than this (seconds), e.g. past start-up")  # fmt: skip
    parser.add_argument("--tag", default="", help="suffix of the result file's name")
    parser.add_argument("--population", action="store_true",
                        help="a population of 2 seeds x 2 alphas instead of one run")  # fmt: skip
    parser.add_argument("--signal", choices=("kill", "term"), default="kill")
    parser.add_argument("--cut", action="store_true",
                        help="cut a file of the newest checkpoint instead of killing")  # fmt: skip
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    rng = random.Random(args.seed)
    work = tempfile.mkdtemp(prefix="minatt-fault-")
    env = {**os.environ, "JAX_COMPILATION_CACHE_DIR": os.path.join(work, "xla-cache")}
    base = ["train", "--preset", "smoke", "--algo", args.algo, "--steps", str(args.steps),
            *[f"--set={kv}" for kv in args.set]]  # fmt: skip
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
    chunk = next(iter(reference.values()))[0]["step"]  # env steps of one chunk
    again = [a for a in base if a not in population_flags] if args.population else base
    for i in range(args.kills):
        run_dir = os.path.join(work, f"kill{i}")
        delay, at_kill, finished_first, cut = 0.0, None, False, None
        if args.cut:  # train to a random earlier chunk (two checkpoints), damage the newest
            stop_at = chunk * rng.randint(2, max(2, args.steps // chunk - 1))
            shorter = [a if a != str(args.steps) else str(stop_at) for a in base]
            _train([*shorter, "--out", run_dir], env).communicate()
            cut = _cut_newest(run_dir, rng)
            at_kill = stop_at
        else:
            delay = rng.uniform(min(args.earliest, wall), wall)
            proc = _train([*base, "--out", run_dir], env)
            time.sleep(delay)
            finished_first = proc.poll() is not None
            proc.send_signal(signal.SIGKILL if args.signal == "kill" else signal.SIGTERM)
            proc.wait()
            at_kill = (checkpoint.latest_step(run_dir) if os.path.isdir(run_dir)
                       and not args.population else None)  # fmt: skip
        resumes = 0
        while True:
            resumes += 1
            fresh = not _started(run_dir)
            # a population's resume takes its members from population.json
            argv = [*base, "--out", run_dir] if fresh else [*again, "--out", run_dir, "--resume"]
            proc = _train(argv, env)
            _, err = proc.communicate()
            if proc.returncode == 0 or resumes >= 3:
                break
        exact = proc.returncode == 0 and _records(run_dir) == reference
        trials.append({"kill_after_s": round(delay, 2), "checkpoint_at_kill": at_kill,
                       "finished_before_kill": finished_first, "resumes": resumes, "cut": cut,
                       "exit_status": proc.returncode, "exact": exact,
                       "error": "" if proc.returncode == 0 else err.strip()[-300:]})  # fmt: skip
        what = f"cut {cut}" if args.cut else f"{args.signal} after {delay:5.1f} s"
        print(f"trial {i + 1}/{args.kills}: {what} (checkpoint {at_kill}): "
              f"{'exact' if exact else 'DIFFERENT'}", flush=True)  # fmt: skip
        shutil.rmtree(run_dir, ignore_errors=True)
    tally = {
        "algo": args.algo,
        "population": args.population,
        "steps": args.steps,
        "reference_wall_s": round(compile_wall, 1),
        "cached_run_wall_s": round(wall, 1),
        "kills": args.kills,
        "fault": "cut newest checkpoint" if args.cut else f"SIG{args.signal.upper()}",
        "settings": args.set,
        "earliest_s": args.earliest,
        "exact": sum(t["exact"] for t in trials),
        "trials": trials,
        "command": f"python benchmarks/fault_injection.py --algo {args.algo} --kills "
        f"{args.kills} --steps {args.steps} --seed {args.seed} --earliest {args.earliest}"
        + (f" --tag {args.tag}" if args.tag else "")
        + (f" --signal {args.signal}" if args.signal != "kill" else "")
        + (" --cut" if args.cut else "")
        + "".join(f" --set {kv}" for kv in args.set)
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
