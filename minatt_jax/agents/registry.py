"""The registry of agents: ``--algo`` and ``minatt_jax.train(algo=...)`` read only this.

An agent is registered as an :class:`AgentSpec` under its name. The built-in agents (sac, mbpo,
mbmpo, dreamer) are found by module name and imported on first use, as plugin entry points are,
so that the registry (and ``config``, which resolves a run's defaults through it) depends on no
agent module. A user's agent registers itself with ``register(spec)`` (see ``docs/agents.md``).
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Callable
from typing import Any

# name -> the module that registers it when imported
BUILTIN = {
    "sac": "minatt_jax.agents.sac",
    "mbpo": "minatt_jax.agents.mbpo",
    "mbmpo": "minatt_jax.agents.mbmpo",
    "dreamer": "minatt_jax.agents.dreamer",
    "mamba": "minatt_jax.agents.mamba",
}


class UnknownAgentError(ValueError):
    """An algorithm name that no agent is registered under."""


@dataclasses.dataclass(frozen=True)
class AgentSpec:
    """What the library needs to know of an algorithm, without building it.

    Attributes:
      name: the ``--algo`` name.
      make: ``(config, env, task_set) -> agents.base.Agent``: the agent's pure functions for a
        resolved configuration (its structure: sizes, placements, schedules; never its ``hyper``
        values, which the state carries).
      policy: ``(config, env) -> agents.base.PolicyFamily``: how a saved policy acts, built
        without the training parts (evaluation, export, analysis, meta-testing).
      hyper: ``{hyper name: config field}``: every value a population may sweep without
        recompiling, read by the losses from the state's ``hyper`` subtree. ``"ma_terms"`` (the
        MA mode's term weights) is derived from ``ma.mode`` when named here.
      defaults: ``config -> {dotted field: value}``: the algorithm's derived defaults for fields
        left at ``None`` (``config.resolve``), and its cross-field checks (ValueError).
      adapter: ``(config, env, family, settings) -> agents.base.Adapter``: what a meta-test does
        with new experience.
      recurrent: the policy carries memory (export and the C-engine evaluation refuse it).
      preset_settings: ``(preset, env) -> {dotted field: value}``: what the agent sets in a
        preset for an environment (MAMBA's meta-episodes and official settings), applied under
        the user's overrides (``config.preset_config``).
    """

    name: str
    make: Callable[..., Any]
    policy: Callable[..., Any]
    hyper: dict[str, str]
    defaults: Callable[[Any], dict[str, Any]] = lambda config: {}
    adapter: Callable[..., Any] | None = None
    recurrent: bool = False
    preset_settings: Callable[[str, str], dict[str, Any]] = lambda preset, env: {}


_SPECS: dict[str, AgentSpec] = {}


def register(spec: AgentSpec) -> AgentSpec:
    """Registers ``spec`` under its name (a later registration replaces an earlier one)."""
    _SPECS[spec.name] = spec
    return spec


def names() -> list[str]:
    """Every algorithm name: the built-in ones and those registered since."""
    return [*BUILTIN, *sorted(set(_SPECS) - set(BUILTIN))]


def get(name: str) -> AgentSpec:
    """The spec registered under ``name`` (UnknownAgentError, one line, when there is none)."""
    if name not in _SPECS and name in BUILTIN:
        importlib.import_module(BUILTIN[name])
    if name not in _SPECS:
        raise UnknownAgentError(f"unknown algorithm {name!r}; choose from {', '.join(names())}")
    return _SPECS[name]
