"""meta-test on run directories: curves per task for sac and mbmpo runs, files, bad input."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from minatt_jax.cli import main as _main

# One worker runs this module: its module-scoped run is made once (pytest-xdist --dist loadgroup).
pytestmark = pytest.mark.xdist_group("test_meta_test")


def main(argv):
    """The CLI's exit status, whether it returns it or argparse raises SystemExit."""
    try:
        return _main(argv)
    except SystemExit as e:
        return e.code


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("meta_test_runs")
    out = {}
    for algo in ("sac", "mbmpo"):
        run_dir = str(root / algo)
        argv = ["train", "--env", "hopper", "--algo", algo, "--preset", "smoke", "--steps", "300",
                "--alpha", "1", "--out", run_dir]  # fmt: skip
        assert main(argv) == 0
        out[algo] = run_dir
    return out


@pytest.mark.parametrize("algo", ["sac", "mbmpo"])
def test_meta_test_writes_curves_per_task(algo, runs, capsys):
    run_dir = runs[algo]
    argv = ["meta-test", run_dir, "--variant", "crippled", "--shots", "1", "--adapt-steps", "2",
            "--episodes", "2", "--updates-per-step", "5", "--json"]  # fmt: skip
    assert main(argv) == 0
    printed = json.loads(capsys.readouterr().out)
    with open(os.path.join(run_dir, "meta_test_crippled.json")) as f:
        saved = json.load(f)
    assert saved == printed
    assert [r["task"] for r in saved["tasks"]] == ["crippled thigh_joint"]
    for row in saved["tasks"]:
        for metric in ("return", "feedback_norm", "feedforward_norm", "energy"):
            curve = row[f"{metric}_curve"]
            assert len(curve) == 3 and np.all(np.isfinite(curve))
        assert row["collected_transitions"] > 0
        # Adaptation changed the policy: the curve is not flat.
        assert row["energy_curve"][0] != row["energy_curve"][-1]
    with open(os.path.join(run_dir, "meta_test_crippled.png"), "rb") as f:
        assert f.read(8) == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--variant", "windy"], "unknown variant"),
        (["--variant", "mass", "--shots", "0"], "positive integer"),
    ],
)
def test_meta_test_bad_input_exit_2(argv, message, runs, capsys):
    assert main(["meta-test", runs["sac"], *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1


def test_meta_test_missing_run_or_checkpoint_exit_2(tmp_path, runs, capsys):
    assert main(["meta-test", str(tmp_path / "nothing"), "--variant", "mass"]) == 2
    assert "does not exist" in capsys.readouterr().err
    empty = tmp_path / "empty"
    empty.mkdir()
    with open(os.path.join(runs["sac"], "config.json")) as f:
        (empty / "config.json").write_text(f.read())
    assert main(["meta-test", str(empty), "--variant", "mass"]) == 2
    assert "no checkpoint" in capsys.readouterr().err
