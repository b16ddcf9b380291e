"""Named checkpoints: items by key path, a policy without a trainer, one-line mismatch errors."""

from __future__ import annotations

import json
import os
import shutil

import jax
import numpy as np
import pytest

from minatt_jax import checkpoint, runner
from minatt_jax import training as train_module
from minatt_jax.cli import main
from minatt_jax.config import PRESETS, resolve, with_overrides
from minatt_jax.training import hyper_of

# One worker runs this module: its module-scoped run is made once (pytest-xdist --dist loadgroup).
pytestmark = pytest.mark.xdist_group("test_checkpoint")

CONFIG = with_overrides(PRESETS["smoke"], total_steps=300)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    run_dir = str(tmp_path_factory.mktemp("ckpt") / "run")
    os.makedirs(run_dir)
    config = with_overrides(CONFIG, sac_normalize_obs=True)
    runner.train(config, run_dir, log=lambda m: None)
    return run_dir


def test_items_are_listed_by_key_path(run, capsys):
    manifest = checkpoint.describe(run)
    items = manifest["items"]
    assert manifest["format"] == checkpoint.FORMAT and manifest["step"] == 300
    for name in ("agent/actor_params/params/MLP_0/Dense_0/kernel", "agent/log_entropy_coef",
                 "data/real/data/obs", "data/normalizer/mean", "collector/episode_return",
                 "rng", "env_steps"):  # fmt: skip
        assert name in items, name
    assert items["data/real/data/obs"]["shape"] == [CONFIG.buffer_size, 11]
    assert not any(k.startswith(("model/", "meta/")) for k in items)  # sac has neither
    assert main(["inspect", run, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["items"] == items


def test_load_policy_needs_no_trainer(run, monkeypatch):
    state_like = train_module.make_train(resolve(runner.load_config(run))).init(
        jax.random.PRNGKey(0), hyper_of(runner.load_config(run))
    )
    _, full = checkpoint.restore(run, state_like)

    def refuse(*args, **kwargs):
        raise AssertionError("load_policy built a trainer")

    monkeypatch.setattr(train_module, "make_train", refuse)
    policy = checkpoint.load_policy(run)
    assert policy.step == 300
    for a, b in zip(jax.tree.leaves(policy.actor_params), jax.tree.leaves(full.agent.actor_params),
                    strict=True):  # fmt: skip
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert float(policy.normalizer.count) == 300  # normalization was on and is restored
    np.testing.assert_array_equal(policy.normalizer.mean, full.data.normalizer.mean)
    # Without the snapshot, the agent and normalizer items are read from the checkpoint alone.
    snapshot = os.path.join(run, "policy_snapshots", "step_000000300.npz")
    os.rename(snapshot, snapshot + ".bak")
    try:
        again = checkpoint.load_policy(run)
    finally:
        os.rename(snapshot + ".bak", snapshot)
    for a, b in zip(jax.tree.leaves(again.actor_params), jax.tree.leaves(policy.actor_params),
                    strict=True):  # fmt: skip
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    u = policy.control(np.zeros(11, np.float32))
    assert u.shape == (3,) and np.all(np.abs(np.asarray(u)) <= 1)


def test_a_different_structure_is_named_in_one_line(run):
    wider = resolve(with_overrides(CONFIG, sac_hidden=(48, 48), sac_normalize_obs=True))
    like = train_module.make_train(wider).init(jax.random.PRNGKey(0), hyper_of(wider))
    with pytest.raises(checkpoint.CheckpointError) as err:
        checkpoint.restore(run, like)
    message = str(err.value)
    assert "does not match this configuration (of another shape: agent/" in message
    assert "MLP_0/Dense_0" in message and "more)" in message
    assert "\n" not in message


def test_checkpoint_without_manifest_is_reported(run, tmp_path):
    copy = str(tmp_path / "copy")
    shutil.copytree(run, copy)
    shutil.rmtree(os.path.join(copy, "checkpoints", "300", "manifest"))
    with pytest.raises(checkpoint.CheckpointError, match="no manifest"):
        checkpoint.describe(copy)


def test_a_checkpoint_from_before_the_hyper_subtree_restores_the_runs_own_values(run, tmp_path):
    """Checkpoints written before the swept values moved into ``agent/hyper`` hold them as
    ``agent/ma_alpha`` and ``agent/ma_terms``: those are ignored and the hyper values come from
    the template, which every caller builds from the run's configuration; any other missing item
    is an error."""
    config = resolve(runner.load_config(run))
    like = train_module.make_train(config).init(jax.random.PRNGKey(0), hyper_of(config))
    _, full = checkpoint.restore(run, like)
    agent = full.agent
    older = {f: getattr(agent, f) for f in agent.__dataclass_fields__ if f != "hyper"}
    older["ma_alpha"], older["ma_terms"] = np.float32(7.0), np.ones(2, np.float32)
    old_dir = str(tmp_path / "old")
    checkpoint.save(old_dir, 300, {"agent": older})
    template = agent.replace(hyper={k: v * 0 + 0.25 for k, v in agent.hyper.items()})
    _, parts = checkpoint.restore_items(old_dir, {"agent": template})
    assert {k: float(np.ravel(v)[0]) for k, v in parts["agent"].hyper.items()} == {
        k: 0.25 for k in agent.hyper
    }
    for a, b in zip(jax.tree.leaves(parts["agent"].actor_params),
                    jax.tree.leaves(agent.actor_params), strict=True):  # fmt: skip
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    del older["log_entropy_coef"]
    checkpoint.save(str(tmp_path / "older"), 300, {"agent": older})
    with pytest.raises(checkpoint.CheckpointError, match="missing: agent/log_entropy_coef"):
        checkpoint.restore_items(str(tmp_path / "older"), {"agent": template})
