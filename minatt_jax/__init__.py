"""minatt-jax: meta-reinforcement learning with minimum attention, end to end in JAX/MJX."""

import contextlib as _contextlib
import io as _io

# mujoco.mjx prints a note to stdout when its optional Warp (GPU) backend is absent; the JAX
# backend this package uses needs no Warp, so the note is only noise in CLI output.
with _contextlib.redirect_stdout(_io.StringIO()):
    from mujoco import mjx as _mjx  # noqa: F401

from minatt_jax.api import (  # noqa: E402 - after the mjx note is silenced
    Run,
    load_run,
    make_config,
    plot_curves,
    train,
    train_population,
)

__version__ = "0.1.0"
__all__ = ["Run", "load_run", "make_config", "plot_curves", "train", "train_population"]
