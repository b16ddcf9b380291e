"""Frozen configuration dataclasses, the named presets ``smoke``, ``cpu`` and ``paper``, and the
one place that turns a preset plus overrides into a run's configuration.

* ``apply_overrides(config, ["ma.alpha=0.5", "mb.meta_inner_lr=1e-3"])``: dotted overrides of any
  field, typed from the dataclass annotations (``with_overrides`` is the keyword form for code);
* ``resolve(config)``: every derived default (fields left at ``None``) and every cross-field
  rule. The CLI, the runner, experiments and benchmarks all call it; ``make_train`` refuses an
  unresolved configuration.

Derived defaults: ``task_set`` and ``updates_per_step`` are the agent's (its registry entry's
``defaults``: mbmpo meta-trains on the "train" tasks, the model-based agents make 2 updates per
env step as in the paper's appendix); ``model.num_elites`` is min(5, ensemble_size);
``ma.temporal_dt`` is 1 update for the parameter reading and the environment's dt for the rollout
reading.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import typing
from typing import Any

from minatt_jax.agents import registry
from minatt_jax.dreamer.config import DreamerConfig
from minatt_jax.dynamics_ensemble import ModelConfig
from minatt_jax.fields import check, setting
from minatt_jax.min_attention import CAPSConfig, MAConfig


@dataclasses.dataclass(frozen=True)
class MBConfig:
    """The model-based loop (mbpo, mbmpo): defaults are the paper's appendix / MBPO hopper values.

    Attributes:
      epoch_length: env steps per epoch (the rollout-length schedule counts epochs).
      model_train_every: env steps between model fits (each followed by a rollout).
      rollout_batch: start states per rollout (split evenly over the slots).
      rollout_schedule: (start_epoch, end_epoch, min_len, max_len): the rollout length grows
        linearly from min_len to max_len between the two epochs (official MBPO's and mbrl-lib's
        hopper schedule, epochs 20 -> 150, length 1 -> 15; minatt-jax's earlier default ended at
        epoch 100).
      model_buffer_size: capacity of the imagined-transition buffer (all slots together).
      real_ratio: fraction of each agent batch drawn from real data (the rest from the model).
      obs_clip: imagined observations are clipped to [-obs_clip, obs_clip].
      meta_inner_lr: beta of the MAML inner step theta' = theta - beta grad L_i(theta).
      meta_first_order: drop the inner gradient's dependence on theta (first-order MAML).
      meta_inner: inner-step objective, "sac" (the SAC actor loss) or "vpg" (REINFORCE on
        imagined trajectories of ``vpg_horizon`` steps from ``task batch`` start states).
      meta_outer: outer step, "sac" (Adam on the meta objective) or "trpo" (a trust-region step
        on it with KL <= ``trpo_max_kl``).
    """

    epoch_length: int = setting(1000, ge=1)
    model_train_every: int = setting(250, ge=1)
    rollout_batch: int = setting(100_000, ge=1)
    rollout_schedule: tuple[int, int, int, int] = setting(
        (20, 150, 1, 15), length=4, item={"kind": int, "ge": 0}
    )
    model_buffer_size: int = setting(2_000_000, ge=1)
    real_ratio: float = setting(0.05, ge=0, le=1)
    obs_clip: float = setting(100.0, gt=0)
    meta_inner_lr: float = setting(1e-3, ge=0)
    meta_first_order: bool = setting(False)
    meta_inner: str = setting("sac", choices=("sac", "vpg"))
    vpg_horizon: int = setting(10, ge=1)
    meta_outer: str = setting("sac", choices=("sac", "trpo"))
    trpo_max_kl: float = setting(0.01, gt=0)

    def __post_init__(self) -> None:
        check(self, "mb")
        start, end, lo, hi = self.rollout_schedule
        if not (0 < lo <= hi and start <= end):
            raise ValueError("mb.rollout_schedule must be (start_epoch, end_epoch, min_len, "
                             "max_len) with start <= end and 0 < min <= max, got "
                             f"{self.rollout_schedule}")  # fmt: skip

    def rollout_length(self, epoch):
        """The scheduled rollout length at ``epoch`` (works on ints and traced arrays)."""
        start, end, lo, hi = self.rollout_schedule
        frac = (epoch - start) / max(end - start, 1)
        frac = frac * (frac > 0)
        frac = frac - (frac - 1) * (frac > 1)
        return (lo + frac * (hi - lo)) // 1


@dataclasses.dataclass(frozen=True)
class SACConfig:
    """SAC settings (paper appendix): 256x256 ReLU, Adam 3e-4, gamma 0.99, tau 0.005.

    ``normalize_reward``: the paper's "rewards were normalized during training", read as the
    common running scale of the return (as gym's ``NormalizeReward`` / baselines'
    ``VecNormalize``): every environment keeps its discounted return G <- gamma G + r (zeroed
    when an episode ends), the running variance of G over all steps is tracked, and the rewards
    of every SAC batch (real, imagined, adaptation) are divided by sqrt(var + 1e-8), not
    shifted. MA's reward placement then subtracts its penalty from the scaled reward.
    """

    hidden: tuple[int, ...] = setting((256, 256), min_length=1, item={"kind": int, "ge": 1})
    actor_lr: float = setting(3e-4, ge=0)
    critic_lr: float = setting(3e-4, ge=0)
    entropy_lr: float = setting(3e-4, ge=0)
    gamma: float = setting(0.99, ge=0, lt=1)
    tau: float = setting(0.005, gt=0, le=1)
    batch_size: int = setting(256, ge=1)
    init_entropy_coef: float = setting(1.0, gt=0)
    target_entropy: float | None = setting(None, kind=float, optional=True)  # None = -act_dim
    log_std_min: float = setting(-20.0)
    log_std_max: float = setting(2.0)
    normalize_obs: bool = setting(False)
    normalize_reward: bool = setting(False)

    def __post_init__(self) -> None:
        check(self, "sac")
        if not self.log_std_min < self.log_std_max:
            raise ValueError(f"sac.log_std_min ({self.log_std_min}) must be below "
                             f"sac.log_std_max ({self.log_std_max})")  # fmt: skip


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Everything a training run needs; saved as ``config.json`` in the run directory."""

    # env, algo, task_set, tasks and physics name registered things: ``resolve`` checks them.
    env: str = "hopper"
    algo: str = "sac"
    preset: str = setting("cpu", choices=("smoke", "cpu", "paper"))
    task_set: str | None = None  # None: the agent's default ("train" for mbmpo, else "nominal")
    tasks: tuple[str, ...] = ()  # custom tasks ("mass=1.25,slope=0.1"); replace task_set if given
    physics: str | None = None  # None: the environment's default (fast; gym for cheetah_run)
    seed: int = setting(0, ge=0, lt=2**32)
    total_steps: int = setting(50_000, ge=1)
    num_envs: int = setting(1, ge=1)
    # agent updates per env step; None: the agent's default
    updates_per_step: int | None = setting(None, kind=int, ge=1, optional=True)
    warmup_steps: int = setting(5_000, ge=0)
    buffer_size: int = setting(1_000_000, ge=1)
    max_episode_steps: int = setting(1000, ge=1)
    # Episodes of one task per meta-episode (envs.meta_episode): an agent with memory adapts in
    # context across them; each lasts at most max_episode_steps. 1: plain episodes.
    meta_episodes: int = setting(1, ge=1)
    eval_every: int = setting(5_000, ge=1)
    eval_episodes: int = setting(5, ge=1)
    noise: str = setting("gaussian", choices=("gaussian", "ou"))  # SAC's own sampling, or OU
    ou_theta: float = setting(0.15, ge=0)
    ou_sigma: float = setting(0.2, ge=0)
    sac: SACConfig = SACConfig()
    ma: MAConfig = MAConfig()
    caps: CAPSConfig = CAPSConfig()
    model: ModelConfig = ModelConfig()
    mb: MBConfig = MBConfig()
    dreamer: DreamerConfig = DreamerConfig()

    def __post_init__(self) -> None:
        check(self, "")
        if self.eval_every % self.num_envs:
            raise ValueError("eval_every must be a multiple of num_envs")

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
        return None not in (self.task_set, self.updates_per_step, self.model.num_elites,
                            self.ma.temporal_dt)  # fmt: skip

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrainConfig:
        """Inverse of ``to_dict`` (as read back from ``config.json``; JSON lists become tuples).

        Reads the format before the one-field rule too: ``mb.agent_updates_per_step`` of a
        model-based run becomes ``updates_per_step``; a run written before MA's placement was
        recorded has MA in the actor loss (the default then).
        """
        d = copy.deepcopy(d)
        if "ma" in d:
            d["ma"].setdefault("placement", "actor_loss")
        legacy_updates = d.get("mb", {}).pop("agent_updates_per_step", None)
        if legacy_updates is not None and d.get("algo", "sac") != "sac":
            d["updates_per_step"] = legacy_updates
        return _from_dict(cls, d)


def _from_dict(cls: type, d: dict[str, Any]) -> Any:
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
    return cls(**values)


PRESETS: dict[str, TrainConfig] = {
    # A few seconds of training after compilation: for tests.
    "smoke": TrainConfig(
        preset="smoke",
        total_steps=600,
        warmup_steps=200,
        buffer_size=5_000,
        max_episode_steps=100,
        eval_every=300,
        eval_episodes=2,
        sac=SACConfig(hidden=(32, 32), batch_size=64),
        model=ModelConfig(
            ensemble_size=3,
            num_elites=2,
            hidden=(32, 32),
            weight_decay=(2.5e-5, 5e-5, 1e-4),
            batch_size=64,
            max_holdout=200,
            max_epochs=3,
        ),
        updates_per_step=1,
        # DreamerV3 at toy size: the program's structure, in seconds.
        dreamer=DreamerConfig(
            deter=32,
            hidden=16,
            stoch=4,
            classes=4,
            blocks=2,
            units=32,
            layers=2,
            bins=41,
            batch_size=4,
            batch_length=16,
            imag_length=5,
            train_ratio=64.0,
            warmup=10,
        ),  # fmt: skip
        mb=MBConfig(
            epoch_length=100,
            model_train_every=100,
            rollout_batch=64,
            rollout_schedule=(0, 2, 1, 3),
            model_buffer_size=2_000,
        ),
    ),
    # What runs in minutes (sac) to under an hour (mbmpo, 50K hopper steps) on 2 CPU cores.
    # Reduced from the paper for the model-based loop, and why (measured, meta_step.py): model
    # fits are capped at 10 "epochs" of at most 20 minibatches, warm-started from the last fit
    # (one 7 x 4x200 minibatch takes 13-19 ms; full-data epochs with early stopping take 20-40 s
    # per fit, 1-2 h over the 180 fits of a 50K run). Everything else keeps the paper's values.
    "cpu": TrainConfig(
        preset="cpu",
        total_steps=50_000,
        warmup_steps=5_000,
        buffer_size=1_000_000,
        max_episode_steps=1000,
        eval_every=5_000,
        eval_episodes=5,
        model=ModelConfig(max_epochs=10, max_batches_per_epoch=20),
        # DreamerV3 at a size this CPU trains in an hour (benchmarks/dreamer_update.py: the
        # official size1m with 16 x 64 batches runs 1.4 updates/s here, a day per 100K steps at
        # train ratio 1024): half the recurrent state, sequences of 32, train ratio 256 (one
        # update per 2 env steps). Everything else is the official proprioceptive setting.
        dreamer=DreamerConfig(deter=256, batch_length=32, train_ratio=256.0),
    ),
    # The paper's appendix values (200K steps, 10 evaluation episodes).
    "paper": TrainConfig(
        preset="paper",
        total_steps=200_000,
        warmup_steps=5_000,
        buffer_size=1_000_000,
        max_episode_steps=1000,
        eval_every=10_000,
        eval_episodes=10,
    ),
}


GROUPS = ("sac", "ma", "caps", "model", "mb", "dreamer")
FLOAT32_MAX = 3.4028234663852886e38  # training runs in float32: larger values become inf


class OverrideError(ValueError):
    """An override naming an unknown field or giving a value of the wrong type."""


def _field_type(config: TrainConfig, dotted: str) -> Any:
    """The annotation of field ``group.field`` or ``field`` (OverrideError if there is none)."""
    *group, name = dotted.split(".")
    owner: Any = config
    if len(group) > 1 or (group and group[0] not in GROUPS):
        raise OverrideError(f"unknown setting {dotted!r}; groups are {', '.join(GROUPS)}")
    if group:
        owner = getattr(config, group[0])
    hints = typing.get_type_hints(type(owner))
    if name not in hints or (not group and name in GROUPS):
        fields = sorted(f"{group[0]}.{n}" if group else n for n in hints if n not in GROUPS)
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


def replace_fields(config: TrainConfig, values: dict[str, Any]) -> TrainConfig:
    """A copy with fields set by dotted name (``{"ma.alpha": 1.0, "seed": 3}``); values are
    checked by the dataclasses' own validation (ValueError)."""
    top: dict[str, Any] = {}
    nested: dict[str, dict[str, Any]] = {}
    for dotted, value in values.items():
        _field_type(config, dotted)
        if "." in dotted:
            group, name = dotted.split(".")
            nested.setdefault(group, {})[name] = value
        else:
            top[dotted] = value
    for group, fields in nested.items():
        top[group] = dataclasses.replace(getattr(config, group), **fields)
    return dataclasses.replace(config, **top)


def apply_overrides(config: TrainConfig, overrides: list[str] | tuple[str, ...]) -> TrainConfig:
    """A copy with ``"group.field=value"`` overrides applied (OverrideError / ValueError)."""
    values: dict[str, Any] = {}
    for item in overrides:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep:
            raise OverrideError(f"override {item!r} must look like group.field=value")
        values[key] = _parse(text.strip(), _field_type(config, key), key)
    return replace_fields(config, values)


def dotted_fields(**fields: Any) -> dict[str, Any]:
    """Keyword fields as dotted names (``ma_alpha`` -> ``ma.alpha``), ``None`` values dropped."""
    values = {}
    for key, value in fields.items():
        if value is None:
            continue
        group, _, name = key.partition("_")
        values[f"{group}.{name}" if group in GROUPS and name else key] = value
    return values


def with_overrides(config: TrainConfig, **fields: Any) -> TrainConfig:
    """Keyword form of ``replace_fields`` for code: ``ma_alpha=1.0`` sets ``ma.alpha``; a
    ``None`` value leaves the field unchanged."""
    return replace_fields(config, dotted_fields(**fields))


def preset_config(
    preset: str, overrides: list[str] | tuple[str, ...] = (), fields: dict[str, Any] | None = None
) -> TrainConfig:
    """A preset for the algorithm and environment the overrides and dotted ``fields`` name:
    ``PRESETS[preset]``, then what that agent sets in the preset for that environment
    (``AgentSpec.preset_settings``), then ``overrides`` ("group.field=value"), then ``fields``.
    Unresolved; OverrideError / ValueError as ``apply_overrides``."""
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; choose from {', '.join(PRESETS)}")
    fields = dict(fields or {})
    base = PRESETS[preset]
    chosen = replace_fields(apply_overrides(base, overrides), fields)
    settings = registry.get(chosen.algo).preset_settings(preset, chosen.env)
    if settings:
        base = replace_fields(base, settings)
    return replace_fields(apply_overrides(base, overrides), fields)


def resolve(config: TrainConfig) -> TrainConfig:
    """``config`` with every derived default filled in and the cross-field rules checked.

    Idempotent. Raises ValueError (one line, for the user) when the fields do not fit together
    or name an environment, physics preset or task set that is not registered.
    """
    import minatt_jax.envs as envs

    if config.env not in envs.ENVIRONMENTS:
        raise envs.UnknownNameError(f"unknown environment {config.env!r}; choose from "
                                    f"{', '.join(envs.ENVIRONMENTS)}")  # fmt: skip
    if config.physics is not None and config.physics not in envs.PHYSICS_PRESETS:
        raise ValueError(f"physics must be one of {tuple(envs.PHYSICS_PRESETS)} (or None: the "
                         f"environment's default), got {config.physics!r}")  # fmt: skip
    if config.task_set is not None:
        envs.check_task_set_name(config.task_set)
    agent_defaults = registry.get(config.algo).defaults(config)  # checks the agent's rules too
    values: dict[str, Any] = {}
    for name in ("task_set", "updates_per_step"):
        if getattr(config, name) is None:
            values[name] = agent_defaults[name]
    if config.model.num_elites is None:
        values["model.num_elites"] = min(5, config.model.ensemble_size)
    if config.ma.temporal_dt is None:
        if config.ma.temporal == "rollout":
            values["ma.temporal_dt"] = envs.make(config.env, config.physics).dt
        else:
            values["ma.temporal_dt"] = 1.0
    return replace_fields(config, values) if values else config
