"""meta-test on run directories: curves per task for sac and mbmpo runs, files, bad input."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from minatt_jax import meta_test
from minatt_jax.cli import main as _main

# One worker runs this module: its module-scoped run is made once (pytest-xdist --dist loadgroup).
pytestmark = pytest.mark.xdist_group("test_meta_test")


def main(argv):
    """The CLI's exit status, whether it returns it or argparse raises SystemExit."""
    try:
        return _main(argv)
    except SystemExit as e:
        return e.code


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("meta_test_runs")
    out = {}
    for name, algo, seed, alpha in (("sac", "sac", 0, "1"), ("mbmpo", "mbmpo", 0, "1"),
                                    ("sac_seed1", "sac", 1, "1"),
                                    ("sac_alpha0.2", "sac", 1, "0.2")):  # fmt: skip
        run_dir = str(root / name)
        argv = ["train", "--env", "hopper", "--algo", algo, "--preset", "smoke", "--steps", "300",
                "--alpha", alpha, "--seed", str(seed), "--out", run_dir]  # fmt: skip
        assert main(argv) == 0
        out[name] = run_dir
    return out


def test_meta_testing_runs_of_one_configuration_compiles_once(runs):
    """Runs of two seeds and two MA weights and two task sets share the compiled programs, and
    a run's results do not depend on which run compiled them (its arrays, its MA weight among
    them, are arguments, not constants)."""
    settings = meta_test.MetaTestConfig(adapt_steps=2, episodes=1, updates_per_step=3)
    meta_test._PROGRAMS.clear()
    meta_test.meta_test(runs["sac"], "mass", settings, log=lambda _: None)
    shared = meta_test.meta_test(runs["sac_seed1"], "crippled", settings, log=lambda _: None)
    other_alpha = meta_test.meta_test(runs["sac_alpha0.2"], "crippled", settings,
                                      log=lambda _: None)  # fmt: skip
    assert len(meta_test._PROGRAMS) == 1
    (programs,) = meta_test._PROGRAMS.values()
    for fn in (programs.adapter.step, programs.evaluate, programs.collect):
        assert fn._cache_size() == 1
    assert other_alpha["tasks"] != shared["tasks"]  # the other weight trained another policy
    for name, result in (("sac_seed1", shared), ("sac_alpha0.2", other_alpha)):
        meta_test._PROGRAMS.clear()
        alone = meta_test.meta_test(runs[name], "crippled", settings, log=lambda _: None)
        assert result["tasks"] == alone["tasks"]


@pytest.mark.parametrize("algo", ["sac", "mbmpo"])
def test_meta_test_writes_curves_per_task(algo, runs, capsys):
    run_dir = runs[algo]
    argv = ["meta-test", run_dir, "--variant", "crippled", "--shots", "1", "--adapt-steps", "2",
            "--episodes", "2", "--updates-per-step", "5", "--json"]  # fmt: skip
    assert main(argv) == 0
    printed = json.loads(capsys.readouterr().out)
    with open(os.path.join(run_dir, "meta_test_crippled.json")) as f:
        saved = json.load(f)
    assert saved == printed
    assert [r["task"] for r in saved["tasks"]] == ["crippled thigh_joint"]
    for row in saved["tasks"]:
        for metric in ("return", "feedback_norm", "feedforward_norm", "energy"):
            curve = row[f"{metric}_curve"]
            assert len(curve) == 3 and np.all(np.isfinite(curve))
        assert row["collected_transitions"] > 0
        # Adaptation changed the policy: the curve is not flat.
        assert row["energy_curve"][0] != row["energy_curve"][-1]
        assert len(row["policy_distance_curve"]) == 2 and min(row["policy_distance_curve"]) > 0
    with open(os.path.join(run_dir, "meta_test_crippled.png"), "rb") as f:
        assert f.read(8) == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--variant", "windy"], "unknown variant"),
        (["--variant", "mass", "--shots", "0"], "positive integer"),
    ],
)
def test_meta_test_bad_input_exit_2(argv, message, runs, capsys):
    assert main(["meta-test", runs["sac"], *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1


def test_meta_test_missing_run_or_checkpoint_exit_2(tmp_path, runs, capsys):
    assert main(["meta-test", str(tmp_path / "nothing"), "--variant", "mass"]) == 2
    assert "does not exist" in capsys.readouterr().err
    empty = tmp_path / "empty"
    empty.mkdir()
    with open(os.path.join(runs["sac"], "config.json")) as f:
        (empty / "config.json").write_text(f.read())
    assert main(["meta-test", str(empty), "--variant", "mass"]) == 2
    assert "no checkpoint" in capsys.readouterr().err


def test_meta_test_adapt_alpha_changes_only_the_adaptation(runs, tmp_path, capsys):
    """MA's weight in the adaptation updates: the evaluation before adapting is the same, the
    adapted policy differs from the one adapted with the run's alpha (1)."""
    base = ["meta-test", runs["sac"], "--variant", "mass", "--adapt-steps", "1", "--episodes",
            "1", "--updates-per-step", "3", "--out", str(tmp_path), "--json"]  # fmt: skip
    curves = []
    for extra in ([], ["--adapt-alpha", "0"]):
        assert main(base + extra) == 0
        curves.append(json.loads(capsys.readouterr().out)["tasks"][0]["feedback_norm_curve"])
    assert curves[0][0] == curves[1][0] and curves[0][1] != curves[1][1]


def test_meta_test_inner_lr_zero_leaves_the_mbmpo_policy_where_it_was(runs, tmp_path, capsys):
    argv = ["meta-test", runs["mbmpo"], "--variant", "mass", "--adapt-steps", "2",
            "--episodes", "1", "--inner-lr", "0", "--out", str(tmp_path), "--json"]  # fmt: skip
    assert main(argv) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["settings"]["inner_lr"] == 0
    for row in result["tasks"]:
        # theta - 0 * grad, averaged over the elite slots: equal up to float32 rounding
        assert max(row["policy_distance_curve"]) < 1e-5


def test_meta_test_sweeps_inner_step_alpha_and_refit_without_recompiling(runs):
    """The adaptation's swept settings (inner step size, MA's weight, refit or not) are data:
    one compile per program, and each setting changes the adapted policy as it should."""
    meta_test._PROGRAMS.clear()
    moved = {}
    for beta, adapt_alpha, refit in ((1e-3, None, True), (1e-4, None, True), (1e-3, 0.0, True),
                                     (1e-3, None, False)):  # fmt: skip
        settings = meta_test.MetaTestConfig(
            adapt_steps=1, episodes=1, inner_lr=beta, adapt_alpha=adapt_alpha, refit_model=refit
        )
        result = meta_test.meta_test(runs["mbmpo"], "mass", settings, log=lambda _: None,
                                     task_specs=("mass=1.5",))  # fmt: skip
        moved[beta, adapt_alpha, refit] = result["tasks"][0]["policy_distance_curve"][0]
    assert len(meta_test._PROGRAMS) == 1
    (programs,) = meta_test._PROGRAMS.values()
    for fn in (programs.adapter.step, programs.evaluate, programs.collect):
        assert fn._cache_size() == 1
    # the SAC inner step does not read the model: it is never refitted, so never compiled
    assert programs.adapter.parts["refit"]._cache_size() == 0
    meta_test._PROGRAMS.clear()
    base = moved[1e-3, None, True]
    # one inner step from the same policy on the same imagined data: distance is linear in beta
    np.testing.assert_allclose(moved[1e-4, None, True], base / 10, rtol=1e-2)
    assert moved[1e-3, 0.0, True] != base
    # mbmpo's default inner step (the SAC actor loss on one-step supports; MA's temporal term
    # read between parameter versions) reads only the supports' states, which are collected
    # real states: the model, refitted or not, does not enter the adaptation.
    assert moved[1e-3, None, False] == base
