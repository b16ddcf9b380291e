"""Checkpoints of the train state as named items (atomic: orbax writes, then renames).

Format 2. Every array of the state is saved under its key path, e.g.
``agent/actor_params/params/Dense_0/kernel``, ``collector/env_state/obs``, ``data/real/size``,
``model/params/...``, ``meta/...`` (the top-level items: agent, collector, data, model, meta and
the counters). Beside the arrays each checkpoint holds a small JSON ``manifest``: the format
version and every item's shape and dtype, so a tool can list what is inside (``describe``)
without reading arrays. Consequences:

* restoring into a template of another structure fails with one line that names the items that
  differ (missing, unexpected, or of another shape), never by loading values into wrong fields;
* one subtree can be read alone (``restore_items``), e.g. the agent without the replay buffers;
* policy snapshots (one small ``.npz`` per evaluation) use the same key paths for the actor and
  the observation normalizer, and ``load_policy`` reads them without building a trainer.

Zero-size leaves, which orbax refuses and MJX's physics data has several of, are not saved and
are taken from the template on restore.
"""

from __future__ import annotations

import logging
import os
import re
import shutil
import sys
import tempfile
import time
from typing import Any, NamedTuple

import jax
import numpy as np
import orbax.checkpoint as ocp

from minatt_jax import run_files, run_guard
from minatt_jax.config import TrainConfig

FORMAT = 2


class CheckpointError(Exception):
    """A missing, corrupt or incompatible checkpoint (a user-facing error)."""


def _key_name(entry: Any) -> str:
    for attr in ("name", "key", "idx"):
        if hasattr(entry, attr):
            return str(getattr(entry, attr))
    return str(entry)


def named_leaves(tree: Any) -> dict[str, Any]:
    """``{"a/b/c": leaf}`` for every leaf of ``tree`` (None subtrees have no leaves)."""
    flat, _ = jax.tree_util.tree_flatten_with_path(tree)
    return {"/".join(_key_name(k) for k in path): leaf for path, leaf in flat}


def _nest(flat: dict[str, Any]) -> dict[str, Any]:
    nested: dict[str, Any] = {}
    for name, value in flat.items():
        node = nested
        *parents, last = name.split("/")
        for p in parents:
            node = node.setdefault(p, {})
        node[last] = value
    return nested


def _flatten(nested: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in nested.items():
        name = f"{prefix}/{k}" if prefix else k
        if isinstance(v, dict):
            out.update(_flatten(v, name))
        else:
            out[name] = v
    return out


def _manifest(items: dict[str, Any]) -> dict[str, Any]:
    return {
        "format": FORMAT,
        "items": {k: {"shape": list(np.shape(v)), "dtype": str(v.dtype)} for k, v in items.items()},
    }


def _manager(run_dir: str, create: bool) -> ocp.CheckpointManager:
    path = os.path.join(os.path.abspath(run_dir), "checkpoints")
    options = ocp.CheckpointManagerOptions(max_to_keep=2, create=create)
    if jax.process_count() > 1:
        # Every run directory belongs to one process, also in a population split over processes
        # (jax.distributed): orbax must not wait for the other processes at its barriers, and
        # then leaves making the folder to us.
        index = jax.process_index()
        alone = ocp.options.MultiprocessingOptions(
            primary_host=index, active_processes={index}, barrier_sync_key_prefix=f"p{index}"
        )
        options = ocp.CheckpointManagerOptions(max_to_keep=2, create=False,
                                               multiprocessing_options=alone)  # fmt: skip
        if create:
            os.makedirs(path, exist_ok=True)
    return ocp.CheckpointManager(
        path,
        options=options,
        item_names=("state", "manifest"),
    )


class _QuietAbsl:
    """Silences absl's logger (orbax's ``ERROR:absl`` lines) while we report errors ourselves."""

    def __enter__(self) -> None:
        self.logger = logging.getLogger("absl")
        self.level = self.logger.level
        self.logger.setLevel(logging.CRITICAL)

    def __exit__(self, *exc: Any) -> None:
        self.logger.setLevel(self.level)


class _AbandonedReads(logging.Filter):
    """Drops asyncio's "Future exception was never retrieved" for a tensorstore read that
    failed: orbax abandons its other reads once one fails, and each logs, whenever it is
    collected, the error our one line (CheckpointError) already reports."""

    def filter(self, record: logging.LogRecord) -> bool:
        text = record.getMessage()
        return not ("exception was never retrieved" in text and "OCDBT" in text)


logging.getLogger("asyncio").addFilter(_AbandonedReads())


# Printed by orbax's asyncio machinery when a read or write fails: tensorstore's callbacks reach
# an event loop orbax has already closed, each printing a traceback from a native thread (the
# threads' writes interleave, so the pieces are removed wherever they fall).
_LOOP_CLOSED = re.compile(
    r"Traceback \(most recent call last\):|File \"[^\"]*asyncio/base_events\.py\", line \d+, "
    r"in \w+|self\._check_closed\(\)|raise RuntimeError\('Event loop is closed'\)|"
    r"RuntimeError: Event loop is closed|RuntimeError:?|Event loop is closed"
)


# What those tracebacks say, whole: a leftover piece of them (a line cut by another thread's
# write) is one of its substrings.
_LOOP_CLOSED_TEXT = (
    'Traceback (most recent call last): File "asyncio/base_events.py", line 806, in '
    "call_soon_threadsafe self._check_closed() line 519, in _check_closed raise "
    "RuntimeError('Event loop is closed') RuntimeError: Event loop is closed"
)


class _QuietLoopErrors:
    """Captures file descriptor 2 around an orbax call and, when the call failed, drops the
    "Event loop is closed" tracebacks its native callbacks print (after a moment for the late
    ones), passing every other line on: a failed read or write then ends in our one line."""

    def __enter__(self) -> None:
        sys.stderr.flush()
        self.saved = os.dup(2)
        self.capture = tempfile.TemporaryFile()
        os.dup2(self.capture.fileno(), 2)
        self.real = run_guard.real_stderr(self.saved)  # a signal's line still reaches the user
        self.real.__enter__()

    def __exit__(self, kind: Any, *exc: Any) -> None:
        if kind is not None:
            time.sleep(0.3)  # the callbacks of the failed operation's pending reads
        sys.stderr.flush()
        os.dup2(self.saved, 2)
        self.real.__exit__(None, None, None)
        os.close(self.saved)
        self.capture.seek(0)
        text = self.capture.read().decode(errors="replace")
        self.capture.close()
        if kind is not None:
            text = _LOOP_CLOSED.sub("", text)
        kept = [line for line in text.splitlines() if any(c.isalnum() for c in line)
                and not (kind is not None and line.strip() in _LOOP_CLOSED_TEXT)]  # fmt: skip
        if kept:
            sys.stderr.write("\n".join(kept) + "\n")
            sys.stderr.flush()


def save(run_dir: str, step: int, state: Any) -> None:
    """Saves ``state`` as checkpoint ``step`` and waits until it is on disk.

    Orbax writes into a temporary directory and renames it when complete, so a crash or a full
    disk never leaves a half checkpoint that reads as complete. Raises CheckpointError (one line,
    orbax's own log lines silenced) when the checkpoint was not written."""
    # As host arrays: orbax refuses to write process-local device arrays when several processes
    # run (jax.distributed); the values read back are numpy arrays in any case.
    items = {k: v for k, v in jax.device_get(named_leaves(state)).items() if np.size(v) > 0}
    try:
        with _QuietLoopErrors(), _QuietAbsl(), _manager(run_dir, create=True) as manager:
            saved = manager.save(
                step,
                args=ocp.args.Composite(
                    state=ocp.args.PyTreeSave(_nest(items)),
                    manifest=ocp.args.JsonSave(_manifest(items)),
                ),
            )
            manager.wait_until_finished()
    except Exception as e:  # noqa: BLE001 - orbax and tensorstore raise many types on a write
        _remove_temporary(run_dir, step)
        why = e.strerror if isinstance(e, OSError) and e.strerror else _first_line(e)
        raise CheckpointError(
            f"checkpoint {step} could not be written in {run_dir}: {why}; the previous "
            "checkpoint is intact"
        ) from None
    if not saved:
        raise CheckpointError(
            f"checkpoint {step} was not written in {run_dir}: a checkpoint at or after it exists"
        )


def _remove_temporary(run_dir: str, step: int) -> None:
    """Removes what a failed save left: orbax's temporary folder of ``step``."""
    directory = os.path.join(run_dir, "checkpoints")
    if os.path.isdir(directory):
        for name in os.listdir(directory):
            if name.startswith(f"{step}.orbax-checkpoint-tmp"):
                shutil.rmtree(os.path.join(directory, name), ignore_errors=True)


def _first_line(error: Exception) -> str:
    """An exception's message, first line (tensorstore's messages run to many lines)."""
    text = str(error).strip().splitlines()
    return text[0] if text else type(error).__name__


def latest_step(run_dir: str) -> int | None:
    """The newest complete checkpoint's step, or None when there is none."""
    if not os.path.isdir(os.path.join(run_dir, "checkpoints")):
        return None
    with _manager(run_dir, create=False) as manager:
        return manager.latest_step()


def all_steps(run_dir: str) -> list[int]:
    """The steps of every complete checkpoint, ascending."""
    if not os.path.isdir(os.path.join(run_dir, "checkpoints")):
        return []
    with _manager(run_dir, create=False) as manager:
        return sorted(manager.all_steps())


def set_aside(run_dir: str, step: int, folder: str = "checkpoints_unreadable") -> str:
    """Moves checkpoint ``step`` (an unreadable one, or one ahead of its population's) out of
    ``checkpoints/`` into ``folder``, so training can go on from an older one and save over its
    step again; the files are kept for inspection. Returns where they went."""
    source = os.path.join(run_dir, "checkpoints", str(step))
    target_dir = os.path.join(run_dir, folder)
    os.makedirs(target_dir, exist_ok=True)
    target = os.path.join(target_dir, f"{step}-{os.getpid()}")
    os.replace(source, target)
    return target


def describe(run_dir: str, step: int | None = None) -> dict[str, Any]:
    """The manifest of checkpoint ``step`` (default: the latest): format and items."""
    step = _step(run_dir, step)
    try:
        with _QuietLoopErrors(), _QuietAbsl(), _manager(run_dir, create=False) as manager:
            restored = manager.restore(
                step, args=ocp.args.Composite(manifest=ocp.args.JsonRestore())
            )
        manifest = restored.manifest
    except Exception:  # noqa: BLE001 - orbax raises many types for missing or bad files
        manifest = None
    if not isinstance(manifest, dict) or "format" not in manifest:
        raise CheckpointError(
            f"checkpoint {step} in {run_dir} has no manifest: it is corrupt or of format 1 "
            f"(leaves by position, minatt-jax before named checkpoints); this version reads "
            f"format {FORMAT}"
        )
    if manifest["format"] != FORMAT:
        raise CheckpointError(
            f"checkpoint {step} in {run_dir} has format {manifest['format']}; this version "
            f"reads format {FORMAT}"
        )
    return {"step": step, **manifest}


def _step(run_dir: str, step: int | None) -> int:
    if step is None:
        step = latest_step(run_dir)
        if step is None:
            raise CheckpointError(f"no checkpoint in {run_dir}")
    elif step not in (steps := all_steps(run_dir)):
        have = ", ".join(map(str, steps)) or "none"
        raise CheckpointError(f"no checkpoint {step} in {run_dir} (it has: {have})")
    return step


# Checkpoints written before the agents' swept values moved into one ``hyper`` subtree hold
# them under these names, and no ``hyper`` items: those restore as the template's values, which
# every caller sets from the run's configuration (the run's own values, never a default).
LEGACY_ITEMS = ("ma_alpha", "ma_terms", "alpha", "inner_lr")


def _added_later(name: str) -> bool:
    return "/hyper/" in f"/{name}"


def _legacy(name: str) -> bool:
    return name.rsplit("/", 1)[-1] in LEGACY_ITEMS


def _check_items(
    run_dir: str, step: int, stored: dict[str, Any], wanted: dict[str, Any], prefix: str
) -> None:
    """One-line CheckpointError naming the items where the checkpoint and the template differ."""
    if prefix:
        stored = {k: v for k, v in stored.items() if k == prefix or k.startswith(prefix + "/")}
    wanted = {k: v for k, v in wanted.items() if np.size(v) > 0}
    missing = sorted(k for k in set(wanted) - set(stored) if not _added_later(k))
    hyper_stored = any(_added_later(k) for k in stored)
    extra = sorted(k for k in set(stored) - set(wanted) if hyper_stored or not _legacy(k))
    shapes = sorted(k for k in set(wanted) & set(stored)
                    if list(np.shape(wanted[k])) != stored[k]["shape"])  # fmt: skip
    problems = []
    for label, names in (("missing", missing), ("unexpected", extra), ("of another shape", shapes)):
        if names:
            more = f" and {len(names) - 3} more" if len(names) > 3 else ""
            problems.append(f"{label}: {', '.join(names[:3])}{more}")
    if problems:
        raise CheckpointError(
            f"checkpoint {step} in {run_dir} does not match this configuration ("
            + "; ".join(problems)
            + ")"
        )


def restore_items(run_dir: str, like: dict[str, Any], step: int | None = None) -> tuple[int, Any]:
    """Restores only the items ``like`` names: ``{"agent": template, "data/normalizer": ...}``.

    Each template gives the structure, shapes and dtypes; nothing else is read from disk.
    """
    step = _step(run_dir, step)
    stored = describe(run_dir, step)["items"]
    wanted: dict[str, Any] = {}
    for prefix, template in like.items():
        items = {f"{prefix}/{k}" if k else prefix: v for k, v in named_leaves(template).items()}
        _check_items(run_dir, step, stored, items, prefix)
        wanted.update({k: v for k, v in items.items() if np.size(v) > 0 and k in stored})
    # Shapes and dtypes only: copying the templates (replay buffers) to the host is not needed.
    abstract = _nest({k: jax.ShapeDtypeStruct(np.shape(v), v.dtype) for k, v in wanted.items()})
    restore_args = jax.tree.map(lambda _: ocp.RestoreArgs(restore_type=np.ndarray), abstract)
    try:
        with _QuietLoopErrors(), _QuietAbsl(), _manager(run_dir, create=False) as manager:
            restored = manager.restore(
                step,
                args=ocp.args.Composite(
                    state=ocp.args.PyTreeRestore(
                        item=abstract, restore_args=restore_args, partial_restore=True
                    )
                ),
            )
    except Exception as e:  # noqa: BLE001 - orbax raises many types for bad files
        raise CheckpointError(
            f"checkpoint {step} in {run_dir} is corrupt ({type(e).__name__}: "
            f"{str(e).splitlines()[0][:200] if str(e) else ''})"
        ) from None
    values = _flatten(restored.state)

    def leaf_value(name: str, template_leaf: Any) -> Any:
        if name in values:
            return jax.numpy.asarray(values[name])
        return jax.numpy.asarray(template_leaf)  # an empty item, or a hyper value (above)

    out = {}
    for prefix, template in like.items():
        leaves, treedef = jax.tree.flatten(template)
        names = [f"{prefix}/{k}" if k else prefix for k in named_leaves(template)]
        out[prefix] = jax.tree.unflatten(
            treedef, [leaf_value(n, leaf) for n, leaf in zip(names, leaves, strict=True)]
        )
    return step, out


def restore(run_dir: str, like: Any, step: int | None = None) -> tuple[int, Any]:
    """Restores checkpoint ``step`` (default: the latest) whole, into the structure of ``like``
    (a train state): every item must match (``hyper`` items may be absent: ``LEGACY_ITEMS``)."""
    step = _step(run_dir, step)
    stored = describe(run_dir, step)["items"]
    _check_items(run_dir, step, stored, named_leaves(like), "")
    fields = [f for f in like.__dataclass_fields__ if jax.tree.leaves(getattr(like, f))]
    step, parts = restore_items(run_dir, {f: getattr(like, f) for f in fields}, step)
    return step, like.replace(**parts)


# ---- policy snapshots -------------------------------------------------------------------------


def _snapshot_path(run_dir: str, step: int) -> str:
    return os.path.join(run_dir, "policy_snapshots", f"step_{step:09d}.npz")


def save_policy_snapshot(run_dir: str, step: int, actor_params: Any, normalizer: Any) -> str:
    """Saves the policy alone (actor parameters and observation normalizer) as a small .npz.

    Full checkpoints keep only the latest two (a model-based state with its buffers is hundreds
    of MB); these snapshots, one per evaluation, let analyses look at the policy at any step.
    Keys are the checkpoint's key paths (``agent/actor_params/...``, ``data/normalizer/...``).
    """
    directory = os.path.join(run_dir, "policy_snapshots")
    os.makedirs(directory, exist_ok=True)
    arrays = {
        **{f"agent/actor_params/{k}": np.asarray(v) for k, v in named_leaves(actor_params).items()},
        **{f"data/normalizer/{k}": np.asarray(v) for k, v in named_leaves(normalizer).items()},
        "format": np.asarray(FORMAT),
    }
    path = _snapshot_path(run_dir, step)
    run_files.write_npz_atomic(path, arrays)
    return path


def snapshot_steps(run_dir: str) -> list[int]:
    """The steps that have a policy snapshot, ascending."""
    directory = os.path.join(run_dir, "policy_snapshots")
    if not os.path.isdir(directory):
        return []
    return sorted(int(f[5:14]) for f in os.listdir(directory)
                  if f.startswith("step_") and f.endswith(".npz") and ".tmp" not in f)  # fmt: skip


def load_policy_snapshot(run_dir: str, step: int, like: tuple[Any, Any]) -> tuple[Any, Any]:
    """(actor_params, normalizer) of snapshot ``step``, in the structure of ``like``."""
    path = _snapshot_path(run_dir, step)
    try:
        with np.load(path) as f:
            stored = {k: f[k] for k in f.files}
    except (OSError, ValueError) as e:
        raise CheckpointError(f"policy snapshot {path} is missing or corrupt ({e})") from None
    if int(stored.get("format", 1)) != FORMAT:
        raise CheckpointError(
            f"policy snapshot {path} has format {int(stored.get('format', 1))}; this version "
            f"reads format {FORMAT}"
        )
    out = []
    for prefix, template in zip(("agent/actor_params", "data/normalizer"), like, strict=True):
        leaves, treedef = jax.tree.flatten(template)
        loaded = []
        for name, leaf in zip(named_leaves(template), leaves, strict=True):
            key = f"{prefix}/{name}"
            if key not in stored or stored[key].shape != np.shape(leaf):
                raise CheckpointError(
                    f"policy snapshot {path} does not match this configuration ({key} "
                    f"{'missing' if key not in stored else 'of another shape'})"
                )
            loaded.append(jax.numpy.asarray(stored[key]))
        out.append(jax.tree.unflatten(treedef, loaded))
    return out[0], out[1]


class Policy(NamedTuple):
    """A trained policy read from a run directory, with what is needed to act."""

    config: TrainConfig
    step: int
    env: Any  # the run's environment (LocomotionEnv)
    agent: Any  # the family's learner functions (the agent's own; see PolicyFamily.agent)
    actor_params: Any  # the policy's parameters (DreamerV3: world model and actor)
    normalizer: Any
    family: Any  # agents.base.PolicyFamily: how these parameters act

    def control(self, obs: jax.Array) -> jax.Array:
        """The deterministic control u(obs) on a raw observation (the family's own
        normalization applied) of a feedforward policy; a recurrent one (DreamerV3) acts
        through ``acting_policy``."""
        try:
            u = self.family.control(self.actor_params, self.normalizer)
        except ValueError as e:
            raise CheckpointError(f"the {self.config.algo} policy: {e}") from None
        return u(obs)

    def acting_policy(self, stochastic: bool = False) -> Any:
        """The policy as an ``acting`` policy (deterministic or sampling) for ``acting.unroll``."""
        build = self.family.stochastic if stochastic else self.family.deterministic
        return build(self.actor_params, self.normalizer)


def latest_policy_step(run_dir: str) -> int | None:
    """The step whose policy ``load_policy`` reads by default: the latest checkpoint, else the
    latest policy snapshot (a run whose checkpoints were deleted to save space); None if
    neither exists."""
    step = latest_step(run_dir)
    if step is None:
        snapshots = snapshot_steps(run_dir)
        step = snapshots[-1] if snapshots else None
    return step


def load_policy(run_dir: str, step: int | None = None) -> Policy:
    """The policy of ``run_dir`` at ``step`` (default: the latest checkpoint) without building a
    trainer: from the step's policy snapshot, or from the checkpoint's items that hold the policy
    alone when there is no snapshot. No replay or model buffer is allocated."""
    from minatt_jax.agents import registry

    config = run_files.load_config(run_dir)
    if step is None:
        step = latest_policy_step(run_dir)
        if step is None:
            raise CheckpointError(f"no checkpoint or policy snapshot in {run_dir}")
    env = config.make_env()
    kind = registry.get(config.algo).policy(config, env)
    if step in snapshot_steps(run_dir):
        params, norm = load_policy_snapshot(run_dir, step, kind.like)
    else:
        _, parts = restore_items(run_dir, kind.checkpoint_items, step)
        params, norm = kind.from_items(parts)
    if not all(np.all(np.isfinite(np.asarray(x))) for x in jax.tree.leaves((params, norm))):
        raise CheckpointError(
            f"the policy of {run_dir} at step {step} has non-finite weights (its training "
            "diverged); use an earlier step"
        )
    return Policy(config, step, env, kind.agent, params, norm, kind)
