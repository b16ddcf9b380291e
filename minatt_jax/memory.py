"""Memory a computation may use, checked before it allocates: one clear line instead of an
out-of-memory crash (or a machine swapping) minutes later."""

from __future__ import annotations

import os
from typing import Any

import jax
import numpy as np

from minatt_jax.agents.base import hyper_values
from minatt_jax.run_files import RunError


def available_bytes() -> int | None:
    """Memory the local devices offer: the accelerators' limit, or the host's available memory
    on the CPU; None where neither can be read."""
    devices = jax.local_devices()
    stats = devices[0].memory_stats() if hasattr(devices[0], "memory_stats") else None
    if stats and "bytes_limit" in stats:
        return int(stats["bytes_limit"]) * len(devices)
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def check_fits(needed: int, what: str, advice: str) -> None:
    """RunError ("<what> need about X GiB, more than 90% of the Y GiB the device has free now:
    <advice>") when ``needed`` bytes do not fit."""
    available = available_bytes()
    if available is not None and needed > 0.9 * available:
        raise RunError(
            f"{what} need about {needed / 2**30:.1f} GiB, more than 90% of the "
            f"{available / 2**30:.1f} GiB the device has free now: {advice}"
        )


def state_bytes(trainer: Any) -> int:
    """Bytes of one train state of ``trainer`` (a ``training.Trainer``), from shapes alone:
    nothing is allocated, so a network or buffer far too large is measured, not attempted."""
    hyper = hyper_values(trainer.spec, trainer.config)
    shapes = jax.eval_shape(trainer.init_state, jax.random.PRNGKey(0), hyper)
    return sum(int(np.prod(s.shape)) * s.dtype.itemsize for s in jax.tree.leaves(shapes))


def check_states(per_state: int, count: int, what: str) -> None:
    """RunError before anything is allocated or compiled when ``count`` train states of
    ``per_state`` bytes cannot fit (a state is held about twice while a chunk runs: input and
    output buffers)."""
    check_fits(
        2 * per_state * count,
        what,
        f"{per_state / 2**20:.0f} MiB of state each, held twice while a chunk runs; free "
        "memory, fewer members, smaller networks or buffers (--set buffer_size=..., "
        "--set mb.model_buffer_size=...)",
    )
