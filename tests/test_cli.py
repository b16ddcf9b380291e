"""The command line: listings, a rollout, and one-line errors with exit status 2."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import pytest

from minatt_jax.cli import main


def test_envs_json(capsys):
    assert main(["envs", "--json"]) == 0
    table = json.loads(capsys.readouterr().out)
    assert table["hopper"]["observation_size"] == 11
    assert table["humanoid"]["action_size"] == 17
    assert table["humanoid_376"]["observation_size"] == 376
    assert len(table["halfcheetah"]["task_sets"]["train"]) == 5
    assert table["walker2d"]["task_sets"]["crippled"] == ["crippled thigh_joint"]


@pytest.mark.parametrize(
    "argv, message",
    [
        (["rollout", "--env", "hoppr"], "unknown environment 'hoppr'"),
        (["rollout", "--env", "hopper", "--variant", "icy"], "unknown variant 'icy'"),
        (["rollout", "--env", "hopper", "--steps", "-5"], "expected a positive integer"),
        (["rollout", "--env", "hopper", "--steps", "ten"], "expected a positive integer"),
        (["rollout", "--env", "hopper", "--physics", "x"], "unknown physics preset 'x'"),
    ],
)
def test_user_errors_exit_2_with_one_line(capsys, argv, message):
    try:
        status = main(argv)
    except SystemExit as e:  # argparse errors
        status = e.code
    err = capsys.readouterr().err
    assert status == 2
    assert message in err
    assert len(err.strip().splitlines()) == 1
    assert err.startswith("minatt-jax: error:")


def test_rollout_runs_a_task_set_and_writes_json(tmp_path, capsys):
    out = tmp_path / "sub" / "summary.json"
    argv = ["rollout", "--env", "hopper", "--variant", "mass", "--steps", "30", "--out", str(out)]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "env steps/s" in printed
    summary = json.loads(out.read_text())
    assert [t["task"] for t in summary["tasks"]][0] == "mass x0.5"
    assert all(0 < t["length"] <= 30 for t in summary["tasks"])
    assert summary["env_steps_per_s"] > 0


def test_console_script_error_has_no_traceback():
    exe = shutil.which("minatt-jax") or os.path.join(os.path.dirname(sys.executable), "minatt-jax")
    proc = subprocess.run(
        [exe, "rollout", "--env", "ant"], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines() == [
        "minatt-jax: error: unknown environment 'ant'; choose from hopper, halfcheetah, "
        "walker2d, humanoid, humanoid_376, cheetah_run, humanoid_dir, point_robot, "
        "point_robot_dense"
    ]


def test_loading_every_environment_prints_nothing_on_stderr():
    """MuJoCo's C-level warning about Gym's humanoid.xml (deprecated ``settotalmass``) and the
    mjx Warp note are dropped; the listing itself goes to stdout."""
    proc = subprocess.run([sys.executable, "-m", "minatt_jax.cli", "envs"], capture_output=True,
                          text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 0 and "humanoid" in proc.stdout
    assert proc.stderr == ""
