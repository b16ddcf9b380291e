"""Meta-testing a trained run on out-of-distribution tasks: evaluate, adapt with K shots, repeat.

For every task of a task set (mass, crippled, slope, ...):

1. evaluate the trained policy (deterministic episodes on that task): step 0;
2. collect ``shots`` real episodes on the task with the trained (stochastic) policy;
3. ``adapt_steps`` times: one adaptation step, then evaluate again. An adaptation step is
   * sac: ``updates_per_step`` SAC updates (actor, critics, entropy; MA included) on batches drawn
     from the K collected episodes;
   * mbpo / mbmpo: the dynamics ensemble is refitted once on the K episodes (starting from the
     trained ensemble); each step imagines transitions of the current policy in the refitted
     model from collected states (one slot per elite) and applies the inner step
     theta <- theta - beta grad L(theta) on each slot's imagined data, averaged over slots.
     mbmpo uses its own inner step (``mb.meta_inner``: the SAC actor loss on one-step
     transitions, or VPG on ``vpg_horizon``-step trajectories; first-order or not; beta =
     ``meta_inner_lr``); mbpo, which has no meta step, the SAC inner step. The SAC inner step
     reads only the supports' states (collected real states) and the trained critic, so the
     model, refitted or not (``refit_model``), enters only through VPG's inner step or the
     rollout reading of MA's temporal term, and is refitted only for those;
   * dreamer: ``updates_per_step`` DreamerV3 updates (world model, actor, critic; MA included)
     on sequences sampled from the K collected episodes (its policy is recurrent: collection and
     evaluation run it through ``policies``, feedback with respect to the observation).

Every jitted function takes the task as data, so all tasks of a set run through one compiled
program. Returns per task and per step: return, feedback norm, feedforward norm, energy.
"""

from __future__ import annotations

import collections
import dataclasses
import functools
import json
import types
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import minatt_jax.envs as envs
from minatt_jax import acting, checkpoint, imagination, replay, runner
from minatt_jax import normalizer as obs_norm
from minatt_jax.dynamics_ensemble import make_ensemble
from minatt_jax.evaluation import make_evaluator, summarize
from minatt_jax.maml import Trajectories, make_meta_step
from minatt_jax.training import make_meta, run_program_config

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


def _flat(traj: acting.Trajectory) -> tuple[Any, jax.Array]:
    """The episodes' transitions and alive mask, flattened to (episodes * steps,)."""
    flat = lambda x: x.reshape((-1,) + x.shape[2:])  # noqa: E731
    return jax.tree.map(flat, traj.transitions()), flat(traj.alive)


def _dreamer_adapt(agent_fns: Any, config: Any, settings: MetaTestConfig) -> Callable:
    """DreamerV3's adaptation step: ``updates_per_step`` updates (world model, actor, critic,
    MA included) on windows of the run's sequence length sampled from the collected episodes."""
    from minatt_jax.dreamer.training import episode_sequences, sample_episode_sequences

    d = config.dreamer

    @jax.jit
    def adapt(agent, traj, key):
        episodes, lengths = episode_sequences(traj)

        def one(agent, k):
            k_batch, k_update = jax.random.split(k)
            batch = sample_episode_sequences(episodes, lengths, k_batch, d.batch_size,
                                             d.batch_length)  # fmt: skip
            return agent_fns.update(agent, batch, k_update)[0], None

        return jax.lax.scan(one, agent, jax.random.split(key, settings.updates_per_step))[0]

    return adapt


def _distance(a: Any, b: Any) -> float:
    """The Euclidean distance between two parameter pytrees."""
    squares = jax.tree.map(lambda x, y: jnp.sum(jnp.square(x - y)), a, b)
    return float(jnp.sqrt(sum(jax.tree.leaves(squares))))


_PROGRAMS: collections.OrderedDict[str, Any] = collections.OrderedDict()


def _adaptation_reads_model(config: Any) -> bool:
    """Whether the model-based inner step reads the model's predictions: VPG's trajectories or
    MA's rollout temporal term; the SAC inner step reads only the supports' (real) states."""
    vpg = config.algo == "mbmpo" and config.mb.meta_inner == "vpg"
    return vpg or config.ma.temporal == "rollout"


def _programs(config: Any, env: Any, sac: Any, kind: Any, ensemble: Any,
              settings: MetaTestConfig) -> Any:  # fmt: skip
    """The meta-test's compiled functions (evaluate, collect, refit, adapt, policy_params) for
    one program, built once per process (the latest few kept, ``runner.keep_latest``): a run's
    own arrays (agent with its MA weight and learning rates, normalizer, return statistics,
    model) are their arguments, so meta-testing the runs of one program (seeds, alphas,
    learning rates, stages, task sets) compiles once; so are the inner step size and MA's
    weight in the adaptation (swept by ``experiments/adaptation_step.py``). Keyed by the run's
    program (``training.run_program_config``) and the settings but those."""
    swept = dataclasses.replace(settings, seed=0, inner_lr=None, adapt_alpha=None,
                                refit_model=True)  # fmt: skip
    key = json.dumps([run_program_config(config).to_dict(), repr(swept)], sort_keys=True,
                     default=str)  # fmt: skip
    build = functools.partial(_build_programs, config, env, sac, kind, ensemble, settings)
    return runner.keep_latest(_PROGRAMS, key, build)


def _build_programs(config: Any, env: Any, sac: Any, kind: Any, ensemble: Any,
                    settings: MetaTestConfig) -> Any:  # fmt: skip
    """``_programs``' functions, compiled on first call."""
    model_based = config.model_based
    dreamer = config.algo == "dreamer"
    norm_on = config.sac.normalize_obs
    max_steps = config.max_episode_steps

    def normalize(normalizer, obs):
        return obs_norm.normalize(normalizer, obs, norm_on)

    def learned(b, normalizer, return_stats):
        """A batch as the run's agent learned from it (observation and reward scales)."""
        return b.replace(obs=normalize(normalizer, b.obs),
                         next_obs=normalize(normalizer, b.next_obs),
                         reward=obs_norm.scale_reward(return_stats, b.reward))  # fmt: skip

    evaluator = make_evaluator(env, kind.deterministic, max_steps, settings.episodes)
    collect = _collector(env, kind.stochastic, max_steps, settings.shots)
    if dreamer:
        adapt = _dreamer_adapt(sac, config, settings)

        def policy_params(agent):
            return {"world_model": agent.params["world_model"], "actor": agent.params["actor"]}
    else:

        def policy_params(agent):
            return agent.actor_params

    capacity = settings.shots * max_steps
    batch = config.sac.batch_size
    refit = None

    def collected_buffer(data, valid):
        empty = replay.init_buffer(capacity, env.observation_size, env.action_size)
        return replay.insert_masked(empty, data, valid)

    if not model_based and not dreamer:

        @jax.jit
        def adapt(agent, data, valid, key, normalizer, return_stats):
            buffer = collected_buffer(data, valid)

            def one(agent, k):
                k_batch, k_sac = jax.random.split(k)
                b = replay.sample(buffer, k_batch, batch)
                b = learned(b, normalizer, return_stats)
                return sac.update(agent, b, k_sac)[0], None

            keys = jax.random.split(key, settings.updates_per_step)
            return jax.lax.scan(one, agent, keys)[0]

    elif model_based:
        # mbmpo adapts with its own inner step (inner objective, first-order or not, beta);
        # mbpo, which has no meta step, with the SAC inner step at the run's meta_inner_lr.
        meta = make_meta(config, sac) if config.algo == "mbmpo" else make_meta_step(
            sac, config.mb.meta_inner_lr
        )  # fmt: skip
        vpg = config.algo == "mbmpo" and config.mb.meta_inner == "vpg"
        horizon = config.mb.vpg_horizon if vpg else 1
        slots = config.model.num_elites
        per_slot = max(batch // slots, 16)

        @jax.jit
        def refit(ens_state, data, valid, key):
            buffer = collected_buffer(data, valid)
            return ensemble.fit(ens_state, buffer.data, buffer.size, key)[0]

        @jax.jit
        def adapt(agent, ens_state, data, valid, key, normalizer, return_stats, step_size):
            k_start, k_roll, k_inner = jax.random.split(key, 3)
            count = jnp.maximum(jnp.sum(valid).astype(jnp.int32), 1)
            order = jnp.argsort(valid <= 0, stable=True)
            idx = order[jax.random.randint(k_start, (slots, per_slot), 0, count)]
            rollouts, alive = imagination.imagine(
                ensemble, ens_state, ens_state.elites,
                lambda p, obs, k: sac.sample(p, normalize(normalizer, obs), k), agent.actor_params,
                env.terminated, data.obs[idx], jnp.asarray(horizon), horizon, k_roll,
                config.mb.obs_clip,
            )  # fmt: skip
            rollouts = learned(rollouts, normalizer, return_stats)
            if vpg:
                supports = Trajectories(data=rollouts, alive=alive)
            else:  # one step from real states: every transition is taken
                supports = jax.tree.map(lambda x: x[:, 0], rollouts)

            def inner(p, k):
                adapted = jax.vmap(
                    lambda s, kk: meta.adapt(p, agent, s, kk, step_size=step_size)[0]
                )(supports, jax.random.split(k, slots))
                return jax.tree.map(lambda a: jnp.mean(a, axis=0), adapted)

            return agent.replace(actor_params=inner(agent.actor_params, k_inner))

    return types.SimpleNamespace(evaluate=evaluator, collect=collect, refit=refit, adapt=adapt,
                                 policy_params=policy_params)  # fmt: skip


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
    config, env, sac, kind = policy.config, policy.env, policy.agent, policy.family
    model_based = config.model_based
    dreamer = config.algo == "dreamer"
    # The agent (and the ensemble) alone: no replay or model buffers are allocated.
    like = {"agent": jax.eval_shape(sac.init, jax.random.PRNGKey(0))}
    ensemble = None
    if model_based:
        ensemble = make_ensemble(env.observation_size, env.action_size, config.model)
        like["model"] = jax.eval_shape(ensemble.init, jax.random.PRNGKey(0))
    if config.sac.normalize_reward:
        like["data/return_stats"] = obs_norm.init_normalizer(1)
    like = jax.tree.map(lambda s: np.zeros(s.shape, s.dtype), like)
    try:
        step, parts = checkpoint.restore_items(run_dir, like, policy.step)
    except checkpoint.CheckpointError as e:
        raise runner.RunError(str(e)) from None
    trained_agent = parts["agent"]
    adapting_agent = trained_agent  # what the adaptation updates start from
    if settings.adapt_alpha is not None:
        if not hasattr(trained_agent, "ma_alpha"):
            raise runner.RunError("--adapt-alpha applies to sac, mbpo and mbmpo runs")
        adapting_agent = trained_agent.replace(ma_alpha=jnp.float32(settings.adapt_alpha))
    try:
        tasks, labels = envs.resolve_tasks(env, variant, task_specs)
    except envs.TaskSpecError as e:
        raise runner.RunError(str(e)) from None
    programs = _programs(config, env, sac, kind, ensemble, settings)
    normalizer, return_stats = policy.normalizer, parts.get("data/return_stats")
    policy_params = programs.policy_params
    step_size = None
    if model_based:
        beta = config.mb.meta_inner_lr if settings.inner_lr is None else settings.inner_lr
        step_size = jnp.float32(beta)
    key = jax.random.PRNGKey(settings.seed)
    rows = []
    for t, (task, label) in enumerate(zip(tasks, labels, strict=True)):
        k_task = jax.random.fold_in(key, t)
        task_set = envs.stack_tasks([task])
        agent = adapting_agent

        def evaluate(agent, i, task_set=task_set, k_task=k_task):
            result = programs.evaluate(policy_params(agent), normalizer,
                                       jax.random.fold_in(k_task, 1000 + i), task_set)  # fmt: skip
            return summarize(jax.device_get(result), env.dt)

        curve, moved = [evaluate(agent, 0)], []
        traj = programs.collect(policy_params(agent), normalizer, jax.random.fold_in(k_task, 1),
                                task)  # fmt: skip
        data, valid = _flat(traj)
        ens_state = None
        if model_based and settings.adapt_steps > 0:
            ens_state = parts["model"]
            if settings.refit_model and _adaptation_reads_model(config):
                ens_state = programs.refit(ens_state, data, valid, jax.random.fold_in(k_task, 2))
        for i in range(1, settings.adapt_steps + 1):
            k = jax.random.fold_in(k_task, 10 + i)
            if model_based:
                agent = programs.adapt(
                    agent, ens_state, data, valid, k, normalizer, return_stats, step_size
                )
            elif dreamer:
                agent = programs.adapt(agent, traj, k)
            else:
                agent = programs.adapt(agent, data, valid, k, normalizer, return_stats)
            moved.append(_distance(policy_params(agent), policy_params(trained_agent)))
            curve.append(evaluate(agent, i))
        row = {
            "task": label,
            "shots": settings.shots,
            "collected_transitions": int(np.sum(np.asarray(valid))),
            **{f"{m}_curve": [c[m] for c in curve] for m in REPORTED},
            **{f"{m}_std_curve": [c[f"{m}_std"] for c in curve] for m in REPORTED},
            # || adapted policy parameters - trained ones || after each adaptation step: how
            # far the inner steps moved the policy (a collapse shows as a jump here)
            "policy_distance_curve": moved,
        }
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
