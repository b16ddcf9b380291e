"""The minimum-attention (MA) regularizer, for any JAX control law ``u(params, x)``.

penalty = alpha * (feedback + temporal), with

* feedback = mean over states of ||du/dx||_F^2, the Jacobian of the deterministic control with
  respect to the observation the policy receives. Estimators: ``jacfwd`` and ``jacrev`` (exact),
  ``hutchinson`` (k Rademacher probes v in action space, E ||v^T J||^2 = ||J||_F^2, one VJP per
  probe: unbiased, noisier). Optionally on the leading states of a (randomly ordered) batch.
* temporal = mean over states of ||(u(x; theta) - u(x; theta_prev)) / dt||^2, the appendix reading
  (change of the control law over learning time at fixed states, theta_prev = the parameters before
  the last update, held fixed), or, as an option, the rollout reading ||(u(x') - u(x)) / dt||^2 over
  consecutive states (x, x') of the batch.

**Update interval.** With ``interval = k > 1`` the feedback term (with ``interval_terms="both"``
the temporal term too: the whole attention cost) is computed on every k-th update only, and on
those updates it enters with weight ``alpha * k``: it still carries a gradient there, and
averaged over k updates the regularization strength equals alpha per update (the same total pull
as computing it every time, delivered in fewer, larger steps). ``interval_scaling=False`` keeps
weight alpha on those updates instead (then the effective strength is alpha / k).

A CAPS regularizer (Mysore et al. 2021) sits beside it as a comparison baseline:
lambda_T ||u(x) - u(x')|| + lambda_S ||u(x) - u(x + N(0, sigma^2))||.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Callable, Iterator
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from minatt_jax.fields import check, setting

# u(params, obs) -> action for a single observation (deterministic control, e.g. tanh(mean)).
ControlFn = Callable[[Any, jax.Array], jax.Array]

MODES = ("full", "jacobian", "temporal", "none")
ESTIMATORS = ("jacfwd", "jacrev", "hutchinson")
TEMPORAL_READINGS = ("parameter", "rollout")
PLACEMENTS = ("actor_loss", "reward", "entropy")


@dataclasses.dataclass(frozen=True)
class MAConfig:
    """Settings of the minimum-attention penalty.

    Attributes:
      alpha: weight of the penalty (0 switches it off).
      mode: "full" (both terms), "jacobian" (feedback only), "temporal" or "none".
      estimator: feedback-term estimator, one of ESTIMATORS.
      probes: Hutchinson probes per state.
      subsample: number of batch states both terms use (0 = the whole batch): the leading ones,
        which for a batch in random order (a replay sample) are a uniform random subset.
      interval: compute the feedback term every ``interval`` updates (see the module docstring).
      interval_scaling: weight the feedback term by alpha * interval on the updates computing it.
      interval_terms: which terms ``interval`` thins: "feedback" (the Jacobian term alone) or
        "both" (the whole attention cost, the temporal term too).
      temporal: "parameter" (appendix reading, default) or "rollout".
      temporal_dt: dt of the temporal term; None (default) = 1 update for the parameter reading,
        the environment's dt for the rollout reading (``config.resolve`` fills it in).
      placement: (None in a run's unresolved configuration: its agent's default placement,
        ``config.resolve``) "entropy" (default here: as SAC's entropy term, in the actor loss, and
        alpha * penalty(s') subtracted from the soft value of the next state in the critic
        target), "actor_loss" (the actor loss alone) or "reward" (subtract alpha * penalty(s)
        from rewards). The default is the reading study's choice
        (``experiments/results/reading_study_cpu_sac_20k.md``; the README says why); runs
        written before the placement was recorded have "actor_loss" (``TrainConfig.from_dict``).
    """

    alpha: float = setting(
        0.0,
        ge=0,
        why="plain SAC, the paper's baseline; 0.05 is the best setting measured on "
        "hopper (docs: Training with minimum attention)",
    )
    mode: str = setting(
        "full", choices=MODES, why="the paper's penalty, feedback and temporal terms"
    )
    estimator: str = setting(
        "jacrev", choices=ESTIMATORS,
        why="exact, and cheaper than jacfwd for a policy with fewer outputs than inputs",
    )  # fmt: skip
    probes: int = setting(1, ge=1, why="read by the hutchinson estimator only")
    subsample: int = setting(
        32, ge=0, why="batch states the penalty reads; enough for an exact mean within noise"
    )
    interval: int = setting(1, ge=1, why="the feedback term on every update, as the paper")
    interval_scaling: bool = setting(True)
    interval_terms: str = setting("feedback", choices=("feedback", "both"),
                                  why="the appendix thins the Jacobian term")  # fmt: skip
    temporal: str = setting(
        "parameter", choices=TEMPORAL_READINGS,
        why="the paper appendix's reading, the change of u between updates",
    )  # fmt: skip
    temporal_dt: float | None = setting(None, kind=float, gt=0, optional=True)
    placement: str | None = setting(
        "entropy", kind=str, choices=PLACEMENTS, optional=True,
        why="the agent's first placement; for the SAC family entropy, the reading study's best "
        "return at a 21x lower feedback norm on hopper SAC",
    )  # fmt: skip

    def __post_init__(self) -> None:
        check(self, "ma")
        if self.placement == "entropy" and self.temporal == "rollout":
            raise ValueError(
                "ma.placement 'entropy' (the default) takes the penalty at the next state "
                "alone: it needs the parameter reading of the temporal term; with ma.temporal "
                "'rollout' choose placement 'actor_loss' or 'reward'"
            )

    @property
    def dt(self) -> float:
        """The temporal term's dt (1.0 where ``temporal_dt`` is unset)."""
        return 1.0 if self.temporal_dt is None else self.temporal_dt

    @property
    def active(self) -> bool:
        return self.alpha > 0 and self.mode != "none"

    @property
    def uses_feedback(self) -> bool:
        return self.active and self.mode in ("full", "jacobian")

    @property
    def uses_temporal(self) -> bool:
        return self.active and self.mode in ("full", "temporal")


def term_weights(mode: str) -> tuple[float, float]:
    """(feedback, temporal) weights of a mode: 1 where it uses the term. Populations carry them
    as data, so members in different modes share one program (which computes the union)."""
    config = MAConfig(alpha=1.0, mode=mode)
    return float(config.uses_feedback), float(config.uses_temporal)


def _split(terms: jax.Array | None) -> tuple[jax.Array | None, jax.Array | None]:
    """The (feedback, temporal) weights of ``terms`` (``term_weights``), or none to apply."""
    return (None, None) if terms is None else (terms[0], terms[1])


def union_mode(configs: list[MAConfig]) -> str:
    """The mode whose terms cover every config's (what a program shared by them computes)."""
    feedback = any(c.uses_feedback for c in configs)
    temporal = any(c.uses_temporal for c in configs)
    return {(True, True): "full", (True, False): "jacobian", (False, True): "temporal",
            (False, False): "none"}[(feedback, temporal)]  # fmt: skip


def _scaled(term: jax.Array, weight: jax.Array | None) -> jax.Array:
    """``term`` times its 0/1 mode weight (untouched without one: a weight of 1 is exact)."""
    return term if weight is None else weight * term


def control_jacobian(u: ControlFn, params: Any, obs: jax.Array, mode: str = "jacfwd") -> jax.Array:
    """The control law's Jacobian at each state of a batch, exactly.

    Args:
        u: the control law ``u(params, obs)``.
        params: its parameters.
        obs: states, (n, obs_dim).
        mode: ``"jacfwd"`` (cheaper for few inputs) or ``"jacrev"``.

    Returns:
        du/dx, (n, act_dim, obs_dim).
    """
    jac = jax.jacfwd if mode == "jacfwd" else jax.jacrev
    return jax.vmap(jac(lambda x: u(params, x)))(obs)


def feedback_exact(u: ControlFn, params: Any, obs: jax.Array, mode: str = "jacfwd") -> jax.Array:
    """Per-state ||du/dx||_F^2, exactly.

    The one function that computes the feedback norm: the penalty, evaluation, the analysis
    and the report all call it.

    Args:
        u: the control law ``u(params, obs)``.
        params: its parameters.
        obs: states, (n, obs_dim).
        mode: ``"jacfwd"`` or ``"jacrev"``.

    Returns:
        (n,) squared Frobenius norms.
    """
    return jnp.sum(jnp.square(control_jacobian(u, params, obs, mode)), axis=(-2, -1))


def feedback_hutchinson(
    u: ControlFn, params: Any, obs: jax.Array, key: jax.Array, probes: int = 1
) -> jax.Array:
    """Per-state unbiased estimate of ||du/dx||_F^2 from Rademacher vector-Jacobian products
    (E[||v^T J||^2] = ||J||_F^2 for v with independent +-1 entries).

    Args:
        u: the control law ``u(params, obs)``.
        params: its parameters.
        obs: states, (n, obs_dim).
        key: the probes' random key.
        probes: probes per state (the estimate's variance falls as 1/probes).

    Returns:
        (n,) estimates.
    """

    def batch_u(x: jax.Array) -> jax.Array:
        return jax.vmap(lambda xi: u(params, xi))(x)

    actions, vjp = jax.vjp(batch_u, obs)

    def one_probe(k: jax.Array) -> jax.Array:
        v = jax.random.rademacher(k, actions.shape, dtype=actions.dtype)
        (row,) = vjp(v)  # v_i^T J_i for every state i
        return jnp.sum(jnp.square(row), axis=-1)

    return jnp.mean(jax.vmap(one_probe)(jax.random.split(key, probes)), axis=0)


def feedback_term(
    config: MAConfig, u: ControlFn, params: Any, obs: jax.Array, key: jax.Array
) -> jax.Array:
    """The feedback term: mean ||du/dx||_F^2 over a batch, by the configured estimator.

    Args:
        config: ``MAConfig`` (``estimator``, ``probes``, ``subsample``).
        u: the control law ``u(params, obs)``.
        params: the policy parameters (differentiated).
        obs: a batch of policy inputs, (n, obs_dim); the leading ``subsample`` are used.
        key: the random key of the Hutchinson probes.

    Returns:
        A scalar.
    """
    if 0 < config.subsample < obs.shape[0]:
        obs = obs[: config.subsample]
    return jnp.mean(_feedback_per_state(config, u, params, obs, key))


def _feedback_per_state(
    config: MAConfig, u: ControlFn, params: Any, obs: jax.Array, key: jax.Array
) -> jax.Array:
    """||du/dx||_F^2 per state with the configured estimator (no subsample)."""
    if config.estimator == "hutchinson":
        return feedback_hutchinson(u, params, obs, key, config.probes)
    return feedback_exact(u, params, obs, config.estimator)


def _temporal_per_state(
    config: MAConfig,
    u: ControlFn,
    params: Any,
    obs: jax.Array,
    prev_params: Any,
    next_obs: jax.Array | None,
    controls: jax.Array | None,
) -> jax.Array:
    """||du/dt||^2 per state in the configured reading (parameter or rollout)."""
    now = jax.vmap(lambda x: u(params, x))(obs) if controls is None else controls
    if config.temporal == "parameter":
        if prev_params is None:
            raise ValueError("the parameter reading of the temporal term needs prev_params")
        prev = jax.lax.stop_gradient(prev_params)
        other = jax.lax.stop_gradient(jax.vmap(lambda x: u(prev, x))(obs))
    else:
        if next_obs is None:
            raise ValueError("the rollout reading of the temporal term needs next_obs")
        other = jax.vmap(lambda x: u(params, x))(next_obs)
    return jnp.sum(jnp.square((now - other) / config.dt), axis=-1)


def temporal_parameter(
    u: ControlFn,
    params: Any,
    prev_params: Any,
    obs: jax.Array,
    dt: float = 1.0,
    controls: jax.Array | None = None,
) -> jax.Array:
    """Mean ||(u(x; params) - u(x; prev_params)) / dt||^2; prev_params get no gradient.

    ``controls`` may pass u(obs; params) when the caller has computed it already (SAC's actor
    loss has): then only the previous parameters' forward pass is added.
    """
    config = MAConfig(temporal="parameter", temporal_dt=dt)
    return jnp.mean(_temporal_per_state(config, u, params, obs, prev_params, None, controls))


def temporal_rollout(
    u: ControlFn, params: Any, obs: jax.Array, next_obs: jax.Array, dt: float
) -> jax.Array:
    """Mean ||(u(x') - u(x)) / dt||^2 over consecutive-state pairs (x, x')."""
    config = MAConfig(temporal="rollout", temporal_dt=dt, placement="actor_loss")
    return jnp.mean(_temporal_per_state(config, u, params, obs, None, next_obs, None))


def penalty(
    config: MAConfig,
    u: ControlFn,
    params: Any,
    obs: jax.Array,
    key: jax.Array,
    *,
    prev_params: Any = None,
    next_obs: jax.Array | None = None,
    update_step: jax.Array | int = 0,
    controls: jax.Array | None = None,
    alpha: jax.Array | float,
    terms: jax.Array | None = None,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """The weighted MA penalty and its parts ``{'feedback', 'temporal', 'penalty'}``.

    ``alpha`` (a traced value allowed: the agent state's ``hyper["alpha"]``) is the weight, always
    passed: populations sweep it as data, and ``config.alpha`` only decides whether the terms are
    computed at all (``config.active``). ``terms`` (traced, ``term_weights(mode)``) weighs the
    (feedback, temporal) terms by 0 or 1: a member's mode as data. Which terms are computed stays
    a property of the config (``config.active``, ``config.mode``: the union of the members'
    modes).

    ``prev_params`` is needed for the parameter reading of the temporal term, ``next_obs`` for the
    rollout reading; ``update_step`` selects the updates that compute the feedback term when
    ``config.interval > 1``; ``controls`` (u at ``obs``, differentiable in ``params``) saves the
    temporal term a forward pass when the caller has it.
    """
    zero = jnp.zeros((), jnp.float32)
    feedback, temporal, total = zero, zero, zero
    w_feedback, w_temporal = _split(terms)
    key_probe = key
    k = config.subsample
    if 0 < k < obs.shape[0]:
        # The leading k states serve both terms. A replay batch is drawn uniformly at random, so
        # they are a uniform random subset and each term stays an unbiased estimate of its batch
        # mean; a slice costs nothing, where drawing indices (jax.random.choice) cost more than
        # the smaller batch saved (measured in benchmarks/sac_update.py).
        obs = obs[:k]
        controls = None if controls is None else controls[:k]
        next_obs = None if next_obs is None else next_obs[:k]
    if config.uses_feedback:

        def feedback_fn() -> jax.Array:
            return jnp.mean(_feedback_per_state(config, u, params, obs, key_probe))

        feedback, weight = _thinned(config, feedback_fn, _scaled(alpha, w_feedback), update_step,
                                    config.interval)  # fmt: skip
        total = total + weight * feedback
    if config.uses_temporal:

        def temporal_fn() -> jax.Array:
            return jnp.mean(
                _temporal_per_state(config, u, params, obs, prev_params, next_obs, controls)
            )

        every = 1 if config.interval_terms == "feedback" else config.interval
        temporal, weight = _thinned(config, temporal_fn, _scaled(alpha, w_temporal), update_step,
                                    every)  # fmt: skip
        total = total + weight * temporal
    return total, {"feedback": feedback, "temporal": temporal, "penalty": total}


def _thinned(config: MAConfig, term: Callable[[], jax.Array], weight: jax.Array,
             update_step: jax.Array | int, every: int) -> tuple[jax.Array, jax.Array]:  # fmt: skip
    """(the term, its weight) computed on every ``every``-th update only (``lax.cond`` on the
    unbatched update counter: the other updates skip its cost), weighted by ``every`` there
    when ``interval_scaling`` (the same pull per update on average).

    The term is rematerialized (``jax.checkpoint``): differentiated, a ``cond`` returns the
    residuals its backward pass needs, and the skipping branch must fill each with zeros (for
    the Jacobian term, arrays of states x probes x hidden units). Saving only the term's inputs
    cut what a skipped MB-MPO update pays over MA off from +15% to +2% (benchmarks/README.md)."""
    if every == 1:
        return term(), weight
    due = jnp.asarray(update_step) % every == 0
    value = jax.lax.cond(due, jax.checkpoint(term), lambda: jnp.zeros((), jnp.float32))
    scale = every if config.interval_scaling else 1
    return value, jnp.where(due, weight * scale, 0.0)


@dataclasses.dataclass(frozen=True)
class CAPSConfig:
    """CAPS smoothness regularizer: lambda_T temporal, lambda_S spatial with noise sigma."""

    lambda_t: float = setting(0.0, ge=0, why="CAPS, a baseline regularizer, off")
    lambda_s: float = setting(0.0, ge=0, why="CAPS, a baseline regularizer, off")
    sigma: float = setting(0.2, ge=0)

    def __post_init__(self) -> None:
        check(self, "caps")

    @property
    def active(self) -> bool:
        return self.lambda_t > 0 or self.lambda_s > 0


def caps_penalty(
    config: CAPSConfig,
    u: ControlFn,
    params: Any,
    obs: jax.Array,
    next_obs: jax.Array,
    key: jax.Array,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """CAPS: lambda_T mean ||u(x) - u(x')|| + lambda_S mean ||u(x) - u(x + N(0, sigma^2))||."""
    batch_u = jax.vmap(lambda x: u(params, x))
    a = batch_u(obs)
    temporal = jnp.mean(_safe_norm(a - batch_u(next_obs)))
    noisy = obs + config.sigma * jax.random.normal(key, obs.shape)
    spatial = jnp.mean(_safe_norm(a - batch_u(noisy)))
    total = config.lambda_t * temporal + config.lambda_s * spatial
    return total, {"caps_temporal": temporal, "caps_spatial": spatial, "caps_penalty": total}


def _safe_norm(x: jax.Array) -> jax.Array:
    """Euclidean norm over the last axis with a finite gradient at zero."""
    return jnp.sqrt(jnp.sum(jnp.square(x), axis=-1) + 1e-12)


def per_state_penalty(
    config: MAConfig,
    u: ControlFn,
    params: Any,
    obs: jax.Array,
    key: jax.Array,
    *,
    prev_params: Any = None,
    next_obs: jax.Array | None = None,
    alpha: jax.Array | float,
    terms: jax.Array | None = None,
) -> jax.Array:
    """alpha * (feedback + temporal) for every state of the batch (no subsample, no interval);
    ``alpha`` and ``terms`` as in ``penalty``.

    Used by the reward-shaping placement, which subtracts it from each transition's reward.
    """
    w_feedback, w_temporal = _split(terms)
    total = jnp.zeros(obs.shape[:1], jnp.float32)
    if config.uses_feedback:
        total = total + _scaled(_feedback_per_state(config, u, params, obs, key), w_feedback)
    if config.uses_temporal:
        temporal = _temporal_per_state(config, u, params, obs, prev_params, next_obs, None)
        total = total + _scaled(temporal, w_temporal)
    return alpha * total


# The regularizer's hooks each placement needs an agent to call (``check_applied``).
HOOKS_OF_PLACEMENT = {
    "actor_loss": ("actor_penalty",),
    "entropy": ("actor_penalty", "next_value_penalty"),
    "reward": ("shape_rewards",),
}


class PlacementError(ValueError):
    """MA is on but the agent does not apply it in its placement (one line, for the user)."""


class _Record:
    """The hooks called on the regularizers made while an agent is built."""

    def __init__(self) -> None:
        self.made = 0
        self.called: set[str] = set()


_RECORDS: list[_Record] = []


@contextlib.contextmanager
def recording() -> Iterator[_Record]:
    """Records the regularizers made inside and the hooks later called on them (at trace
    time): the training program builds an agent inside it and checks, once its update is
    traced, that MA was applied as placed (``check_applied``)."""
    record = _Record()
    _RECORDS.append(record)
    try:
        yield record
    finally:
        _RECORDS.remove(record)


def check_applied(record: _Record, ma_config: MAConfig, algo: str) -> None:
    """PlacementError unless, with MA on, the agent made a regularizer and called every hook
    its placement needs: an agent cannot drop the penalty, or half of it, in silence."""
    if not ma_config.active:
        return
    if record.made == 0:
        raise PlacementError(
            f"{algo} applies no minimum attention (it builds no min_attention.make_regularizer) "
            f"while ma.alpha is {ma_config.alpha:g}: set ma.alpha=0, or apply it in the agent"
        )
    missing = [h for h in HOOKS_OF_PLACEMENT[ma_config.placement] if h not in record.called]
    if missing:
        raise PlacementError(
            f"{algo} never calls the regularizer's {' and '.join(missing)}, which ma.placement "
            f"{ma_config.placement!r} needs: choose a placement the agent applies (its "
            "AgentSpec.placements), or call Regularizer.apply for every loss piece"
        )


class Placed(NamedTuple):
    """What ``Regularizer.apply`` gives an agent for one batch, whatever the placement: add
    ``actor_penalty`` to the actor (policy) loss, learn from ``rewards`` in place of the batch's
    rewards, subtract ``next_value_penalty`` from the value of the next states where the agent
    bootstraps one (zeros unless the placement is "entropy")."""

    actor_penalty: jax.Array
    rewards: jax.Array
    next_value_penalty: jax.Array
    metrics: dict[str, jax.Array]


class Regularizer(NamedTuple):
    """The smoothness penalties of a control law ``u``, as a learner needs them.

    * ``apply(params, obs, next_obs, rewards, keys, prev_params, update_step, alpha, terms)``
      -> ``Placed``: every piece for one batch in one call, placed as ``ma.placement`` says:
      the one hook an agent needs (it calls the three below);
    * ``actor_penalty(params, obs, next_obs, keys, prev_params, update_step, controls, alpha,
      terms)`` ->
      (penalty, metrics): what the actor objective adds (MA with ``placement="actor_loss"`` and
      CAPS); ``keys`` = (MA probe key, CAPS noise key); metrics named ``ma_*`` and ``caps_*``;
    * ``next_value_penalty(params, next_obs, key, prev_params, alpha, terms)`` -> per-state
      penalty at the next states, subtracted from the soft value in the critic target with
      ``placement="entropy"`` (zero otherwise), as SAC subtracts ent * log pi(a'|s');
    * ``shape_rewards(params, obs, next_obs, reward, key, prev_params, alpha, terms)`` -> rewards:
      the batch transform of ``placement="reward"`` (alpha * penalty per state subtracted, no
      gradient); the identity otherwise.

    ``alpha`` (traced values allowed) is required: the weight comes from the agent state's
    ``hyper``, never from the config, so a learner cannot train with another value than the
    run's. ``terms`` weighs the (feedback, temporal) terms (``term_weights``): a population's
    members carry their own alpha and mode as data in the agent state. The training program
    checks that an agent called the hooks its placement needs (``check_applied``).
    """

    actor_penalty: Callable[..., tuple[jax.Array, dict[str, jax.Array]]]
    shape_rewards: Callable[..., jax.Array]
    next_value_penalty: Callable[..., jax.Array]
    ma_config: MAConfig
    caps_config: CAPSConfig
    apply: Callable[..., Placed]


def make_regularizer(
    u: ControlFn, ma_config: MAConfig, caps_config: CAPSConfig | None = None
) -> Regularizer:
    """The one place a learner gets its MA and CAPS penalties from (see ``Regularizer``).

    Args:
        u: the control law ``u(params, obs) -> action`` the penalties differentiate.
        ma_config: the run's ``MAConfig`` (its placement resolved by ``config.resolve``).
        caps_config: CAPS's settings, or None (off).

    Returns:
        A ``Regularizer``: its ``apply`` gives every penalty piece for one batch, placed as
        ``ma.placement`` says.

    Raises:
        ValueError: MA is on and its placement is unresolved.
    """
    caps_config = caps_config or CAPSConfig()
    if ma_config.active and ma_config.placement is None:
        raise ValueError("ma.placement is unresolved: config.resolve fills in the agent's")
    in_actor = ma_config.active and ma_config.placement in ("actor_loss", "entropy")
    in_reward = ma_config.active and ma_config.placement == "reward"
    in_value = ma_config.active and ma_config.placement == "entropy"
    records = list(_RECORDS)
    for record in records:
        record.made += 1

    def called(hook: str) -> None:
        for record in records:
            record.called.add(hook)

    def actor_penalty(params, obs, next_obs, keys, prev_params=None, update_step=0,
                      controls=None, *, alpha, terms=None):  # fmt: skip
        called("actor_penalty")
        k_ma, k_caps = keys
        total = jnp.zeros((), jnp.float32)
        metrics: dict[str, jax.Array] = {}
        if in_actor:
            pen, parts = penalty(ma_config, u, params, obs, k_ma, prev_params=prev_params,
                                 next_obs=next_obs, update_step=update_step,
                                 controls=controls, alpha=alpha, terms=terms)  # fmt: skip
            total = total + pen
            metrics.update({f"ma_{k}": v for k, v in parts.items()})
        if caps_config.active:
            pen, parts = caps_penalty(caps_config, u, params, obs, next_obs, k_caps)
            total = total + pen
            metrics.update(parts)
        return total, metrics

    def shape_rewards(params, obs, next_obs, reward, key, prev_params=None, *, alpha,
                      terms=None):  # fmt: skip
        called("shape_rewards")
        if not in_reward:
            return reward
        shaping = per_state_penalty(ma_config, u, params, obs, key, prev_params=prev_params,
                                    next_obs=next_obs, alpha=alpha, terms=terms)  # fmt: skip
        return reward - jax.lax.stop_gradient(shaping)

    def next_value_penalty(params, next_obs, key, prev_params=None, *, alpha, terms=None):
        called("next_value_penalty")
        if not in_value:
            return jnp.zeros(next_obs.shape[:1], jnp.float32)
        per_state = per_state_penalty(ma_config, u, params, next_obs, key,
                                      prev_params=prev_params, alpha=alpha,
                                      terms=terms)  # fmt: skip
        return jax.lax.stop_gradient(per_state)

    def apply(params, obs, next_obs, rewards, keys, prev_params=None, update_step=0, *, alpha,
              terms=None) -> Placed:  # fmt: skip
        """Every piece for one batch (``keys``: MA probe key, CAPS noise key)."""
        pen, metrics = actor_penalty(params, obs, next_obs, keys, prev_params, update_step,
                                     alpha=alpha, terms=terms)  # fmt: skip
        shaped = shape_rewards(params, obs, next_obs, rewards, keys[0], prev_params,
                               alpha=alpha, terms=terms)  # fmt: skip
        at_next = next_value_penalty(params, next_obs, keys[0], prev_params, alpha=alpha,
                                     terms=terms)  # fmt: skip
        if in_reward:  # the penalty the rewards carry (the actor's is in ``ma_penalty``)
            metrics = {**metrics, "ma_reward_penalty": jnp.mean(rewards - shaped)}
        return Placed(pen, shaped, at_next, metrics)

    return Regularizer(actor_penalty, shape_rewards, next_value_penalty, ma_config, caps_config,
                       apply)  # fmt: skip
