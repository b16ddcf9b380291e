"""Export a run's deterministic policy to one ``.npz`` that runs without JAX.

The file's layout and the numpy loader that reads it are in :mod:`minatt_jax.numpy_policy`; this
module writes it from a run directory (``minatt-jax export RUN_DIR --out policy.npz``).
"""

from __future__ import annotations

import json
import os
import re
from typing import Any

import numpy as np

from minatt_jax import checkpoint, run_files
from minatt_jax import normalizer as obs_norm
from minatt_jax.numpy_policy import EXPORT_FORMAT


def _actor_layers(actor_params: Any) -> list[tuple[np.ndarray, np.ndarray]]:
    """The actor MLP's (kernel, bias) pairs in order (flax names them ``Dense_0``, ...)."""
    mlp = actor_params["params"]["MLP_0"]
    names = sorted(mlp, key=lambda n: int(re.fullmatch(r"Dense_(\d+)", n).group(1)))
    return [(np.asarray(mlp[n]["kernel"], np.float32), np.asarray(mlp[n]["bias"], np.float32))
            for n in names]  # fmt: skip


def export_policy(run_dir: str, out: str, step: int | None = None) -> dict[str, Any]:
    """Writes the policy of ``run_dir`` at ``step`` (default: the latest) to ``out`` atomically;
    returns the metadata written. Raises CheckpointError/RunError for a run it cannot read and
    OSError for a path it cannot write; RunError for ``out`` on the run's own files."""
    run_files.check_not_run_file(run_dir, out)
    policy = checkpoint.load_policy(run_dir, step)
    config, env = policy.config, policy.env
    if policy.family.recurrent:
        raise checkpoint.CheckpointError(
            f"{run_dir} is a {config.algo} run: its policy is recurrent (a world model's state "
            "and an actor), and export writes feedforward actors for numpy; load it with "
            "minatt_jax.checkpoint.load_policy instead"
        )
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
        "normalize_obs": bool(config.sac.normalize_obs),
        "obs_eps": obs_norm.EPS,
        "obs_clip": obs_norm.CLIP,
        "activation": "relu",
        "action": "tanh of the first act_dim outputs of the last layer",
        "run_dir": os.path.abspath(run_dir),
    }
    arrays: dict[str, np.ndarray] = {
        "metadata": np.asarray(json.dumps(metadata)),
        "obs_mean": np.asarray(policy.normalizer.mean, np.float32),
        "obs_var": np.asarray(policy.normalizer.var, np.float32),
    }
    for i, (kernel, bias) in enumerate(_actor_layers(policy.actor_params)):
        arrays[f"layer_{i}/kernel"], arrays[f"layer_{i}/bias"] = kernel, bias
    run_files.write_npz_atomic(out, arrays)
    return metadata
