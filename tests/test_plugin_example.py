"""The plugin example (``examples/minatt_ars``) installed as a package and driven only through
the ``minatt-jax`` console command, as ``docs/extending.md`` shows it: the page's commands and
Python blocks run as written, in order, and what they claim holds (one program for the swept
settings, an exact resume, export equal to the JAX policy, meta-test through the agent's
``no_adaptation`` adapter, analyze, inspect). A module on the Python path is a plugin through
``--plugin``, and a run records where its agent came from."""

from __future__ import annotations

import json
import os
import pathlib
import re
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "extending.md"
BIN = pathlib.Path(sys.executable).parent


def blocks(language: str) -> list[str]:
    """The page's fenced blocks of ``language``, in order."""
    return re.findall(rf"```{language}\n(.*?)```", PAGE.read_text(), flags=re.S)


def shell(line: str, cwd: pathlib.Path, **env: str) -> subprocess.CompletedProcess:
    environ = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}", **env}
    environ.pop("MINATT_JAX_PLUGINS", None)
    return subprocess.run(line, shell=True, cwd=cwd, env=environ, capture_output=True,
                          text=True, timeout=900)  # fmt: skip


def records(run_dir: pathlib.Path) -> list[dict]:
    from minatt_jax import runner

    return runner.without_timings(runner.read_metrics(str(run_dir)))


@pytest.fixture
def uninstalls_the_example():
    """The page installs the example into the running environment; remove it afterwards, so
    the suite leaves no editable install pointing into a temporary folder."""
    yield
    subprocess.run([sys.executable, "-m", "pip", "uninstall", "-y", "minatt-ars"],
                   capture_output=True, timeout=300)  # fmt: skip


@pytest.mark.slow
@pytest.mark.usefixtures("uninstalls_the_example")
def test_the_plugin_example_runs_through_the_console_command_as_documented(tmp_path):
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    outputs = {}
    for block in blocks("bash"):
        for line in block.strip().splitlines():
            proc = shell(line, tmp_path)
            assert proc.returncode == 0, (line, proc.stderr[-2000:])
            assert "Traceback" not in proc.stderr, (line, proc.stderr[-2000:])
            outputs[line.split()[1] if line.startswith("minatt-jax") else "pip"] = proc.stdout
    runs = tmp_path / "runs" / "ars"
    members = ["ars_step_size0.02_seed0", "ars_step_size0.05_seed0"]
    # Two swept values of the agent's own setting: one compiled program.
    assert "population of 2 members in 1 compiled program(s)" in outputs["train"] or all(
        (runs / m / "metrics.jsonl").exists() for m in members
    )
    stored = json.loads((runs / members[1] / "config.json").read_text())
    assert stored["agent_module"] == "minatt_ars" and stored["ars"]["step_size"] == 0.05
    assert stored["ma"]["placement"] == "actor_loss" and "sac" not in stored
    # Resumed from 600 to 900 steps: the records of the run made in one go.
    whole = tmp_path / "runs" / "whole"
    proc = shell("minatt-jax train --algo ars --env point_robot_dense --preset smoke --alpha 0.5 "
                 f"--seeds 0 --sweep ars.step_size=0.02,0.05 --steps 900 --out {whole}",
                 tmp_path)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    for m in members:
        split, straight = records(runs / m), records(whole / m)
        assert len(split) == 3 and split == straight, m
        assert split[-1]["ma_penalty"] > 0  # MA is on, in the agent's own placement
    # MA's weight moved the members apart: the step sizes trained different policies.
    assert records(runs / members[0])[-1]["return"] != records(runs / members[1])[-1]["return"]
    assert "on crippled" in outputs["evaluate"]
    meta = json.loads((runs / members[1] / "meta_test_crippled.json").read_text())
    for task in meta["tasks"]:  # no adaptation: the policy is unchanged by the step
        assert task["policy_distance_curve"] == [0.0]
        assert task["return_curve"][0] == pytest.approx(task["return_curve"][1])
    assert (tmp_path / "runs" / "ars_report" / "report.html").exists()
    assert "agent/params/W" in outputs["inspect"]
    # The page's Python blocks, in one interpreter (it sees the package just installed).
    code = "\n".join(blocks("python"))
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                          text=True, timeout=600)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "ars applies minimum attention in placement actor_loss or reward" in proc.stdout


@pytest.mark.slow
def test_a_module_on_the_path_is_a_plugin_and_its_runs_remember_it(tmp_path):
    """``--plugin`` loads a module that registers an agent; the run's config.json records the
    module, so later commands find the agent alone, and say in one line what to do when the
    module is gone. ``inspect`` reads the run without its agent."""
    tests = str(ROOT / "tests")
    run = tmp_path / "toy"
    proc = shell(f"minatt-jax --plugin test_user_agent train --algo toy_reinforce --env "
                 f"point_robot_dense --preset smoke --steps 200 --set eval_every=100 "
                 f"--set toy.lr=0.01 --out {run}", tmp_path, PYTHONPATH=tests)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert json.loads((run / "config.json").read_text())["agent_module"] == "test_user_agent"
    proc = shell(f"minatt-jax evaluate {run} --episodes 1", tmp_path, PYTHONPATH=tests)
    assert proc.returncode == 0 and "return" in proc.stdout, proc.stderr[-2000:]
    gone = shell(f"minatt-jax evaluate {run} --episodes 1", tmp_path)
    lines = gone.stderr.strip().splitlines()
    assert gone.returncode == 2 and len(lines) == 1, gone.stderr
    assert "test_user_agent" in lines[0] and "--plugin" in lines[0] and "corrupt" not in lines[0]
    proc = shell(f"minatt-jax inspect {run}", tmp_path)
    assert proc.returncode == 0 and "agent/params" in proc.stdout, proc.stderr
    # No adapter (toy_reinforce declares none): meta-test refuses in one line.
    proc = shell(f"minatt-jax meta-test {run} --variant crippled", tmp_path, PYTHONPATH=tests)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and "no adapter" in lines[0], proc.stderr
