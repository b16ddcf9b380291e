"""Analysis of a learned control law: K(t) x + v(t), binned heatmaps, failure criteria.

* ``decompose``: along a rollout, u(x_t) = K(t) x_t + v(t) with K(t) = du/dx at x_t (exact,
  ``jax.jacfwd``) and v(t) = u(x_t) - K(t) x_t, so the identity holds exactly by construction;
  ||K(t)||_F is the feedback gain and ||v(t)||_2 the feedforward part;
* ``binned_means``: mean of a per-state value over a 2D grid of a projection of visited states
  (NaN where no state fell), with counts;
* ``failed``: the failure criterion. HalfCheetah (the paper): torso z < -0.42 or |pitch| > 1.1 rad,
  i.e. obs[0] (rootz, relative to its initial height) and obs[1] (rooty). The environments that
  terminate use their own termination as the equivalent (hopper, walker2d, humanoid: the
  ``envs.termination`` functions of the observation);
* ``PROJECTIONS``: the paper's 2D projections per environment, as observation names;
* ``FAILURE_GRID_RANGES``: the (forward velocity, pitch rate) ranges of the failure grid per
  environment. The paper gives none; ours span what each body survives at least sometimes.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from minatt_jax.envs.termination import TERMINATION_FNS

# The paper's heatmap projections (x axis, y axis) by observation name.
PROJECTIONS: dict[str, tuple[tuple[str, str], ...]] = {
    "halfcheetah": (("vel_rootx", "rootz"), ("vel_rootx", "vel_rootz"),
                    ("vel_rootx", "vel_rooty")),
    "hopper": (("rooty", "rootz"), ("rooty", "vel_rooty"), ("vel_rootx", "rooty")),
    "walker2d": (("rooty", "rootz"), ("rooty", "vel_rooty"), ("vel_rootx", "rooty")),
    "humanoid": (("vel_root_x", "root_z"), ("right_hip_y", "left_hip_y")),
}  # fmt: skip

# (vx min, vx max), (pitch rate min, pitch rate max) of the initial states, m/s and rad/s. The
# hopper and walker terminate at |pitch| >= 0.2 and 1.0 rad, so a pitch rate of 4 rad/s ends a
# hopper episode within a few steps whatever the policy does: their ranges are narrower.
FAILURE_GRID_RANGES: dict[str, tuple[tuple[float, float], tuple[float, float]]] = {
    "halfcheetah": ((-1.0, 4.0), (-4.0, 4.0)),
    "hopper": ((-1.0, 2.0), (-1.5, 1.5)),
    "walker2d": ((-1.0, 3.0), (-3.0, 3.0)),
    "humanoid": ((-1.0, 2.0), (-1.0, 1.0)),
}

HALFCHEETAH_Z_MIN = -0.42
HALFCHEETAH_PITCH_MAX = 1.1


def decompose(
    control: Callable[[Any, jax.Array], jax.Array], params: Any, obs: jax.Array
) -> dict[str, jax.Array]:
    """K (T, act, obs), v (T, act), u (T, act) and their norms along states ``obs`` (T, obs)."""
    u = jax.vmap(lambda x: control(params, x))(obs)
    gain = jax.vmap(jax.jacfwd(lambda x: control(params, x)))(obs)
    v = u - jnp.einsum("tao,to->ta", gain, obs)
    return {
        "K": gain,
        "v": v,
        "u": u,
        "K_norm": jnp.sqrt(jnp.sum(jnp.square(gain), axis=(1, 2))),
        "v_norm": jnp.linalg.norm(v, axis=-1),
        "feedback": jnp.sum(jnp.square(gain), axis=(1, 2)),  # ||du/dx||_F^2 per state
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


def failed(env_name: str, obs: jax.Array) -> jax.Array:
    """1.0 where a state counts as a failure (see the module docstring); obs (..., obs_dim)."""
    if env_name == "halfcheetah":
        bad = (obs[..., 0] < HALFCHEETAH_Z_MIN) | (jnp.abs(obs[..., 1]) > HALFCHEETAH_PITCH_MAX)
        return bad.astype(jnp.float32)
    return TERMINATION_FNS[env_name](obs)


def projection_indices(obs_names: tuple[str, ...], env_name: str) -> list[tuple[int, int]]:
    """The observation indices of ``PROJECTIONS[env_name]``."""
    return [(obs_names.index(a), obs_names.index(b)) for a, b in PROJECTIONS[env_name]]


def make_failure_grid(
    env: Any,
    control: Callable[[Any, jax.Array], jax.Array],
    steps: int = 100,
    rollouts: int = 20,
    noise: float = 0.01,
) -> Callable[..., jax.Array]:
    """A jitted ``(params, vx (nx,), w (ny,), key, task) -> failure rate (nx, ny)``.

    Each cell starts ``rollouts`` episodes from the initial state with forward velocity ``vx``
    and torso angular velocity ``w`` (plus N(0, noise^2) on every qpos and qvel entry), runs the
    deterministic policy for ``steps`` steps, and counts an episode as failed when any visited
    state fails (``failed``). The paper's HalfCheetah grid: 20 rollouts of 100 steps per cell.
    """
    from mujoco import mjx

    from minatt_jax.envs.tasks import apply_task

    name = env.name
    # qvel indices of forward velocity and torso pitch rate: planar root joints (x, z, pitch)
    # for the 2D walkers; the humanoid's free joint has (vx, vy, vz, wx, wy, wz).
    vx_index, w_index = (0, 4) if name == "humanoid" else (0, 2)

    def episode(params, vx, w, key, task):
        k_reset, k_q, k_v = jax.random.split(key, 3)
        state = env.reset(k_reset, task)
        data = state.pipeline_state
        qvel = data.qvel.at[vx_index].set(vx).at[w_index].set(w)
        qpos = data.qpos + noise * jax.random.normal(k_q, data.qpos.shape)
        qvel = qvel + noise * jax.random.normal(k_v, qvel.shape)
        model = apply_task(env.mjx_model, env.nominal_fields, task)
        data = mjx.forward(model, data.replace(qpos=qpos, qvel=qvel))
        state = state.replace(pipeline_state=data, obs=env.observation(data))

        def body(carry, _):
            state, fail = carry
            state = env.step(state, control(params, state.obs))
            return (state, jnp.maximum(fail, failed(name, state.obs))), None

        (_, fail), _ = jax.lax.scan(body, (state, jnp.zeros(())), None, length=steps)
        return fail

    def grid(params, vx, w, key, task):
        nx, ny = vx.shape[0], w.shape[0]
        vxs = jnp.repeat(vx, ny * rollouts)
        ws = jnp.tile(jnp.repeat(w, rollouts), nx)
        keys = jax.random.split(key, nx * ny * rollouts)
        fails = jax.vmap(episode, in_axes=(None, 0, 0, 0, None))(params, vxs, ws, keys, task)
        return jnp.mean(fails.reshape(nx, ny, rollouts), axis=-1)

    return jax.jit(grid)
