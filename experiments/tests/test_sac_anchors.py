"""The 100K SAC anchors: SB3 seeds short of the step are left out, and the comparison's exact
permutation p is the hand-counted one."""

from __future__ import annotations

import json

import pytest
import sac_hopper_anchors as anchors


def test_sb3_seeds_short_of_the_step_are_listed_but_not_counted(tmp_path) -> None:
    for seed, last in ((0, 100_000), (1, 40_000)):
        records = [{"step": s, "return": s / 100} for s in range(5_000, last + 1, 5_000)]
        (tmp_path / f"sb3_sac_hopper_seed{seed}.json").write_text(
            json.dumps({"env": "Hopper-v5", "seed": seed, "records": records})
        )
    runs = {r["seed"]: r for r in anchors.sb3_runs(str(tmp_path))}
    assert runs[0]["return"] == pytest.approx(1000.0) and runs[0]["last_step"] == 100_000
    assert runs[1]["return"] is None and runs[1]["last_return"] == pytest.approx(400.0)


def test_the_comparison_is_exact_and_needs_two_seeds_a_side() -> None:
    # [1, 2, 3] against [4, 5, 6]: 2 of the C(6, 3) = 20 relabelings are as extreme
    d = anchors.compare([1.0, 2.0, 3.0], [4.0, 5.0, 6.0])
    assert d["diff"] == pytest.approx(-3.0) and d["permutation_p"] == pytest.approx(0.1)
    low, high = d["welch_ci"]
    assert low < -3.0 < high < 0.0
    assert anchors.compare([1.0, 2.0], [4.0])["permutation_p"] is None
