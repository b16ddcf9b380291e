"""The agent interface: what every algorithm gives the generic training program.

An algorithm is a unit: ``registry.AgentSpec`` (its name, its swept ``hyper`` fields, its derived
defaults) and the pure functions of :class:`Agent` that ``spec.make(config, env, task_set)``
builds for one configuration. The training program (``training.make_train``) runs, for every
iteration of a chunk,

    keys = split(state.rng)          one key per name in ``agent.keys``
    collect(state, keys, steps)      act (through ``acting``) and step the environments
    store(state, collected)          into the agent's replay
    update(state, keys, steps)       everything that learns: model phase, agent updates

and knows nothing else of the algorithm. Every value a population may sweep (alpha, learning
rates, the inner step, ...) lives in the state's ``hyper`` subtree (``state.agent.hyper``), read
by the losses directly; ``init`` takes it explicitly, so no value can default silently.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import numpy as np

from minatt_jax import acting
from minatt_jax import min_attention as ma
from minatt_jax.agents.registry import AgentSpec


class NumpyForm(NamedTuple):
    """A feedforward policy as numpy arrays, for ``export`` (``minatt_jax.numpy_policy``):

        x = clip((obs - obs_mean) / sqrt(obs_var + eps), -clip, clip)   # if normalize_obs
        h = act(x @ W_0 + b_0) ... ; out = h @ W_n + b_n ; action = tanh(out[..., :act_dim])

    ``layers``: (kernel (in, out), bias) pairs; ``activation``: the hidden layers' activation,
    one of ``numpy_policy.ACTIVATIONS``; ``obs_mean``/``obs_var``: the normalizer (used when
    ``normalize_obs``).
    """

    layers: list[tuple[np.ndarray, np.ndarray]]
    activation: str
    obs_mean: np.ndarray
    obs_var: np.ndarray
    normalize_obs: bool


def mlp_numpy_form(mlp: dict, activation: str, normalizer: Any, normalize: bool) -> NumpyForm:
    """The numpy form of a flax MLP actor, for ``PolicyFamily.export``.

    Args:
        mlp: the actor's parameters (``Dense_0``, ``Dense_1``, ...; the first ``act_dim``
            outputs of the last layer are the tanh's input).
        activation: the hidden layers' activation (``relu``, ``tanh``, ``elu``, ``swish``,
            ``identity``).
        normalizer: the observation normalizer the actor acts behind.
        normalize: whether the policy normalizes its observations.

    Returns:
        A ``NumpyForm`` (layers, activation, normalizer) that ``numpy_policy`` runs.
    """
    from minatt_jax.numpy_policy import dense_layers

    return NumpyForm(dense_layers(mlp), activation, np.asarray(jax.device_get(normalizer.mean)),
                     np.asarray(jax.device_get(normalizer.var)), normalize)  # fmt: skip


class PolicyFamily(NamedTuple):
    """How a saved policy acts, whatever trained it; everything past training (evaluation on
    MJX and the C engine, ``Policy.control``, export, analysis) asks the family, never the
    agent's settings.

    * ``agent``: the learner's functions, for the agent's own adapter (SAC: control, sample,
      update; DreamerAgent); nothing outside the agent reads it;
    * ``like``: the (params, normalizer) templates of a policy snapshot (numpy zeros);
    * ``checkpoint_items`` / ``from_items``: the checkpoint items that hold the same policy, and
      how they assemble into (params, normalizer), for runs without a snapshot at a step;
    * ``deterministic(params, normalizer)`` (evaluation) and ``stochastic(params, normalizer)``
      (data collection) as ``acting`` policies: a feedforward one's ``prepare`` applies the
      family's own observation normalization and its ``control`` is u(x);
    * ``recurrent``: the policy carries memory (no u(obs) alone, no numpy export);
    * ``export(params, normalizer) -> NumpyForm``: the policy in numpy, or None where the family
      has no numpy form (export then refuses in one line).
    """

    agent: Any
    like: tuple[Any, Any]
    checkpoint_items: dict[str, Any]
    from_items: Callable[[dict[str, Any]], tuple[Any, Any]]
    deterministic: Callable[[Any, Any], acting.AnyPolicy]
    stochastic: Callable[[Any, Any], acting.AnyPolicy]
    recurrent: bool
    export: Callable[[Any, Any], NumpyForm] | None = None

    def control(self, params: Any, normalizer: Any) -> Callable[[jax.Array], jax.Array]:
        """``obs -> u``: the deterministic control on raw observations (the family's own
        normalization applied). ValueError for a recurrent policy: u depends on its memory."""
        if self.recurrent:
            raise ValueError("the policy is recurrent: u depends on its memory; act with its "
                             "acting policy (acting.unroll runs it)")  # fmt: skip
        policy = self.deterministic(params, normalizer)
        return lambda obs: policy.control(policy.prepare(obs))


class Agent(NamedTuple):
    """The pure functions of one algorithm for one configuration (see the module docstring).

    ``collect(state, keys, steps, members_axis) -> (state, collected, metrics)``: ``steps`` is the
    unbatched env-step counter before the step; ``members_axis`` names a population's vmapped
    axis (``acting.reset_ended``). ``store(state, collected) -> state``. ``update(state, keys,
    steps) -> (state, metrics)`` with ``steps`` the counter after the step. ``summarize(state,
    per_iteration) -> dict``: a chunk's metrics from the stacked per-iteration ones.
    """

    keys: tuple[str, ...]
    init: Callable[[jax.Array, dict[str, jax.Array]], Any]
    collect: Callable[..., tuple[Any, Any, dict]]
    store: Callable[[Any, Any], Any]
    update: Callable[[Any, dict[str, jax.Array], jax.Array], tuple[Any, dict]]
    summarize: Callable[[Any, dict], dict]
    policy: PolicyFamily
    parts: dict[str, Callable] = {}  # stages for timing breakdowns and benchmarks


class Adapter(NamedTuple):
    """What a meta-test does with new experience (``meta_test``); an agent without one
    (``AgentSpec.adapter`` None) is refused by meta-test in one line, and ``no_adaptation``
    is the adapter of an agent that adapts by nothing (or in context).

    * ``like``: the checkpoint items the adaptation reads (``checkpoint.restore_items``, by
      their key paths, e.g. ``{"agent": template}``); the restored item ``parts["agent"]`` is the
      learner that adapts, and its ``hyper`` subtree (if any) is where the meta-test sets the
      adaptation's MA weight and inner step size (``--adapt-alpha``, ``--inner-lr``);
    * ``prepare(parts, normalizer, traj, key, refit) -> context``: once per task, from the
      collected episodes (``acting.Trajectory``, (shots, steps, ...)): a replay, a refitted model;
    * ``step(learner, context, key) -> learner``: one adaptation step (gradient updates, MAML
      inner steps; the identity for an agent that adapts in context);
    * ``policy_params(learner)``: the policy's parameters of a learner.
    """

    like: dict[str, Any]
    prepare: Callable[..., Any]
    step: Callable[[Any, Any, jax.Array], Any]
    policy_params: Callable[[Any], Any]
    parts: dict[str, Callable] = {}  # compiled pieces (a model refit), for tests and timings


def no_adaptation(config: Any, env: Any, family: PolicyFamily, settings: Any) -> Adapter:
    """The adapter of an agent that does not adapt at meta-test time (or adapts in context):
    the saved policy (its ``family.checkpoint_items``), unchanged by every step, so a meta-test
    reports its evaluation on each new task. Name it as ``AgentSpec(adapter=no_adaptation)``.

    Args:
        config: the run's configuration.
        env: its environment.
        family: its policy family.
        settings: the meta-test's settings (unused: nothing adapts).

    Returns:
        An ``Adapter`` whose steps return the policy unchanged.
    """
    return Adapter(
        like=family.checkpoint_items,
        prepare=lambda parts, normalizer, traj, key, refit: None,
        step=lambda learner, context, key: learner,
        policy_params=lambda parts: family.from_items(parts)[0],
    )


def config_field(config: Any, dotted: str) -> Any:
    """The value of a dotted field of a configuration.

    Args:
        config: a ``TrainConfig`` (or any object of nested attributes).
        dotted: ``"seed"``, ``"ma.alpha"``, ``"sac.actor_lr"``, ...

    Returns:
        The field's value.
    """
    value: Any = config
    for part in dotted.split("."):
        value = getattr(value, part)
    return value


def hyper_values(spec: AgentSpec, config: Any) -> dict[str, np.ndarray]:
    """A configuration's values of the agent's ``hyper`` fields: the one channel through which
    swept values reach the program (data, never a recompile).

    Args:
        spec: the agent (its ``hyper``: name -> dotted field).
        config: the run's configuration.

    Returns:
        name -> float32 array (``"ma_terms"``: the MA mode's (feedback, temporal) weights).
    """
    values = {}
    for name, field in spec.hyper.items():
        if name == "ma_terms":
            values[name] = np.asarray(ma.term_weights(config.ma.mode), np.float32)
        else:
            values[name] = np.float32(config_field(config, field))
    return values


def zeros_like_shapes(tree: Any) -> Any:
    """Numpy zeros in the shapes and dtypes of ``tree`` (checkpoint templates)."""
    return jax.tree.map(lambda s: np.zeros(s.shape, s.dtype), tree)


def abstract_hyper(names: Any) -> dict[str, jax.Array]:
    """Zeros in the shapes of hyper values named ``names`` (templates: shapes, never values)."""
    return {k: jax.numpy.zeros((2,) if k == "ma_terms" else ()) for k in names}


def check_hyper(spec: AgentSpec, hyper: dict[str, Any]) -> None:
    """Checks that a hyper dict holds exactly the agent's declared fields.

    Args:
        spec: the agent.
        hyper: name -> value.

    Raises:
        ValueError: a field missing or one the agent does not declare.
    """
    missing = sorted(set(spec.hyper) - set(hyper))
    extra = sorted(set(hyper) - set(spec.hyper))
    if missing or extra:
        raise ValueError(
            f"{spec.name} hyper values must name exactly {', '.join(sorted(spec.hyper))}"
            + (f"; missing {', '.join(missing)}" if missing else "")
            + (f"; unknown {', '.join(extra)}" if extra else "")
        )


def with_hyper(state: Any, hyper: dict[str, Any]) -> Any:
    """A train state with its agent's ``hyper`` subtree replaced (how a resume applies changed
    swept values without recompiling).

    Args:
        state: the train state.
        hyper: name -> value, the same names and shapes as the state's.

    Returns:
        The state with the new values.
    """
    old = state.agent.hyper
    if set(old) != set(hyper):
        raise ValueError(f"hyper values name {sorted(hyper)}, the state holds {sorted(old)}")
    new = {k: jax.numpy.asarray(v, jax.numpy.asarray(old[k]).dtype) for k, v in hyper.items()}
    return state.replace(agent=state.agent.replace(hyper=new))
