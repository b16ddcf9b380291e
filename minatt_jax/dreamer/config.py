"""DreamerV3's settings (the ``dreamer`` group of a run's configuration).

Defaults mirror the official configuration for proprioceptive DeepMind Control (``dmc_proprio``
in danijar/dreamerv3's ``configs.yaml``: the ``size1m`` model, train ratio 1024, batches of 16
sequences of 64 steps, 16 environments, LaProp-style optimizer with adaptive gradient clipping).
Deviations are listed in ``DEVIATIONS`` (the README repeats them).
"""

from __future__ import annotations

import dataclasses

from minatt_jax.fields import check, setting

# What minatt-jax's DreamerV3 does differently from the official implementation, and why.
DEVIATIONS = (
    "Replayed sequences start from a zero latent state (the official agent can carry the "
    "replayed latent state over from the previous chunk: replay_context 1).",
    "No replay-value loss (repval, weight 0.3): the critic learns on imagined trajectories only.",
    "Two-hot bins in symlog space with symexp of the expected bin (the paper's reading); the "
    "current code spaces the bins by symexp instead.",
    "float32 everywhere (official: bfloat16 compute on GPU).",
    "Uniform replay (the official default, fracs uniform 1.0) over fixed per-environment rings.",
)


@dataclasses.dataclass(frozen=True)
class DreamerConfig:
    """World model, actor-critic and optimizer settings (names follow the official config).

    Attributes:
      deter, hidden, stoch, classes, blocks: RSSM sizes (h, its embeddings, z groups x classes,
        block-diagonal groups of the recurrent core).
      units, layers: encoder, decoder, actor and critic MLP width and depth.
      bins: two-hot bins of the reward and critic heads.
      unimix: uniform mixture of the latent categoricals.
      free_nats: KL losses below this are not optimized.
      loss_dyn, loss_rep: weights of the KL balance terms (reconstruction, reward, continue: 1).
      imag_length: imagination horizon H.
      horizon: effective horizon 1 / (1 - gamma): gamma = 1 - 1 / 333.
      lam: lambda of the lambda-returns.
      actent: entropy bonus of the actor.
      slowreg: weight of the critic's regularizer toward its slow (EMA) copy.
      slow_rate: EMA rate of the slow critic (every update).
      retnorm_rate, retnorm_limit: percentile-EMA rate and the divisor's floor.
      min_std, max_std: the bounded normal policy's std range.
      lr, agc, eps, beta1, beta2, warmup: optimizer (one chain for all modules).
      batch_size, batch_length: replayed sequences per update and their length.
      train_ratio: replayed steps per environment step (1024: one update of 16 x 64 per step).
    """

    deter: int = setting(512, ge=1)
    hidden: int = setting(64, ge=1)
    stoch: int = setting(32, ge=1)
    classes: int = setting(4, ge=1)
    blocks: int = setting(8, ge=1)
    units: int = setting(64, ge=1)
    layers: int = setting(3, ge=1)
    bins: int = setting(255, ge=2)
    unimix: float = setting(0.01, ge=0, lt=1)
    free_nats: float = setting(1.0, ge=0)
    loss_dyn: float = setting(1.0, ge=0)
    loss_rep: float = setting(0.1, ge=0)
    imag_length: int = setting(15, ge=1)
    horizon: float = setting(333.0, gt=1)
    lam: float = setting(0.95, ge=0, le=1)
    actent: float = setting(3e-4, ge=0)
    slowreg: float = setting(1.0, ge=0)
    slow_rate: float = setting(0.02, gt=0, le=1)
    retnorm_rate: float = setting(0.01, gt=0, le=1)
    retnorm_limit: float = setting(1.0, gt=0)
    min_std: float = setting(0.1, gt=0)
    max_std: float = setting(1.0, gt=0)
    lr: float = setting(4e-5, gt=0, le=1)
    agc: float = setting(0.3, gt=0)
    eps: float = setting(1e-20, gt=0)
    beta1: float = setting(0.9, ge=0, lt=1)
    beta2: float = setting(0.999, ge=0, lt=1)
    warmup: int = setting(1000, ge=0)
    batch_size: int = setting(16, ge=1)
    batch_length: int = setting(64, ge=2)
    train_ratio: float = setting(1024.0, gt=0)

    def __post_init__(self) -> None:
        check(self, "dreamer")
        if self.deter % self.blocks:
            raise ValueError(f"dreamer.deter ({self.deter}) must be a multiple of dreamer.blocks "
                             f"({self.blocks})")  # fmt: skip
        if not self.min_std <= self.max_std:
            raise ValueError(f"dreamer.min_std ({self.min_std}) must be at most dreamer.max_std "
                             f"({self.max_std})")  # fmt: skip

    @property
    def gamma(self) -> float:
        return 1.0 - 1.0 / self.horizon
