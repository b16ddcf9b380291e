"""Runs the pieces of a grid as single-thread processes, one per CPU core ("lanes").

    python tools/lanes.py [--lanes 2] [--logs runs/lanes] --values 0 1 2 3 4 -- \\
        python experiments/ensemble_size.py --scale cpu --steps 10000 --seeds {} \\
        --records experiments/records --no-tables

Each value replaces ``{}`` in the command: one piece each, queued over ``--lanes`` processes
that each take the next piece when theirs ends. Where ``{}`` stands alone as an argument, a value
of several words becomes several arguments, so a piece can be a split of the arms as well as a
seed: ``--values "--seeds 2 --sizes 20 1" "--seeds 2 --sizes 15 5" -- ... {}``. A lane is
pinned to one core (``taskset -c`` where it exists) and runs XLA's CPU backend on one thread.
Why: on the 2-core machine two such lanes trained 8 HalfCheetah MB-MPO members 1.48x faster than
one 2-thread process (experiments/README.md), since one member's small matmuls do not fill two
cores. Each piece's output goes to ``<logs>/<value>.log`` (its words joined by ``_``);
a line is printed as each piece starts and ends, and the exit status is 1 if any piece failed.
"""

from __future__ import annotations

import argparse
import os
import re
import shlex
import shutil
import subprocess
import sys
import time

SINGLE_THREAD = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"


def fail(message: str) -> None:
    print(f"lanes.py: {message}", file=sys.stderr)
    raise SystemExit(2)


def log_name(value: str) -> str:
    """A file name for ``value``'s log: its words without leading dashes, joined by ``_``."""
    words = (w.lstrip("-") for w in value.split())
    return re.sub(r"[^A-Za-z0-9.=+-]+", "_", "_".join(words)).strip("_") or "_"


def lane_command(command: list[str], value: str, core: int | None) -> list[str]:
    """``command`` with ``{}`` replaced by ``value``, pinned to ``core`` (None: not pinned).

    A ``{}`` that is a whole argument becomes the value's words (shell quoting rules)."""
    argv = [w for a in command
            for w in (shlex.split(value) if a == "{}" else [a.replace("{}", value)])]  # fmt: skip
    return (["taskset", "-c", str(core)] if core is not None else []) + argv


def lane_env(base: dict[str, str]) -> dict[str, str]:
    """``base`` with XLA's CPU backend on one thread (beside any XLA flags already set)."""
    return {**base, "XLA_FLAGS": f"{base.get('XLA_FLAGS', '')} {SINGLE_THREAD}".strip()}


def run(command: list[str], values: list[str], lanes: int, logs: str,
        pin: bool = True) -> dict[str, int]:  # fmt: skip
    """Runs one piece per value over ``lanes`` processes; returns value -> exit status."""
    os.makedirs(logs, exist_ok=True)
    pin = pin and shutil.which("taskset") is not None
    queue, running, status = list(values), {}, {}
    free = list(range(lanes))
    start = time.time()
    while queue or running:
        while queue and free:
            lane, value = free.pop(0), queue.pop(0)
            log_path = os.path.join(logs, f"{log_name(value)}.log")
            log = open(log_path, "w")  # noqa: SIM115 (closed below)
            proc = subprocess.Popen(lane_command(command, value, lane if pin else None),
                                    stdout=log, stderr=subprocess.STDOUT,
                                    env=lane_env(dict(os.environ)))  # fmt: skip
            running[value] = (proc, lane, log)
            print(f"[{time.time() - start:7.0f} s] lane {lane}: {value} started "
                  f"({log_path})", flush=True)  # fmt: skip
        time.sleep(0.2)
        for value, (proc, lane, log) in list(running.items()):
            if proc.poll() is not None:
                log.close()
                status[value] = proc.returncode
                free.append(lane)
                del running[value]
                print(f"[{time.time() - start:7.0f} s] lane {lane}: {value} ended, exit status "
                      f"{proc.returncode}", flush=True)  # fmt: skip
    return status


def main() -> None:
    argv = sys.argv[1:]
    if "--" not in argv:
        fail("give the command after --, with {} where each value goes")
    split = argv.index("--")
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lanes", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--logs", default="runs/lanes")
    parser.add_argument("--values", nargs="+", required=True)
    parser.add_argument("--no-pin", action="store_true", help="do not pin lanes to cores")
    args = parser.parse_args(argv[:split])
    command = argv[split + 1 :]
    if not command or not any("{}" in a for a in command):
        fail("the command after -- needs {} where each value goes")
    if not 1 <= args.lanes <= (os.cpu_count() or 1):
        fail(f"--lanes {args.lanes}: the machine has {os.cpu_count()} cores")
    for v in args.values:
        try:
            shlex.split(v)
        except ValueError as e:
            fail(f"--values {v!r}: {e}")
    if len({log_name(v) for v in args.values}) != len(args.values):
        fail("--values repeats a value (each names its log: words joined by _)")
    status = run(command, args.values, args.lanes, args.logs, pin=not args.no_pin)
    failed = [v for v, rc in status.items() if rc != 0]
    print(f"lanes.py: {len(status) - len(failed)} of {len(status)} pieces ended well"
          + (f"; failed: {' '.join(failed)} (see their logs)" if failed else ""))  # fmt: skip
    raise SystemExit(1 if failed else 0)


if __name__ == "__main__":
    main()
