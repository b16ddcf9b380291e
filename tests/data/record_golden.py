"""Records the smoke-preset golden runs of every algorithm (tests/test_golden_runs.py).

    python tests/data/record_golden.py [NAME ...]

Each golden run is a CLI argv; its records (timings dropped) are kept in
``tests/data/golden/<name>.json``, one recording per platform it was recorded on (XLA's CPU code
depends on the instruction set): recording on a new platform adds its recording beside the
others. The test compares bit for bit where a recording of its platform exists, and elsewhere
within ``TOLERANCE`` of the first recording (the runs whose numbers agree across instruction
sets to far better than any change in the computation would leave them).
"""

from __future__ import annotations

import json
import os
import pathlib
import platform
import sys
import tempfile

import jax

DATA = pathlib.Path(__file__).parent
GOLDEN = DATA / "golden"

# name -> train argv (smoke preset; --out is added)
RUNS: dict[str, list[str]] = {
    "sac": ["train", "--preset", "smoke", "--algo", "sac", "--alpha", "1"],
    "mbpo": ["train", "--preset", "smoke", "--algo", "mbpo", "--alpha", "1"],
    "mbmpo": ["train", "--preset", "smoke", "--algo", "mbmpo", "--alpha", "1"],
    "mbmpo_vpg_trpo": [
        "train",
        "--preset",
        "smoke",
        "--algo",
        "mbmpo",
        "--alpha",
        "1",
        "--inner",
        "vpg",
        "--outer",
        "trpo",
    ],
    "dreamer": ["train", "--preset", "smoke", "--algo", "dreamer", "--alpha", "1"],
    "population_sac": [
        "train",
        "--preset",
        "smoke",
        "--algo",
        "sac",
        "--seeds",
        "0-1",
        "--sweep",
        "ma.alpha=0,1",
    ],
}


# Relative tolerance on every mean metric (timings and spreads aside) against a recording made on
# another platform. Measured between an avx512 and an avx2 x86-64 CPU: at most 1.5e-5 (sac,
# mbpo, mbmpo, dreamer) and 2.2e-3 (the population). TRPO's line search turns last-bit
# differences into other steps (returns differ by half): it is compared on its own platforms only.
TOLERANCE = {"sac": 1e-2, "mbpo": 1e-2, "mbmpo": 1e-2, "dreamer": 1e-2, "population_sac": 1e-2}


def cpu_flags() -> list[str]:
    """The instruction-set flags XLA's CPU code depends on."""
    try:
        text = open("/proc/cpuinfo").read()
    except OSError:
        return []
    line = next((x for x in text.splitlines() if x.startswith("flags")), "")
    have = set(line.split(":", 1)[-1].split())
    return sorted(f for f in ("avx", "avx2", "fma", "avx512f", "avx512_bf16", "amx_tile")
                  if f in have)  # fmt: skip


def platform_key() -> dict:
    return {"jax": jax.__version__, "machine": platform.machine(), "cpu_flags": cpu_flags()}


def run_records(argv: list[str]) -> dict[str, list[dict]]:
    """The records of every run directory the argv makes (one, or one per member)."""
    from minatt_jax import runner
    from minatt_jax.cli import main as cli

    with tempfile.TemporaryDirectory() as tmp:
        out = f"{tmp}/run"
        assert cli([*argv, "--out", out]) == 0
        dirs = sorted({os.path.dirname(p) for p in pathlib.Path(out).rglob("metrics.jsonl")})
        return {os.path.relpath(d, out): runner.without_timings(runner.read_metrics(str(d)))
                for d in dirs}  # fmt: skip


def main() -> None:
    GOLDEN.mkdir(exist_ok=True)
    for name in sys.argv[1:] or list(RUNS):
        records = run_records(RUNS[name])
        path = GOLDEN / f"{name}.json"
        here = platform_key()
        old = json.loads(path.read_text())["recordings"] if path.exists() else []
        kept = [r for r in old if {k: r[k] for k in here} != here]
        doc = {"argv": RUNS[name], "recordings": [*kept, {**here, "runs": records}]}
        path.write_text(json.dumps(doc, indent=1) + "\n")
        print(f"recorded {name}: {sum(len(r) for r in records.values())} records", flush=True)


if __name__ == "__main__":
    main()
