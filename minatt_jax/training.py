"""The training program of every agent: collect -> store -> update, scanned over a chunk.

``make_train(config)`` looks the algorithm up in the registry (``agents.registry``), builds its
:class:`~minatt_jax.agents.base.Agent` and returns a :class:`Trainer` whose pure functions are

* ``init(key, hyper) -> state``: the agent's whole training state, one pytree; ``hyper`` holds
  every value a population sweeps (``agents.base.hyper_values(spec, config)``);
* ``train_chunk(state) -> (state, metrics)``: ``eval_every / num_envs`` iterations in one
  ``lax.scan``, compiled once; ``run_chunk(state, start, members)`` is the same over a
  population's stacked states (vmapped, axis ``"members"``);
* ``evaluate(state, key, tasks) -> EvalResult``: deterministic episodes of the agent's policy.

The program knows no algorithm by name. The env-step counter it passes to the agent is unbatched,
so the agents' schedules (warm-up, model refits, update start) stay ``lax.cond`` branches in a
population instead of selects that run both sides for every member.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

import minatt_jax.envs as envs
from minatt_jax import min_attention as ma
from minatt_jax.agents import registry
from minatt_jax.agents.base import Agent, check_hyper, hyper_values
from minatt_jax.evaluation import EvalResult, make_evaluator


class Trainer(NamedTuple):
    """The pure functions of a training program, and what they were built from."""

    config: Any
    env: envs.LocomotionEnv
    spec: registry.AgentSpec
    agent: Agent
    task_set: envs.Task
    init: Callable[[jax.Array, dict], Any]  # jitted; every leaf its own buffer
    init_state: Callable[[jax.Array, dict], Any]  # the same, unjitted (to vmap)
    train_chunk: Callable[[Any], tuple[Any, dict]]
    run_chunk: Callable[[Any, jax.Array, bool], tuple[Any, dict]]
    evaluate: Callable[[Any, jax.Array, envs.Task], EvalResult]
    steps_per_chunk: int


def training_tasks(config: Any, env: envs.LocomotionEnv) -> envs.Task:
    """The stacked tasks a run trains on: its custom ``tasks`` or its named ``task_set``."""
    tasks, _ = envs.resolve_tasks(env, config.task_set, config.tasks)
    return envs.stack_tasks(tasks)


def scan_iterations(
    iteration: Callable[[Any, jax.Array, str | None], tuple[Any, dict]],
    ts: Any,
    start: jax.Array,
    steps_per_iteration: int,
    iterations: int,
    members: bool,
) -> tuple[Any, dict]:
    """``iterations`` calls of ``iteration(state, env_step, members_axis)`` from env step
    ``start``, in one ``lax.scan``; returns the state and the per-iteration metrics. With
    ``members`` the state has a leading population axis: each iteration is vmapped over it
    (axis name ``"members"``) and the metrics come back member-first."""
    if members:
        step = jax.vmap(lambda t, s: iteration(t, s, "members"), in_axes=(0, None),
                        axis_name="members")  # fmt: skip
    else:
        step = lambda t, s: iteration(t, s, None)  # noqa: E731

    def body(state: Any, i: jax.Array) -> tuple[Any, dict]:
        return step(state, start + i * steps_per_iteration)

    ts, metrics = jax.lax.scan(body, ts, jnp.arange(iterations, dtype=jnp.int32))
    if members:
        metrics = jax.tree.map(lambda x: jnp.moveaxis(x, 0, 1), metrics)
    return ts, metrics


def make_train(config: Any) -> Trainer:
    """The training program of a resolved configuration (see the module docstring)."""
    if not config.is_resolved:
        raise ValueError("make_train needs a resolved configuration: call config.resolve first")
    spec = registry.get(config.algo, config.agent_module)
    env = config.make_env()
    task_set = training_tasks(config, env)
    with ma.recording() as applied:
        agent = spec.make(config, env, task_set)
    n = config.num_envs

    def iteration(state: Any, steps: jax.Array, members_axis: str | None) -> tuple[Any, dict]:
        """One env step of every environment, its storage and the agent's learning; ``steps``
        is the (unbatched) env-step counter before the step."""
        rng, *keys = jax.random.split(state.rng, 1 + len(agent.keys))
        keys = dict(zip(agent.keys, keys, strict=True))
        state, collected, collect_metrics = agent.collect(
            state.replace(rng=rng), keys, steps, members_axis
        )
        state = agent.store(state.replace(env_steps=state.env_steps + n), collected)
        state, update_metrics = agent.update(state, keys, steps + n)
        return state, {**collect_metrics, **update_metrics}

    def run_chunk(state: Any, start: jax.Array, members: bool) -> tuple[Any, dict]:
        state, metrics = scan_iterations(iteration, state, start, n, config.eval_every // n,
                                         members)  # fmt: skip
        # Traced now: the agent's update has called its regularizer's hooks, or has not.
        ma.check_applied(applied, config.ma, config.algo)
        return state, (jax.vmap(agent.summarize) if members else agent.summarize)(state, metrics)

    def init_state(key: jax.Array, hyper: dict) -> Any:
        check_hyper(spec, hyper)
        return agent.init(key, hyper)

    init_compiled = jax.jit(init_state)

    def init(key: jax.Array, hyper: dict) -> Any:
        # Compiled (an eager MJX reset takes tens of seconds). Every leaf then gets its own
        # buffer: the state is donated to train_chunk, and donation fails when one buffer
        # appears twice (XLA may return one buffer for equal outputs). The copies stay
        # committed to the device, as jit keys its cache on committed-ness.
        check_hyper(spec, hyper)
        state = init_compiled(key, hyper)
        return jax.device_put(jax.tree.map(lambda x: jnp.array(x, copy=True), state),
                              jax.devices()[0])  # fmt: skip

    evaluator = make_evaluator(env, agent.policy.deterministic, config.episode_limit,
                               config.eval_episodes)  # fmt: skip

    def evaluate(state: Any, key: jax.Array, tasks: envs.Task) -> EvalResult:
        return evaluator(*state.policy_items(), key, tasks)

    return Trainer(
        config=config, env=env, spec=spec, agent=agent, task_set=task_set, init=init,
        init_state=init_state,
        train_chunk=jax.jit(lambda s: run_chunk(s, s.env_steps, False), donate_argnums=0),
        run_chunk=run_chunk, evaluate=evaluate, steps_per_chunk=config.eval_every,
    )  # fmt: skip


# Fields a run's program never reads: the seed (the init key) and the length (the run loop's).
_RUN_FIELDS = ("seed", "total_steps")


def swept_fields(config: Any) -> tuple[str, ...]:
    """The configuration fields that reach the program only as its state's ``hyper`` values
    (the agent's ``AgentSpec.hyper``): changing them never recompiles. The MA mode is among
    them for a population only (``program_key``)."""
    return tuple(f for f in registry.get(config.algo).hyper.values() if f != "ma.mode")


def program_key(config: Any, ma_structure: bool = True) -> str:
    """What decides a compiled program: the configuration without its swept fields, seed and
    length, and which MA terms it computes (whether MA is on, and its mode's terms). Population
    members are grouped without the latter (``ma_structure=False``): their program computes the
    union of their terms, each member weighing them by its own ``hyper`` values."""
    import json

    fields = config.to_dict()
    for dotted in (*swept_fields(config), *_RUN_FIELDS, "ma.mode"):
        *group, name = dotted.split(".")
        (fields[group[0]] if group else fields).pop(name)
    if ma_structure:
        fields["ma_program"] = [config.ma.active, config.ma.mode]
    return json.dumps(fields, sort_keys=True, default=str)


def hyper_of(config: Any) -> dict[str, Any]:
    """``config``'s values of its agent's hyper fields: ``trainer.init(key, hyper_of(config))``."""
    return hyper_values(registry.get(config.algo), config)
