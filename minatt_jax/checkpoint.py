"""Orbax checkpoints of the whole train-state pytree (atomic: orbax writes, then renames).

The state is saved as its flat list of leaves (keyed by position); zero-size leaves, which orbax
refuses and MJX's physics data has several of, are skipped and taken from the template on
restore. Restoring into a template of another structure or shape fails with CheckpointError.
"""

from __future__ import annotations

import os
from typing import Any

import jax
import orbax.checkpoint as ocp


class CheckpointError(Exception):
    """A missing, corrupt or incompatible checkpoint (a user-facing error)."""


def _manager(run_dir: str, create: bool) -> ocp.CheckpointManager:
    options = ocp.CheckpointManagerOptions(max_to_keep=2, create=create)
    return ocp.CheckpointManager(
        os.path.join(os.path.abspath(run_dir), "checkpoints"), options=options
    )


def save(run_dir: str, step: int, state: Any) -> None:
    """Saves ``state`` as checkpoint ``step`` and waits until it is on disk."""
    with _manager(run_dir, create=True) as manager:
        manager.save(step, args=ocp.args.StandardSave(_payload(state)))
        manager.wait_until_finished()


def latest_step(run_dir: str) -> int | None:
    """The newest complete checkpoint's step, or None when there is none."""
    if not os.path.isdir(os.path.join(run_dir, "checkpoints")):
        return None
    with _manager(run_dir, create=False) as manager:
        return manager.latest_step()


def restore(run_dir: str, like: Any, step: int | None = None) -> tuple[int, Any]:
    """Restores checkpoint ``step`` (default: the latest) into the structure of ``like``."""
    step = latest_step(run_dir) if step is None else step
    if step is None:
        raise CheckpointError(f"no checkpoint in {run_dir}")
    abstract = jax.tree.map(ocp.utils.to_shape_dtype_struct, _payload(like))
    try:
        with _manager(run_dir, create=False) as manager:
            payload = manager.restore(step, args=ocp.args.StandardRestore(abstract))
    except Exception as e:  # orbax raises many types for bad files
        raise CheckpointError(
            f"checkpoint {step} in {run_dir} is corrupt or does not match this configuration "
            f"({type(e).__name__}: {str(e).splitlines()[0][:200] if str(e) else ''})"
        ) from None
    leaves, treedef = jax.tree.flatten(like)
    restored = [payload.get(_key(i), leaf) for i, leaf in enumerate(leaves)]
    return step, jax.tree.unflatten(treedef, restored)


def _key(index: int) -> str:
    return f"leaf{index:05d}"


def _payload(state: Any) -> dict[str, Any]:
    """The non-empty leaves of ``state`` keyed by position."""
    return {_key(i): x for i, x in enumerate(jax.tree.leaves(state)) if x.size > 0}


def save_policy_snapshot(run_dir: str, step: int, actor_params: Any, normalizer: Any) -> str:
    """Saves the policy alone (actor parameters and observation normalizer) as a small .npz.

    Full checkpoints keep only the latest two (a model-based state with its buffers is hundreds
    of MB); these snapshots, one per evaluation, let analyses look at the policy at any step.
    """
    import numpy as np

    directory = os.path.join(run_dir, "policy_snapshots")
    os.makedirs(directory, exist_ok=True)
    leaves = jax.tree.leaves((actor_params, normalizer))
    path = os.path.join(directory, f"step_{step:09d}.npz")
    tmp = path + ".tmp.npz"
    np.savez(tmp, **{_key(i): np.asarray(x) for i, x in enumerate(leaves)})
    os.replace(tmp, path)
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
    import numpy as np

    path = os.path.join(run_dir, "policy_snapshots", f"step_{step:09d}.npz")
    leaves, treedef = jax.tree.flatten(like)
    try:
        with np.load(path) as f:
            loaded = [f[_key(i)] for i in range(len(leaves))]
    except (OSError, KeyError, ValueError) as e:
        raise CheckpointError(f"policy snapshot {path} is missing or corrupt ({e})") from None
    if any(a.shape != b.shape for a, b in zip(loaded, leaves, strict=True)):
        raise CheckpointError(f"policy snapshot {path} does not match this configuration")
    return jax.tree.unflatten(treedef, [jax.numpy.asarray(x) for x in loaded])
