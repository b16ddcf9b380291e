"""Export a run's deterministic policy to one ``.npz`` that runs without JAX.

The file's layout and the numpy loader that reads it are in :mod:`minatt_jax.numpy_policy`; this
module writes it from a run directory (``minatt-jax export RUN_DIR --out policy.npz``).
"""

from __future__ import annotations

import json
import os
from typing import Any

import numpy as np

from minatt_jax import checkpoint, run_files
from minatt_jax import normalizer as obs_norm
from minatt_jax.agents.base import NumpyForm
from minatt_jax.numpy_policy import EXPORT_FORMAT


def export_policy(run_dir: str, out: str, step: int | None = None) -> dict[str, Any]:
    """Writes the policy of ``run_dir`` at ``step`` (default: the latest) to ``out`` atomically;
    returns the metadata written. Raises CheckpointError/RunError for a run it cannot read and
    OSError for a path it cannot write; RunError for ``out`` on the run's own files."""
    run_files.check_not_run_file(run_dir, out)
    policy = checkpoint.load_policy(run_dir, step)
    config, env = policy.config, policy.env
    if policy.family.recurrent or policy.family.export is None:
        why = ("is recurrent (it carries memory), and export writes feedforward policies"
               if policy.family.recurrent else "has no numpy form (its PolicyFamily.export is "
               "None)")  # fmt: skip
        raise checkpoint.CheckpointError(
            f"{run_dir} is a {config.algo} run: its policy {why}; load it with "
            "minatt_jax.checkpoint.load_policy instead"
        )
    if config.meta_episodes > 1:
        raise checkpoint.CheckpointError(
            f"{run_dir} acts in meta-episodes: its observation carries the meta-episode inputs "
            "(reward, previous action, flags) that a numpy policy alone cannot form; load it "
            "with minatt_jax.checkpoint.load_policy instead"
        )
    form = policy.family.export(policy.actor_params, policy.normalizer)
    metadata = {
        "format": EXPORT_FORMAT,
        "env": config.env,
        "algo": config.algo,
        "step": int(policy.step),
        "ma_alpha": float(config.ma.alpha),
        "obs_dim": int(env.observation_size),
        "act_dim": int(env.action_size),
        "obs_names": list(env.obs_names),
        "dt": float(env.dt),
        "normalize_obs": bool(form.normalize_obs),
        "obs_eps": obs_norm.EPS,
        "obs_clip": obs_norm.CLIP,
        "activation": form.activation,
        "action": "tanh of the first act_dim outputs of the last layer",
        "run_dir": os.path.abspath(run_dir),
    }
    run_files.write_npz_atomic(out, form_arrays(form, metadata))
    return metadata


def form_arrays(form: NumpyForm, metadata: dict[str, Any]) -> dict[str, np.ndarray]:
    """The arrays of an export file (``numpy_policy``'s layout) for a policy's numpy form."""
    arrays: dict[str, np.ndarray] = {
        "metadata": np.asarray(json.dumps(metadata)),
        "obs_mean": np.asarray(form.obs_mean, np.float32),
        "obs_var": np.asarray(form.obs_var, np.float32),
    }
    for i, (kernel, bias) in enumerate(form.layers):
        arrays[f"layer_{i}/kernel"] = np.asarray(kernel, np.float32)
        arrays[f"layer_{i}/bias"] = np.asarray(bias, np.float32)
    return arrays
