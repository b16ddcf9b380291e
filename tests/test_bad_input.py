"""Every bad input is one line on stderr and exit status 2, and damages nothing already written.

The cases run in-process against one small run directory (a config, a checkpoint at step 600
and a policy snapshot, made without training) whose files are hashed before and after each case.
"""

from __future__ import annotations

import os
import shutil

import pytest
from conftest import digest, untrained_run

from minatt_jax import run_files
from minatt_jax.cli import main
from minatt_jax.config import PRESETS, resolve, with_overrides

# One worker runs this module: its module-scoped run is made once (pytest-xdist --dist loadgroup).
pytestmark = pytest.mark.xdist_group("test_bad_input")

CONFIG = resolve(with_overrides(PRESETS["smoke"], total_steps=300))


@pytest.fixture(scope="module")
def paths(tmp_path_factory):
    root = tmp_path_factory.mktemp("bad")
    run = str(root / "run")
    untrained_run(run, CONFIG, 600)
    bad_metrics = str(root / "bad_metrics")  # the same run, its metrics.jsonl damaged
    shutil.copytree(run, bad_metrics)
    with open(os.path.join(bad_metrics, "metrics.jsonl"), "w") as f:
        f.write('{"step": 300, "return": 1.0}\n{"step": 600, "retu\n')
    moon = str(root / "moon")  # a config.json naming an environment that is not registered
    run_files.write_json_atomic(os.path.join(moon, "config.json"), {**CONFIG.to_dict(),
                                                                    "env": "moon"})  # fmt: skip
    a_file = str(root / "a_file")
    open(a_file, "w").write("not a directory")
    corrupt = str(root / "corrupt")
    os.makedirs(corrupt)
    open(os.path.join(corrupt, "config.json"), "w").write('{"env": "hopper", "sac": 3}')
    metrics_dir = str(root / "metrics_dir")  # the same run, its metrics.jsonl a folder
    shutil.copytree(run, metrics_dir)
    os.remove(os.path.join(metrics_dir, "metrics.jsonl"))
    os.makedirs(os.path.join(metrics_dir, "metrics.jsonl"))
    loop = str(root / "loop")  # a symbolic link to itself
    os.symlink(loop, loop)
    unstarted = str(root / "unstarted")  # killed before config.json: a lock and no training
    os.makedirs(os.path.join(unstarted, "tensorboard"))
    return {"RUN": run, "BAD_METRICS": bad_metrics, "MOON": moon, "FILE": a_file,
            "CORRUPT": corrupt, "LOOP": loop, "UNSTARTED": unstarted,
            "METRICS_DIR": metrics_dir,
            "MISSING": str(root / "missing"), "ROOT": str(root)}  # fmt: skip


BIG = "99999999999999999999"
CASES = [
    (["train", "--env", "hoppr"], "unknown environment 'hoppr'"),
    (["train", "--algo", "td3"], "unknown algorithm 'td3'"),
    (["train", "--variant", "ood"], "hopper has no 'ood' task set"),
    (["train", "--env", "point_robot", "--task", "mass=2"], "point_robot's dynamics ignore mass"),
    (["train", "--env", "point_robot", "--variant", "slope"], "dynamics ignore slope"),
    (["train", "--alpha=-1"], "expected a finite number >= 0"),
    (["train", "--alpha", "1e39"], "float32"),
    (["train", "--alpha", "nan"], "expected a finite number"),
    (["train", "--steps", "0"], "expected a positive integer"),
    (["train", "--steps", "ten"], "expected a positive integer"),
    (["train", "--seed", BIG], "seed"),
    (["train", "--seed", "-1"], "expected an integer >= 0"),
    (["train", "--variant", "moon"], "unknown variant 'moon'"),
    (["train", "--set", "ma.nope=1"], "unknown"),
    (["train", "--set", "sac.hidden=abc"], "sac.hidden"),
    (["train", "--set", "ma.alpha"], "group.field=value"),
    # declared admissible values (minatt_jax.fields), one line naming the field
    (["train", "--set", "physics=bogus"], "physics must be one of"),
    (["train", "--set", "sac.gamma=1.5"], "sac.gamma must be a finite number in [0, 1)"),
    (["train", "--set", "sac.actor_lr=-0.001"], "sac.actor_lr must be a finite number in [0, 1]"),
    # a step size past any sane value (it used to train to a loss of 1e21 and exit 0)
    (["train", "--set", "sac.actor_lr=1e3"], "sac.actor_lr must be a finite number in [0, 1]"),
    (["train", "--algo", "ppo", "--set", "ppo.lr=2"], "ppo.lr must be a finite number in (0, 1]"),
    # a network far too large for memory: measured from shapes, refused before allocating
    (
        ["train", "--preset", "smoke", "--set", "sac.hidden=200000,200000", "--out", "{MISSING}"],
        "these settings need",
    ),
    (["train", "--out", "{LOOP}"], "symbolic link that leads nowhere"),
    (["train", "--seeds", "0-1", "--out", "{LOOP}"], "symbolic link that leads nowhere"),
    (["train", "--resume", "--out", "{UNSTARTED}"], "run the original command again"),
    (["train", "--set", "sac.hidden="], "sac.hidden must be at least 1 value"),
    (["train", "--set", "sac.hidden=0"], "sac.hidden must be at least 1 value"),
    (["train", "--set", "sac.batch_size=0"], "sac.batch_size must be an integer >= 1"),
    (
        ["train", "--algo", "mbpo", "--set", "mb.rollout_schedule=1,2"],
        "mb.rollout_schedule must be 4 values",
    ),
    (["train", "--set", "ma.alpha=nan"], "ma.alpha expects a finite number"),
    (["train", "--seeds", "", "--out", "{MISSING}"], "seeds is empty"),
    (["train", "--seeds", "0,0", "--out", "{MISSING}"], "seed 0 is given twice"),
    (["train", "--sweep", "env=hopper,bogus", "--out", "{MISSING}"], "unknown environment"),
    (
        ["train", "--temporal", "rollout", "--placement", "entropy", "--out", "{MISSING}"],
        "choose placement 'actor_loss'",
    ),
    (["train", "--temporal", "rollout", "--out", "{MISSING}"], "(the default)"),
    (["train", "--task", "mass=-1"], "mass"),
    (["train", "--task", "crippled=nojoint"], "nojoint"),
    (["train", "--task", "foo=1"], "unknown field 'foo'"),
    (["train", "--preset", "huge"], "invalid choice"),
    (["train", "--out", "{FILE}"], "not a directory"),
    (["train", "--out", "/proc/minatt-jax-run"], "cannot"),
    (["train", "--preset", "smoke", "--out", "{RUN}"], "already holds a run"),
    (["train", "--resume", "--out", "{MISSING}"], "does not exist"),
    (["train", "--resume"], "--resume needs --out"),
    (["train", "--resume", "--out", "{RUN}", "--env", "walker2d"], "other settings (env"),
    (["train", "--resume", "--out", "{RUN}", "--preset", "paper"], "drop --preset"),
    (["train", "--resume", "--out", "{RUN}", "--steps", "100"], "already at step 600"),
    (
        ["train", "--resume", "--out", "{RUN}", "--steps", "600", "--set", "sac.actor_lr=1e-3"],
        "already at its last",
    ),
    (["train", "--resume", "--out", "{CORRUPT}"], "config.json"),
    # read before anything is written: the new alpha must not reach config.json
    (
        ["train", "--resume", "--out", "{BAD_METRICS}", "--alpha", "0.5", "--steps", "900"],
        "line 2 is not a JSON",
    ),
    (["train", "--seeds", "0-3", "--seed", "1", "--out", "{MISSING}"], "--seeds"),
    (["train", "--seeds", "3-1", "--out", "{MISSING}"], "seeds"),
    (
        ["train", "--seeds", "0-1", "--coordinator", "localhost:1", "--out", "{MISSING}"],
        "go together",
    ),
    (
        [
            "train",
            "--seeds",
            "0-1",
            "--coordinator",
            "localhost:1",
            "--num-processes",
            "2",
            "--process-id",
            "2",
            "--out",
            "{MISSING}",
        ],
        "not below",
    ),
    (["train", "--distributed", "--out", "{MISSING}"], "a single run takes one"),
    (["train", "--sweep", "ma.alpha=", "--out", "{MISSING}"], "ma.alpha"),
    (["train", "--sweep", "ma.nope=1,2", "--out", "{MISSING}"], "ma.nope"),
    (["rollout", "--env", "hopper", "--steps", "10000000000"], "too large"),
    (["rollout", "--env", "hopper", "--seed", BIG], "seed"),
    (["rollout", "--env", "hopper", "--variant", "icy"], "unknown variant 'icy'"),
    (["rollout", "--env", "hopper", "--policy", "smart"], "invalid choice"),
    (["rollout", "--env", "hopper", "--out", "{FILE}/x.json"], "cannot write"),
    (["evaluate", "{MISSING}"], "does not exist"),
    (["evaluate", "{FILE}"], "is a file, not a run directory"),
    (["evaluate", "{ROOT}"], "no config.json"),
    (["evaluate", "{CORRUPT}"], "config.json"),
    (["evaluate", "{RUN}", "--variant", "icy"], "unknown variant 'icy'"),
    (["evaluate", "{RUN}", "--task", "mass=0"], "mass"),
    (["evaluate", "{RUN}", "--engine", "bullet"], "invalid choice"),
    (["evaluate", "{RUN}", "--episodes", "2000000000"], "ask for fewer episodes"),
    (["evaluate", "{MOON}"], "unknown environment 'moon'"),
    (["export", "{MOON}", "--out", "{ROOT}/moon.npz"], "unknown environment 'moon'"),
    (["analyze", "{MOON}", "--out", "{ROOT}/moon_report"], "unknown environment 'moon'"),
    (["meta-test", "{RUN}", "--variant", "icy"], "unknown variant 'icy'"),
    (["meta-test", "{MISSING}", "--variant", "mass"], "does not exist"),
    (["analyze", "{MISSING}", "--out", "{ROOT}/report"], "does not exist"),
    (["inspect", "{MISSING}"], "does not exist"),
    (["inspect", "{RUN}", "--step", "7"], "no checkpoint 7 in"),
    (["export", "{RUN}", "--out", "{ROOT}"], "is a directory"),
    (["export", "{RUN}", "--out", "/proc/policy.npz"], "cannot write"),
    (["export", "{MISSING}", "--out", "{ROOT}/p.npz"], "does not exist"),
    (["export", "{RUN}", "--out", "{RUN}/config.json"], "the run's own file"),
    (["export", "{RUN}", "--out", "{RUN}/policy_snapshots/x.npz"], "the run's own file"),
    (["analyze", "{RUN}", "--out", "{RUN}"], "the run's own directory"),
    (["analyze", "{RUN}", "{RUN}/", "--out", "{ROOT}/report"], "given twice"),
    # refused before the analysis, not after minutes of it
    (
        ["analyze", "{RUN}", "--maturation-steps", "300", "99999", "--out", "{ROOT}/report"],
        "maturation step 99999 is past the last policy snapshot",
    ),
    (["analyze", "{METRICS_DIR}", "--out", "{ROOT}/report"], "Is a directory"),
]


@pytest.mark.parametrize("argv, message", CASES, ids=[" ".join(a) for a, _ in CASES])
def test_bad_input_is_one_line_and_exit_2(paths, argv, message, capsys):
    argv = [a.format(**paths) for a in argv]
    before = digest(paths["ROOT"])
    try:
        status = main(argv)
    except SystemExit as e:  # argparse
        status = e.code
    err = capsys.readouterr().err
    assert status == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("minatt-jax: error:"), err
    assert message in lines[0]
    assert digest(paths["ROOT"]) == before  # nothing already written was changed


@pytest.mark.parametrize("episodes", [0, -1, 2.5, True])
def test_the_python_api_refuses_an_evaluation_of_no_episodes(paths, episodes):
    from minatt_jax import api, runner

    with pytest.raises(runner.RunError, match="episodes must be a positive integer"):
        api.load_run(str(paths["RUN"])).evaluate(episodes=episodes)


def test_meta_test_into_a_read_only_run_is_refused_before_any_work(paths, monkeypatch, capsys):
    """A run directory the user cannot write into (simulated: tests may run as root, whom
    permissions do not stop) is refused at once, not after the meta-test's minutes of work."""
    import os as os_module

    real = os_module.access
    monkeypatch.setattr(os_module, "access", lambda p, mode: False if p == paths["RUN"]
                        and mode == os_module.W_OK else real(p, mode))  # fmt: skip
    before = digest(paths["ROOT"])
    status = main(["meta-test", paths["RUN"], "--variant", "mass"])
    err = capsys.readouterr().err
    assert status == 2 and len(err.strip().splitlines()) == 1
    assert "not writable; give --out DIR" in err and digest(paths["ROOT"]) == before
