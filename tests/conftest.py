"""Shared fixtures: environments are built once per session (building compiles nothing)."""

from __future__ import annotations

import pytest

import minatt_jax.envs as envs


@pytest.fixture(scope="session")
def make_env():
    cache: dict[str, envs.LocomotionEnv] = {}

    def get(name: str) -> envs.LocomotionEnv:
        if name not in cache:
            cache[name] = envs.make(name)
        return cache[name]

    return get
