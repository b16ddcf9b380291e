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


class PolicyFamily(NamedTuple):
    """How a saved policy acts, whatever trained it.

    * ``like``: the (params, normalizer) templates of a policy snapshot (numpy zeros);
    * ``checkpoint_items`` / ``from_items``: the checkpoint items that hold the same policy, and
      how they assemble into (params, normalizer), for runs without a snapshot at a step;
    * ``deterministic(params, normalizer)`` (evaluation) and ``stochastic(params, normalizer)``
      (data collection) as ``acting`` policies;
    * ``control(params, x)``: the deterministic u(x) of a memoryless policy (None if recurrent).
    """

    agent: Any  # the learner's functions (SAC: control, sample, ...; DreamerAgent)
    like: tuple[Any, Any]
    checkpoint_items: dict[str, Any]
    from_items: Callable[[dict[str, Any]], tuple[Any, Any]]
    deterministic: Callable[[Any, Any], acting.AnyPolicy]
    stochastic: Callable[[Any, Any], acting.AnyPolicy]
    recurrent: bool


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
    """What a meta-test does with new experience (``meta_test``).

    * ``like``: the checkpoint items the adaptation reads (``checkpoint.restore_items``);
      ``parts["agent"]`` is the learner that adapts;
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


def config_field(config: Any, dotted: str) -> Any:
    """The value of a dotted field name (``"ma.alpha"``) of a configuration."""
    value: Any = config
    for part in dotted.split("."):
        value = getattr(value, part)
    return value


def hyper_values(spec: AgentSpec, config: Any) -> dict[str, np.ndarray]:
    """A configuration's values of the agent's ``hyper`` fields, as float32 arrays: the one
    channel through which they reach the program (``"ma_terms"``: the MA mode's term weights)."""
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
    """ValueError unless ``hyper`` holds exactly the agent's declared fields."""
    missing = sorted(set(spec.hyper) - set(hyper))
    extra = sorted(set(hyper) - set(spec.hyper))
    if missing or extra:
        raise ValueError(
            f"{spec.name} hyper values must name exactly {', '.join(sorted(spec.hyper))}"
            + (f"; missing {', '.join(missing)}" if missing else "")
            + (f"; unknown {', '.join(extra)}" if extra else "")
        )


def with_hyper(state: Any, hyper: dict[str, Any]) -> Any:
    """``state`` with its agent's ``hyper`` subtree replaced (same names, same shapes)."""
    old = state.agent.hyper
    if set(old) != set(hyper):
        raise ValueError(f"hyper values name {sorted(hyper)}, the state holds {sorted(old)}")
    new = {k: jax.numpy.asarray(v, jax.numpy.asarray(old[k]).dtype) for k, v in hyper.items()}
    return state.replace(agent=state.agent.replace(hyper=new))
