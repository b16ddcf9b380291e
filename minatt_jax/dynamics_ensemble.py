"""A probabilistic ensemble of dynamics models (MBPO / MB-MPO), stacked and vmapped.

Each of the M members is a swish MLP (appendix: 4 x 200) from the normalized (obs, action) to the
mean and log-variance of the normalized target (delta obs, reward). Log-variances are soft-bounded
by learned per-member maxima and minima (softplus, with a 0.01 penalty on their spread), each layer
has its own weight decay, and the Gaussian negative log-likelihood is minimized with Adam.

``fit`` is one pure, jittable function over fixed-capacity data with a ``size`` count, so a growing
dataset never changes shapes (and never recompiles):

* inputs and targets are normalized with the mean and std of the valid data at each fit;
* a fresh random holdout split per fit: ``holdout_ratio`` of the data, capped at ``max_holdout``;
* epochs of ``ceil(n_train / batch)`` minibatches (optionally capped), each member drawing its own
  minibatch indices, all inside ``lax.while_loop``;
* early stopping on holdout MSE: an epoch counts as progress when some member improves its best by
  more than ``improvement`` (relative); training stops after ``patience`` epochs without progress
  or at ``max_epochs``; each member's best weights are restored;
* elites = the ``num_elites`` members with the lowest holdout MSE.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax
from flax import struct

from minatt_jax.fields import check, setting
from minatt_jax.replay import Transitions, select_rows


@dataclasses.dataclass(frozen=True)
class ModelConfig:
    """Ensemble settings (defaults: the paper's appendix / MBPO)."""

    ensemble_size: int = setting(7, ge=1, why="the paper appendix and MBPO")
    # None: min(5, ensemble_size) (``config.resolve``)
    num_elites: int | None = setting(
        None, kind=int, ge=1, optional=True, why="min(5, ensemble size), as MBPO"
    )
    hidden: tuple[int, ...] = setting((200, 200, 200, 200), min_length=1,
                                      item={"kind": int, "ge": 1})  # fmt: skip
    lr: float = setting(1e-3, ge=0, le=1)
    batch_size: int = setting(256, ge=1)
    holdout_ratio: float = setting(0.2, gt=0, lt=1)
    max_holdout: int = setting(5_000, ge=1)
    weight_decay: tuple[float, ...] = setting((2.5e-5, 5e-5, 7.5e-5, 7.5e-5, 1e-4),
                                              item={"kind": float, "ge": 0})  # fmt: skip
    logvar_bound_penalty: float = setting(0.01, ge=0)
    max_epochs: int = setting(100, ge=1)
    # 0 = ceil(n_train / batch_size), the full data each epoch
    max_batches_per_epoch: int = setting(0, ge=0)
    patience: int = setting(5, ge=1)
    improvement: float = setting(0.01, ge=0)

    def __post_init__(self) -> None:
        check(self, "model")
        if self.num_elites is not None and not 1 <= self.num_elites <= self.ensemble_size:
            raise ValueError(
                f"model.num_elites must be in [1, ensemble_size={self.ensemble_size}], "
                f"got {self.num_elites}"
            )
        if len(self.weight_decay) != len(self.hidden) + 1:
            raise ValueError(
                f"model.weight_decay needs one value per layer ({len(self.hidden) + 1}), "
                f"got {len(self.weight_decay)}"
            )


@struct.dataclass
class Normalization:
    """Mean and std of the model inputs (obs, action) and targets (delta obs, reward)."""

    in_mean: jax.Array
    in_std: jax.Array
    out_mean: jax.Array
    out_std: jax.Array


@struct.dataclass
class EnsembleState:
    """Ensemble parameters (leading axis = member), optimizer state and fit results."""

    params: Any
    opt_state: Any
    norm: Normalization
    holdout_mse: jax.Array  # (M,) at the restored (best) weights of the last fit
    elites: jax.Array  # (num_elites,) member indices, lowest holdout MSE first
    fits: jax.Array  # number of fits so far
    last_epochs: jax.Array  # epochs the last fit ran


class Ensemble(NamedTuple):
    """Pure functions of an ensemble for fixed dimensions and settings."""

    config: ModelConfig
    init: Callable[[jax.Array], EnsembleState]
    fit: Callable[[EnsembleState, Transitions, jax.Array, jax.Array], tuple[EnsembleState, dict]]
    predict: Callable[[Any, Normalization, jax.Array, jax.Array], tuple[jax.Array, jax.Array]]
    step: Callable[..., tuple[jax.Array, jax.Array]]


def _targets(data: Transitions) -> jax.Array:
    return jnp.concatenate([data.next_obs - data.obs, data.reward[..., None]], axis=-1)


def _inputs(obs: jax.Array, action: jax.Array) -> jax.Array:
    return jnp.concatenate([obs, action], axis=-1)


def make_ensemble(obs_dim: int, act_dim: int, config: ModelConfig) -> Ensemble:
    """Builds the ensemble's ``init``, ``fit``, ``predict`` and ``step`` functions
    (``config.num_elites`` must be set: ``minatt_jax.config.resolve`` fills it)."""
    if config.num_elites is None:
        raise ValueError("model num_elites is unset: resolve the configuration first")
    in_dim, out_dim = obs_dim + act_dim, obs_dim + 1
    sizes = (in_dim, *config.hidden, 2 * out_dim)
    m = config.ensemble_size
    tx = optax.adam(config.lr)

    def init_params(key: jax.Array) -> dict:
        layers = []
        for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:], strict=True)):
            k = jax.random.fold_in(key, i)
            # MBPO's initialization: truncated normal with std 1 / (2 sqrt(fan_in)).
            w = jax.random.truncated_normal(k, -2.0, 2.0, (m, a, b)) / (2.0 * jnp.sqrt(a))
            layers.append({"w": w, "b": jnp.zeros((m, b))})
        return {
            "layers": layers,
            "max_logvar": jnp.full((m, out_dim), 0.5, jnp.float32),
            "min_logvar": jnp.full((m, out_dim), -10.0, jnp.float32),
        }

    def member_forward(p: dict, x: jax.Array) -> tuple[jax.Array, jax.Array]:
        """One member (unstacked params) on normalized inputs -> (mean, bounded logvar)."""
        h = x
        for layer in p["layers"][:-1]:
            h = jax.nn.swish(h @ layer["w"] + layer["b"])
        out = h @ p["layers"][-1]["w"] + p["layers"][-1]["b"]
        mean, logvar = jnp.split(out, 2, axis=-1)
        logvar = p["max_logvar"] - jax.nn.softplus(p["max_logvar"] - logvar)
        logvar = p["min_logvar"] + jax.nn.softplus(logvar - p["min_logvar"])
        return mean, logvar

    def member_loss(p: dict, x: jax.Array, y: jax.Array) -> jax.Array:
        mean, logvar = member_forward(p, x)
        nll = jnp.mean(jnp.square(mean - y) * jnp.exp(-logvar) + logvar)
        bounds = config.logvar_bound_penalty * (jnp.sum(p["max_logvar"]) - jnp.sum(p["min_logvar"]))
        decay = sum(
            wd * 0.5 * jnp.sum(jnp.square(layer["w"]))
            for wd, layer in zip(config.weight_decay, p["layers"], strict=True)
        )
        return nll + bounds + decay

    def ensemble_loss(params: dict, x: jax.Array, y: jax.Array) -> jax.Array:
        """Sum of the members' losses; x, y: (M, B, dim), member i on its own minibatch."""
        return jnp.sum(jax.vmap(member_loss)(params, x, y))

    def holdout_mse(params: dict, x: jax.Array, y: jax.Array, w: jax.Array) -> jax.Array:
        """(M,) weighted MSE of each member's mean on the holdout rows (normalized targets)."""
        mean, _ = jax.vmap(member_forward, in_axes=(0, None))(params, x)
        per_row = jnp.mean(jnp.square(mean - y[None]), axis=-1)
        return jnp.sum(per_row * w[None], axis=-1) / jnp.maximum(jnp.sum(w), 1.0)

    def init(key: jax.Array) -> EnsembleState:
        params = init_params(key)
        return EnsembleState(
            params=params,
            opt_state=tx.init(params),
            norm=Normalization(
                in_mean=jnp.zeros((in_dim,)),
                in_std=jnp.ones((in_dim,)),
                out_mean=jnp.zeros((out_dim,)),
                out_std=jnp.ones((out_dim,)),
            ),
            holdout_mse=jnp.full((m,), jnp.inf, jnp.float32),
            elites=jnp.arange(config.num_elites, dtype=jnp.int32),
            fits=jnp.zeros((), jnp.int32),
            last_epochs=jnp.zeros((), jnp.int32),
        )

    def fit(
        state: EnsembleState, data: Transitions, size: jax.Array, key: jax.Array
    ) -> tuple[EnsembleState, dict]:
        """Trains on the first ``size`` rows of ``data`` (fixed capacity); see module docs."""
        capacity = data.reward.shape[0]
        valid = jnp.arange(capacity) < size
        n = jnp.maximum(size, 2)
        k_split, k_train = jax.random.split(key)

        x_all = _inputs(data.obs, data.action)
        y_all = _targets(data)

        def masked_stats(v: jax.Array) -> tuple[jax.Array, jax.Array]:
            w = valid[:, None].astype(v.dtype)
            mean = jnp.sum(v * w, 0) / n
            var = jnp.sum(jnp.square(v - mean) * w, 0) / n
            std = jnp.sqrt(var)
            return mean, jnp.where(std < 1e-6, 1.0, std)

        in_mean, in_std = masked_stats(x_all)
        out_mean, out_std = masked_stats(y_all)
        norm = Normalization(in_mean, in_std, out_mean, out_std)

        # Random holdout split among the valid rows: valid rows first, in random order.
        u = jnp.where(valid, jax.random.uniform(k_split, (capacity,)), 2.0)
        perm = jnp.argsort(u)
        n_hold = jnp.minimum((config.holdout_ratio * n).astype(jnp.int32), config.max_holdout)
        n_hold = jnp.maximum(n_hold, 1)
        n_train = jnp.maximum(n - n_hold, 1)
        h = min(config.max_holdout, capacity)
        hold_idx = perm[:h]
        hold_w = (jnp.arange(h) < n_hold).astype(jnp.float32)
        hold_x = (x_all[hold_idx] - in_mean) / in_std
        hold_y = (y_all[hold_idx] - out_mean) / out_std

        batches = (n_train + config.batch_size - 1) // config.batch_size
        if config.max_batches_per_epoch > 0:
            batches = jnp.minimum(batches, config.max_batches_per_epoch)

        def train_batch(_, carry):
            params, opt_state, key = carry
            key, k = jax.random.split(key)
            j = n_hold + jax.random.randint(k, (m, config.batch_size), 0, n_train)
            idx = perm[j]
            x = (x_all[idx] - in_mean) / in_std
            y = (y_all[idx] - out_mean) / out_std
            grads = jax.grad(ensemble_loss)(params, x, y)
            updates, opt_state = tx.update(grads, opt_state, params)
            return optax.apply_updates(params, updates), opt_state, key

        def epoch(carry):
            params, opt_state, best_params, best, since, count, key = carry
            key, k = jax.random.split(key)
            params, opt_state, _ = jax.lax.fori_loop(
                0, batches, train_batch, (params, opt_state, k)
            )
            mse = holdout_mse(params, hold_x, hold_y, hold_w)
            improved = (best - mse) / jnp.maximum(best, 1e-12) > config.improvement
            best_params = select_rows(improved, params, best_params)
            best = jnp.where(improved, mse, best)
            since = jnp.where(jnp.any(improved), 0, since + 1)
            return params, opt_state, best_params, best, since, count + 1, key

        def keep_going(carry):
            *_, since, count, _ = carry
            return (since < config.patience) & (count < config.max_epochs)

        start_mse = holdout_mse(state.params, hold_x, hold_y, hold_w)
        carry = (state.params, state.opt_state, state.params, start_mse,
                 jnp.zeros((), jnp.int32), jnp.zeros((), jnp.int32), k_train)  # fmt: skip
        _, opt_state, best_params, best, _, epochs, _ = jax.lax.while_loop(keep_going, epoch, carry)
        elites = jnp.argsort(best)[: config.num_elites].astype(jnp.int32)
        new_state = EnsembleState(
            params=best_params,
            opt_state=opt_state,
            norm=norm,
            holdout_mse=best,
            elites=elites,
            fits=state.fits + 1,
            last_epochs=epochs,
        )
        metrics = {
            "model_holdout_mse": jnp.mean(best[elites]),
            "model_epochs": epochs.astype(jnp.float32),
            "model_train_batches": (epochs * batches).astype(jnp.float32),
        }
        return new_state, metrics

    def predict(
        params: dict, norm: Normalization, obs: jax.Array, action: jax.Array
    ) -> tuple[jax.Array, jax.Array]:
        """One member's (unstacked params) mean and variance of (delta obs, reward), raw units."""
        x = (_inputs(obs, action) - norm.in_mean) / norm.in_std
        mean, logvar = member_forward(params, x)
        return mean * norm.out_std + norm.out_mean, jnp.exp(logvar) * jnp.square(norm.out_std)

    def step(
        params: dict,
        norm: Normalization,
        obs: jax.Array,
        action: jax.Array,
        key: jax.Array,
        deterministic: bool = False,
    ) -> tuple[jax.Array, jax.Array]:
        """A sampled next observation and reward from one member (unstacked params)."""
        mean, var = predict(params, norm, obs, action)
        sample = (
            mean if deterministic else mean + jnp.sqrt(var) * jax.random.normal(key, mean.shape)
        )
        return obs + sample[..., :-1], sample[..., -1]

    return Ensemble(config=config, init=init, fit=fit, predict=predict, step=step)


def member(params: Any, index: jax.Array) -> Any:
    """The parameters of one member (or of several, for an index array)."""
    return jax.tree.map(lambda p: p[index], params)
