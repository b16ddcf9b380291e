"""The smoke-preset runs of every algorithm give exactly the records kept in ``tests/data/golden``.

The golden files were recorded before the agents became units of one interface
(``tests/data/record_golden.py``); the restructure kept every number bit for bit: sac, mbpo,
mbmpo (SAC inner/outer and VPG/TRPO), dreamer and a 2-seed x 2-alpha population. Compared where
the platform matches the recording: XLA's CPU code depends on the instruction set.
"""

from __future__ import annotations

import json
import pathlib
import sys

import pytest

DATA = pathlib.Path(__file__).parent / "data"
sys.path.insert(0, str(DATA))

import record_golden  # noqa: E402 - from tests/data

NAMES = sorted(p.stem for p in record_golden.GOLDEN.glob("*.json"))


def test_every_algorithm_has_a_golden_run():
    assert set(NAMES) == set(record_golden.RUNS)
    assert {"sac", "mbpo", "mbmpo", "mbmpo_vpg_trpo", "dreamer", "population_sac"} <= set(NAMES)


@pytest.mark.slow
@pytest.mark.parametrize("name", NAMES)
def test_golden_run_is_unchanged(name):
    golden = json.loads((record_golden.GOLDEN / f"{name}.json").read_text())
    here = record_golden.platform_key()
    there = {k: golden[k] for k in here}
    if here != there:
        pytest.skip(f"recorded on {there}, this platform is {here}")
    runs = record_golden.run_records(golden["argv"])
    assert sorted(runs) == sorted(golden["runs"])
    for run_dir, records in golden["runs"].items():
        assert runs[run_dir] == records, run_dir
