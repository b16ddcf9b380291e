"""analyze: seed aggregation in tables, every figure from smoke runs, bad input."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from minatt_jax.analysis.report import FIGURES, Run, aggregate_tables, tables_markdown
from minatt_jax.cli import main as _main
from minatt_jax.config import PRESETS, with_overrides

# One worker runs this module: its module-scoped run is made once (pytest-xdist --dist loadgroup).
pytestmark = pytest.mark.xdist_group("test_report")


def main(argv):
    """The CLI's exit status, whether it returns it or argparse raises SystemExit."""
    try:
        return _main(argv)
    except SystemExit as e:
        return e.code


def _fake_run(path, alpha, seed, returns, meta_after=None):
    os.makedirs(path, exist_ok=True)
    config = with_overrides(PRESETS["smoke"], ma_alpha=alpha, seed=seed)
    with open(os.path.join(path, "config.json"), "w") as f:
        json.dump(config.to_dict(), f)
    with open(os.path.join(path, "metrics.jsonl"), "w") as f:
        for step, ret in zip((300, 600), returns, strict=True):
            f.write(json.dumps({"step": step, "return": ret, "feedback_norm": ret / 10,
                                "feedforward_norm": 1.0, "energy": 0.5}) + "\n")  # fmt: skip
    if meta_after is not None:
        mean = {k: {"before": 1.0, "after": meta_after} for k in
                ("return", "feedback_norm", "feedforward_norm", "energy")}  # fmt: skip
        with open(os.path.join(path, "meta_test_mass.json"), "w") as f:
            json.dump({"mean_over_tasks": mean}, f)
    return Run(str(path), config, f"sac alpha={alpha:g}")


def test_tables_aggregate_seeds(tmp_path):
    runs = [
        _fake_run(tmp_path / "a0", 0.0, 0, (10.0, 100.0), meta_after=50.0),
        _fake_run(tmp_path / "a1", 0.0, 1, (10.0, 140.0), meta_after=70.0),
        _fake_run(tmp_path / "b0", 1.0, 0, (10.0, 90.0)),
    ]
    tables = aggregate_tables(runs)
    a, b = tables["meta_training"]
    assert a["group"] == "sac alpha=0" and a["seeds"] == 2 and a["step"] == 600
    assert a["return"] == pytest.approx(120.0) and a["return_std"] == pytest.approx(20.0)
    assert a["feedback_norm"] == pytest.approx(12.0)
    assert b["seeds"] == 1 and b["return"] == pytest.approx(90.0) and b["return_std"] == 0.0
    (test_row,) = tables["meta_testing"]
    assert test_row["variant"] == "mass" and test_row["seeds"] == 2
    assert test_row["return"] == pytest.approx(60.0) and test_row["return_std"] == pytest.approx(10)
    assert test_row["return_before"] == pytest.approx(1.0)
    markdown = tables_markdown(tables)
    assert "| sac alpha=0 | 2 | 600 | 120 +- 20 |" in markdown


@pytest.fixture(scope="module")
def smoke_runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("analyze_runs")
    dirs = []
    for alpha in ("0", "1"):
        run_dir = str(root / f"alpha{alpha}")
        assert main(["train", "--preset", "smoke", "--steps", "300", "--alpha", alpha,
                     "--out", run_dir]) == 0  # fmt: skip
        dirs.append(run_dir)
    return dirs


def test_analyze_writes_every_figure_and_a_self_contained_report(smoke_runs, tmp_path):
    out = tmp_path / "report"
    argv = ["analyze", *smoke_runs, "--out", str(out), "--episodes", "2", "--bins", "5",
            "--grid", "2", "--grid-rollouts", "2", "--grid-steps", "10",
            "--maturation-steps", "300"]  # fmt: skip
    assert main(argv) == 0
    html = (out / "report.html").read_text()
    drawn = (*FIGURES, "frames.png")  # frames.png: the tests render offscreen (conftest)
    for name in drawn:
        data = (out / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 2000, name
        assert f"id='{name}'" in html
    assert html.count("data:image/png;base64,") == len(drawn)
    assert "src='http" not in html  # nothing to fetch: readable offline
    # tables as HTML tables (no raw Markdown), each figure captioned, each run's settings
    assert html.count("<table>") >= 3 and "<th>return</th>" in html and "|---|" not in html
    assert html.count("<figcaption>") == len(drawn) and "config.json</summary>" in html
    tables = json.loads((out / "tables.json").read_text())
    assert [r["group"] for r in tables["meta_training"]] == ["sac alpha=0", "sac alpha=1"]
    assert np.isfinite(tables["meta_training"][0]["return"])
    grid = json.loads((out / "failure_grid.json").read_text())
    assert list(grid["failure_rate"]) == ["sac alpha=0", "sac alpha=1"]
    rates = np.asarray(grid["failure_rate"]["sac alpha=0"])
    assert rates.shape == (2, 2) and np.all((rates >= 0) & (rates <= 1))
    assert grid["forward_velocity"][0] < 0 < grid["forward_velocity"][-1]  # the hopper's range


def test_analyze_bad_input_exit_2(smoke_runs, tmp_path, capsys):
    other = tmp_path / "walker"
    other.mkdir()
    with open(os.path.join(smoke_runs[0], "config.json")) as f:
        config = json.load(f)
    (other / "config.json").write_text(json.dumps({**config, "env": "walker2d"}))
    assert main(["analyze", smoke_runs[0], str(other), "--out", str(tmp_path / "r")]) == 2
    assert "different environments" in capsys.readouterr().err
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "config.json").write_text(json.dumps(config))
    assert main(["analyze", str(empty), "--out", str(tmp_path / "r")]) == 2
    assert "has no checkpoint or policy snapshot" in capsys.readouterr().err
    argv = ["analyze", smoke_runs[0], "--out", str(tmp_path / "r"), "--perturbation", "windy"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "unknown variant" in err and len(err.strip().splitlines()) == 1


def test_analyze_accepts_the_runs_evaluate_accepts(smoke_runs, tmp_path, capsys):
    """A run whose checkpoints were deleted to save space keeps its policy snapshots: evaluate
    reads its policy from the latest one, and analyze takes the same run."""
    import shutil

    run = tmp_path / "snapshots_only"
    shutil.copytree(smoke_runs[1], run, ignore=shutil.ignore_patterns(".lock"))
    shutil.rmtree(run / "checkpoints")
    assert main(["evaluate", str(run), "--episodes", "1", "--json"]) == 0
    evaluated = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert evaluated["step"] == 300
    # The settings of the test above: its compiled programs serve this analysis too.
    argv = ["analyze", str(run), "--out", str(tmp_path / "r"), "--episodes", "2", "--bins", "5",
            "--grid", "2", "--grid-rollouts", "2", "--grid-steps", "10"]  # fmt: skip
    assert main(argv) == 0, capsys.readouterr().err
    assert (tmp_path / "r" / "report.html").is_file()


def test_figures_and_text_files_use_a_unique_temporary_name(tmp_path):
    """Two processes writing one figure (two experiment lanes did) must not share a temporary
    file: each write goes through its own, and none is left behind."""
    from minatt_jax import runner
    from minatt_jax.analysis import plots

    plt = plots._pyplot()
    target = str(tmp_path / "curves.png")
    temporaries = []
    for i in range(2):
        fig, ax = plt.subplots()
        ax.plot([0, i])
        savefig = fig.savefig
        fig.savefig = lambda tmp, *a, _save=savefig, **k: (
            temporaries.append(tmp),
            _save(tmp, *a, **k),
        )
        plots.save_figure(fig, target)
    assert len(set(temporaries)) == 2 and target + ".tmp.png" not in temporaries
    runner.write_text_atomic(str(tmp_path / "table.md"), "| a |\n")
    assert sorted(os.listdir(tmp_path)) == ["curves.png", "table.md"]
    assert open(target, "rb").read(8) == b"\x89PNG\r\n\x1a\n"


def test_rollouts_split_a_meta_episode_by_inner_episode(make_env):
    """analyze on a meta-episode run: each inner episode's return, feedback, feedforward and
    energy, against a hand computation. The policy u = (0.1, 0.2 + 0.4 s) reads the scaled
    episode index s (0, 0.5, 1): constant within an episode, so the feedforward is 0 once the
    jump at each boundary (a new episode's first action) is left out; ||du/dx||^2 = 0.16."""
    from types import SimpleNamespace

    import jax
    import jax.numpy as jnp

    from minatt_jax import acting
    from minatt_jax.analysis.report import by_inner_episode, make_rollouts, visited_states
    from minatt_jax.envs.meta_episode import MetaEpisode

    episodes, steps = 3, 10
    env = MetaEpisode(make_env("point_robot_dense"), episodes, steps)
    u = lambda x: jnp.stack([0.1 + 0.0 * x[0], 0.2 + 0.4 * x[-1]])  # noqa: E731
    policy = acting.Policy(act=lambda x, key: u(x), control=u)
    rollouts = make_rollouts(env, lambda params, norm: policy, env.max_steps)
    tools = SimpleNamespace(inner_episodes=episodes, rollouts=rollouts)
    visited = visited_states(tools, None, None, jax.random.PRNGKey(0), 2, env.nominal_task())
    got = by_inner_episode(visited, episodes)

    pushes = [0.2 + 0.4 * s for s in (0.0, 0.5, 1.0)]
    t = np.arange(1, steps + 1)[:, None]
    goal = np.array([0.0, 1.0])  # the nominal goal at pi / 2; every episode starts at the origin
    returns = [-np.sum(np.linalg.norm(0.1 * t * np.array([0.1, p]) - goal, axis=1)) for p in pushes]
    np.testing.assert_allclose(got["return"], returns, rtol=1e-5)
    np.testing.assert_allclose(got["energy"], [0.01 + p**2 for p in pushes], rtol=1e-5)
    np.testing.assert_allclose(got["feedback"], 0.16, rtol=1e-5)
    np.testing.assert_allclose(got["feedforward"], 0.0, atol=1e-6)
    assert np.count_nonzero(visited["episode"] == 2) == 2 * steps
