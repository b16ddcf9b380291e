"""The registry of agents: ``--algo`` and ``minatt_jax.train(algo=...)`` read only this.

An agent is registered as an :class:`AgentSpec` under its name. Where an agent comes from, in the
order ``get`` looks:

1. agents registered in this process (``register(spec)``, as an agent module does when imported);
2. the built-in agents (sac, mbpo, mbmpo, dreamer, mamba, ppo), imported on first use, so that the
   registry (and ``config``, which resolves a run's defaults through it) imports no agent module;
3. installed plugins: the entry points of group ``minatt_jax.agents`` (name = the algorithm, value
   = the module that registers it), imported when their name is asked for;
4. the module a run's ``config.json`` records (``TrainConfig.agent_module``), so every command
   on a run finds its agent without being told;
5. modules named by ``--plugin MODULE`` or ``MINATT_JAX_PLUGINS`` (``load_plugins``).

Plugins load when a command asks for them, never at interpreter start. An agent owns its settings:
``AgentSpec.groups`` declares each settings group (a frozen dataclass of ``fields.setting``
fields) it reads, with the group's values per preset; ``docs/extending.md`` is the guide.
"""

from __future__ import annotations

import dataclasses
import importlib
import os
from collections.abc import Callable, Iterable, Mapping
from typing import Any

# name -> the module that registers it when imported
BUILTIN = {
    "sac": "minatt_jax.agents.sac",
    "mbpo": "minatt_jax.agents.mbpo",
    "mbmpo": "minatt_jax.agents.mbmpo",
    "dreamer": "minatt_jax.agents.dreamer",
    "mamba": "minatt_jax.agents.mamba",
    "ppo": "minatt_jax.agents.ppo",
}
AGENT_ENTRY_POINTS = "minatt_jax.agents"
ENV_ENTRY_POINTS = "minatt_jax.envs"
PLUGINS_VARIABLE = "MINATT_JAX_PLUGINS"


class UnknownAgentError(ValueError):
    """An algorithm name that no agent is registered under (one line, naming what to do)."""


class PluginError(ValueError):
    """A plugin module that cannot be imported (one line, naming the module and the cause)."""


@dataclasses.dataclass(frozen=True)
class SettingsGroup:
    """A group of settings an agent owns: ``--set <name>.<field>=...``, ``config.<name>``.

    Attributes:
      name: the group's name in dotted settings and in ``config.json`` (``"sac"``, ``"td3"``).
      settings: a frozen dataclass whose fields are declared with ``fields.setting`` (default and
        rule together) and whose ``__post_init__`` calls ``fields.check(self, name)``.
      presets: ``{preset: {field: value}}``: the group's values in a preset (``smoke``, ``cpu``,
        ``paper``); fields not named keep the dataclass default.
    """

    name: str
    settings: type
    presets: Mapping[str, Mapping[str, Any]] = dataclasses.field(default_factory=dict)

    def default(self, preset: str) -> Any:
        """The group's settings in ``preset``."""
        return self.settings(**self.presets.get(preset, {}))


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
      groups: the settings groups the agent owns (``SettingsGroup``); a run's configuration
        holds exactly these beside the common fields, ``ma`` and ``caps``.
      defaults: ``config -> {dotted field: value}``: the algorithm's derived defaults, applied
        by ``config.resolve`` to every named field left at ``None`` (a name that is no setting
        is refused), and its cross-field checks (ValueError).
      adapter: ``(config, env, family, settings) -> agents.base.Adapter``: what a meta-test does
        with new experience; None: the agent does not adapt (meta-test refuses it in one line).
      recurrent: the policy carries memory (export and the C-engine evaluation refuse it).
      preset_settings: ``(preset, env) -> {dotted field: value}``: what the agent sets in a
        preset for an environment (MAMBA's meta-episodes and official settings), applied
        whenever a configuration switches to this agent, under the user's own values.
      placements: the MA placements (``ma.placement``) the agent applies; ``config.resolve``
        refuses others while MA is on. The first is its default.
      read_stored: ``config.json``'s dict -> the dict in the current format: how the agent reads
        runs its earlier versions wrote.
    """

    name: str
    make: Callable[..., Any]
    policy: Callable[..., Any]
    hyper: dict[str, str]
    groups: tuple[SettingsGroup, ...] = ()
    defaults: Callable[[Any], dict[str, Any]] = lambda config: {}
    adapter: Callable[..., Any] | None = None
    recurrent: bool = False
    preset_settings: Callable[[str, str], dict[str, Any]] = lambda preset, env: {}
    placements: tuple[str, ...] = ("actor_loss", "reward")
    read_stored: Callable[[dict[str, Any]], dict[str, Any]] = lambda stored: stored

    @property
    def module(self) -> str:
        """The module that defines the agent (recorded in a run's config.json)."""
        return getattr(self.make, "__module__", "") or ""

    def group(self, name: str) -> SettingsGroup | None:
        """The agent's settings group ``name`` (None if it owns none of that name)."""
        return next((g for g in self.groups if g.name == name), None)


_SPECS: dict[str, AgentSpec] = {}


def register(spec: AgentSpec) -> AgentSpec:
    """Registers an agent under its name, so ``--algo NAME`` and ``make_config(algo=NAME)``
    find it (a later registration replaces an earlier one; a configuration refuses a settings
    group named like a common setting).

    Args:
        spec: the agent's ``AgentSpec``.

    Returns:
        ``spec`` itself, so that a module can write ``SPEC = register(AgentSpec(...))``.
    """
    _SPECS[spec.name] = spec
    return spec


def registered() -> list[AgentSpec]:
    """The agents registered in this process so far (a built-in once its module is imported)."""
    return list(_SPECS.values())


def _entry_points(group: str) -> dict[str, Any]:
    from importlib.metadata import entry_points

    return {ep.name: ep for ep in entry_points(group=group)}


def names() -> list[str]:
    """Every algorithm name: the built-in ones, installed plugins and those registered since."""
    extra = (set(_SPECS) | set(_entry_points(AGENT_ENTRY_POINTS))) - set(BUILTIN)
    return [*BUILTIN, *sorted(extra)]


def import_plugin(module: str) -> None:
    """Imports a plugin module, which registers its agents or environments as it is imported.

    Args:
        module: a dotted module name on the Python path.

    Raises:
        PluginError: the module cannot be imported (one line).
    """
    try:
        importlib.import_module(module)
    except ImportError as e:
        raise PluginError(f"cannot import plugin module {module!r} ({e}); install it or put it "
                          "on the Python path") from None  # fmt: skip


def load_plugins(modules: Iterable[str] = ()) -> list[str]:
    """Imports plugin modules: the given ones and those named in ``MINATT_JAX_PLUGINS``.

    Args:
        modules: dotted module names (the command line's ``--plugin``).

    Returns:
        The modules imported, each once, in order.

    Raises:
        PluginError: a module cannot be imported.
    """
    from_env = [m.strip() for m in os.environ.get(PLUGINS_VARIABLE, "").split(",")]
    loaded = []
    for module in [*modules, *from_env]:
        if module and module not in loaded:
            import_plugin(module)
            loaded.append(module)
    return loaded


def load_env_plugins() -> None:
    """Imports the environment plugins installed under entry-point group ``minatt_jax.envs``
    (each registers its environments with ``minatt_jax.envs.register``)."""
    for ep in _entry_points(ENV_ENTRY_POINTS).values():
        import_plugin(ep.value.partition(":")[0])


def get(name: str, module: str = "") -> AgentSpec:
    """The agent registered under a name, looked up as the module docstring says (registered,
    built in, entry points, the recorded module).

    Args:
        name: the agent's name (``--algo``).
        module: the module a run's ``config.json`` records its agent came from ("" for none).

    Returns:
        The ``AgentSpec``.

    Raises:
        UnknownAgentError: no agent of that name can be found (one line naming ``--plugin``).
    """
    if name not in _SPECS and name in BUILTIN:
        importlib.import_module(BUILTIN[name])
    if name not in _SPECS:
        ep = _entry_points(AGENT_ENTRY_POINTS).get(name)
        if ep is not None:
            import_plugin(ep.value.partition(":")[0])
    if name not in _SPECS and module:
        try:
            importlib.import_module(module)
        except ImportError as e:
            raise UnknownAgentError(
                f"algorithm {name!r} comes from module {module!r}, which cannot be imported "
                f"({e}): install it, or pass --plugin {module} with its folder on the Python path"
            ) from None
    if name not in _SPECS:
        raise UnknownAgentError(
            f"unknown algorithm {name!r}; choose from {', '.join(names())} (a plugin agent is "
            f"loaded with --plugin MODULE, {PLUGINS_VARIABLE}, or an installed entry point in "
            f"group {AGENT_ENTRY_POINTS})"
        )
    return _SPECS[name]
