"""Re-records the "current" block of a smoke reference (tests/test_train_program.py).

    python tests/data/record_reference.py sac "what changed" [--check-unchanged]

Runs the reference's argv with this version and stores its records (timings dropped) beside
the old ones. With --check-unchanged it refuses unless every value the previous "current"
recording has is equal, bit for bit, in the new one (a change that only adds metrics).
"""

from __future__ import annotations

import argparse
import json
import pathlib
import tempfile

from minatt_jax import runner
from minatt_jax.cli import main as cli

DATA = pathlib.Path(__file__).parent


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("name")
    parser.add_argument("recorded_with")
    parser.add_argument("--check-unchanged", action="store_true")
    args = parser.parse_args()
    path = DATA / f"reference_smoke_{args.name}.json"
    reference = json.loads(path.read_text())
    with tempfile.TemporaryDirectory() as tmp:
        assert cli([*reference["argv"], "--out", f"{tmp}/run"]) == 0
        records = runner.without_timings(runner.read_metrics(f"{tmp}/run"))
    if args.check_unchanged:
        for new, old in zip(records, reference["current"]["records"], strict=True):
            changed = {k: (old[k], new.get(k)) for k in old if new.get(k) != old[k]}
            if changed:
                raise SystemExit(f"values changed: {changed}")
    reference["current"] = {"recorded_with": args.recorded_with, "records": records}
    path.write_text(json.dumps(reference, indent=1) + "\n")
    print(f"recorded {len(records)} records into {path}")


if __name__ == "__main__":
    main()
