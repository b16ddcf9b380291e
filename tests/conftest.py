"""Shared fixtures and a persistent XLA compilation cache for the whole session.

Several tests compile the same programs (in-process, in subprocesses and in pytest-xdist
workers); the cache, in one fresh temporary folder per session that the workers and subprocesses
inherit through the environment, lets the later ones load them instead of compiling again.
"""

from __future__ import annotations

import os
import tempfile

import jax
import pytest

import minatt_jax.envs as envs

# The controller makes the folder; xdist workers and subprocesses find it in their environment.
_CACHE = os.environ.get("JAX_COMPILATION_CACHE_DIR") or tempfile.mkdtemp(
    prefix="minatt-jax-xla-cache-"
)
os.environ["JAX_COMPILATION_CACHE_DIR"] = _CACHE
jax.config.update("jax_compilation_cache_dir", _CACHE)
jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)


@pytest.fixture(scope="session")
def make_env():
    cache: dict[str, envs.LocomotionEnv] = {}

    def get(name: str) -> envs.LocomotionEnv:
        if name not in cache:
            cache[name] = envs.make(name)
        return cache[name]

    return get


def run_cli(argv: list[str], capsys: pytest.CaptureFixture) -> tuple[int, object]:
    """The CLI's exit status (returned, or raised by argparse) and what it printed."""
    from minatt_jax.cli import main

    try:
        status = main(argv)
    except SystemExit as e:
        status = e.code
    return status, capsys.readouterr()
