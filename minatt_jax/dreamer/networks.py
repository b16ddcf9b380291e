"""DreamerV3's networks for vector observations (flax linen).

Every hidden layer is Dense -> RMSNorm -> SiLU with truncated-normal fan-in initialization; output
layers scale that initialization by ``outscale`` (0: zeros, as the reward and critic heads start
predicting 0). The world model:

* encoder: symlog(obs) -> ``layers`` hidden layers -> token;
* RSSM: a GRU-like recurrent core on a deterministic state h of size ``deter`` split into
  ``blocks`` groups (block-diagonal weights: each group sees its own part of h and the shared
  embeddings of h, z and a), a stochastic state z of ``stoch`` categoricals with ``classes``
  classes each; the prior p(z | h) has ``img_layers`` hidden layers, the posterior q(z | h, token)
  ``obs_layers``;
* heads on the feature [h, z]: decoder (symlog obs, MSE), reward (two-hot bins), continue (logit).

The actor maps a feature to the bounded normal's (raw mean, raw std); the critic to two-hot bins.
"""

from __future__ import annotations

from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

from minatt_jax.dreamer.distributions import symlog


def _init(scale: float = 1.0) -> nn.initializers.Initializer:
    if scale == 0.0:
        return nn.initializers.zeros
    return nn.initializers.variance_scaling(scale, "fan_in", "truncated_normal")


class Hidden(nn.Module):
    """Dense -> RMSNorm -> SiLU."""

    units: int

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        x = nn.Dense(self.units, kernel_init=_init())(x)
        return nn.silu(nn.RMSNorm()(x))


class MLP(nn.Module):
    """``layers`` hidden layers of ``units``, then a linear output of ``out`` (``outscale``)."""

    layers: int
    units: int
    out: int
    outscale: float = 1.0

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        for _ in range(self.layers):
            x = Hidden(self.units)(x)
        return nn.Dense(self.out, kernel_init=_init(self.outscale))(x)


class BlockLinear(nn.Module):
    """A linear map with block-diagonal weights: input and output split into ``groups``."""

    out: int
    groups: int

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        g = self.groups
        x = x.reshape(*x.shape[:-1], g, x.shape[-1] // g)
        kernel = self.param("kernel", _init(), (g, x.shape[-1], self.out // g))
        bias = self.param("bias", nn.initializers.zeros, (self.out,))
        y = jnp.einsum("...gi,gio->...go", x, kernel)
        return y.reshape(*y.shape[:-2], self.out) + bias


class RSSM(nn.Module):
    """The recurrent state-space model (see the module docstring)."""

    deter: int
    hidden: int
    stoch: int
    classes: int
    blocks: int
    img_layers: int = 2
    obs_layers: int = 1
    dyn_layers: int = 1

    def setup(self) -> None:
        self.embed_deter = Hidden(self.hidden)
        self.embed_stoch = Hidden(self.hidden)
        self.embed_action = Hidden(self.hidden)
        self.dyn_hidden = [BlockLinear(self.deter, self.blocks) for _ in range(self.dyn_layers)]
        self.dyn_norms = [nn.RMSNorm() for _ in range(self.dyn_layers)]
        self.gru = BlockLinear(3 * self.deter, self.blocks)
        self.prior_net = MLP(self.img_layers, self.hidden, self.stoch * self.classes)
        self.post_net = MLP(self.obs_layers, self.hidden, self.stoch * self.classes)

    def core(self, deter: jax.Array, stoch: jax.Array, action: jax.Array) -> jax.Array:
        """The next deterministic state from (h, z, a); actions above 1 in size are scaled."""
        g = self.blocks
        stoch = stoch.reshape(*stoch.shape[:-2], -1)
        action = action / jax.lax.stop_gradient(jnp.maximum(1.0, jnp.abs(action)))
        shared = jnp.concatenate(
            [self.embed_deter(deter), self.embed_stoch(stoch), self.embed_action(action)], -1
        )
        grouped = deter.reshape(*deter.shape[:-1], g, -1)
        shared = jnp.broadcast_to(shared[..., None, :], (*grouped.shape[:-1], shared.shape[-1]))
        x = jnp.concatenate([grouped, shared], -1).reshape(*deter.shape[:-1], -1)
        for layer, norm in zip(self.dyn_hidden, self.dyn_norms, strict=True):
            x = nn.silu(norm(layer(x)))
        gates = self.gru(x).reshape(*deter.shape[:-1], g, 3, -1)
        reset, cand, update = (gates[..., i, :].reshape(deter.shape) for i in range(3))
        cand = jnp.tanh(jax.nn.sigmoid(reset) * cand)
        update = jax.nn.sigmoid(update - 1.0)
        return update * cand + (1.0 - update) * deter

    def prior(self, deter: jax.Array) -> jax.Array:
        """Logits of p(z | h): (..., stoch, classes)."""
        return self.prior_net(deter).reshape(*deter.shape[:-1], self.stoch, self.classes)

    def posterior(self, deter: jax.Array, token: jax.Array) -> jax.Array:
        """Logits of q(z | h, token): (..., stoch, classes)."""
        logits = self.post_net(jnp.concatenate([deter, token], -1))
        return logits.reshape(*deter.shape[:-1], self.stoch, self.classes)

    def __call__(self, deter: jax.Array, stoch: jax.Array, action: jax.Array, token: jax.Array):
        """Every parameter touched once (for ``init``)."""
        deter = self.core(deter, stoch, action)
        return self.prior(deter), self.posterior(deter, token)


class WorldModel(nn.Module):
    """Encoder, RSSM and the three heads (see the module docstring)."""

    obs_size: int
    deter: int
    hidden: int
    stoch: int
    classes: int
    blocks: int
    units: int
    layers: int
    bins: int

    def setup(self) -> None:
        self.encoder_net = MLP(self.layers - 1, self.units, self.units)
        self.encoder_norm = nn.RMSNorm()
        self.rssm = RSSM(self.deter, self.hidden, self.stoch, self.classes, self.blocks)
        self.decoder = MLP(self.layers, self.units, self.obs_size)
        self.reward_head = MLP(1, self.units, self.bins, outscale=0.0)
        self.cont_head = MLP(1, self.units, 1)

    def encode(self, obs: jax.Array) -> jax.Array:
        """The token of an observation (symlog input, ``layers`` hidden layers)."""
        return nn.silu(self.encoder_norm(self.encoder_net(symlog(obs))))

    def core(self, deter: jax.Array, stoch: jax.Array, action: jax.Array) -> jax.Array:
        return self.rssm.core(deter, stoch, action)

    def prior(self, deter: jax.Array) -> jax.Array:
        return self.rssm.prior(deter)

    def posterior(self, deter: jax.Array, token: jax.Array) -> jax.Array:
        return self.rssm.posterior(deter, token)

    def heads(self, feat: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
        """(decoded symlog observation, reward bin logits, continue logit) of features."""
        return self.decoder(feat), self.reward_head(feat), self.cont_head(feat)[..., 0]

    def __call__(self, obs: jax.Array, action: jax.Array) -> tuple:
        """Every parameter touched once (for ``init``)."""
        batch = obs.shape[:-1]
        deter = jnp.zeros((*batch, self.deter))
        stoch = jnp.zeros((*batch, self.stoch, self.classes))
        prior, post = self.rssm(deter, stoch, action, self.encode(obs))
        feat = jnp.concatenate([deter, stoch.reshape(*batch, -1)], -1)
        return prior, post, self.heads(feat)


class Actor(nn.Module):
    """Feature -> (raw mean, raw std) of the bounded normal policy."""

    action_size: int
    layers: int
    units: int
    outscale: float = 0.01

    @nn.compact
    def __call__(self, feat: jax.Array) -> tuple[jax.Array, jax.Array]:
        out = MLP(self.layers, self.units, 2 * self.action_size, self.outscale)(feat)
        return out[..., : self.action_size], out[..., self.action_size :]


class Critic(nn.Module):
    """Feature -> two-hot bin logits of the value (zero-initialized output: predicts 0)."""

    layers: int
    units: int
    bins: int

    @nn.compact
    def __call__(self, feat: jax.Array) -> jax.Array:
        return MLP(self.layers, self.units, self.bins, outscale=0.0)(feat)


def feature(deter: jax.Array, stoch: jax.Array) -> jax.Array:
    """The model state [h, flattened z] that heads, actor and critic read."""
    return jnp.concatenate([deter, stoch.reshape(*stoch.shape[:-2], -1)], -1)


__all__: Sequence[str] = ("Actor", "BlockLinear", "Critic", "MLP", "RSSM", "WorldModel", "feature")
