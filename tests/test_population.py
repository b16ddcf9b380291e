"""Populations: members in one program, equal to single runs, refits when due, resume, devices."""

from __future__ import annotations

import collections
import json
import os
import shutil
import socket
import subprocess
import sys

import jax
import numpy as np
import pytest
from conftest import digest

from minatt_jax import checkpoint, population, runner
from minatt_jax import training as train_module
from minatt_jax.agents.base import with_hyper
from minatt_jax.cli import main
from minatt_jax.config import PRESETS, resolve, with_overrides
from minatt_jax.training import hyper_of

ONE_CHUNK = with_overrides(PRESETS["smoke"], total_steps=300)


def test_members_and_groups():
    members = population.expand(ONE_CHUNK, [0, 1, 2], ["ma.alpha=0,0.5,1"])
    assert len(members) == 9 and {m.seed for m in members} == {0, 1, 2}
    assert sorted({m.ma.alpha for m in members}) == [0.0, 0.5, 1.0]
    assert population.groups(members) == [list(range(9))]  # data fields only: one program
    shapes = population.expand(ONE_CHUNK, [0, 1], ["sac.hidden=(32,32),(64,64)", "ma.alpha=0,1"])
    assert [len(g) for g in population.groups(shapes)] == [4, 4]  # a shape field: two programs
    names = {population.member_name(m, ["sac.hidden", "ma.alpha"]) for m in shapes}
    assert "sac_hidden(64,64)_alpha1_seed1" in names and len(names) == 8
    # Values that print alike at 6 digits keep their own names (and directories).
    close = population.expand(ONE_CHUNK, [0], ["ma.alpha=0.1234567,0.1234568,0.05"])
    names = [population.member_name(m, ["ma.alpha"]) for m in close]
    assert names == ["sac_alpha0.1234567_seed0", "sac_alpha0.1234568_seed0", "sac_alpha0.05_seed0"]
    assert population.parse_seeds("0-3,7") == [0, 1, 2, 3, 7]
    for bad in ("a-b", "3-1", "-1", "", "0-3,7,2", "1,1"):  # a repeated seed would be lost
        with pytest.raises(ValueError, match="seed"):
            population.parse_seeds(bad)


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--seeds", "0-1", "--seed", "3"], "a population takes --seeds"),
        (["--seeds", "x"], "seeds must look like"),
        (["--sweep", "ma.alpha"], "must look like group.field=v1,v2"),
        (["--sweep", "ma.alpah=0,1"], "unknown setting 'ma.alpah'"),
        (["--sweep", "ma.alpha=0,-1"], "ma.alpha must be a finite number >= 0"),
        (["--sweep", "seed=0,1"], "seeds are set with --seeds"),
    ],
)
def test_population_bad_input_exit_2(argv, message, capsys, tmp_path):
    status = main(["train", "--preset", "smoke", "--out", str(tmp_path / "pop"), *argv])
    err = capsys.readouterr().err
    assert status == 2 and message in err and len(err.strip().splitlines()) == 1
    assert main(["train", "--preset", "smoke", "--seeds", "0-1"]) == 2
    assert "needs --out" in capsys.readouterr().err


@pytest.mark.slow
def test_a_member_equals_its_single_run_and_sweeps_do_not_recompile():
    members = population.expand(ONE_CHUNK, [0, 1], ["ma.alpha=0,1"])
    program = population.Program(members)
    states, metrics = program.chunk(program.init())
    compiled = program.chunk._cache_size()  # 1, or more where this process ran other shapes
    alone = train_module.make_train(resolve(members[0]))  # alpha 0, seed 0, no MA terms at all
    single, single_metrics = alone.train_chunk(
        alone.init(jax.random.PRNGKey(0), hyper_of(alone.config))
    )
    for key in ("critic_loss", "actor_loss", "q_mean", "train_episode_return"):
        np.testing.assert_allclose(metrics[key][0], single_metrics[key], rtol=1e-4, err_msg=key)
    np.testing.assert_allclose(
        jax.tree.leaves(states.agent.actor_params)[0][0],
        jax.tree.leaves(single.agent.actor_params)[0], rtol=1e-4, atol=1e-6,
    )  # fmt: skip
    assert float(metrics["ma_feedback"][3]) > 0  # alpha 1 members are regularized
    assert not np.allclose(metrics["actor_loss"][0], metrics["actor_loss"][2])
    # Other swept values (MA weight, learning rates) are data: the same program runs them.
    values = population.stack(
        [hyper_of(with_overrides(m, ma_alpha=0.3, sac_actor_lr=1e-3)) for m in members]
    )
    other = jax.vmap(with_hyper)(program.init(), values)
    program.chunk(other)
    assert program.chunk._cache_size() == compiled


@pytest.mark.slow
def test_ma_modes_share_one_program_and_each_member_equals_its_single_run():
    """Full / Jacobian-only / temporal-only / none are data (0/1 term weights): one program for
    all four, computing both terms, and each member trains as its mode's own program does
    (which computes only its terms)."""
    modes = ["full", "jacobian", "temporal", "none"]
    members = population.expand(with_overrides(ONE_CHUNK, ma_alpha=1.0), [0],
                                [f"ma.mode={','.join(modes)}"])  # fmt: skip
    assert population.groups(members) == [[0, 1, 2, 3]]
    program = population.Program(members)
    assert program.config.ma.mode == "full"
    states, metrics = program.chunk(program.init())
    assert program.chunk._cache_size() == 1
    for i in (1, 2):  # single-term modes (full and alpha-0 members: the test above)
        alone = train_module.make_train(resolve(members[i]))
        single, single_metrics = alone.train_chunk(
            alone.init(jax.random.PRNGKey(0), hyper_of(alone.config))
        )
        for key in ("critic_loss", "actor_loss", "train_episode_return"):
            np.testing.assert_allclose(metrics[key][i], single_metrics[key], rtol=1e-4,
                                       err_msg=f"{modes[i]}: {key}")  # fmt: skip
        np.testing.assert_allclose(
            jax.tree.leaves(states.agent.actor_params)[0][i],
            jax.tree.leaves(single.agent.actor_params)[0], rtol=1e-4, atol=1e-6,
            err_msg=modes[i],
        )  # fmt: skip
    # The modes do differ: the penalty each member pays is its own.
    penalties = np.asarray(metrics["ma_penalty"])
    assert penalties[3] == 0 and len(set(np.round(penalties[:3], 6))) == 3


@pytest.mark.slow
def test_model_refits_run_only_when_due_in_a_population(monkeypatch):
    calls = []
    from minatt_jax import acting
    from minatt_jax.agents import mbpo

    real_make = mbpo.make_ensemble

    def counting(*args, **kwargs):
        ensemble = real_make(*args, **kwargs)

        def fit(*a, **k):
            jax.debug.callback(lambda: calls.append(1))
            return ensemble.fit(*a, **k)

        return ensemble._replace(fit=fit)

    monkeypatch.setattr(mbpo, "make_ensemble", counting)
    resets = []
    real_reset = acting.reset_with_tasks

    def counting_reset(*args):
        jax.debug.callback(lambda: resets.append(1))
        return real_reset(*args)

    monkeypatch.setattr(acting, "reset_with_tasks", counting_reset)
    monkeypatch.setattr(runner, "_TRAINERS", collections.OrderedDict())  # build with the counters
    members = population.expand(with_overrides(ONE_CHUNK, algo="mbpo"), [0, 1, 2], [])
    program = population.Program(members)
    state = program.init()
    jax.effects_barrier()
    resets.clear()  # the initial reset
    _, metrics = program.chunk(state)
    jax.effects_barrier()
    # Resets run only at steps where some member's episode ended (the predicate is taken over
    # the members: acting.collect_step's members_axis), at most once per ended episode; as a
    # select under vmap they would run at all 300 steps.
    ended = int(np.sum(metrics["train_episodes"]) + np.sum(metrics["env_non_finite_resets"]))
    assert 1 <= len(resets) <= ended < 300
    # Warm-up ends at 200, refits every 100 steps: at 200 and 300, each time once for all three
    # members together (the callback takes no per-member argument, so vmap calls it once per
    # execution of the branch). Had the schedule's cond become a select under vmap, the fit
    # branch would have run at all 300 steps.
    np.testing.assert_array_equal(metrics["model_fits"], [2, 2, 2])
    assert len(calls) == 2


def _cut_largest_file(folder: str) -> None:
    """Cuts the largest file under ``folder`` to half its length (a damaged checkpoint)."""
    files = [os.path.join(b, f) for b, _, fs in os.walk(folder) for f in fs]
    path = max(files, key=os.path.getsize)
    os.truncate(path, os.path.getsize(path) // 2)


@pytest.mark.slow
def test_population_resume_is_exact_and_sharding_over_two_devices(tmp_path):
    base = ["train", "--preset", "smoke", "--seeds", "0-1", "--sweep", "ma.alpha=0,1"]
    straight, split = str(tmp_path / "straight"), str(tmp_path / "split")
    assert main([*base, "--out", straight]) == 0
    assert main([*base, "--steps", "300", "--out", split]) == 0
    assert main(["train", "--out", split, "--resume", "--steps", "600"]) == 0
    names = sorted(d for d in os.listdir(straight) if d not in ("population.json", ".lock"))
    assert names == ["sac_alpha0_seed0", "sac_alpha0_seed1", "sac_alpha1_seed0",
                     "sac_alpha1_seed1"]  # fmt: skip
    # A population already at its length: nothing restored or compiled, nothing rewritten.
    members = [runner.load_config(os.path.join(split, n)) for n in names]
    before = [runner.read_metrics(os.path.join(split, n)) for n in names]
    lines: list[str] = []
    population.train_in_stages(members, split, ["ma.alpha"], [300, 600], log=lines.append)
    assert lines[1::2] == ["4 members already at env step 600"] * 2
    assert not [line for line in lines if "compiled" in line]
    assert [runner.read_metrics(os.path.join(split, n)) for n in names] == before
    for name in names:
        a = runner.read_metrics(os.path.join(straight, name))
        b = runner.read_metrics(os.path.join(split, name))
        assert [r["step"] for r in a] == [300, 600]
        assert runner.without_timings(a) == runner.without_timings(b)
    # A stop while the population saved: one member lacks checkpoint 600. The resume goes on
    # from 300 for every member, sets the others' 600 aside and ends where the straight run did.
    torn = str(tmp_path / "torn")
    shutil.copytree(split, torn)
    shutil.rmtree(os.path.join(torn, names[1], "checkpoints", "600"))
    lines = []
    population.train_in_stages(members, torn, ["ma.alpha"], [600], log=lines.append)
    assert any("resumes from checkpoint 300" in line for line in lines)
    for name in names:
        assert checkpoint.latest_step(os.path.join(torn, name)) == 600
        ours, straight_run = (runner.read_metrics(os.path.join(f, name)) for f in (torn, straight))
        assert runner.without_timings(ours) == runner.without_timings(straight_run)
    assert os.listdir(os.path.join(torn, names[0], "checkpoints_ahead"))
    # One member's newest checkpoint damaged (half of its largest file cut): the resume reads
    # every member's checkpoints before it writes anything, and every member goes on from 300.
    damaged = str(tmp_path / "damaged")
    shutil.copytree(split, damaged)
    _cut_largest_file(os.path.join(damaged, names[0], "checkpoints", "600"))
    lines = []
    longer = [with_overrides(m, total_steps=900) for m in members]
    population.train_population(longer, damaged, ["ma.alpha"], resume=True, log=lines.append)
    assert any("sac_alpha0_seed0: checkpoint 600 is unreadable" in line for line in lines)
    for name in names:
        ours = runner.without_timings(runner.read_metrics(os.path.join(damaged, name)))
        straight_run = runner.without_timings(runner.read_metrics(os.path.join(straight, name)))
        assert [r["step"] for r in ours] == [300, 600, 900] and ours[:2] == straight_run
    # No step readable by all: refused in one line before anything is written or compiled.
    _cut_largest_file(os.path.join(damaged, names[0], "checkpoints", "600"))
    _cut_largest_file(os.path.join(damaged, names[0], "checkpoints", "900"))
    before = digest(damaged)
    refused = subprocess.run([sys.executable, "-m", "minatt_jax.cli", "train", "--out", damaged,
                              "--resume", "--steps", "1200"], capture_output=True, text=True,
                             timeout=600)  # fmt: skip
    assert refused.returncode == 2, refused.stderr
    assert refused.stderr.strip().splitlines() == [refused.stderr.strip()]
    assert "no checkpoint step common to all members reads back" in refused.stderr
    assert "compiled the" not in refused.stdout and digest(damaged) == before
    # The same population with its members split over two (forced host) devices.
    sharded = str(tmp_path / "sharded")
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2"}
    subprocess.run([sys.executable, "-m", "minatt_jax.cli", *base, "--steps", "300", "--out",
                    sharded], env=env, check=True, capture_output=True, timeout=900)  # fmt: skip
    _assert_same_members(straight, sharded, names)


@pytest.mark.slow
@pytest.mark.extended  # three more processes compiling (4 min on 2 cores): pytest -m extended
def test_population_over_two_processes_equals_one_device(tmp_path):
    """The same population over two processes (jax.distributed, one CPU device each): each
    trains the two members a forced two-device run puts on its device."""
    base = ["train", "--preset", "smoke", "--seeds", "0-1", "--sweep", "ma.alpha=0,1",
            "--steps", "300"]  # fmt: skip
    one_device = str(tmp_path / "one_device")
    assert main([*base, "--out", one_device]) == 0
    names = sorted(d for d in os.listdir(one_device) if d.startswith("sac_"))
    assert len(names) == 4
    processes = str(tmp_path / "processes")
    with socket.socket() as s:
        s.bind(("localhost", 0))
        port = s.getsockname()[1]
    procs = [
        subprocess.Popen([sys.executable, "-m", "minatt_jax.cli", *base,
                          "--out", processes, "--coordinator", f"localhost:{port}",
                          "--num-processes", "2", "--process-id", str(rank)],
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        for rank in (0, 1)
    ]  # fmt: skip
    outputs = [p.communicate(timeout=900)[0] for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outputs[0][-2000:] + outputs[1][-2000:]
    assert "2 members (process 2/2)" in outputs[1]
    with open(os.path.join(processes, "population.json")) as f:
        assert json.load(f)["processes"] == 2
    _assert_same_members(one_device, processes, names)


def _assert_same_members(one_device: str, other: str, names: list[str]) -> None:
    """Members' first records equal those of the one-device population (float tolerance)."""
    for name in names:
        a = runner.read_metrics(os.path.join(one_device, name))[:1]
        b = runner.read_metrics(os.path.join(other, name))
        assert len(b) == 1
        for key in ("return", "feedback_norm", "critic_loss", "energy"):
            # Two members per device (or process) instead of four on one: XLA's CPU kernels
            # order float sums differently for other batch sizes, and the updates compound it
            # (measured: up to 2.2e-3 relative at 600 steps). A wrong member-to-device mapping
            # would differ by far more (other seeds and alphas: 10-100%).
            assert a[0][key] == pytest.approx(b[0][key], rel=2e-2), (name, key)


def test_a_population_that_cannot_fit_is_refused_before_compiling(monkeypatch, capsys, tmp_path):
    monkeypatch.setattr(population.memory, "available_bytes", lambda: 64 * 2**20)  # a 64 MiB device
    argv = ["train", "--preset", "cpu", "--seeds", "0-3", "--out", str(tmp_path / "pop")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "4 members need about" in err and "--set buffer_size" in err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "pop").exists()


def test_after_group_sees_each_group_once_its_training_returned(monkeypatch, tmp_path):
    """``after_group`` gets each group's run directories, in order, right after that group's
    training: a hook that keeps results then has only finished members to keep."""
    trained: list[list[str]] = []

    def fake_group(program, dirs, *rest):
        trained.append(dirs)
        return [{} for _ in dirs]

    monkeypatch.setattr(population, "_train_group", fake_group)
    swept = ["ma.alpha", "ma.placement"]
    members = population.expand(
        ONE_CHUNK, [0, 1], ["ma.alpha=0,1", "ma.placement=actor_loss,entropy"]
    )
    out = str(tmp_path / "pop")
    seen: list[tuple[int, list[str]]] = []

    def after_group(dirs: list[str]) -> None:
        seen.append((len(trained), dirs))

    population.train_population(members, out, swept, log=lambda _: None, after_group=after_group)
    assert len(population.groups(members)) == 2 and len(seen) == 2
    assert seen == [(g + 1, dirs) for g, dirs in enumerate(trained)]
    assert sorted(d for _, dirs in seen for d in dirs) == sorted(
        os.path.join(out, population.member_name(c, swept)) for c in members
    )


def test_a_locked_population_is_refused_before_anything_is_written(monkeypatch, tmp_path):
    """A second process on a population being trained neither creates members nor rewrites a
    resumed member's length: the lock is taken before the population's files are touched."""
    monkeypatch.setattr(population, "_train_group", lambda program, dirs, *a: [{} for _ in dirs])
    members = population.expand(ONE_CHUNK, [0, 1], [])
    out = str(tmp_path / "pop")
    population.train_population(members, out, [], log=lambda _: None)  # files only: no training
    config_path = os.path.join(out, population.member_name(members[0], []), "config.json")
    with open(config_path) as f:
        written = f.read()
    longer = [with_overrides(m, total_steps=600) for m in members]
    with population.run_guard.lock_run(out):
        with pytest.raises(runner.RunError, match="another process"):
            population.train_population(longer, out, [], resume=True, log=lambda _: None)
        fresh = str(tmp_path / "fresh")
        with population.run_guard.lock_run(fresh):
            with pytest.raises(runner.RunError, match="another process"):
                population.train_population(members, fresh, [], log=lambda _: None)
            assert sorted(os.listdir(fresh)) == [".lock"]  # the refused population wrote nothing
        assert not os.path.exists(fresh)  # and the lock's own folder went with the lock
    with open(config_path) as f:
        assert f.read() == written
    population.train_population(longer, out, [], resume=True, log=lambda _: None)
    with open(config_path) as f:
        assert json.load(f)["total_steps"] == 600  # unlocked, the length changes as before
    more = population.expand(ONE_CHUNK, [0, 1, 2], [])  # another member: said, nothing written
    with pytest.raises(runner.RunError, match="started without sac_seed2: a resume goes on"):
        population.train_population(more, out, [], resume=True, log=lambda _: None)
    assert not os.path.exists(os.path.join(out, population.member_name(more[2], [])))


def test_a_trained_population_resumes_without_the_memory_its_training_needs(monkeypatch, tmp_path):
    """Tabulating or meta-testing a finished population must not be refused for memory that only
    training needs; extending it still is."""
    # The first test's population: its program comes from the compilation cache.
    members = population.expand(ONE_CHUNK, [0, 1], ["ma.alpha=0,1"])
    out = str(tmp_path / "pop")
    population.train_population(members, out, ["ma.alpha"], log=lambda _: None)
    monkeypatch.setattr(population.memory, "available_bytes", lambda: 2**20)  # a 1 MiB device
    population.train_population(members, out, ["ma.alpha"], resume=True, log=lambda _: None)
    longer = [with_overrides(m, total_steps=2 * m.total_steps) for m in members]
    with pytest.raises(runner.RunError, match="members need about"):
        population.train_population(longer, out, ["ma.alpha"], resume=True, log=lambda _: None)
