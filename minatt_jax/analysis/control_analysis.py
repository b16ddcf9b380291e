"""Analysis of a learned control law: K(t) x + v(t), binned heatmaps, failure criteria.

* ``decompose``: along a rollout, u(x_t) = K(t) x_t + v(t) with K(t) = du/dx at x_t
  (exact, ``min_attention.control_jacobian``) and v(t) = u(x_t) - K(t) x_t, so the identity holds
  exactly by construction; ||K(t)||_F is the feedback gain and ||v(t)||_2 the feedforward part;
* ``binned_means``: mean of a per-state value over a 2D grid of a projection of visited states
  (NaN where no state fell), with counts;
* ``make_failure_grid``: failure rates over initial (forward velocity, pitch rate) states, with
  each environment's own failure criterion (``env.failed``: the paper's for HalfCheetah, torso
  z < -0.42 or |pitch| > 1.1 rad; the environment's termination for the others) and ranges
  (``env.failure_grid_ranges``; the paper gives none: ours span what each body survives at least
  sometimes). The heatmap projections are ``env.projections``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from minatt_jax import acting
from minatt_jax import min_attention as ma


def decompose(
    control: Callable[[Any, jax.Array], jax.Array], params: Any, obs: jax.Array
) -> dict[str, jax.Array]:
    """K (T, act, obs), v (T, act), u (T, act) and their norms along states ``obs`` (T, obs)."""
    u = jax.vmap(lambda x: control(params, x))(obs)
    return decompose_gains(ma.control_jacobian(control, params, obs), u, obs)


def decompose_gains(gain: jax.Array, u: jax.Array, obs: jax.Array) -> dict[str, jax.Array]:
    """``decompose`` from Jacobians already taken (``acting.unroll``'s gain probe: how a
    recurrent policy's K(t) at its memory is read)."""
    v = u - jnp.einsum("tao,to->ta", gain, obs)
    feedback = jnp.sum(jnp.square(gain), axis=(1, 2))  # ||du/dx||_F^2 per state
    return {
        "K": gain,
        "v": v,
        "u": u,
        "K_norm": jnp.sqrt(feedback),
        "v_norm": jnp.linalg.norm(v, axis=-1),
        "feedback": feedback,
    }


def binned_means(
    x: np.ndarray,
    y: np.ndarray,
    values: np.ndarray,
    x_edges: np.ndarray,
    y_edges: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Mean of ``values`` per (x bin, y bin); shape (len(x_edges)-1, len(y_edges)-1).

    Bins are half-open [lo, hi) except the last, which includes its upper edge (numpy's
    ``histogram2d`` convention); states outside the edges are left out. Empty bins are NaN.
    """
    x, y, values = (np.asarray(a, np.float64).ravel() for a in (x, y, values))
    sums, _, _ = np.histogram2d(x, y, bins=(x_edges, y_edges), weights=values)
    counts, _, _ = np.histogram2d(x, y, bins=(x_edges, y_edges))
    with np.errstate(invalid="ignore", divide="ignore"):
        means = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
    return means, counts.astype(np.int64)


def make_failure_grid(
    env: Any,
    policy_of: Callable[[Any], acting.AnyPolicy],
    steps: int = 100,
    rollouts: int = 20,
    noise: float = 0.01,
) -> Callable[..., jax.Array]:
    """A jitted ``(params, vx (nx,), w (ny,), key, task) -> failure rate (nx, ny)``;
    ``policy_of(params)`` is the deterministic policy.

    Each cell starts ``rollouts`` episodes from the initial state with forward velocity ``vx``
    and torso angular velocity ``w`` (plus N(0, noise^2) on every qpos and qvel entry), runs the
    deterministic policy for ``steps`` steps, and counts an episode as failed when any visited
    state fails (``env.failed``). The paper's HalfCheetah grid: 20 rollouts of 100 steps per cell.
    """
    from mujoco import mjx

    from minatt_jax.envs.tasks import apply_task

    vx_index, w_index = env.failure_qvel_indices

    def episode(params, vx, w, key, task):
        k_reset, k_q, k_v = jax.random.split(key, 3)
        state = env.reset(k_reset, task)
        data = state.pipeline_state
        qvel = data.qvel.at[vx_index].set(vx).at[w_index].set(w)
        qpos = data.qpos + noise * jax.random.normal(k_q, data.qpos.shape)
        qvel = qvel + noise * jax.random.normal(k_v, qvel.shape)
        model = apply_task(env.mjx_model, env.nominal_fields, task)
        data = env.complete(model, mjx.forward(model, data.replace(qpos=qpos, qvel=qvel)))
        state = env.with_start(state, data)

        traj = acting.unroll(env, policy_of(params), state, steps)
        return jnp.max(env.failed(traj.next_obs))

    def grid(params, vx, w, key, task):
        nx, ny = vx.shape[0], w.shape[0]
        vxs = jnp.repeat(vx, ny * rollouts)
        ws = jnp.tile(jnp.repeat(w, rollouts), nx)
        keys = jax.random.split(key, nx * ny * rollouts)
        # One cell's rollouts at a time, not all nx * ny * rollouts in one batch: under jaxlib
        # 0.10.2 MJX's Newton solver on a batch of 1620 episodes hung in the LAPACK Cholesky
        # kernel (gdb: ParallelBatchMap waiting on the XLA pool its callers occupy), a walker2d
        # report with two busy cores; cell-sized batches finish.
        fails = jax.lax.map(lambda a: episode(params, *a, task), (vxs, ws, keys),
                            batch_size=rollouts)  # fmt: skip
        return jnp.mean(fails.reshape(nx, ny, rollouts), axis=-1)

    return jax.jit(grid)
