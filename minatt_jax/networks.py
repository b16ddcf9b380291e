"""Actor and twin-critic networks (flax.linen MLPs) of SAC; the MLP the other agents build on."""

from __future__ import annotations

from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

# Hidden-layer activations by name (the names ``numpy_policy.ACTIVATIONS`` reads back).
ACTIVATIONS = {"relu": nn.relu, "tanh": jnp.tanh, "elu": nn.elu, "swish": nn.swish}


class MLP(nn.Module):
    """An MLP (``activation``, ReLU by default, after each hidden layer) with a linear output
    layer; its layers are ``Dense_0`` ... ``Dense_n`` (``numpy_policy.dense_layers``)."""

    hidden: Sequence[int]
    out: int
    activation: str = "relu"

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        act = ACTIVATIONS[self.activation]
        for width in self.hidden:
            x = act(nn.Dense(width)(x))
        return nn.Dense(self.out)(x)


class Actor(nn.Module):
    """Tanh-squashed Gaussian policy head: returns the pre-tanh mean and the clamped log-std."""

    hidden: Sequence[int]
    act_dim: int
    log_std_min: float = -20.0
    log_std_max: float = 2.0

    @nn.compact
    def __call__(self, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        out = MLP(self.hidden, 2 * self.act_dim)(obs)
        mean, log_std = jnp.split(out, 2, axis=-1)
        return mean, jnp.clip(log_std, self.log_std_min, self.log_std_max)


class TwinCritic(nn.Module):
    """Two independent Q networks Q(s, a); returns shape (2, ...).

    The two networks' parameters are stacked and the MLP vmapped over them, so each layer of
    both critics is one batched matmul.
    """

    hidden: Sequence[int]

    @nn.compact
    def __call__(self, obs: jax.Array, action: jax.Array) -> jax.Array:
        x = jnp.concatenate([obs, action], axis=-1)
        critics = nn.vmap(
            MLP,
            variable_axes={"params": 0},
            split_rngs={"params": True},
            in_axes=None,
            out_axes=0,
            axis_size=2,
        )
        return critics(self.hidden, 1)(x)[..., 0]


def sample_tanh_gaussian(
    key: jax.Array, mean: jax.Array, log_std: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """A reparameterized tanh-Gaussian sample and its log-probability (summed over actions)."""
    std = jnp.exp(log_std)
    eps = jax.random.normal(key, mean.shape)
    pre = mean + std * eps
    action = jnp.tanh(pre)
    log_prob = -0.5 * (eps**2 + 2 * log_std + jnp.log(2 * jnp.pi))
    # log(1 - tanh(x)^2) written stably: 2 * (log 2 - x - softplus(-2x)).
    log_prob = log_prob - 2.0 * (jnp.log(2.0) - pre - jax.nn.softplus(-2.0 * pre))
    return action, jnp.sum(log_prob, axis=-1)


def tanh_gaussian_log_prob(mean: jax.Array, log_std: jax.Array, action: jax.Array) -> jax.Array:
    """log pi(action) of a tanh-squashed Gaussian (summed over actions); action in (-1, 1)."""
    a = jnp.clip(action, -1.0 + 1e-6, 1.0 - 1e-6)
    pre = jnp.arctanh(a)
    eps = (pre - mean) * jnp.exp(-log_std)
    log_prob = -0.5 * (eps**2 + 2 * log_std + jnp.log(2 * jnp.pi))
    log_prob = log_prob - 2.0 * (jnp.log(2.0) - pre - jax.nn.softplus(-2.0 * pre))
    return jnp.sum(log_prob, axis=-1)
