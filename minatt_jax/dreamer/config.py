"""DreamerV3's settings (the ``dreamer`` group of a run's configuration).

Defaults mirror the official configuration for proprioceptive DeepMind Control (``dmc_proprio``
in danijar/dreamerv3's ``configs.yaml``: the ``size1m`` model, train ratio 1024, batches of 16
sequences of 64 steps, 16 environments, LaProp-style optimizer with adaptive gradient clipping).
Deviations are listed in ``DEVIATIONS`` (the README repeats them).
"""

from __future__ import annotations

import dataclasses

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

    deter: int = 512
    hidden: int = 64
    stoch: int = 32
    classes: int = 4
    blocks: int = 8
    units: int = 64
    layers: int = 3
    bins: int = 255
    unimix: float = 0.01
    free_nats: float = 1.0
    loss_dyn: float = 1.0
    loss_rep: float = 0.1
    imag_length: int = 15
    horizon: float = 333.0
    lam: float = 0.95
    actent: float = 3e-4
    slowreg: float = 1.0
    slow_rate: float = 0.02
    retnorm_rate: float = 0.01
    retnorm_limit: float = 1.0
    min_std: float = 0.1
    max_std: float = 1.0
    lr: float = 4e-5
    agc: float = 0.3
    eps: float = 1e-20
    beta1: float = 0.9
    beta2: float = 0.999
    warmup: int = 1000
    batch_size: int = 16
    batch_length: int = 64
    train_ratio: float = 1024.0

    def __post_init__(self) -> None:
        positive = ("deter", "hidden", "stoch", "classes", "blocks", "units", "bins",
                    "imag_length", "batch_size", "batch_length")  # fmt: skip
        for name in positive:
            if getattr(self, name) <= 0:
                raise ValueError(f"dreamer {name} must be positive, got {getattr(self, name)}")
        if self.deter % self.blocks:
            raise ValueError(f"dreamer deter ({self.deter}) must be a multiple of blocks "
                             f"({self.blocks})")  # fmt: skip
        if self.train_ratio <= 0 or self.lr <= 0 or self.horizon <= 1:
            raise ValueError("dreamer train_ratio and lr must be positive and horizon > 1")
        if not 0 <= self.unimix < 1 or not 0 < self.min_std <= self.max_std:
            raise ValueError("dreamer unimix must be in [0, 1) and 0 < min_std <= max_std")

    @property
    def gamma(self) -> float:
        return 1.0 - 1.0 / self.horizon
