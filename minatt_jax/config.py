"""Frozen configuration dataclasses and the named presets ``smoke``, ``cpu`` and ``paper``.

Presets set the scale of a run; CLI flags override single fields (``with_overrides``).
"""

from __future__ import annotations

import dataclasses
from typing import Any

from minatt_jax.dynamics_ensemble import ModelConfig
from minatt_jax.min_attention import CAPSConfig, MAConfig

ALGOS = ("sac", "mbpo", "mbmpo")


@dataclasses.dataclass(frozen=True)
class MBConfig:
    """The model-based loop (mbpo, mbmpo): defaults are the paper's appendix / MBPO hopper values.

    Attributes:
      epoch_length: env steps per epoch (the rollout-length schedule counts epochs).
      model_train_every: env steps between model fits (each followed by a rollout).
      rollout_batch: start states per rollout (split evenly over the slots).
      rollout_schedule: (start_epoch, end_epoch, min_len, max_len): the rollout length grows
        linearly from min_len to max_len between the two epochs (MBPO's hopper schedule).
      model_buffer_size: capacity of the imagined-transition buffer (all slots together).
      real_ratio: fraction of each agent batch drawn from real data (the rest from the model).
      agent_updates_per_step: agent updates per env step.
      obs_clip: imagined observations are clipped to [-obs_clip, obs_clip].
      meta_inner_lr: beta of the MAML inner step theta' = theta - beta grad L_i(theta).
      meta_first_order: drop the inner gradient's dependence on theta (first-order MAML).
      meta_inner: inner-step objective, "sac" (the SAC actor loss) or "vpg" (REINFORCE on
        imagined trajectories of ``vpg_horizon`` steps from ``task batch`` start states).
      meta_outer: outer step, "sac" (Adam on the meta objective) or "trpo" (a trust-region step
        on it with KL <= ``trpo_max_kl``).
    """

    epoch_length: int = 1000
    model_train_every: int = 250
    rollout_batch: int = 100_000
    rollout_schedule: tuple[int, int, int, int] = (20, 100, 1, 15)
    model_buffer_size: int = 2_000_000
    real_ratio: float = 0.05
    agent_updates_per_step: int = 2
    obs_clip: float = 100.0
    meta_inner_lr: float = 1e-3
    meta_first_order: bool = False
    meta_inner: str = "sac"
    vpg_horizon: int = 10
    meta_outer: str = "sac"
    trpo_max_kl: float = 0.01

    def __post_init__(self) -> None:
        for name in ("epoch_length", "model_train_every", "rollout_batch", "model_buffer_size",
                     "agent_updates_per_step"):  # fmt: skip
            if getattr(self, name) <= 0:
                raise ValueError(f"mb {name} must be positive, got {getattr(self, name)}")
        start, end, lo, hi = self.rollout_schedule
        if not (0 < lo <= hi and 0 <= start <= end):
            raise ValueError(f"mb rollout_schedule must be (start, end, min>0, max>=min), got "
                             f"{self.rollout_schedule}")  # fmt: skip
        if not 0.0 <= self.real_ratio <= 1.0:
            raise ValueError(f"mb real_ratio must be in [0, 1], got {self.real_ratio}")
        if self.meta_inner not in ("sac", "vpg"):
            raise ValueError(f"mb meta_inner must be 'sac' or 'vpg', got {self.meta_inner!r}")
        if self.meta_outer not in ("sac", "trpo"):
            raise ValueError(f"mb meta_outer must be 'sac' or 'trpo', got {self.meta_outer!r}")
        if self.trpo_max_kl <= 0:
            raise ValueError(f"mb trpo_max_kl must be positive, got {self.trpo_max_kl}")
        if self.vpg_horizon <= 0:
            raise ValueError(f"mb vpg_horizon must be positive, got {self.vpg_horizon}")
        if self.meta_inner_lr < 0:
            raise ValueError(f"mb meta_inner_lr must be >= 0, got {self.meta_inner_lr}")

    def rollout_length(self, epoch):
        """The scheduled rollout length at ``epoch`` (works on ints and traced arrays)."""
        start, end, lo, hi = self.rollout_schedule
        frac = (epoch - start) / max(end - start, 1)
        frac = frac * (frac > 0)
        frac = frac - (frac - 1) * (frac > 1)
        return (lo + frac * (hi - lo)) // 1


@dataclasses.dataclass(frozen=True)
class SACConfig:
    """SAC settings (paper appendix): 256x256 ReLU, Adam 3e-4, gamma 0.99, tau 0.005."""

    hidden: tuple[int, ...] = (256, 256)
    actor_lr: float = 3e-4
    critic_lr: float = 3e-4
    entropy_lr: float = 3e-4
    gamma: float = 0.99
    tau: float = 0.005
    batch_size: int = 256
    init_entropy_coef: float = 1.0
    target_entropy: float | None = None  # None = -act_dim
    log_std_min: float = -20.0
    log_std_max: float = 2.0
    normalize_obs: bool = False


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Everything a training run needs; saved as ``config.json`` in the run directory."""

    env: str = "hopper"
    algo: str = "sac"
    preset: str = "cpu"
    task_set: str = "nominal"
    physics: str = "fast"
    seed: int = 0
    total_steps: int = 50_000
    num_envs: int = 1
    updates_per_step: int = 1
    warmup_steps: int = 5_000
    buffer_size: int = 1_000_000
    max_episode_steps: int = 1000
    eval_every: int = 5_000
    eval_episodes: int = 5
    noise: str = "gaussian"  # "gaussian" (SAC's own sampling) or "ou"
    ou_theta: float = 0.15
    ou_sigma: float = 0.2
    sac: SACConfig = SACConfig()
    ma: MAConfig = MAConfig()
    caps: CAPSConfig = CAPSConfig()
    model: ModelConfig = ModelConfig()
    mb: MBConfig = MBConfig()

    def __post_init__(self) -> None:
        positive = ("total_steps", "num_envs", "updates_per_step", "buffer_size",
                    "max_episode_steps", "eval_every", "eval_episodes")  # fmt: skip
        for name in positive:
            if getattr(self, name) <= 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if self.warmup_steps < 0:
            raise ValueError(f"warmup_steps must be >= 0, got {self.warmup_steps}")
        if self.noise not in ("gaussian", "ou"):
            raise ValueError(f"noise must be 'gaussian' or 'ou', got {self.noise!r}")
        if self.algo not in ALGOS:
            raise ValueError(f"unknown algorithm {self.algo!r}; choose from {', '.join(ALGOS)}")
        if self.algo != "sac" and self.num_envs != 1:
            raise ValueError(f"{self.algo} collects real data in one environment (num_envs 1)")
        slots, max_len = self.model.num_elites, self.mb.rollout_schedule[3]
        if self.algo != "sac" and self.mb.rollout_batch < slots:
            raise ValueError(
                f"mb rollout_batch ({self.mb.rollout_batch}) must be >= model num_elites ({slots})"
            )
        if self.algo != "sac" and (
            self.mb.rollout_batch // slots * max_len > self.mb.model_buffer_size // slots
        ):
            raise ValueError(
                f"mb model_buffer_size ({self.mb.model_buffer_size}) must hold one rollout: "
                f">= rollout_batch x max rollout length = {self.mb.rollout_batch * max_len}"
            )
        if self.eval_every % self.num_envs:
            raise ValueError("eval_every must be a multiple of num_envs")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrainConfig:
        """Inverse of ``to_dict`` (as read back from ``config.json``)."""
        nested = ("sac", "ma", "caps", "model", "mb")
        top = {k: v for k, v in d.items() if k not in nested}
        sac = {**d["sac"], "hidden": tuple(d["sac"]["hidden"])}
        model = {k: tuple(v) if isinstance(v, list) else v for k, v in d.get("model", {}).items()}
        mb = {k: tuple(v) if isinstance(v, list) else v for k, v in d.get("mb", {}).items()}
        return cls(
            **top,
            sac=SACConfig(**sac),
            ma=MAConfig(**d["ma"]),
            caps=CAPSConfig(**d["caps"]),
            model=ModelConfig(**model),
            mb=MBConfig(**mb),
        )


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
        mb=MBConfig(
            epoch_length=100,
            model_train_every=100,
            rollout_batch=64,
            rollout_schedule=(0, 2, 1, 3),
            model_buffer_size=2_000,
            agent_updates_per_step=1,
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


def with_overrides(config: TrainConfig, **fields: Any) -> TrainConfig:
    """A copy with top-level fields or ``<group>_<field>`` set (ma, sac, caps, model, mb)."""
    top, nested = {}, {"ma": {}, "sac": {}, "caps": {}, "model": {}, "mb": {}}
    for key, value in fields.items():
        if value is None:
            continue
        prefix = key.split("_", 1)[0]
        if prefix in nested and key.split("_", 1)[1] in {
            f.name for f in dataclasses.fields(getattr(config, prefix))
        }:
            nested[prefix][key.split("_", 1)[1]] = value
        else:
            top[key] = value
    for prefix, values in nested.items():
        if values:
            top[prefix] = dataclasses.replace(getattr(config, prefix), **values)
    return dataclasses.replace(config, **top)
