"""Termination functions on observations, for imagined rollouts (one per environment).

A learned model predicts observations, not MuJoCo states, so imagined episodes end by these
functions of the predicted next observation, which mirror each environment's ``is_healthy``:

* hopper: done unless z > 0.7, |angle| < 0.2 and |obs[1:]| < 100 elementwise. The official MBPO
  function writes ``np.abs(next_obs[:, 1:] < 100)`` (the parenthesis closes after the comparison,
  so large negative values never terminate); here the absolute value is taken first.
  Hopper's observation clips velocities at 10, so the |.| < 100 test acts on the angles only;
  the environment's own test also sees the unclipped velocities (tested to agree on real states);
* walker2d: done unless 0.8 < z < 2 and -1 < angle < 1;
* halfcheetah: never;
* humanoid: done unless 1 < z < 2 (z = obs[0] of the truncated observation).

Every function maps (..., obs_dim) to a float (...,) array, 1.0 where the episode ends.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp


def hopper(obs: jax.Array) -> jax.Array:
    z, angle = obs[..., 0], obs[..., 1]
    ok = jnp.all(jnp.abs(obs[..., 1:]) < 100.0, axis=-1) & (z > 0.7) & (jnp.abs(angle) < 0.2)
    return 1.0 - ok.astype(jnp.float32)


def walker2d(obs: jax.Array) -> jax.Array:
    z, angle = obs[..., 0], obs[..., 1]
    ok = (z > 0.8) & (z < 2.0) & (angle > -1.0) & (angle < 1.0)
    return 1.0 - ok.astype(jnp.float32)


def halfcheetah(obs: jax.Array) -> jax.Array:
    return jnp.zeros(obs.shape[:-1], jnp.float32)


def humanoid(obs: jax.Array) -> jax.Array:
    z = obs[..., 0]
    return 1.0 - ((z > 1.0) & (z < 2.0)).astype(jnp.float32)


TERMINATION_FNS: dict[str, Callable[[jax.Array], jax.Array]] = {
    "hopper": hopper,
    "walker2d": walker2d,
    "halfcheetah": halfcheetah,
    "humanoid": humanoid,
}
