"""DreamerV3's output transforms and distributions, as plain functions on arrays.

* ``symlog``/``symexp``: sign(x) log(1 + |x|) and its inverse: inputs and decoder targets in
  symlog space keep large and small magnitudes trainable with one scale.
* Two-hot: a scalar y becomes weights on its two neighbouring bins of ``B = linspace(-20, 20,
  255)`` placed at symlog(y); a head predicts logits over the bins, its loss is the cross-entropy
  with the two-hot target and its prediction is symexp(softmax(logits) . B) (the paper's reward
  and critic heads: large returns do not dominate the gradient).
* Latent categoricals: 1% uniform mixed into the softmax ("unimix": no probability reaches 0, so
  the KL stays finite), one-hot samples with straight-through gradients (sample + p - sg(p)), and
  the KL between groups of categoricals summed over the groups.
* The bounded normal policy for continuous actions: mean tanh(m), std in [min_std, max_std].
* Return normalization: exponential moving averages of the 5th and 95th percentiles of the
  lambda-returns; advantages are divided by max(1, P95 - P5) (small returns are not amplified).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

sg = jax.lax.stop_gradient


@jax.custom_jvp
def symlog(x: jax.Array) -> jax.Array:
    """sign(x) * log(1 + |x|), with its derivative 1 / (1 + |x|) everywhere (autodiff of the
    formula gives 0 at x = 0, where sign jumps: a wrong zero column in Jacobians through the
    encoder for any observation entry that is exactly 0)."""
    return jnp.sign(x) * jnp.log1p(jnp.abs(x))


@symlog.defjvp
def _symlog_jvp(primals: tuple, tangents: tuple) -> tuple[jax.Array, jax.Array]:
    (x,), (dx,) = primals, tangents
    return symlog(x), dx / (1.0 + jnp.abs(x))


def symexp(x: jax.Array) -> jax.Array:
    """sign(x) * (exp(|x|) - 1), the inverse of ``symlog``."""
    return jnp.sign(x) * jnp.expm1(jnp.abs(x))


def twohot_bins(num_bins: int = 255, limit: float = 20.0) -> jax.Array:
    """The bin positions, in symlog space."""
    return jnp.linspace(-limit, limit, num_bins)


def twohot(y: jax.Array, bins: jax.Array) -> jax.Array:
    """Two-hot encoding of symlog(y) on ``bins``: (...,) -> (..., num_bins); the weights of the
    two neighbouring bins sum to 1 and their mean is symlog(y) (clipped to the bins' range)."""
    x = jnp.clip(symlog(y), bins[0], bins[-1])
    above = jnp.clip(jnp.searchsorted(bins, x, side="right"), 1, len(bins) - 1)
    below = above - 1
    width = bins[above] - bins[below]
    w_above = (x - bins[below]) / width
    n = len(bins)
    return (jax.nn.one_hot(below, n) * (1 - w_above)[..., None]
            + jax.nn.one_hot(above, n) * w_above[..., None])  # fmt: skip


def twohot_loss(logits: jax.Array, y: jax.Array, bins: jax.Array) -> jax.Array:
    """Cross-entropy of the head's bin logits with the two-hot target of ``y``: (...,)."""
    target = sg(twohot(y, bins))
    return -jnp.sum(target * jax.nn.log_softmax(logits, -1), -1)


def twohot_mean(logits: jax.Array, bins: jax.Array) -> jax.Array:
    """The head's prediction symexp(softmax(logits) . bins)."""
    return symexp(jnp.sum(jax.nn.softmax(logits, -1) * bins, -1))


def unimix_probs(logits: jax.Array, unimix: float) -> jax.Array:
    """softmax(logits) mixed with ``unimix`` of the uniform distribution."""
    probs = jax.nn.softmax(logits, -1)
    return (1.0 - unimix) * probs + unimix / logits.shape[-1]


def sample_onehot(key: jax.Array, probs: jax.Array) -> jax.Array:
    """One-hot samples of the categoricals ``probs`` (..., classes) with straight-through
    gradients: the forward value is the sample, the gradient that of ``probs``."""
    index = jax.random.categorical(key, jnp.log(probs), -1)
    sample = jax.nn.one_hot(index, probs.shape[-1], dtype=probs.dtype)
    return sample + probs - sg(probs)


def categorical_kl(p: jax.Array, q: jax.Array) -> jax.Array:
    """KL(p || q) of groups of categoricals (..., groups, classes), summed over the groups."""
    return jnp.sum(p * (jnp.log(p) - jnp.log(q)), (-2, -1))


def categorical_entropy(p: jax.Array) -> jax.Array:
    """Entropy of groups of categoricals (..., groups, classes), summed over the groups."""
    return -jnp.sum(p * jnp.log(p), (-2, -1))


def kl_balance(
    post_probs: jax.Array, prior_probs: jax.Array, free_nats: float = 1.0
) -> tuple[jax.Array, jax.Array]:
    """DreamerV3's dynamics and representation losses, each clipped below at ``free_nats``:
    dyn = max(free, KL(sg(post) || prior)) trains the prior toward the posterior; rep =
    max(free, KL(post || sg(prior))) keeps the posterior predictable (weighted 1 and 0.1)."""
    dyn = categorical_kl(sg(post_probs), prior_probs)
    rep = categorical_kl(post_probs, sg(prior_probs))
    return jnp.maximum(dyn, free_nats), jnp.maximum(rep, free_nats)


def bounded_normal(
    raw_mean: jax.Array, raw_std: jax.Array, min_std: float, max_std: float
) -> tuple[jax.Array, jax.Array]:
    """The policy's mean tanh(raw_mean) and std (max - min) sigmoid(raw_std + 2) + min."""
    mean = jnp.tanh(raw_mean)
    std = (max_std - min_std) * jax.nn.sigmoid(raw_std + 2.0) + min_std
    return mean, std


def normal_log_prob(mean: jax.Array, std: jax.Array, x: jax.Array) -> jax.Array:
    """log N(x; mean, std) summed over the last axis."""
    z = (x - mean) / std
    return jnp.sum(-0.5 * z**2 - jnp.log(std) - 0.5 * jnp.log(2 * jnp.pi), -1)


def normal_entropy(std: jax.Array) -> jax.Array:
    """Entropy of a diagonal normal, summed over the last axis."""
    return jnp.sum(jnp.log(std) + 0.5 * jnp.log(2 * jnp.pi * jnp.e), -1)


@struct.dataclass
class ReturnScale:
    """Moving averages of the low and high percentiles of imagined returns."""

    low: jax.Array
    high: jax.Array

    @classmethod
    def create(cls) -> ReturnScale:
        return cls(jnp.zeros(()), jnp.zeros(()))


def update_return_scale(
    scale: ReturnScale, returns: jax.Array, rate: float = 0.01,
    percentiles: tuple[float, float] = (5.0, 95.0),
) -> ReturnScale:  # fmt: skip
    """One EMA step of the percentiles toward those of ``returns`` (all its entries)."""
    lo, hi = jnp.percentile(sg(returns), jnp.asarray(percentiles))
    return ReturnScale((1 - rate) * scale.low + rate * lo, (1 - rate) * scale.high + rate * hi)


def return_normalizer(scale: ReturnScale, limit: float = 1.0) -> jax.Array:
    """The advantages' divisor max(limit, high - low)."""
    return jnp.maximum(limit, scale.high - scale.low)
