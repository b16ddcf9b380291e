"""A plain (non-editable) install provides minatt_jax.envs, not a top-level ``envs``."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.mark.slow
def test_non_editable_install_imports_envs(tmp_path):
    target = tmp_path / "site"
    subprocess.run(
        [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation",
         "--target", str(target), ROOT],
        check=True, capture_output=True, timeout=300,
    )  # fmt: skip
    assert (target / "minatt_jax" / "envs" / "hopper.py").exists()
    assert not (target / "envs").exists()  # no top-level name that could collide
    for folder, _, files in os.walk(os.path.join(ROOT, "minatt_jax")):  # every subpackage
        if "__init__.py" in files:
            relative = os.path.relpath(folder, ROOT)
            assert (target / relative / "__init__.py").exists(), f"{relative} is not installed"
    code = (
        "import minatt_jax.config, minatt_jax.agents.dreamer; "
        "import minatt_jax.envs as e; env = e.make('hopper'); "
        "print(e.__file__); print(env.observation_size)"
    )
    env = {**os.environ, "PYTHONPATH": str(target)}
    proc = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True,
        timeout=300,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.strip().splitlines()
    # (importing config before envs lets mjx print its Warp note first: the last two lines)
    assert lines[-2].startswith(str(target))
    assert lines[-1] == "11"
