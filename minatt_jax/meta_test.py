"""Meta-testing a trained run on out-of-distribution tasks: evaluate, adapt with K shots, repeat.

For every task of a task set (mass, crippled, slope, ...):

1. evaluate the trained policy (deterministic episodes on that task): step 0;
2. collect ``shots`` real episodes on the task with the trained (stochastic) policy;
3. ``adapt_steps`` times: one adaptation step of the agent's own ``Adapter`` (its registry
   entry's ``adapter``: SAC updates on the collected episodes for sac; the inner step
   theta <- theta - beta grad L(theta) on data imagined in the (refitted) model for mbpo and
   mbmpo; DreamerV3 updates on the collected sequences for dreamer), then evaluate again.

The adaptation reads its learner's ``hyper`` values (MA's weight, the inner step beta), which are
the run's own unless the settings override them (``adapt_alpha``, ``inner_lr``).
Every jitted function takes the task as data, so all tasks of a set run through one compiled
program. Returns per task and per step: return, feedback norm, feedforward norm, energy.
"""

from __future__ import annotations

import collections
import dataclasses
import json
import types
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import minatt_jax.envs as envs
from minatt_jax import acting, checkpoint, runner
from minatt_jax.agents import registry
from minatt_jax.agents.base import hyper_values
from minatt_jax.evaluation import make_evaluator, summarize
from minatt_jax.training import program_key

REPORTED = ("return", "feedback_norm", "feedforward_norm", "energy")


@dataclasses.dataclass(frozen=True)
class MetaTestConfig:
    """Meta-test settings (the paper plots 10 adaptation steps)."""

    shots: int = 1
    adapt_steps: int = 10
    episodes: int = 5
    updates_per_step: int = 20
    seed: int = 0
    inner_lr: float | None = None  # model-based runs: the inner step's beta (None: the run's)
    adapt_alpha: float | None = None  # MA's weight in the adaptation updates (None: the run's)
    # model-based runs: refit the ensemble on the collected episodes before adapting (False:
    # adapt on the trained ensemble, to tell a model error from the adaptation step's)
    refit_model: bool = True

    def __post_init__(self) -> None:
        for name in ("shots", "episodes", "updates_per_step"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if self.adapt_steps < 0:
            raise ValueError(f"adapt_steps must be >= 0, got {self.adapt_steps}")
        for name in ("inner_lr", "adapt_alpha"):
            value = getattr(self, name)
            if value is not None and not value >= 0:
                raise ValueError(f"{name} must be >= 0, got {value}")


def _collector(env, policy_of: Callable, max_steps: int, shots: int):
    """(params, norm, key, task) -> Trajectory (shots, max_steps, ...): ``shots`` episodes of
    the stochastic policy (``acting.unroll``)."""

    def episode(params, norm, key, task):
        k_reset, k_run = jax.random.split(key)
        return acting.unroll(env, policy_of(params, norm), env.reset(k_reset, task), max_steps,
                             key=k_run)  # fmt: skip

    def collect(params, norm, key, task):
        return jax.vmap(episode, in_axes=(None, None, 0, None))(
            params, norm, jax.random.split(key, shots), task
        )

    return jax.jit(collect)


def _distance(a: Any, b: Any) -> float:
    """The Euclidean distance between two parameter pytrees."""
    squares = jax.tree.map(lambda x, y: jnp.sum(jnp.square(x - y)), a, b)
    return float(jnp.sqrt(sum(jax.tree.leaves(squares))))


_PROGRAMS: collections.OrderedDict[str, Any] = collections.OrderedDict()


def _programs(config: Any, env: Any, family: Any, settings: MetaTestConfig) -> Any:
    """The meta-test's compiled functions (evaluate, collect, and the agent's ``Adapter``) for
    one program, built once per process (the latest few kept, ``runner.keep_latest``): a run's
    own arrays (its learner with its hyper values, normalizer, model) are their arguments, so
    meta-testing the runs of one program (seeds, alphas, learning rates, stages, task sets)
    compiles once. Keyed by the run's program (``training.program_key``) and the settings but
    the seed and those that enter as data."""
    swept = dataclasses.replace(settings, seed=0, inner_lr=None, adapt_alpha=None,
                                refit_model=True)  # fmt: skip
    key = json.dumps([program_key(config), repr(swept)], sort_keys=True, default=str)

    def build() -> Any:
        spec = registry.get(config.algo)
        return types.SimpleNamespace(
            evaluate=make_evaluator(env, family.deterministic, config.episode_limit,
                                    settings.episodes),
            collect=_collector(env, family.stochastic, config.episode_limit, settings.shots),
            adapter=spec.adapter(config, env, family, settings),
        )  # fmt: skip

    return runner.keep_latest(_PROGRAMS, key, build)


def _learner_hyper(spec: Any, config: Any, settings: MetaTestConfig) -> dict[str, Any]:
    """The learner's hyper values for the adaptation: the run's, with the settings' overrides
    (RunError when the agent has no such value)."""
    hyper = hyper_values(spec, config)
    for setting, name in (("adapt_alpha", "alpha"), ("inner_lr", "inner_lr")):
        value = getattr(settings, setting)
        if value is None:
            continue
        if name not in hyper:
            flag = setting.replace("_", "-")
            raise runner.RunError(f"--{flag} does not apply to {config.algo} runs (their learner "
                                  f"has no {name})")  # fmt: skip
        hyper[name] = np.float32(value)
    return hyper


def meta_test(
    run_dir: str,
    variant: str,
    settings: MetaTestConfig,
    log: Callable[[str], None] = print,
    task_specs: tuple[str, ...] = (),
) -> dict[str, Any]:
    """Meta-tests the latest checkpoint of ``run_dir`` on every task of ``variant`` (or on the
    custom ``task_specs``, one task each)."""
    try:
        policy = checkpoint.load_policy(run_dir)
        envs.check_task_set_name(variant)
    except (checkpoint.CheckpointError, envs.UnknownNameError) as e:
        raise runner.RunError(str(e)) from None
    config, env, family = policy.config, policy.env, policy.family
    spec = registry.get(config.algo)
    if spec.adapter is None:
        raise runner.RunError(
            f"{config.algo} runs cannot be meta-tested: the agent declares no adapter "
            "(AgentSpec.adapter; agents.base.no_adaptation evaluates without adapting); "
            f"evaluate it on the tasks instead: minatt-jax evaluate {run_dir} --variant {variant}"
        )
    hyper = _learner_hyper(spec, config, settings)
    try:
        tasks, labels = envs.resolve_tasks(env, variant, task_specs)
    except envs.TaskSpecError as e:
        raise runner.RunError(str(e)) from None
    programs = _programs(config, env, family, settings)
    adapter = programs.adapter
    # The learner (and what its adaptation reads) alone: no replay or model buffers are read.
    # Its hyper values are the run's (with the settings' overrides), whatever the checkpoint held.
    try:
        step, parts = checkpoint.restore_items(run_dir, adapter.like, policy.step)
    except checkpoint.CheckpointError as e:
        raise runner.RunError(str(e)) from None
    trained = parts["agent"] if "agent" in parts else parts
    adapting = trained
    if hasattr(trained, "hyper"):
        adapting = trained.replace(hyper={k: jnp.asarray(v) for k, v in hyper.items()})
    normalizer = policy.normalizer
    key = jax.random.PRNGKey(settings.seed)
    rows = []
    for t, (task, label) in enumerate(zip(tasks, labels, strict=True)):
        k_task = jax.random.fold_in(key, t)
        task_set = envs.stack_tasks([task])
        learner = adapting

        def evaluate(learner, i, task_set=task_set, k_task=k_task):
            params = adapter.policy_params(learner)
            result = programs.evaluate(params, normalizer, jax.random.fold_in(k_task, 1000 + i),
                                       task_set)  # fmt: skip
            return summarize(jax.device_get(result), env.dt)

        curve, moved = [evaluate(learner, 0)], []
        traj = programs.collect(adapter.policy_params(learner), normalizer,
                                jax.random.fold_in(k_task, 1), task)  # fmt: skip
        context = adapter.prepare(parts, normalizer, traj, jax.random.fold_in(k_task, 2),
                                  settings.refit_model)  # fmt: skip
        for i in range(1, settings.adapt_steps + 1):
            learner = adapter.step(learner, context, jax.random.fold_in(k_task, 10 + i))
            moved.append(_distance(adapter.policy_params(learner),
                                   adapter.policy_params(trained)))  # fmt: skip
            curve.append(evaluate(learner, i))
        row = {
            "task": label,
            "shots": settings.shots,
            "collected_transitions": int(np.sum(np.asarray(traj.alive))),
            **{f"{m}_curve": [c[m] for c in curve] for m in REPORTED},
            **{f"{m}_std_curve": [c[f"{m}_std"] for c in curve] for m in REPORTED},
            # || adapted policy parameters - trained ones || after each adaptation step: how
            # far the inner steps moved the policy (a collapse shows as a jump here)
            "policy_distance_curve": moved,
        }
        inner = sorted(k for k in curve[-1] if k.startswith("return_episode_")
                       and not k.endswith("_std"))  # fmt: skip
        if inner:  # meta-episodes: each inner episode's return after the last step (in context)
            row["return_by_episode"] = [curve[-1][f"return_episode_{i + 1}"]
                                        for i in range(len(inner))]  # fmt: skip
        rows.append(row)
        first, last = curve[0], curve[-1]
        log(f"{label:40s} return {first['return']:9.2f} -> {last['return']:9.2f} | feedback "
            f"{first['feedback_norm']:8.3f} -> {last['feedback_norm']:8.3f}")  # fmt: skip
    summary = {
        m: {
            "before": float(np.mean([r[f"{m}_curve"][0] for r in rows])),
            "after": float(np.mean([r[f"{m}_curve"][-1] for r in rows])),
        }
        for m in REPORTED
    }
    return {
        "run_dir": run_dir,
        "env": config.env,
        "algo": config.algo,
        "alpha": config.ma.alpha,
        "step": step,
        "variant": variant,
        "settings": dataclasses.asdict(settings),
        "tasks": rows,
        "mean_over_tasks": summary,
    }
