"""The run's configuration: its common fields, the shared groups ``ma`` and ``caps``, and the
settings groups its agent owns; the named presets ``smoke``, ``cpu`` and ``paper``; the one place
that turns a preset plus overrides into a run's configuration.

* ``apply_overrides(config, ["ma.alpha=0.5", "mb.meta_inner_lr=1e-3"])``: dotted overrides of any
  field, typed from the dataclass annotations (``with_overrides`` is the keyword form for code);
* ``resolve(config)``: every derived default (fields left at ``None``) and every cross-field
  rule. The CLI, the runner, experiments and benchmarks all call it; ``make_train`` refuses an
  unresolved configuration.

An agent's own settings (``sac.*``, ``mb.*``, ``dreamer.*``, a plugin's ``td3.*``) are not
declared here: its ``AgentSpec.groups`` declares them (``agents.registry.SettingsGroup``), and a
configuration holds exactly the groups of its ``algo``, read as attributes (``config.sac``).
Switching the algorithm (``with_overrides(config, algo="mbpo")``) keeps the groups both agents
own, gives the others their values in the configuration's preset, and applies the new agent's
``preset_settings``; the caller's own values are applied after all of that.

Derived defaults: ``task_set``, ``updates_per_step``, ``ma.placement`` and the agent's own
optional fields are the agent's (its ``defaults`` and ``placements``: mbmpo meta-trains on the
"train" tasks, the model-based agents make 2 updates per env step as in the paper's appendix);
``ma.temporal_dt`` is 1 update for the parameter reading and the environment's dt for the rollout
reading.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import typing
from collections.abc import Iterator, Mapping
from typing import Any

from minatt_jax.agents import registry
from minatt_jax.fields import check, setting
from minatt_jax.min_attention import CAPSConfig, MAConfig

# Groups every agent shares (an agent's own groups may take no name of these or of a top field).
COMMON_GROUPS = ("ma", "caps")
# Groups of the configuration format before agents owned their settings: every run held all
# four; a run's config.json read back keeps those its agent owns and drops the others.
LEGACY_GROUPS = ("sac", "model", "mb", "dreamer")


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Everything a training run needs; saved as ``config.json`` in the run directory.

    The agent's own settings groups are read as attributes (``config.sac``, ``config.mb``):
    ``groups`` holds them, exactly those of ``algo``'s ``AgentSpec.groups`` (filled in on
    construction, each with its value in ``preset`` where not given).
    """

    # env, algo, task_set, tasks and physics name registered things: ``resolve`` checks them.
    env: str = setting("hopper", why="the paper's first environment")
    algo: str = setting("sac", why="model-free SAC; mbmpo is the paper's meta-learner")
    preset: str = setting("cpu", choices=("smoke", "cpu", "paper"))
    task_set: str | None = None  # None: the agent's default ("train" for mbmpo, else "nominal")
    tasks: tuple[str, ...] = ()  # custom tasks ("mass=1.25,slope=0.1"); replace task_set if given
    physics: str | None = None  # None: the environment's default (fast; gym for cheetah_run)
    seed: int = setting(0, ge=0, lt=2**32)
    total_steps: int = setting(50_000, ge=1, why="the preset's")
    num_envs: int = setting(1, ge=1, why="one env step per update, as the paper")
    # agent updates per env step; None: the agent's default
    updates_per_step: int | None = setting(
        None, kind=int, ge=1, optional=True,
        why="the agent's: 1 for sac, the paper's 2 for mbpo and mbmpo",
    )  # fmt: skip
    warmup_steps: int = setting(5_000, ge=0)
    buffer_size: int = setting(1_000_000, ge=1)
    max_episode_steps: int = setting(1000, ge=1)
    # Episodes of one task per meta-episode (envs.meta_episode): an agent with memory adapts in
    # context across them; each lasts at most max_episode_steps. 1: plain episodes.
    meta_episodes: int = setting(1, ge=1)
    eval_every: int = setting(5_000, ge=1, why="the preset's")
    eval_episodes: int = setting(5, ge=1)
    noise: str = setting("gaussian", choices=("gaussian", "ou"),
                         why="SAC's own Gaussian exploration")  # fmt: skip
    ou_theta: float = setting(0.15, ge=0)
    ou_sigma: float = setting(0.2, ge=0)
    ma: MAConfig = MAConfig(placement=None)  # placement None: the agent's default
    caps: CAPSConfig = CAPSConfig()
    # The module a plugin agent came from ("" for a built-in agent): later commands import it.
    agent_module: str = ""
    # The agent's settings groups, (name, settings) in its declared order (see the docstring).
    groups: tuple[tuple[str, Any], ...] = ()

    def __post_init__(self) -> None:
        check(self, "")
        if self.eval_every % self.num_envs:
            raise ValueError("eval_every must be a multiple of num_envs")
        spec = registry.get(self.algo, self.agent_module)
        for group in spec.groups:
            if group.name in COMMON_GROUPS or group.name in {
                f.name for f in dataclasses.fields(self)
            }:
                raise ValueError(f"agent {self.algo!r}: settings group {group.name!r} has the "
                                 "name of a common setting; choose another")  # fmt: skip
        given = dict(self.groups)
        groups = tuple((g.name, given[g.name] if isinstance(given.get(g.name), g.settings)
                        else g.default(self.preset)) for g in spec.groups)  # fmt: skip
        object.__setattr__(self, "groups", groups)
        if not self.agent_module and self.algo not in registry.BUILTIN:
            object.__setattr__(self, "agent_module", spec.module)

    def __getattr__(self, name: str) -> Any:
        """An agent settings group by name (``config.sac``)."""
        for group, value in self.__dict__.get("groups", ()):
            if group == name:
                return value
        raise AttributeError(
            f"{type(self).__name__} of algorithm {self.__dict__.get('algo')!r} has no field or "
            f"settings group {name!r}"
        )

    @property
    def group_names(self) -> tuple[str, ...]:
        """Every settings group of this configuration: the shared ones, then the agent's."""
        return (*COMMON_GROUPS, *(name for name, _ in self.groups))

    @property
    def episode_limit(self) -> int:
        """The steps a collector or an evaluation lets one episode run: a whole meta-episode."""
        return self.meta_episodes * self.max_episode_steps

    def make_env(self) -> Any:
        """The run's environment: ``env`` with its ``physics``, in meta-episodes of
        ``meta_episodes`` episodes where that is above 1."""
        import minatt_jax.envs as envs
        from minatt_jax.envs.meta_episode import MetaEpisode

        env = envs.make(self.env, self.physics)
        if self.meta_episodes > 1:
            env = MetaEpisode(env, self.meta_episodes, self.max_episode_steps)
        return env

    @property
    def planned_steps(self) -> int:
        """The env steps a run trains: whole chunks of ``eval_every`` covering ``total_steps``."""
        return -(-self.total_steps // self.eval_every) * self.eval_every

    @property
    def is_resolved(self) -> bool:
        if None in (self.task_set, self.updates_per_step, self.ma.temporal_dt, self.ma.placement):
            return False
        derived = registry.get(self.algo, self.agent_module).defaults(self)
        return all(value_of(self, k) is not None for k in derived)

    def to_dict(self) -> dict[str, Any]:
        """The configuration as ``config.json`` holds it: the fields, then one object per
        settings group (``"sac": {...}``); ``agent_module`` only for a plugin agent."""
        d = {f.name: dataclasses.asdict(v) if dataclasses.is_dataclass(v) else v
             for f in dataclasses.fields(self) if f.name != "groups"
             for v in [getattr(self, f.name)]}  # fmt: skip
        d = {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}
        if not self.agent_module:
            del d["agent_module"]
        for name, value in self.groups:
            d[name] = dataclasses.asdict(value)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrainConfig:
        """Inverse of ``to_dict`` (as read back from ``config.json``; JSON lists become tuples).
        The agent is looked up (its recorded ``agent_module`` imported) to read its groups.

        Reads the earlier formats too: ``mb.agent_updates_per_step`` of a model-based run
        becomes ``updates_per_step``; a run written before MA's placement was recorded has MA in
        the actor loss (the default then); groups of the format in which every run held every
        built-in group (``LEGACY_GROUPS``) are dropped where the agent does not own them; the
        agent reads its own earlier formats (``AgentSpec.read_stored``).
        """
        d = copy.deepcopy(d)
        if "ma" in d:
            d["ma"].setdefault("placement", "actor_loss")
        legacy_updates = d.get("mb", {}).pop("agent_updates_per_step", None)
        if legacy_updates is not None and d.get("algo", "sac") != "sac":
            d["updates_per_step"] = legacy_updates
        algo = d.get("algo", "sac")
        spec = registry.get(algo, d.get("agent_module", ""))
        d = spec.read_stored(d)
        names = {f.name for f in dataclasses.fields(cls)} - {"groups"}
        groups = []
        for key in [k for k in d if k not in names]:
            value = d.pop(key)
            group = spec.group(key)
            if group is not None:
                groups.append((key, _from_dict(group.settings, value)))
            elif key not in LEGACY_GROUPS:
                raise TypeError(f"unknown TrainConfig field or {algo} settings group {key!r}")
        return _from_dict(cls, d, groups=tuple(groups))


def _from_dict(cls: type, d: dict[str, Any], **extra: Any) -> Any:
    """A (nested) config dataclass from a dict; unknown keys raise TypeError."""
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(d) - names
    if unknown:
        raise TypeError(f"unknown {cls.__name__} fields: {', '.join(sorted(unknown))}")
    values = {}
    for name, value in d.items():
        hint = hints[name]
        if dataclasses.is_dataclass(hint):
            values[name] = _from_dict(hint, value)
        elif isinstance(value, list):
            values[name] = tuple(value)
        else:
            values[name] = value
    return cls(**values, **extra)


class _Presets(Mapping[str, TrainConfig]):
    """The named presets, each built on first use: a configuration looks its agent up in the
    registry, which imports the agent's module (and that may import this one)."""

    def __init__(self, fields: dict[str, dict[str, Any]]) -> None:
        self._fields = fields
        self._built: dict[str, TrainConfig] = {}

    def __getitem__(self, name: str) -> TrainConfig:
        if name not in self._built:
            self._built[name] = TrainConfig(preset=name, **self._fields[name])
        return self._built[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._fields)

    def __len__(self) -> int:
        return len(self._fields)


PRESETS: Mapping[str, TrainConfig] = _Presets(
    {
        # A few seconds of training after compilation: for tests. (Each agent's own groups carry
        # their smoke values: ``SettingsGroup.presets``.)
        "smoke": dict(
            total_steps=600,
            warmup_steps=200,
            buffer_size=5_000,
            max_episode_steps=100,
            eval_every=300,
            eval_episodes=2,
            updates_per_step=1,
        ),
        # What runs in minutes (sac) to under an hour (mbmpo, 50K hopper steps) on 2 CPU cores
        # (the agents' groups carry their reductions for the cpu preset).
        "cpu": dict(
            total_steps=50_000,
            warmup_steps=5_000,
            buffer_size=1_000_000,
            max_episode_steps=1000,
            eval_every=5_000,
            eval_episodes=5,
        ),
        # The paper's appendix values (200K steps, 10 evaluation episodes).
        "paper": dict(
            total_steps=200_000,
            warmup_steps=5_000,
            buffer_size=1_000_000,
            max_episode_steps=1000,
            eval_every=10_000,
            eval_episodes=10,
        ),
    }
)


FLOAT32_MAX = 3.4028234663852886e38  # training runs in float32: larger values become inf
# Fields that decide which agent, environment and preset the others belong to: applied first.
IDENTITY_FIELDS = ("algo", "env")


class OverrideError(ValueError):
    """An override naming an unknown field or giving a value of the wrong type."""


def value_of(config: TrainConfig, dotted: str) -> Any:
    """The value of field ``group.field`` or ``field`` of ``config``."""
    value: Any = config
    for part in dotted.split("."):
        value = getattr(value, part)
    return value


def _field_type(config: TrainConfig, dotted: str) -> Any:
    """The annotation of field ``group.field`` or ``field`` (OverrideError if there is none)."""
    *group, name = dotted.split(".")
    owner: Any = config
    groups = config.group_names
    if len(group) > 1 or (group and group[0] not in groups):
        others = [s.name for s in registry.registered() if group and s.group(group[0])]
        hint = f" ({group[0]}.* is a setting of --algo {' / '.join(others)})" if others else ""
        raise OverrideError(f"unknown setting {dotted!r}; the groups of algorithm {config.algo} "
                            f"are {', '.join(groups)}{hint}")  # fmt: skip
    if group:
        owner = getattr(config, group[0])
    hints = typing.get_type_hints(type(owner))
    hidden = set(groups) | {"groups"}
    if name not in hints or (not group and name in hidden):
        fields = sorted(f"{group[0]}.{n}" if group else n for n in hints if n not in hidden)
        raise OverrideError(f"unknown setting {dotted!r}; choose from {', '.join(fields)}")
    return hints[name]


def _parse(text: str, hint: Any, dotted: str) -> Any:
    """``text`` as a value of type ``hint`` (int, float, bool, str, tuples of them, X | None)."""
    args = typing.get_args(hint)
    if type(None) in args:  # X | None
        if text.strip().lower() == "none":
            return None
        return _parse(text, next(a for a in args if a is not type(None)), dotted)
    if typing.get_origin(hint) is tuple:
        item = args[0]
        parts = [p for p in text.replace("(", "").replace(")", "").split(",") if p.strip()]
        return tuple(_parse(p.strip(), item, dotted) for p in parts)
    try:
        if hint is bool:
            lowered = text.strip().lower()
            if lowered not in ("true", "false", "1", "0", "yes", "no"):
                raise ValueError
            return lowered in ("true", "1", "yes")
        if hint is int:
            return int(text)
        if hint is float:
            value = float(text)
            if not math.isfinite(value) or abs(value) > FLOAT32_MAX:
                raise ValueError
            return value
    except ValueError:
        kind = {bool: "true or false", int: "an integer",
                float: "a finite number within float32's range"}[hint]  # fmt: skip
        raise OverrideError(f"{dotted} expects {kind}, got {text!r}") from None
    return text


def _switch_agent(config: TrainConfig, algo: str, env: str) -> TrainConfig:
    """``config`` for another agent or environment: the groups both agents own kept, the new
    agent's other groups at their ``preset`` values, then its ``preset_settings``."""
    switched = dataclasses.replace(
        config, algo=algo, env=env, agent_module="" if algo != config.algo else config.agent_module
    )
    settings = registry.get(algo).preset_settings(config.preset, env)
    return replace_fields(switched, settings) if settings else switched


def replace_fields(config: TrainConfig, values: dict[str, Any]) -> TrainConfig:
    """A copy with fields set by dotted name (``{"ma.alpha": 1.0, "seed": 3}``); values are
    checked by the dataclasses' own validation (ValueError). ``algo`` and ``env`` apply first
    (``_switch_agent`` where they change), so the other names may be the new agent's settings."""
    values = dict(values)
    identity = {k: values.pop(k) for k in IDENTITY_FIELDS if k in values}
    if identity:
        for key, value in identity.items():
            if not isinstance(value, str):
                raise ValueError(f"{key} must be a name, got {value!r}")
        algo, env = identity.get("algo", config.algo), identity.get("env", config.env)
        if (algo, env) != (config.algo, config.env):
            config = _switch_agent(config, algo, env)
    top: dict[str, Any] = {}
    nested: dict[str, dict[str, Any]] = {}
    for dotted, value in values.items():
        _field_type(config, dotted)
        if "." in dotted:
            group, name = dotted.split(".")
            nested.setdefault(group, {})[name] = value
        else:
            top[dotted] = value
    groups = dict(config.groups)
    for group, fields in nested.items():
        if group in COMMON_GROUPS:
            top[group] = dataclasses.replace(getattr(config, group), **fields)
        else:
            groups[group] = dataclasses.replace(groups[group], **fields)
    if len(nested.keys() - set(COMMON_GROUPS)):
        top["groups"] = tuple(groups.items())
    return dataclasses.replace(config, **top) if top else config


def apply_overrides(config: TrainConfig, overrides: list[str] | tuple[str, ...]) -> TrainConfig:
    """A copy with ``"group.field=value"`` overrides applied (OverrideError / ValueError):
    ``algo`` and ``env`` first, wherever they stand, so the others are typed against the agent
    they name."""
    pairs = []
    for item in overrides:
        key, sep, text = item.partition("=")
        if not sep:
            raise OverrideError(f"override {item!r} must look like group.field=value")
        pairs.append((key.strip(), text.strip()))
    identity = {k: t for k, t in pairs if k in IDENTITY_FIELDS}
    config = replace_fields(config, identity) if identity else config
    return replace_fields(config, {k: _parse(t, _field_type(config, k), k) for k, t in pairs
                                   if k not in IDENTITY_FIELDS})  # fmt: skip


def dotted_fields(**fields: Any) -> dict[str, Any]:
    """Keyword fields as dotted names (``ma_alpha`` -> ``ma.alpha``, ``td3_policy_noise`` ->
    ``td3.policy_noise`` for the groups of the named or any registered agent), ``None`` values
    dropped."""
    groups = set(COMMON_GROUPS)
    if isinstance(fields.get("algo"), str):
        groups |= {g.name for g in registry.get(fields["algo"]).groups}
    groups |= {g.name for spec in registry.registered() for g in spec.groups}
    values = {}
    for key, value in fields.items():
        if value is None:
            continue
        group = max((g for g in groups if key.startswith(g + "_") and len(key) > len(g) + 1),
                    key=len, default=None)  # fmt: skip
        values[f"{group}.{key[len(group) + 1 :]}" if group else key] = value
    return values


def with_overrides(config: TrainConfig, **fields: Any) -> TrainConfig:
    """Keyword form of ``replace_fields`` for code: ``ma_alpha=1.0`` sets ``ma.alpha``; a
    ``None`` value leaves the field unchanged."""
    return replace_fields(config, dotted_fields(**fields))


def preset_config(
    preset: str, overrides: list[str] | tuple[str, ...] = (), fields: dict[str, Any] | None = None
) -> TrainConfig:
    """A preset for the algorithm and environment the overrides and dotted ``fields`` name:
    ``PRESETS[preset]``, switched to that agent and environment (its groups' values in the
    preset, its ``preset_settings``), then ``overrides`` ("group.field=value"), then ``fields``.
    Unresolved; OverrideError / ValueError as ``apply_overrides``."""
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; choose from {', '.join(PRESETS)}")
    fields = dict(fields or {})
    base = PRESETS[preset]
    identity = {k: fields[k] for k in IDENTITY_FIELDS if k in fields}
    base = replace_fields(base, identity) if identity else base
    return replace_fields(apply_overrides(base, overrides), fields)


def resolve(config: TrainConfig) -> TrainConfig:
    """``config`` with every derived default filled in and the cross-field rules checked.

    Idempotent. Raises ValueError (one line, for the user) when the fields do not fit together
    or name an environment, physics preset or task set that is not registered.
    """
    import minatt_jax.envs as envs

    if config.env not in envs.ENVIRONMENTS:
        envs.load_plugin_env(config.env)
    if config.env not in envs.ENVIRONMENTS:
        raise envs.UnknownNameError(f"unknown environment {config.env!r}; choose from "
                                    f"{', '.join(envs.environment_names())}")  # fmt: skip
    if config.physics is not None and config.physics not in envs.PHYSICS_PRESETS:
        raise ValueError(f"physics must be one of {tuple(envs.PHYSICS_PRESETS)} (or None: the "
                         f"environment's default), got {config.physics!r}")  # fmt: skip
    if config.task_set is not None:
        envs.check_task_set_name(config.task_set)
    spec = registry.get(config.algo, config.agent_module)
    placement = config.ma.placement
    if placement is not None and config.ma.active and placement not in spec.placements:
        raise ValueError(f"{config.algo} applies minimum attention in placement "
                         f"{' or '.join(spec.placements)}; ma.placement {placement!r} would "
                         "leave it out")  # fmt: skip
    values: dict[str, Any] = {}
    if placement is None:
        values["ma.placement"] = spec.placements[0]
    agent_defaults = spec.defaults(config)  # checks the agent's rules too
    for name, value in agent_defaults.items():
        _field_type(config, name)  # a derived default must name a setting
        if value_of(config, name) is None:
            values[name] = value
    for name in ("task_set", "updates_per_step"):
        if getattr(config, name) is None and name not in values:
            raise ValueError(f"agent {config.algo} derives no default for {name}: its "
                             f"AgentSpec.defaults must name it")  # fmt: skip
    if config.ma.temporal_dt is None:
        if config.ma.temporal == "rollout":
            values["ma.temporal_dt"] = envs.make(config.env, config.physics).dt
        else:
            values["ma.temporal_dt"] = 1.0
    return replace_fields(config, values) if values else config


def settings_rows(config: TrainConfig) -> list[dict[str, Any]]:
    """Every setting of ``config`` (its fields and every group's), as rows ``{"name", "type",
    "rule", "default", "meaning"}``: what ``train --help`` and the configuration page list."""
    from minatt_jax.fields import field_rows

    rows = field_rows(config, "", skip=(*config.group_names, "groups", "agent_module"))
    for group in config.group_names:
        rows += field_rows(getattr(config, group), group)
    return rows


def settings_by_owner(builtin_only: bool = False) -> list[tuple[str, list[dict[str, Any]]]]:
    """Every setting of every known agent (``builtin_only``: of minatt-jax's own) once, under
    the first owner that has it ("common" for the fields all share, else the agent's name),
    each row of ``settings_rows`` with ``"presets"``: its value in each preset. What ``train
    --help`` and the settings page list."""
    from minatt_jax.agents import registry

    owners: list[tuple[str, list[dict[str, Any]]]] = []
    seen: set[str] = set()
    for algo in list(registry.BUILTIN) if builtin_only else registry.names():
        try:
            per_preset = {p: settings_rows(with_overrides(PRESETS[p], algo=algo)) for p in PRESETS}
        except ValueError:
            continue
        values = {p: {r["name"]: r["default"] for r in rows} for p, rows in per_preset.items()}
        rows = [{**r, "presets": {p: values[p].get(r["name"]) for p in PRESETS}}
                for r in per_preset["cpu"] if r["name"] not in seen]  # fmt: skip
        if rows:
            owners.append(("common" if not seen else algo, rows))
            seen.update(r["name"] for r in rows)
    return owners


def _group_in_preset(group: str, preset: str) -> Any:
    """The settings of ``group`` in ``preset``: the preset's own (common fields, ``ma``,
    ``caps``, SAC's), else those of the first built-in or registered agent that owns it."""
    config = PRESETS[preset]
    if not group:
        return config
    if group in config.group_names:
        return getattr(config, group)
    for algo in registry.names():
        owned = registry.get(algo).group(group)
        if owned is not None:
            return owned.default(preset)
    raise OverrideError(f"no agent owns settings group {group!r}")


def default_value(dotted: str, preset: str = "cpu") -> Any:
    """A setting's value in ``preset`` (``_group_in_preset``); None where the agent derives it."""
    group, _, name = dotted.rpartition(".")
    return getattr(_group_in_preset(group, preset), name)


def default_note(dotted: str, preset: str = "cpu") -> str:
    """``"default <value>: <why>"`` of a setting in ``preset``, from its declaration (``train
    --help`` appends it to each flag's help)."""
    from minatt_jax.fields import why_of

    group, _, name = dotted.rpartition(".")
    owner = _group_in_preset(group, preset)
    value = getattr(owner, name)
    why = why_of(next(f for f in dataclasses.fields(owner) if f.name == name))
    if value is None:
        shown = "derived"
    elif isinstance(value, bool):
        shown = "on" if value else "off"
    elif isinstance(value, int):
        shown = f"{value:,}"
    elif isinstance(value, float):
        shown = f"{value:g}"
    else:
        shown = str(value)
    return f"default {shown}: {why}" if why else f"default {shown}"
