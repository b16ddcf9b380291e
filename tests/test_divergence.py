"""The divergence guard: a finite blow-up stops a run; no committed run would have tripped it."""

from __future__ import annotations

import glob
import json
import os

import jax.numpy as jnp
import pytest

from minatt_jax import divergence

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


class _State:
    """A stand-in for an agent's state: only its parameter groups are read."""

    def __init__(self, **groups):
        self.groups = groups

    def parameter_groups(self):
        return self.groups


SANE = _State(actor={"w": jnp.ones((3, 3))})
# The first record of `train --preset smoke --steps 1200 --set sac.actor_lr=1e3` (a learning rate
# now refused by its rule), which used to be written and reported as a normal run.
BLOWN_UP = {
    "step": 300,
    "return": -1.6,
    "feedback_norm": 0.0,
    "actor_loss": 1.29e10,
    "critic_loss": 9.07e21,
    "entropy": -1.29e10,
    "entropy_coef": 1.0,
    "q_mean": -0.25,
}


def test_the_red_team_record_is_diverged_in_each_quantity():
    problems = divergence.Guard(action_size=3).check(BLOWN_UP, SANE)
    text = "; ".join(problems)
    assert "critic_loss is 9.07e+21" in text and "actor_loss is 1.29e+10" in text
    assert "entropy is -1.29e+10" in text


def test_a_jump_is_judged_against_the_running_scale():
    guard = divergence.Guard(action_size=1, earlier=[{"critic_loss": 50.0}, {"critic_loss": 2.0}])
    assert guard.check({"critic_loss": 4e7}, SANE) == []  # 8e5 times 50: not yet
    assert guard.check({"critic_loss": 6e7}, SANE) == ["critic_loss is 6e+07 (running scale 50)"]
    assert guard.check({"critic_loss_std": 1e20}, SANE) == []  # spreads are not guarded


def test_weights_entropy_and_non_finite_values():
    big = _State(actor={"w": jnp.full((2,), 2e6)}, critic={"w": jnp.array([jnp.nan])})
    problems = divergence.Guard(action_size=2).check({"entropy": -150.0, "return": 1.0}, big)
    assert problems == ["actor reach 2e+06 (bound 1e+06)", "critic are not finite"]
    problems = divergence.Guard(action_size=2).check({"entropy": -201.0}, SANE)
    assert problems == ["entropy collapsed to -201 (a saturated policy)"]
    assert divergence.Guard(1).check({"return": float("inf"), "model_holdout_mse": float("inf")},
                                     SANE) == ["return is not finite"]  # fmt: skip


@pytest.mark.parametrize("root", ["experiments/records", "tests/data"])
def test_no_committed_record_would_have_tripped_the_guard(root):
    """Every committed run, record by record in the order it was written, passes the guard (an
    action size of 1: the strictest entropy floor)."""
    files = glob.glob(os.path.join(ROOT, root, "**", "metrics.jsonl"), recursive=True)
    assert files or root == "tests/data"
    checked = 0
    for path in files:
        guard = divergence.Guard(action_size=1)
        with open(path) as f:
            for line in f:
                record = json.loads(line)
                assert guard.check(record, SANE) == [], (path, record["step"])
                guard.observe(record)
                checked += 1
    assert checked >= len(files)
