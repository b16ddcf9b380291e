"""minatt-jax: meta-reinforcement learning with minimum attention, end to end in JAX/MJX.

The public API (``train``, ``train_population``, ``load_run``, ...) loads on first use, so
``minatt_jax.numpy_policy`` (an exported policy in numpy alone) imports without JAX.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"
__all__ = ["Run", "load_run", "make_config", "plot_curves", "train", "train_population"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        return getattr(importlib.import_module("minatt_jax.api"), name)
    raise AttributeError(f"module 'minatt_jax' has no attribute {name!r}")
