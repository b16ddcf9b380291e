"""Populations: many agents (seeds x swept values) trained in one compiled program.

A population is a list of member configurations (``expand``: seeds x the cartesian grid of swept
values). Members that differ only in their seed and their agent's *hyper* values (the agent's
``AgentSpec.hyper``: the MA weight, the SAC learning rates, the inner step size; and the MA mode,
full / Jacobian-only / temporal-only, as 0/1 term weights) share one program: their train states
are stacked on a leading axis and every iteration is vmapped over it (the trainer's
``run_chunk``, whatever the agent), so sweeping those values never recompiles. Members that
differ in anything else (network sizes, ensemble size, rollout batch, algorithm, ...) form
separate groups, compiled once each and trained one after another.

The schedule (warm-up, model refits, update start) is a function of the env-step counter, which
all members of a group share: it is passed unbatched, so every ``lax.cond`` of the schedule stays
a branch under ``vmap`` instead of a select that would run both sides for every member.

Members are sharded over all local devices (``jax.sharding``, a mesh over the population axis)
when there are several and their number divides the population. Over several processes or hosts
(``jax.distributed``: ``minatt-jax train --distributed`` or ``--coordinator/--num-processes/
--process-id``) each process trains a contiguous share of every group on its own devices
(``share``): members never exchange anything, so no collective crosses hosts, and member ``i``
lands on the same process and device slot as on one host with that many devices.

Each member has its own run directory (config.json with its own values, metrics.jsonl,
TensorBoard, checkpoints, policy snapshots), so ``evaluate``, ``meta-test`` and ``analyze`` read
members exactly as single runs; the population directory holds ``population.json``, the index.
"""

from __future__ import annotations

import contextlib
import functools
import itertools
import json
import os
import time
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from minatt_jax import checkpoint, memory, run_guard, runner
from minatt_jax import min_attention as ma
from minatt_jax.agents.base import config_field, hyper_values
from minatt_jax.config import TrainConfig, apply_overrides, replace_fields, resolve
from minatt_jax.run_files import (
    RunError,
    load_config,
    write_json_atomic,
)
from minatt_jax.training import Trainer, program_key


def parse_seeds(text: str) -> list[int]:
    """``"0-9"``, ``"0,3,5"`` or ``"0-3,7"`` -> a sorted list of distinct seeds (ValueError for
    an empty list or a seed given twice: a population would silently hold fewer members)."""
    if not text.strip():
        raise ValueError("seeds is empty; give them like 0-9 or 0,3,5")
    seeds: set[int] = set()
    for part in text.split(","):
        part = part.strip()
        lo, dash, hi = part.partition("-")
        try:
            first, last = int(lo), int(hi) if dash else int(lo)
        except ValueError:
            raise ValueError(f"seeds must look like 0-9 or 0,3,5; got {text!r}") from None
        if first < 0 or last < first:
            raise ValueError(f"seeds must be >= 0 and ranges ascending; got {part!r}")
        twice = seeds.intersection(range(first, last + 1))
        if twice:
            raise ValueError(f"seed {min(twice)} is given twice in {text!r}")
        seeds.update(range(first, last + 1))
    return sorted(seeds)


def expand(base: TrainConfig, seeds: list[int], sweeps: list[str]) -> list[TrainConfig]:
    """The members: every seed x every combination of the swept values (each resolved).

    ``sweeps`` are ``"group.field=v1,v2,..."`` strings (values typed from the dataclasses, as
    ``--set``); a field may be swept once.
    """
    if not seeds:
        raise ValueError("a population needs at least one seed")
    if len(set(seeds)) != len(seeds):
        twice = next(s for s in seeds if list(seeds).count(s) > 1)
        raise ValueError(f"seed {twice} is given twice: each member needs its own seed")
    grid: list[list[str]] = []
    names: list[str] = []
    for sweep in sweeps:
        key, sep, values = sweep.partition("=")
        key = key.strip()
        if not sep or not values.strip():
            raise ValueError(f"sweep {sweep!r} must look like group.field=v1,v2,...")
        if key in names:
            raise ValueError(f"{key} is swept twice")
        if key == "seed":
            raise ValueError("seeds are set with --seeds, not swept")
        names.append(key)
        grid.append([f"{key}={v.strip()}" for v in _split_values(values)])
    members = []
    for combo in itertools.product(*grid) if grid else [()]:
        swept = apply_overrides(base, list(combo))
        for seed in seeds:
            members.append(resolve(replace_fields(swept, {"seed": seed})))
    return members


def _split_values(text: str) -> list[str]:
    """Values of a sweep: commas separate values except inside parentheses (tuples)."""
    out, depth, current = [], 0, ""
    for ch in text:
        depth += ch == "("
        depth -= ch == ")"
        if ch == "," and depth == 0:
            out.append(current)
            current = ""
        else:
            current += ch
    return [v for v in [*out, current] if v.strip()]


def groups(members: list[TrainConfig]) -> list[list[int]]:
    """Member indices grouped by program, in first-appearance order."""
    order: dict[str, list[int]] = {}
    for i, m in enumerate(members):
        order.setdefault(program_key(m, ma_structure=False), []).append(i)
    return list(order.values())


def share(indices: list[int], process: int, processes: int) -> list[int]:
    """Process ``process``'s contiguous block of a group's members (``np.array_split``)."""
    return [int(i) for i in np.array_split(np.asarray(indices, int), processes)[process]]


def this_process() -> tuple[int, int]:
    """(index, count) of this process among the population's (``jax.distributed``; (0, 1))."""
    return jax.process_index(), jax.process_count()


def member_name(config: TrainConfig, swept: list[str]) -> str:
    """A run-directory name from the swept fields' values and the seed."""
    parts = [config.algo]
    for key in swept:
        value = config_field(config, key)
        if isinstance(value, float):  # the short form, unless it would merge two values
            text = f"{value:g}" if float(f"{value:g}") == value else repr(value)
        else:
            text = str(value).replace(" ", "")
        parts.append(f"{key.split('.')[-1]}{text}")
    parts.append(f"seed{config.seed}")
    return "_".join(parts)


class Program:
    """One group's compiled functions: init, the vmapped chunk and the vmapped evaluation."""

    def __init__(self, members: list[TrainConfig]) -> None:
        configs = members
        # MA terms are computed when any member uses them (the program's MA structure: the
        # largest alpha's activity, the union of the modes); alpha = 0 members weigh them by 0,
        # members whose mode leaves a term out weigh it by 0 (their hyper "ma_terms").
        alpha = max(c.ma.alpha for c in configs)
        modes = {c.ma.mode for c in configs}
        mode = modes.pop() if len(modes) == 1 else ma.union_mode([c.ma for c in configs])
        self.config = replace_fields(configs[0], {"ma.alpha": alpha, "ma.mode": mode})
        # The trainer and this program's compiled functions are the process's (runner.trainer_for):
        # populations and single runs of one program in a process build them once.
        self.trainer, self.compiled = runner.trainer_for(self.config)
        self.members = configs
        self.length = max(c.total_steps for c in configs)  # env steps the group trains to
        t = self.trainer
        if "bytes_per_member" not in self.compiled:
            self.compiled["bytes_per_member"] = memory.state_bytes(t)
        self.bytes_per_member: int = self.compiled["bytes_per_member"]
        self.sharding = self._member_sharding()
        functions = ("population functions", self.sharding)
        if functions not in self.compiled:
            self.compiled[functions] = _population_functions(t, self.sharding)
        self._init, self.chunk, self.evaluate = self.compiled[functions]

    def compiled_chunk(self, states: Any, log: Callable[[str], None]) -> Any:
        """The chunk compiled for ``states`` (these members, this placement), once per process."""
        key = ("population chunk", self.sharding, len(self.members))
        what = f"population step ({len(self.members)} members)"
        return runner.compiled_once(self.compiled, key, self.chunk, states, what, log)

    def init(self) -> Any:
        """Every member's initial state (its seed's, with its hyper values), stacked. As for
        single runs, every leaf gets its own buffer (the state is donated to the chunk)."""
        keys = jnp.stack([jax.random.PRNGKey(c.seed) for c in self.members])
        spec = self.trainer.spec
        values = stack([hyper_values(spec, c) for c in self.members])
        states = self._init(keys, values)
        return self.place(jax.tree.map(lambda x: jnp.array(x, copy=True), states))

    def _member_sharding(self) -> jax.sharding.Sharding | None:
        """A 1-D mesh over the population axis on all local devices, when there are several
        and they divide the population (else None: one device)."""
        devices = jax.local_devices()
        if len(devices) < 2 or len(self.members) % len(devices):
            return None
        mesh = jax.sharding.Mesh(np.asarray(devices), ("members",))
        return jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("members"))

    def place(self, states: Any) -> Any:
        """The stacked states split over the devices (``_member_sharding``), if several."""
        return states if self.sharding is None else jax.device_put(states, self.sharding)


def _population_functions(
    t: Trainer, sharding: jax.sharding.Sharding | None
) -> tuple[Callable, Callable, Callable]:
    """The jitted, vmapped init (keys, hyper values), chunk and evaluation of a trainer."""

    def chunk(states: Any) -> tuple[Any, dict]:
        return t.run_chunk(states, states.env_steps[0], True)

    if sharding is None:
        jitted_chunk = jax.jit(chunk, donate_argnums=0)
    else:  # states and per-member metrics stay split over the devices, chunk after chunk
        jitted_chunk = jax.jit(chunk, donate_argnums=0, in_shardings=sharding,
                               out_shardings=sharding)  # fmt: skip
    evaluate = jax.jit(jax.vmap(t.evaluate, in_axes=(0, 0, None)))
    return jax.jit(jax.vmap(t.init_state)), jitted_chunk, evaluate


def check_memory(per_member: int, members: int) -> None:
    """RunError before compiling when ``members`` states of ``per_member`` bytes cannot fit
    (``memory.check_states``)."""
    memory.check_states(per_member, members, f"{members} members")


def _finished(program: Program, dirs: list[str]) -> bool:
    """Whether every member of the group already has a checkpoint at its length."""
    return all((s := checkpoint.latest_step(d)) is not None and s >= program.length for d in dirs)


def member(states: Any, i: int) -> Any:
    """Member ``i`` of stacked states."""
    return jax.tree.map(lambda x: x[i], states)


@functools.partial(jax.jit, donate_argnums=0)
def _set_member(states: Any, one: Any, i: jax.Array) -> Any:
    """``states`` with member ``i`` replaced by ``one``, in place (the stacked states are donated):
    a resume holds the population once plus one member, not the restored list and its stack."""
    return jax.tree.map(lambda stacked, x: stacked.at[i].set(x), states, one)


def stack(states: list[Any]) -> Any:
    """Member states stacked on a new leading axis."""
    return jax.tree.map(lambda *xs: jnp.stack(xs), *states)


def train_population(
    members: list[TrainConfig],
    out_dir: str,
    swept: list[str],
    resume: bool = False,
    log: Callable[[str], None] = print,
    process: tuple[int, int] | None = None,
    after_group: Callable[[list[str]], None] | None = None,
) -> list[dict[str, Any]]:
    """Trains (or resumes) this process's share of every group (all members in one process),
    group by group; returns each member's last record ({} for other processes' members).
    ``after_group(run_dirs)`` is called as each group finishes, e.g. to keep its members' results
    elsewhere, so that losing the machine later loses only the group in progress."""
    rank, processes = process or this_process()
    names = [member_name(c, swept) for c in members]
    if len(set(names)) != len(names):
        raise RunError("two members would share a run directory; sweep distinct values")
    dirs = [os.path.join(out_dir, n) for n in names]
    index_path = os.path.join(out_dir, "population.json")
    index = {
        "members": [
            {"run_dir": n, **{k: config_field(c, k) for k in swept}, "seed": c.seed}
            for n, c in zip(names, members, strict=True)
        ],  # fmt: skip
        "swept": swept,
        "groups": groups(members),
        "processes": processes,
    }
    mine = [share(indices, rank, processes) for indices in index["groups"]]
    # Built first: a population that cannot fit is refused before anything is written.
    programs = [Program([members[i] for i in own]) if own else None for own in mine]
    for own, program in zip(mine, programs, strict=True):  # groups already trained need none
        if program is not None and not (resume and _finished(program, [dirs[i] for i in own])):
            check_memory(program.bytes_per_member, len(program.members))
    own_members = [i for own in mine for i in own]
    last: list[dict[str, Any]] = [{} for _ in members]
    lock = ".lock" if processes == 1 else f".lock-process{rank}"
    with contextlib.ExitStack() as held:
        # Everything below, the checks of a resumed population included, runs under the lock:
        # a second process on the same population is refused before it writes anything.
        try:
            held.enter_context(run_guard.lock_run(out_dir, lock))
        except run_guard.RunLockedError as e:
            raise RunError(str(e)) from None
        except OSError as e:
            raise _unwritable(out_dir, e) from None
        hint = f"minatt-jax train --out {out_dir} --resume"
        stop = held.enter_context(run_guard.StopSignals(hint))
        own_dirs = [dirs[i] for i in own_members]
        plans: dict[int, ResumePlan] = {}
        if resume:  # every file a resume reads is read (and checked) before anything is written
            changed = _check_resumed([members[i] for i in own_members], own_dirs, index_path,
                                     index if rank == 0 else None)  # fmt: skip
            for g, (own, program) in enumerate(zip(mine, programs, strict=True)):
                if program is not None:
                    plans[g] = _resume_plan(program, [dirs[i] for i in own])
            for plan in plans.values():
                plan.apply(log)
            for member, run_dir in changed:
                write_json_atomic(os.path.join(run_dir, "config.json"), member.to_dict())
        else:
            _write_members([members[i] for i in own_members], own_dirs, index_path,
                           index if rank == 0 else None)  # fmt: skip
        for g, (indices, program) in enumerate(zip(mine, programs, strict=True)):
            if program is None:
                continue  # more processes than this group has members
            group = program.members
            mib = program.bytes_per_member / 2**20
            on = f" (process {rank + 1}/{processes})" if processes > 1 else ""
            log(f"group {g + 1}/{len(index['groups'])}: {len(group)} members{on} "
                f"({group[0].algo}, {group[0].env}), {mib:.0f} MiB of state each")  # fmt: skip
            records = _train_group(program, [dirs[i] for i in indices], plans.get(g), log, stop)
            for i, r in zip(indices, records, strict=True):
                last[i] = r
            if after_group is not None:
                after_group([dirs[i] for i in indices])
    return last


def stored_members(
    out_dir: str, total_steps: int | None = None
) -> tuple[list[TrainConfig], list[str]]:
    """The members and swept fields of the population in ``out_dir`` (its ``population.json`` and
    the members' ``config.json``), to resume it; ``total_steps`` sets a new length. RunError when
    there is no population there or a member's configuration cannot be read."""
    index_path = os.path.join(out_dir, "population.json")
    if not os.path.exists(index_path):
        raise RunError(f"{out_dir} holds no population to resume (no population.json)")
    try:
        with open(index_path) as f:
            index = json.load(f)
        names, swept = [m["run_dir"] for m in index["members"]], list(index["swept"])
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise RunError(f"{index_path} cannot be read as a population index: {e}") from None
    members = [load_config(os.path.join(out_dir, n)) for n in names]
    if total_steps is not None:  # the length may change on resume (train_population)
        members = [replace_fields(m, {"total_steps": total_steps}) for m in members]
    return members, swept


def _check_resumed(members: list[TrainConfig], dirs: list[str], index_path: str,
                   index: dict[str, Any] | None) -> list[tuple[TrainConfig, str]]:  # fmt: skip
    """Checks a resumed population's members against ``members`` (only the length and the chunk
    length may change, as for single runs) and returns the (member, run_dir) pairs whose
    ``config.json`` the resume rewrites. Reads only: the caller writes once everything is read."""
    out_dir = os.path.dirname(index_path)
    if index is not None and not os.path.exists(index_path):
        raise RunError(f"{out_dir} holds no population to resume (no population.json)")
    if os.path.exists(index_path):
        with open(index_path) as f:
            started = {m["run_dir"] for m in json.load(f)["members"]}
        if new := [os.path.basename(d) for d in dirs if os.path.basename(d) not in started]:
            raise RunError(f"{out_dir} holds a population started without "
                           f"{', '.join(new[:3])}{' ...' if len(new) > 3 else ''}: a resume "
                           "goes on with the members it started with; train the others "
                           "under another folder")  # fmt: skip
    stored = [load_config(d) for d in dirs]
    for member, old, run_dir in zip(members, stored, dirs, strict=True):
        if runner.with_stored_schedule(member, old).to_dict() != old.to_dict():
            raise RunError(f"{run_dir} was made with other settings; see its config.json")
    return [(member, run_dir) for member, old, run_dir in zip(members, stored, dirs, strict=True)
            if member.to_dict() != old.to_dict()]  # fmt: skip


def _write_members(members: list[TrainConfig], dirs: list[str], index_path: str,
                   index: dict[str, Any] | None) -> None:  # fmt: skip
    """Writes a new population's member configurations and (``index`` given: process 0) its
    index."""
    out_dir = os.path.dirname(index_path)
    if index is not None and os.path.exists(index_path):
        raise RunError(f"{out_dir} already holds a population; pass --resume or another --out")
    try:
        for member, run_dir in zip(members, dirs, strict=True):
            os.makedirs(run_dir, exist_ok=True)
            write_json_atomic(os.path.join(run_dir, "config.json"), member.to_dict())
        if index is not None:
            write_json_atomic(index_path, index)
    except OSError as e:
        raise _unwritable(out_dir, e) from None


def _unwritable(out_dir: str, error: OSError) -> RunError:
    return RunError(f"cannot write the population into {out_dir}: {error.strerror or error}")


def train_in_stages(
    members: list[TrainConfig],
    out_dir: str,
    swept: list[str],
    stages: list[int],
    at_stage: Callable[[int, list[str]], None] | None = None,
    log: Callable[[str], None] = print,
) -> list[str]:
    """Trains the population to each of ``stages`` env steps in turn (resuming whatever exists
    under ``out_dir``) and calls ``at_stage(step, run_dirs)`` after each, e.g. to meta-test the
    latest checkpoints, which are the only ones kept. Returns the members' run directories."""
    dirs = [os.path.join(out_dir, member_name(c, swept)) for c in members]
    for step in stages:
        staged = [replace_fields(c, {"total_steps": step}) for c in members]
        resume = os.path.exists(os.path.join(out_dir, "population.json"))
        train_population(staged, out_dir, swept, resume=resume, log=log)
        if at_stage is not None:
            at_stage(step, dirs)
    return dirs


class ResumePlan(NamedTuple):
    """Where a resumed group goes on: the newest checkpoint step every member has and can read
    (None: no member has one, training starts again), the checkpoints that step leaves behind
    (unreadable ones and ones ahead of the others, set aside by ``apply``) and every member's
    records as read."""

    step: int | None
    unreadable: list[tuple[str, int, str]]  # (member dir, step, why)
    ahead: list[tuple[str, int]]
    records: list[list[dict[str, Any]]]

    def apply(self, log: Callable[[str], None]) -> None:
        """Sets the skipped checkpoints aside (kept, out of ``checkpoints/``) and says so."""
        for d, step, why in self.unreadable:
            where = checkpoint.set_aside(d, step)
            log(f"{os.path.basename(d)}: checkpoint {step} is unreadable ({why}); kept in "
                f"{where}")  # fmt: skip
        for d, step in self.ahead:
            checkpoint.set_aside(d, step, folder="checkpoints_ahead")
        if self.ahead or self.unreadable:
            log(f"every member resumes from checkpoint {self.step} (the newest one all of them "
                "have and can read; newer ones are kept in <member>/checkpoints_ahead or "
                "checkpoints_unreadable)")  # fmt: skip


def _resume_plan(program: Program, dirs: list[str]) -> ResumePlan:
    """Reads every member's records and, newest first, each step's checkpoints of all members
    (a dry restore, one member at a time) until one step reads back for every member. RunError
    when the members have checkpoints but no step common to all of them reads back."""
    records = [runner.read_metrics(d) for d in dirs]
    have = [checkpoint.all_steps(d) for d in dirs]
    if not any(have):
        return ResumePlan(None, [], [], records)
    common = sorted(set.intersection(*map(set, have)), reverse=True)
    if common and common[0] >= program.length:  # finished: nothing is restored or trained
        return ResumePlan(common[0], [], [], records)
    like = member(program.init(), 0)
    unreadable: dict[tuple[str, int], str] = {}
    for step in common:
        for d in dirs:
            try:
                checkpoint.restore(d, like, step)
            except checkpoint.CheckpointError as e:
                unreadable[(d, step)] = str(e)
        if not any(key[1] == step for key in unreadable):
            newer = [(d, s) for d, steps in zip(dirs, have, strict=True) for s in steps
                     if s > step]  # fmt: skip
            return ResumePlan(step,
                              [(d, s, unreadable[d, s]) for d, s in newer if (d, s) in unreadable],
                              [(d, s) for d, s in newer if (d, s) not in unreadable],
                              records)  # fmt: skip
    latest = sorted({str(steps[-1]) if steps else "none" for steps in have})
    why = next(iter(unreadable.values()), "")
    raise RunError(f"no checkpoint step common to all members reads back (latest: "
                   f"{', '.join(latest)}){': ' + why if why else ''}; the population is "
                   "unchanged")  # fmt: skip


def _train_group(
    program: Program,
    dirs: list[str],
    plan: ResumePlan | None,
    log: Callable[[str], None],
    stop: run_guard.StopSignals,
) -> list[dict[str, Any]]:
    """Trains one group from its start or from ``plan`` (a resume, read and checked before)."""
    config, trainer = program.config, program.trainer
    step = plan.step if plan is not None else None
    if step is not None and step >= program.length:
        log(f"{len(dirs)} members already at env step {step}")  # no restore, no compile
        return [(records or [{}])[-1] for records in plan.records]
    if step is not None:
        runner.check_on_chunk_grid(step, config.eval_every, os.path.dirname(dirs[0]))
    states = run_guard.interruptible(program.init, "starting")
    if plan is not None:
        if step is not None:
            for i, d in enumerate(dirs):  # into the stacked states, one member at a time
                try:
                    one = checkpoint.restore(d, member(states, i), step)[1]
                except checkpoint.CheckpointError as e:
                    raise RunError(str(e)) from None
                states = _set_member(states, one, jnp.int32(i))
                del one
            states = program.place(states)
        for d, kept in zip(dirs, plan.records, strict=True):
            runner.keep_metrics_until(d, step or 0, kept)
        log(f"resumed {len(dirs)} members at env step {step or 0}")
    t0 = time.perf_counter()
    chunk = program.compiled_chunk(states, log)
    members = runner.Members(trainer, program.members, dirs, chunk, program.evaluate,
                             batched=True)  # fmt: skip
    out_dir = os.path.dirname(os.path.abspath(dirs[0]))
    return runner.train_chunks(members, states, time.perf_counter() - t0, stop, log, out_dir)


__all__ = [
    "Program",
    "expand",
    "groups",
    "member_name",
    "parse_seeds",
    "share",
    "stored_members",
    "this_process",
    "train_in_stages",
    "train_population",
]
