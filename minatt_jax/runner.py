"""A training run on disk: config.json, metrics.jsonl, TensorBoard events, orbax checkpoints.

The loop alternates one compiled ``train_chunk`` (``eval_every`` env steps), an evaluation, one
metrics line and one checkpoint. Everything the next chunk depends on is in the checkpointed train
state and the evaluation keys derive from (seed, step), so a run resumed from its last checkpoint
writes the same metrics as one never interrupted (timings aside).
"""

from __future__ import annotations

import collections
import json
import os
import signal
import time
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

import minatt_jax.envs as envs
from minatt_jax import checkpoint, divergence, memory, mujoco_engine, run_guard
from minatt_jax.agents.base import config_field, hyper_values, with_hyper
from minatt_jax.config import TrainConfig, replace_fields, resolve
from minatt_jax.evaluation import make_evaluator, summarize
from minatt_jax.min_attention import PlacementError
from minatt_jax.run_files import (  # noqa: F401 - re-exported: the runner's public API
    DivergedError,
    RunError,
    StoppedError,
    load_config,
    read_metrics,
    write_json_atomic,
    write_text_atomic,
)
from minatt_jax.training import Trainer, make_train, program_key, swept_fields

TIMING_KEYS = ("env_steps_per_s", "updates_per_s", "imagined_per_s", "wall_s", "chunk_s", "eval_s",
               "compile_s")  # fmt: skip


def without_timings(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Records without their wall-clock fields: what an exact resume reproduces."""
    return [{k: v for k, v in r.items() if k not in TIMING_KEYS} for r in records]


def _json_value(v: Any) -> float | list:
    """A metric as JSON: a float, or a list for per-member arrays (holdout MSE, elites)."""
    v = np.asarray(v)
    return float(v) if v.ndim == 0 else v.tolist()


def keep_metrics_until(run_dir: str, step: int, records: list[dict] | None = None) -> None:
    """Rewrites metrics.jsonl (atomically) without records after ``step``; ``records``: the
    file's records already read (a resume reads every file before it writes any)."""
    records = read_metrics(run_dir) if records is None else records
    kept = [r for r in records if r["step"] <= step]
    write_text_atomic(os.path.join(run_dir, "metrics.jsonl"),
                      "".join(json.dumps(r) + "\n" for r in kept))  # fmt: skip


def tensorboard(run_dir: str):
    """A TensorBoard writer for the run, or None without tensorboardX."""
    try:
        from tensorboardX import SummaryWriter
    except ImportError:  # optional: metrics.jsonl holds the same numbers
        return None
    return SummaryWriter(os.path.join(run_dir, "tensorboard"))


def make_record(
    step: int, evaluation: dict, train_metrics: dict, timings: dict, steps_per_chunk: int
) -> dict[str, Any]:
    """One ``metrics.jsonl`` record: evaluation, chunk metrics, rates and timings."""
    chunk_s = timings["chunk_s"]
    record = {
        "step": step,
        **evaluation,
        **{k: _json_value(v) for k, v in train_metrics.items()},
        "env_steps_per_s": steps_per_chunk / chunk_s,
        "updates_per_s": float(train_metrics["updates"]) / chunk_s,
    }
    if "imagined_transitions" in train_metrics:
        record["imagined_per_s"] = float(train_metrics["imagined_transitions"]) / chunk_s
    return {**record, **timings}


def write_step(run_dir: str, step: int, state: Any, record: dict, writer: Any) -> None:
    """Appends the record (metrics.jsonl, TensorBoard), then the policy snapshot, then the
    checkpoint of ``state``: a crash between the two never leaves a checkpoint without its
    snapshot (a snapshot without a checkpoint is rewritten identically on resume). A write that
    fails (a full disk, a file-size limit, a vanished directory) takes the step's record and
    snapshot back and raises RunError in one line: no record outlives its checkpoint."""
    path = os.path.join(run_dir, "metrics.jsonl")
    size = os.path.getsize(path) if os.path.exists(path) else 0
    snapshot = None
    try:
        with open(path, "a") as f:
            f.write(json.dumps(record) + "\n")
            f.flush()
            os.fsync(f.fileno())
        snapshot = checkpoint.save_policy_snapshot(run_dir, step, *state.policy_items())
        checkpoint.save(run_dir, step, state)
    except (OSError, checkpoint.CheckpointError) as e:
        _take_back(path, size, snapshot)
        why = str(e) if isinstance(e, checkpoint.CheckpointError) else (
            f"cannot write {e.filename or path}: {e.strerror or e}")  # fmt: skip
        raise RunError(f"{why}; nothing of step {step} was kept, the run resumes from its "
                       f"previous checkpoint: {_resume_hint(run_dir)}") from None  # fmt: skip
    if writer is not None:  # optional, after the step is complete: never fails a run
        try:
            for k, v in record.items():
                if k != "step" and not isinstance(v, list) and np.isfinite(v):
                    writer.add_scalar(k, v, step)
            writer.flush()
        except OSError:
            pass


def _take_back(metrics_path: str, size: int, snapshot: str | None) -> None:
    """Undoes a step's partial writes: its record (metrics.jsonl cut back to ``size``) and its
    policy snapshot. Best effort: what cannot be undone is what a resume rewrites anyway."""
    try:
        if os.path.exists(metrics_path) and os.path.getsize(metrics_path) > size:
            os.truncate(metrics_path, size)
        if snapshot is not None and os.path.exists(snapshot):
            os.remove(snapshot)
    except OSError:
        pass


def _restore_newest_intact(run_dir: str, state: Any, log: Callable[[str], None]) -> tuple[int, Any]:
    """The newest checkpoint that reads back, setting aside newer unreadable ones (and saying
    so); (0, state) when there is none. RunError when every checkpoint is unreadable."""
    steps = checkpoint.all_steps(run_dir)
    errors = []
    for step in reversed(steps):
        try:
            restored_step, restored = checkpoint.restore(run_dir, state, step)
        except checkpoint.CheckpointError as e:
            errors.append(str(e))
            continue
        for newer in steps[steps.index(step) + 1 :]:
            where = checkpoint.set_aside(run_dir, newer)
            log(f"checkpoint {newer} is unreadable; resuming from checkpoint {step} "
                f"(the unreadable one is kept in {where})")  # fmt: skip
        return restored_step, jax.device_put(restored, jax.devices()[0])
    if steps:
        raise RunError(f"no checkpoint in {run_dir} can be read: {errors[0]}")
    return 0, state


def _changed_data(stored: TrainConfig, config: TrainConfig) -> dict[str, Any]:
    """The swept fields (``training.swept_fields``: the agent's hyper values) whose values
    differ."""
    return {k: config_field(config, k) for k in swept_fields(config)
            if config_field(config, k) != config_field(stored, k)}  # fmt: skip


# Fields a resume may change besides the data fields: how long to train, and how long a chunk
# is (evaluation and checkpoint every ``eval_every`` env steps). Every schedule reads the env-step
# counter and the random key lives in the state, so other chunks cut the same trajectory at other
# points (tests/test_training.py checks the states bit for bit).
RESUMABLE_FIELDS = ("total_steps", "eval_every")


def with_stored_schedule(config: TrainConfig, stored: TrainConfig) -> TrainConfig:
    """``config`` with ``stored``'s ``RESUMABLE_FIELDS``: equal to ``stored`` when a resume may
    go on from it."""
    return replace_fields(config, {k: config_field(stored, k) for k in RESUMABLE_FIELDS})


def check_on_chunk_grid(step: int, eval_every: int, run_dir: str) -> None:
    """Refuses to resume a checkpoint that is not on the new chunk grid (its chunks would pass
    the asked length and skip the evaluation stages)."""
    if step % eval_every:
        raise RunError(f"{run_dir} is at step {step}, not a multiple of eval_every {eval_every}; "
                       "resume it with an eval_every that divides it")  # fmt: skip


def _check_resumable(stored: TrainConfig, config: TrainConfig, run_dir: str) -> None:
    """Refuses a resume whose configuration differs in more than ``RESUMABLE_FIELDS`` and the
    data fields."""
    as_stored = {k: config_field(stored, k) for k in _changed_data(stored, config)}
    same = replace_fields(with_stored_schedule(config, stored), as_stored)
    if same.to_dict() != stored.to_dict():
        differ = [k for k, v in same.to_dict().items() if v != stored.to_dict()[k]]
        raise RunError(
            f"{run_dir} was made with other settings ({', '.join(differ)} differ); resume takes "
            f"them from its config.json (only the length, eval_every and "
            f"{', '.join(swept_fields(config))} may change)"
        )


# The trainers (and their compiled chunks) of this process's latest programs, newest last: runs
# in one process (a notebook's, a sweep script's, the tests') that differ only in seed, length
# or data values reuse them instead of tracing and compiling again. Evaluators likewise.
_TRAINERS: collections.OrderedDict[str, tuple[Trainer, dict[str, Any]]] = collections.OrderedDict()
_EVALUATORS: collections.OrderedDict[tuple[str, int], Any] = collections.OrderedDict()
_KEEP_PROGRAMS = 4


def keep_latest(cache: collections.OrderedDict, key: Any, build: Callable[[], Any]) -> Any:
    """``cache[key]``, built on first use; the ``_KEEP_PROGRAMS`` most recently used are kept
    (a process's compiled programs: trainers, evaluators, meta-tests)."""
    if key in cache:
        cache.move_to_end(key)
        return cache[key]
    cache[key] = build()
    while len(cache) > _KEEP_PROGRAMS:
        cache.popitem(last=False)
    return cache[key]


def trainer_for(config: TrainConfig) -> tuple[Trainer, dict[str, Any]]:
    """The trainer of ``config``'s program (``training.program_key``) and a dict for what the
    runner compiles from it, built once per process (the last ``_KEEP_PROGRAMS`` kept): runs
    that differ only in seed, length or swept values share it, as the program never reads
    those (they enter the state: ``init(key, hyper)``)."""
    key = program_key(config)
    try:
        return keep_latest(_TRAINERS, key, lambda: (make_train(config), {}))
    except MemoryError as e:  # a template of the networks' shapes already does not fit
        raise RunError(f"these settings need more memory than there is ({e}); choose smaller "
                       "networks or buffers") from None  # fmt: skip


def compiled_once(
    compiled: dict[Any, Any], key: Any, jitted: Any, args: Any, what: str,
    log: Callable[[str], None],
) -> Any:  # fmt: skip
    """``jitted`` compiled for ``args``, once per process: kept under ``key`` in a program's
    ``compiled`` dict (``trainer_for``); the log says whether it compiled or reused it."""
    if key in compiled:
        log(f"reusing the {what} compiled for an earlier run of this program")
    else:
        t0 = time.perf_counter()
        try:
            compiled[key] = run_guard.interruptible(lambda: jitted.lower(args).compile())
        except PlacementError as e:  # raised while the agent's update is traced
            raise RunError(str(e)) from None
        log(f"compiled the {what} in {time.perf_counter() - t0:.1f} s")
    return compiled[key]


def command_config(
    preset: str | None,
    overrides: list[str] | tuple[str, ...],
    fields: dict[str, Any],
    resume_dir: str | None = None,
) -> TrainConfig:
    """A run's resolved configuration from a command's words: ``preset`` (default cpu), or the
    stored configuration of ``resume_dir``, then the ``"group.field=value"`` ``overrides``, then
    the dotted ``fields``; every environment, task set and task named is checked. RunError (one
    line) for anything that does not fit."""
    from minatt_jax.config import apply_overrides, preset_config

    base = load_config(resume_dir) if resume_dir is not None else None
    if base is not None and preset is not None and preset != base.preset:
        # The other fields are checked by train (only the length and data fields may change);
        # a preset is a set of fields, so naming another one is refused here.
        raise RunError(f"{resume_dir} was made with preset {base.preset}; resume takes its "
                       "settings from its config.json (drop --preset)")  # fmt: skip
    try:
        if base is not None:
            config = replace_fields(apply_overrides(base, overrides), fields)
        else:
            config = preset_config(preset or "cpu", overrides, fields)
        if config.task_set is not None:
            envs.check_task_set_name(config.task_set)
        config = checked_tasks(resolve(config))
    except (ValueError, envs.UnknownNameError) as e:
        raise RunError(str(e)) from None
    return config


def checked_tasks(config: TrainConfig) -> TrainConfig:
    """``config`` once its training tasks are readable for its environment (a task set the
    environment holds, custom tasks it can apply); ValueError (one line) otherwise."""
    envs.resolve_tasks(envs.make(config.env, config.physics), config.task_set, config.tasks)
    return config


def _resume_hint(run_dir: str) -> str:
    return f"minatt-jax train --out {run_dir} --resume"


def train(
    config: TrainConfig,
    run_dir: str,
    resume: bool = False,
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Trains (or resumes) the run in ``run_dir``; returns the last metrics record.

    ``config`` is resolved here (``config.resolve``) when it is not already. One process at a
    time trains a directory (``run_guard.lock_run``). SIGINT/SIGTERM stop after the current chunk
    with its checkpoint written (StoppedError, exit 130/143); non-finite training stops before
    anything of the bad chunk is written (DivergedError, exit 3). A resume may change the length
    and the data fields (alpha, learning rates, inner step size), which never recompile.
    """
    try:
        config = checked_tasks(resolve(config))
    except ValueError as e:
        raise RunError(str(e)) from None
    try:
        with run_guard.lock_run(run_dir), run_guard.StopSignals(_resume_hint(run_dir)) as stop:
            return _train(config, run_dir, resume, log, stop)
    except run_guard.RunLockedError as e:
        raise RunError(str(e)) from None


def _train(
    config: TrainConfig,
    run_dir: str,
    resume: bool,
    log: Callable[[str], None],
    stop: run_guard.StopSignals,
) -> dict[str, Any]:
    trainer, compiled = trainer_for(config)
    if "bytes_per_member" not in compiled:
        compiled["bytes_per_member"] = memory.state_bytes(trainer)
    memory.check_states(compiled["bytes_per_member"], 1, "these settings")
    if config.planned_steps != config.total_steps:
        chunks = config.planned_steps // config.eval_every
        log(f"note: {config.total_steps} steps is not a multiple of eval_every "
            f"({config.eval_every}); training {config.planned_steps} steps "
            f"({chunks} chunks of {config.eval_every})")  # fmt: skip
    config_path = os.path.join(run_dir, "config.json")
    if resume:
        stored = load_config(run_dir)
        _check_resumable(stored, config, run_dir)
        latest = checkpoint.latest_step(run_dir)
        if latest == config.planned_steps and stored.to_dict() != config.to_dict():
            raise RunError(f"{run_dir} is already at its last step {latest}: no step would train "
                           "with the changed settings; ask for more steps (--steps) to train "
                           "with them")  # fmt: skip
        hyper = hyper_values(trainer.spec, config)
        step, state = _restore_newest_intact(run_dir, _initial_state(trainer, config), log)
        # Every resume trains with the run's own values, whatever the checkpoint held.
        state = with_hyper(state, hyper)
        if step > config.planned_steps:
            raise RunError(f"{run_dir} is already at step {step}; ask for at least that many "
                           "steps to resume it")  # fmt: skip
        check_on_chunk_grid(step, config.eval_every, run_dir)
        records = read_metrics(run_dir)  # read (and checked) before anything is written
        changed = _changed_data(stored, config)
        if changed:
            log(
                f"resuming with {', '.join(f'{k}={v:g}' for k, v in changed.items())} "
                f"(was {', '.join(f'{k}={config_field(stored, k):g}' for k in changed)})"
            )
        if stored.to_dict() != config.to_dict():  # only now: the resume is valid
            write_json_atomic(config_path, config.to_dict())
        if step and step not in checkpoint.snapshot_steps(run_dir):  # lost in a crash
            checkpoint.save_policy_snapshot(run_dir, step, *state.policy_items())
        # Records after the checkpoint are written again, identically, by the rerun.
        keep_metrics_until(run_dir, step, records)
        log(f"resumed {run_dir} at env step {step}")
    else:
        if os.path.exists(config_path):
            raise RunError(f"{run_dir} already holds a run; pass --resume or choose another --out")
        if checkpoint.latest_step(run_dir) is not None or read_metrics(run_dir):
            raise RunError(f"{run_dir} holds checkpoints or metrics of another run but no "
                           "config.json; choose another --out or remove them")  # fmt: skip
        write_json_atomic(config_path, config.to_dict())
        state = _initial_state(trainer, config)

    t0 = time.perf_counter()
    chunk = compiled_once(compiled, "chunk", trainer.train_chunk, state, "training step", log)
    members = Members(trainer, [config], [run_dir], chunk, trainer.evaluate, batched=False)
    return train_chunks(members, state, time.perf_counter() - t0, stop, log)[0]


def _initial_state(trainer: Trainer, config: TrainConfig) -> Any:
    """The run's initial state (its seed's, with its hyper values); jitted, so built under
    ``run_guard.interruptible``: a signal meanwhile ends the command at once."""
    hyper, key = hyper_values(trainer.spec, config), jax.random.PRNGKey(config.seed)
    return run_guard.interruptible(lambda: trainer.init(key, hyper), "starting")


class Members(NamedTuple):
    """What ``train_chunks`` trains: one run's state (``batched`` False) or a population group's
    states stacked on a leading axis, with the compiled chunk and evaluation that take them."""

    trainer: Trainer
    configs: list[TrainConfig]
    dirs: list[str]
    chunk: Callable[[Any], tuple[Any, dict]]  # states -> (states, chunk metrics)
    evaluate: Callable[[Any, jax.Array, Any], Any]  # (states, eval keys, task set) -> results
    batched: bool

    def member(self, tree: Any, i: int) -> Any:
        """Member ``i``'s part of a (stacked, when batched) tree."""
        return jax.tree.map(lambda x: x[i], tree) if self.batched else tree

    def env_steps(self, states: Any) -> int:
        """The env steps every member has trained (one counter: the schedule is shared)."""
        return int(states.env_steps[0] if self.batched else states.env_steps)


def train_chunks(
    members: Members,
    states: Any,
    compile_s: float,
    stop: run_guard.StopSignals,
    log: Callable[[str], None],
    resume_dir: str | None = None,
) -> list[dict[str, Any]]:
    """The run loop of single runs and populations: one compiled chunk (``eval_every`` env steps
    for every member), one evaluation, then for each member one metrics record, its policy
    snapshot and its checkpoint, until the longest member's length. Every member's record is
    checked for non-finite values before any member's step is written (DivergedError); a signal
    stops it between chunks (StoppedError, resumed on ``resume_dir``, default the first
    member's directory). Returns each member's last record."""
    trainer, dirs = members.trainer, members.dirs
    total = max(c.planned_steps for c in members.configs)  # whole chunks: what the log shows
    writers = [tensorboard(d) for d in dirs]
    eval_keys = [jax.random.PRNGKey(c.seed + 1_000_003) for c in members.configs]
    records: list[dict[str, Any]] = [{} for _ in dirs]
    stop.training()  # from here a signal stops after the chunk in progress
    guards = [divergence.Guard(trainer.env.action_size, read_metrics(d)) for d in dirs]
    start = time.perf_counter()
    try:
        while members.env_steps(states) < total:
            if stop.received is not None:
                raise stopped_error(stop, dirs[0], resume_dir)
            t0 = time.perf_counter()
            states, metrics = members.chunk(states)
            states = jax.block_until_ready(states)
            chunk_s = time.perf_counter() - t0
            step = members.env_steps(states)
            t0 = time.perf_counter()
            keys = [jax.random.fold_in(k, step) for k in eval_keys]
            keys = jnp.stack(keys) if members.batched else keys[0]
            results = jax.device_get(members.evaluate(states, keys, trainer.task_set))
            eval_s = time.perf_counter() - t0
            metrics = jax.device_get(metrics)
            timings = {"chunk_s": chunk_s, "eval_s": eval_s, "compile_s": compile_s,
                       "wall_s": time.perf_counter() - start}  # fmt: skip
            chunk_records = []
            for i, d in enumerate(dirs):
                evaluation = summarize(members.member(results, i), trainer.env.dt)
                record = make_record(step, evaluation, members.member(metrics, i), timings,
                                     trainer.steps_per_chunk)  # fmt: skip
                bad = guards[i].check(record, members.member(states, i))
                if bad:
                    raise _diverged(members, d, step, bad)
                chunk_records.append(record)
            for i, (d, record) in enumerate(zip(dirs, chunk_records, strict=True)):
                # Rates per member: a population's aggregate is len(dirs) times these.
                write_step(d, step, members.member(states, i), record, writers[i])
                guards[i].observe(record)
                records[i] = record
            # The latest chunk's rate: the first chunks are faster (warm-up makes no updates).
            chunks_left = -(-(total - step) // trainer.steps_per_chunk)
            eta = f"ETA {chunks_left * (chunk_s + eval_s) / 60:6.1f} min"
            log(_progress(step, total, records, len(dirs) * trainer.steps_per_chunk / chunk_s,
                          eta))  # fmt: skip
        if stop.received is not None and members.env_steps(states) < total:
            raise stopped_error(stop, dirs[0], resume_dir)
    finally:
        for w in writers:
            if w is not None:
                w.close()
    return records


def _progress(step: int, total: int, records: list[dict], rate: float, eta: str) -> str:
    """The log line of a chunk: one run's return and feedback, or a population's spread."""
    if len(records) == 1:
        r = records[0]
        return (f"step {step:>8d}/{total} | return {r['return']:9.2f} | feedback "
                f"{r['feedback_norm']:8.3f} | {rate:7.0f} env steps/s | {eta}")  # fmt: skip
    returns = np.asarray([r["return"] for r in records])
    return (f"step {step:>8d}/{total} | return {returns.mean():9.2f} (min {returns.min():.1f}, "
            f"max {returns.max():.1f}) over {len(records)} members | {rate:8.0f} env steps/s "
            f"in all | {eta}")  # fmt: skip


def _diverged(members: Members, run_dir: str, step: int, bad: list[str]) -> DivergedError:
    """The error of a chunk that diverged (``divergence.Guard``): nothing of it is written."""
    last = checkpoint.latest_step(run_dir)
    kept = f"checkpoint {last} is kept" if last is not None else "no checkpoint was written yet"
    if not members.batched:
        return DivergedError(
            f"training diverged at step {step} ({'; '.join(bad[:3])}); nothing of this chunk "
            f"was saved and {kept}. Lower alpha or the learning rates and continue: "
            f"{_resume_hint(run_dir)} --alpha A (or --set GROUP.LR=...)"
        )
    return DivergedError(
        f"member {os.path.basename(run_dir)} diverged at step {step} ({'; '.join(bad[:3])}); "
        f"nothing of this chunk was saved and every member's {kept}. Change that member's "
        "settings (its config.json) or train it alone"
    )


def stopped_error(
    stop: run_guard.StopSignals, run_dir: str, resume_dir: str | None = None
) -> StoppedError:
    """The error that ends a run stopped by a signal: what was saved (``run_dir``'s latest
    checkpoint) and the command that resumes it (on ``resume_dir``, default ``run_dir``)."""
    last = checkpoint.latest_step(run_dir)
    saved = f"checkpoint {last} is complete" if last is not None else "nothing was trained yet"
    name = signal.Signals(stop.received).name
    hint = _resume_hint(resume_dir or run_dir)
    return StoppedError(f"stopped by {name}: {saved}; resume with: {hint}", stop.exit_status)


ENGINES = ("mjx", "mujoco")


def evaluate_run(
    run_dir: str,
    task_set_name: str | None,
    episodes: int | None,
    seed: int = 0,
    task_specs: tuple[str, ...] = (),
    engine: str = "mjx",
) -> dict[str, Any]:
    """Evaluates the latest policy of ``run_dir`` (``checkpoint.load_policy``: no trainer, no
    buffers) on a task set or custom tasks; returns the metrics. ``engine`` "mjx" evaluates in
    the run's own environment, "mujoco" in Gymnasium's v5 environment on the MuJoCo C engine
    (``mujoco_engine``) with the same tasks and metrics."""
    if engine not in ENGINES:
        raise RunError(f"unknown engine {engine!r}; choose from {', '.join(ENGINES)}")
    try:
        policy = checkpoint.load_policy(run_dir)
    except checkpoint.CheckpointError as e:
        raise RunError(str(e)) from None
    config, env = policy.config, policy.env
    if episodes is not None and (isinstance(episodes, bool) or not isinstance(episodes, int)
                                 or episodes < 1):  # fmt: skip
        raise RunError(f"episodes must be a positive integer (or None: the run's "
                       f"{config.eval_episodes}), got {episodes!r}")  # fmt: skip
    episodes = episodes or config.eval_episodes
    name = task_set_name or config.task_set
    try:
        envs.check_task_set_name(name)
        tasks, labels = envs.resolve_tasks(env, name, task_specs)
    except (envs.UnknownNameError, envs.TaskSpecError) as e:
        raise RunError(str(e)) from None
    if engine == "mujoco":
        if config.meta_episodes > 1:
            raise RunError(f"{run_dir} trains in meta-episodes of {config.meta_episodes} "
                           "episodes; the C-engine evaluation runs plain episodes: evaluate it "
                           "with --engine mjx")  # fmt: skip
        if policy.family.recurrent:
            raise RunError(
                f"{run_dir} is a {config.algo} run: its policy is recurrent, and the C-engine "
                "evaluation steps memoryless policies; evaluate it with --engine mjx"
            )
        try:
            metrics = mujoco_engine.evaluate(policy, tasks, episodes, seed)
        except (ValueError, mujoco_engine.MissingExtraError) as e:
            raise RunError(str(e)) from None
    else:
        # One evaluator per program and episode count: runs of one program (seeds, stages,
        # data values) evaluate without tracing and compiling again.
        evaluator = keep_latest(
            _EVALUATORS, (program_key(config), episodes),
            lambda: make_evaluator(env, policy.family.deterministic, config.episode_limit,
                                   episodes),
        )  # fmt: skip
        result = evaluator(policy.actor_params, policy.normalizer, jax.random.PRNGKey(seed),
                           envs.stack_tasks(tasks))  # fmt: skip
        metrics = summarize(jax.device_get(result), env.dt)
    variant = ";".join(labels) if task_specs else name
    return {"run_dir": run_dir, "step": policy.step, "variant": variant, "episodes": episodes,
            "engine": engine, **metrics}  # fmt: skip
