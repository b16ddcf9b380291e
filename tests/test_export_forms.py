"""Every built-in agent's policy family exports a numpy form that acts as its JAX policy (its own
observation normalization included), or says it has none; a non-SAC layout (tanh hidden layers)
goes through the same loader."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from minatt_jax.agents import registry
from minatt_jax.config import PRESETS, resolve, with_overrides
from minatt_jax.export import form_arrays
from minatt_jax.numpy_policy import NumpyPolicy, load_policy


def random_like(tree, rng):
    """Weights at the scale of a network's initialization (1 / sqrt(fan in)), biases 0.1."""

    def draw(x):
        scale = 1 / np.sqrt(np.shape(x)[0]) if np.ndim(x) == 2 else 0.1
        return (rng.normal(size=np.shape(x)) * scale).astype(np.float32)

    return jax.tree.map(draw, tree)


def metadata(env, activation, normalize):
    from minatt_jax import normalizer as obs_norm

    return {"format": 1, "obs_dim": env.observation_size, "act_dim": env.action_size,
            "normalize_obs": normalize, "obs_eps": obs_norm.EPS, "obs_clip": obs_norm.CLIP,
            "activation": activation}  # fmt: skip


@pytest.mark.parametrize("algo", list(registry.BUILTIN))
@pytest.mark.parametrize("normalize", [False, True])
def test_a_numpy_export_equals_the_jax_policy_or_is_refused(algo, normalize, tmp_path):
    fields = {"algo": algo, "env": "point_robot" if algo == "mamba" else "hopper"}
    config = with_overrides(PRESETS["smoke"], **fields)
    for group in config.group_names:  # the agent's own observation normalization setting
        if hasattr(getattr(config, group), "normalize_obs"):
            config = with_overrides(config, **{f"{group}_normalize_obs": normalize})
    config = resolve(config)
    env = config.make_env()
    family = registry.get(algo).policy(config, env)
    if family.recurrent:
        assert family.export is None  # export refuses it in one line (test_bad_input)
        return
    rng = np.random.default_rng(0)
    params, norm = family.like
    params = random_like(params, rng)
    norm = norm.replace(mean=rng.normal(size=norm.mean.shape).astype(np.float32),
                        var=rng.uniform(0.5, 2.0, norm.var.shape).astype(np.float32))  # fmt: skip
    form = family.export(params, norm)
    assert form.normalize_obs == normalize
    path = tmp_path / "policy.npz"
    np.savez(path, **form_arrays(form, metadata(env, form.activation, form.normalize_obs)))
    policy = load_policy(str(path))
    obs = rng.normal(size=(64, env.observation_size)).astype(np.float32) * 3
    u = jax.jit(jax.vmap(family.control(params, norm)))(obs)
    np.testing.assert_allclose(policy(obs), np.asarray(u), atol=1e-5)


def test_the_loader_applies_the_recorded_hidden_activation():
    rng = np.random.default_rng(1)
    layers = [
        (rng.normal(size=(3, 5)).astype(np.float32), rng.normal(size=5).astype(np.float32)),
        (rng.normal(size=(5, 4)).astype(np.float32), rng.normal(size=4).astype(np.float32)),
    ]
    meta = {"obs_eps": 1e-8, "obs_clip": 10.0, "act_dim": 2, "obs_dim": 3,
            "normalize_obs": False, "activation": "tanh"}  # fmt: skip
    policy = NumpyPolicy(layers, np.zeros(3, np.float32), np.ones(3, np.float32), meta)
    x = rng.normal(size=3).astype(np.float32)
    hidden = np.tanh(x @ layers[0][0] + layers[0][1])
    expected = np.tanh((hidden @ layers[1][0] + layers[1][1])[:2])
    np.testing.assert_allclose(policy(x), expected, rtol=1e-6)
    with pytest.raises(ValueError, match="unknown activation"):
        NumpyPolicy(layers, np.zeros(3), np.ones(3), {**meta, "activation": "gelu"})
