"""Run an exported minatt-jax policy with numpy alone (no JAX, flax or MuJoCo needed).

``minatt-jax export RUN_DIR --out policy.npz`` writes the deterministic policy of a run; this
module (numpy only; copy the file anywhere) acts with it::

    from minatt_jax.numpy_policy import load_policy
    policy = load_policy("policy.npz")
    action = policy(observation)          # (obs_dim,) or (batch, obs_dim) -> actions in [-1, 1]
    policy.metadata["env"], policy.metadata["obs_names"]

The file holds, besides a JSON ``metadata`` string, the observation normalizer (``obs_mean``,
``obs_var``; applied when ``metadata["normalize_obs"]``, with ``metadata["obs_eps"]`` and
``metadata["obs_clip"]``) and the actor MLP's layers ``layer_{i}/kernel`` (in, out) and
``layer_{i}/bias``. The action is ``tanh(mean)`` where ``mean`` is the first ``act_dim`` outputs
of the last layer, and the hidden layers' activation is ``metadata["activation"]`` (one of
``ACTIVATIONS``):

    x = clip((obs - obs_mean) / sqrt(obs_var + obs_eps), -obs_clip, obs_clip)  # if normalize_obs
    h = act(x @ W_0 + b_0) ... ; out = h @ W_n + b_n ; action = tanh(out[..., :act_dim])
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np

EXPORT_FORMAT = 1

# The hidden layers' activations a numpy policy applies, by the name an export records.
ACTIVATIONS = {
    "relu": lambda x: np.maximum(x, 0.0),
    "tanh": np.tanh,
    "elu": lambda x: np.where(x > 0, x, np.expm1(np.minimum(x, 0.0))),
    "swish": lambda x: x / (1.0 + np.exp(-x)),
    "identity": lambda x: x,
}


def dense_layers(mlp: dict[str, Any]) -> list[tuple[np.ndarray, np.ndarray]]:
    """The (kernel, bias) pairs of a flax MLP's parameters, in order (``Dense_0``, ``Dense_1``,
    ...): the layers of a ``NumpyForm`` for an actor built from ``nn.Dense`` layers."""
    names = sorted((n for n in mlp if n.startswith("Dense_")), key=lambda n: int(n[6:]))
    if not names or len(names) != len(mlp):
        raise ValueError(f"expected Dense_0 ... Dense_n layers, got {sorted(mlp)}")
    return [(np.asarray(mlp[n]["kernel"], np.float32), np.asarray(mlp[n]["bias"], np.float32))
            for n in names]  # fmt: skip


class NumpyPolicy:
    """The deterministic control law u(obs) of an exported policy, in float32 numpy."""

    def __init__(self, layers: list[tuple[np.ndarray, np.ndarray]], obs_mean: np.ndarray,
                 obs_var: np.ndarray, metadata: dict[str, Any]) -> None:  # fmt: skip
        self.layers = layers
        self.obs_mean = obs_mean
        self.obs_std = np.sqrt(obs_var + np.float32(metadata["obs_eps"]))
        self.obs_clip = np.float32(metadata["obs_clip"])
        self.metadata = metadata
        self.act_dim = int(metadata["act_dim"])
        self.obs_dim = int(metadata["obs_dim"])
        name = metadata.get("activation", "relu")
        if name not in ACTIVATIONS:
            raise ValueError(f"unknown activation {name!r}; this loader knows "
                             f"{', '.join(ACTIVATIONS)}")  # fmt: skip
        self.activation = ACTIVATIONS[name]

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """Actions in [-1, 1] for one observation (obs_dim,) or a batch (..., obs_dim)."""
        x = np.asarray(obs, np.float32)
        if x.shape[-1] != self.obs_dim:
            raise ValueError(f"expected observations of {self.obs_dim} values, got {x.shape}")
        if self.metadata["normalize_obs"]:
            x = np.clip((x - self.obs_mean) / self.obs_std, -self.obs_clip, self.obs_clip)
        for kernel, bias in self.layers[:-1]:
            x = self.activation(x @ kernel + bias)
        kernel, bias = self.layers[-1]
        return np.tanh((x @ kernel + bias)[..., : self.act_dim])


def load_policy(path: str) -> NumpyPolicy:
    """The policy exported to ``path`` (raises ValueError for a file that is not one)."""
    try:
        loaded = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as e:
        raise ValueError(f"{path} is not a readable policy file ({e})") from None
    if not isinstance(loaded, np.lib.npyio.NpzFile):
        raise ValueError(f"{path} is not a readable policy file (not an .npz archive)")
    with loaded:
        arrays = {k: loaded[k] for k in loaded.files}
    if "metadata" not in arrays:
        raise ValueError(f"{path} is not a minatt-jax exported policy (no metadata)")
    metadata = json.loads(str(arrays["metadata"]))
    if metadata.get("format") != EXPORT_FORMAT:
        raise ValueError(
            f"{path} has export format {metadata.get('format')}; this loader reads {EXPORT_FORMAT}"
        )
    layers = []
    while f"layer_{len(layers)}/kernel" in arrays:
        i = len(layers)
        layers.append((arrays[f"layer_{i}/kernel"], arrays[f"layer_{i}/bias"]))
    return NumpyPolicy(layers, arrays["obs_mean"], arrays["obs_var"], metadata)
