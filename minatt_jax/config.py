"""Frozen configuration dataclasses and the named presets ``smoke``, ``cpu`` and ``paper``.

Presets set the scale of a run; CLI flags override single fields (``with_overrides``).
"""

from __future__ import annotations

import dataclasses
from typing import Any

from minatt_jax.min_attention import CAPSConfig, MAConfig


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
        if self.eval_every % self.num_envs:
            raise ValueError("eval_every must be a multiple of num_envs")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrainConfig:
        """Inverse of ``to_dict`` (as read back from ``config.json``)."""
        top = {k: v for k, v in d.items() if k not in ("sac", "ma", "caps")}
        sac = {**d["sac"], "hidden": tuple(d["sac"]["hidden"])}
        return cls(
            **top, sac=SACConfig(**sac), ma=MAConfig(**d["ma"]), caps=CAPSConfig(**d["caps"])
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
    ),
    # What runs in minutes to an hour on 2 CPU cores.
    "cpu": TrainConfig(
        preset="cpu",
        total_steps=50_000,
        warmup_steps=5_000,
        buffer_size=1_000_000,
        max_episode_steps=1000,
        eval_every=5_000,
        eval_episodes=5,
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
    """A copy with top-level fields, ``ma_<field>``, ``sac_<field>`` or ``caps_<field>`` set."""
    top, nested = {}, {"ma": {}, "sac": {}, "caps": {}}
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
