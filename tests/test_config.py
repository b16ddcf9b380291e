"""Config in one place: dotted overrides typed from the dataclasses, resolve, custom tasks."""

from __future__ import annotations

import dataclasses
import os

import jax
import numpy as np
import pytest

import minatt_jax.envs as envs
from minatt_jax.cli import main
from minatt_jax.config import (
    PRESETS,
    OverrideError,
    TrainConfig,
    apply_overrides,
    replace_fields,
    resolve,
    with_overrides,
)
from minatt_jax.training import program_key


def test_dotted_overrides_are_typed_from_the_annotations():
    c = apply_overrides(
        PRESETS["smoke"],
        [
            "ma.alpha=0.5",
            "algo=mbmpo",  # first, whatever its place: mb.* and model.* are mbmpo's settings
            "mb.meta_inner_lr=1e-3",
            "seed=7",
            "sac.normalize_obs=true",
            "sac.hidden=64,64",
            "mb.rollout_schedule=(0, 5, 1, 4)",
            "model.num_elites=none",
            "ma.placement=reward",
        ],
    )
    assert c.ma.alpha == 0.5 and isinstance(c.ma.alpha, float)
    assert c.mb.meta_inner_lr == 1e-3 and c.seed == 7 and isinstance(c.seed, int)
    assert c.sac.normalize_obs is True and c.sac.hidden == (64, 64)
    assert c.mb.rollout_schedule == (0, 5, 1, 4) and c.model.num_elites is None
    assert c.ma.placement == "reward"
    # The keyword form for code sets the same fields.
    assert with_overrides(
        PRESETS["smoke"], algo="mbmpo", ma_alpha=0.5, mb_meta_inner_lr=1e-3
    ).ma == (apply_overrides(PRESETS["smoke"], ["ma.alpha=0.5"]).ma)


@pytest.mark.parametrize(
    "override, message",
    [
        ("ma.alpah=1", "unknown setting 'ma.alpah'"),
        ("foo.alpha=1", "unknown setting 'foo.alpha'"),
        ("alpha=1", "unknown setting 'alpha'"),
        ("ma=1", "unknown setting 'ma'"),
        ("ma.alpha=abc", "ma.alpha expects a finite number"),
        ("ma.alpha=inf", "ma.alpha expects a finite number"),
        ("seed=1.5", "seed expects an integer"),
        ("sac.normalize_obs=maybe", "expects true or false"),
        ("ma.alpha", "must look like group.field=value"),
    ],
)
def test_bad_overrides_name_the_problem(override, message):
    with pytest.raises(OverrideError, match=message.replace("(", r"\(")):
        apply_overrides(PRESETS["smoke"], [override])


def test_resolve_fills_every_derived_default_once():
    sac = resolve(PRESETS["cpu"])
    assert (sac.task_set, sac.updates_per_step, sac.ma.placement) == ("nominal", 1, "entropy")
    assert (
        sac.ma.temporal_dt == 1.0 and sac.is_resolved and sac.group_names == ("ma", "caps", "sac")
    )
    assert resolve(with_overrides(PRESETS["cpu"], algo="mbpo")).model.num_elites == 5
    mbmpo = resolve(with_overrides(PRESETS["cpu"], algo="mbmpo", model_ensemble_size=3))
    assert (mbmpo.task_set, mbmpo.updates_per_step, mbmpo.model.num_elites) == ("train", 2, 3)
    assert resolve(mbmpo) == mbmpo  # idempotent
    explicit = resolve(with_overrides(PRESETS["cpu"], algo="mbmpo", task_set="nominal"))
    assert explicit.task_set == "nominal"  # a given value is kept
    rollout = resolve(
        with_overrides(PRESETS["smoke"], ma_temporal="rollout", ma_placement="actor_loss")
    )
    assert rollout.ma.temporal_dt == pytest.approx(envs.make("hopper").dt)
    with pytest.raises(ValueError, match="rollout_batch"):
        resolve(with_overrides(PRESETS["smoke"], algo="mbpo", mb_rollout_batch=1))


def test_config_json_round_trip_and_the_previous_format():
    c = resolve(with_overrides(PRESETS["smoke"], algo="mbmpo", tasks=("mass=1.5",)))
    assert TrainConfig.from_dict(c.to_dict()) == c
    old = c.to_dict()
    old.pop("updates_per_step")
    old["mb"]["agent_updates_per_step"] = 3  # the field before "one concept, one field"
    assert TrainConfig.from_dict(old).updates_per_step == 3
    # MA's placement: the entropy-like reading by default (the reading study's choice); a run
    # written before the placement was recorded had MA in the actor loss
    assert c.ma.placement == "entropy"
    old["ma"]["placement"] = "reward"
    assert TrainConfig.from_dict(old).ma.placement == "reward"
    old["ma"].pop("placement")
    assert TrainConfig.from_dict(old).ma.placement == "actor_loss"


def test_the_format_in_which_every_run_held_every_group_still_loads():
    """Before agents owned their settings every config.json held sac, model, mb and dreamer;
    DreamerV3's and MAMBA's "entropy" placement applied MA in the actor loss alone; MAMBA's
    four fields sat in the dreamer group. Such files read back as what ran."""
    from minatt_jax.agents.mbpo import MBConfig
    from minatt_jax.dreamer.config import DreamerConfig
    from minatt_jax.dynamics_ensemble import ModelConfig
    from minatt_jax.sac import SACConfig

    legacy = {
        "sac": dataclasses.asdict(SACConfig()),
        "model": dataclasses.asdict(ModelConfig()),
        "mb": dataclasses.asdict(MBConfig()),
        "dreamer": dataclasses.asdict(DreamerConfig()),
    }
    sac = resolve(with_overrides(PRESETS["smoke"], ma_alpha=1.0))
    read = TrainConfig.from_dict({**legacy, **sac.to_dict()})
    assert read == sac and read.group_names == ("ma", "caps", "sac")
    mamba = resolve(with_overrides(PRESETS["smoke"], algo="mamba", env="point_robot"))
    old = {**legacy, **mamba.to_dict()}
    old["dreamer"] = {**old["dreamer"], **old.pop("mamba")}
    old["ma"]["placement"] = "entropy"
    read = TrainConfig.from_dict(old)
    assert read.mamba == mamba.mamba and read.dreamer == mamba.dreamer
    assert read.ma.placement == "actor_loss"
    dreamer = resolve(with_overrides(PRESETS["smoke"], algo="dreamer", ma_alpha=1.0))
    old = {**legacy, **dreamer.to_dict()}
    old["dreamer"] = {**old["dreamer"], "head_states": 0, "imag_starts": 0,
                      "wm_horizon_start": 0, "wm_horizon_full_at": 0}  # fmt: skip
    old["ma"]["placement"] = "entropy"
    assert TrainConfig.from_dict(old) == dreamer
    with pytest.raises(TypeError, match="unknown TrainConfig field or sac settings group 'td3'"):
        TrainConfig.from_dict({**sac.to_dict(), "td3": {}})


def test_every_committed_run_config_loads_with_its_values():
    """The run directories kept under experiments/records (350 runs, written before agents
    owned their settings) read back with every stored value unchanged."""
    import glob
    import json

    from minatt_jax import run_files

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    paths = glob.glob(os.path.join(root, "experiments/records/**/config.json"), recursive=True)
    assert len(paths) >= 300
    for path in paths:
        stored = json.load(open(path))
        read = json.loads(json.dumps(run_files.load_config(os.path.dirname(path)).to_dict()))
        for key, value in read.items():
            if isinstance(value, dict):
                assert {k: stored[key][k] for k in value if k in stored[key]} == {
                    k: v for k, v in value.items() if k in stored[key]
                }, (path, key)
            elif key in stored and stored[key] is not None:
                assert stored[key] == value, (path, key)


def test_custom_tasks_combine_fields(make_env):
    hopper = make_env("hopper")
    task, label = envs.parse_task(hopper, "mass=1.25, slope=0.12")
    expected = hopper.make_task(mass_scale=1.25, slope=0.12)
    for a, b in zip(jax.tree.leaves(task), jax.tree.leaves(expected), strict=True):
        np.testing.assert_allclose(a, b)
    assert label == "mass=1.25,slope=0.12"
    cheetah = make_env("halfcheetah")
    task, _ = envs.parse_task(cheetah, "crippled=bthigh+bshin,friction=0.5,gravity=0.9")
    assert list(np.asarray(task.actuator_scale)) == [0, 0, 1, 1, 1, 1]
    assert float(task.friction_scale) == 0.5 and float(task.gravity_scale) == pytest.approx(0.9)
    tasks, labels = envs.resolve_tasks(hopper, "mass", ["mass=2", "crippled=thigh_joint"])
    assert len(tasks) == 2 and labels == ["mass=2", "crippled=thigh_joint"]


@pytest.mark.parametrize(
    "spec, message",
    [
        ("mass=abc", "mass must be a number"),
        ("weight=2", "unknown field 'weight'"),
        ("mass", "expected field=value"),
        ("mass=-1", "must be finite and positive"),
        ("crippled=fthigh", "hopper has no actuated joint 'fthigh'"),
        ("slope=2", "slope must be in"),
        ("mass=1,mass=2", "given twice"),
    ],
)
def test_bad_custom_tasks_name_the_problem(spec, message, make_env):
    with pytest.raises(envs.TaskSpecError, match=message):
        envs.parse_task(make_env("hopper"), spec)


@pytest.mark.parametrize(
    "argv, message",
    [
        (["train", "--set", "ma.alpah=1"], "unknown setting 'ma.alpah'"),
        (["train", "--set", "ma.alpha=-1"], "ma.alpha must be a finite number >= 0"),
        (["train", "--algo", "mbmpo", "--set", "mb.meta_inner=adam"], "meta_inner must be"),
        (["train", "--set", "mb.meta_inner=vpg"], "mb.* is a setting of --algo mbpo / mbmpo"),
        (["train", "--task", "mass=abc"], "mass must be a number"),
        (["train", "--task", "crippled=nojoint"], "no actuated joint"),
        (["rollout", "--env", "hopper", "--task", "weight=2"], "unknown field"),
        (["evaluate", "/nonexistent", "--task", "mass=2"], "does not exist"),
    ],
)
def test_cli_config_errors_exit_2_with_one_line(argv, message, capsys, tmp_path):
    if argv[0] == "train":
        argv = [*argv, "--preset", "smoke", "--out", str(tmp_path / "run")]
    status = main(argv)
    err = capsys.readouterr().err
    assert status == 2 and message in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "run").exists()  # nothing written for a refused run


@pytest.mark.parametrize(
    "argv, message",
    [
        (["train", "--alpha", "1e39"], "overflows float32"),
        (["train", "--set", "ma.alpha=1e39"], "within float32's range"),
        (["train", "--seed", "99999999999999999999"], "too large"),
    ],
)
def test_values_beyond_float32_or_int32_are_refused(argv, message, capsys, tmp_path):
    try:  # argparse's own errors leave by SystemExit(2), ours by the returned status
        status = main([*argv, "--preset", "smoke", "--out", str(tmp_path / "run")])
    except SystemExit as e:
        status = e.code
    err = capsys.readouterr().err
    assert status == 2 and message in err and len(err.strip().splitlines()) == 1


def test_runs_share_a_program_exactly_when_only_hyper_values_differ():
    """The program key leaves out the agent's hyper fields, the seed and the length: runs that
    differ in those share one compiled program; anything else, MA's on/off and mode included
    (a single run computes its own terms alone), is another program."""
    base = resolve(with_overrides(PRESETS["smoke"], ma_alpha=1.0))
    key = program_key(base)
    same = {"seed": 7, "ma.alpha": 0.3, "total_steps": 9000, "sac.actor_lr": 1e-3,
            "sac.critic_lr": 2e-3, "sac.entropy_lr": 5e-4}  # fmt: skip
    for field, value in same.items():
        assert program_key(replace_fields(base, {field: value})) == key, field
    other = {"ma.alpha": 0.0, "ma.mode": "jacobian", "num_envs": 2, "eval_every": 150,
             "sac.batch_size": base.sac.batch_size + 1}  # fmt: skip
    for field, value in other.items():
        assert program_key(replace_fields(base, {field: value})) != key, field
    meta = resolve(with_overrides(base, algo="mbmpo"))
    assert program_key(with_overrides(meta, mb_meta_inner_lr=0.1)) == program_key(meta)
    # Population members are grouped without the MA structure: one program computes the union.
    assert program_key(replace_fields(base, {"ma.mode": "jacobian"}), ma_structure=False) == (
        program_key(base, ma_structure=False)
    )
