"""The MuJoCo C engine evaluation (Gymnasium v5) and the numpy-only policy export.

Run directories here hold a config and an untrained policy snapshot (a random actor with a
non-trivial observation normalizer): what is tested is the plumbing (perturbations written into
the C model, rewards and episode ends, the metrics, the exported file), not learning.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import minatt_jax.envs as envs
from minatt_jax import checkpoint, mujoco_engine, run_files
from minatt_jax import normalizer as obs_norm
from minatt_jax.agents.sac import learner
from minatt_jax.cli import main
from minatt_jax.config import PRESETS, resolve, with_overrides
from minatt_jax.training import hyper_of

pytest.importorskip("imageio", reason="the mujoco-engine extra (imageio) is not installed")

STEPS = {"hopper": 60, "halfcheetah": 20}  # the cheetah is chaotic: float32 rounding shows later
TASKS = {"hopper": "mass=1.5,slope=0.1", "halfcheetah": "crippled=bthigh+bshin,friction=0.7"}


def _make_run(tmp_path, env_name: str, normalize: bool = True) -> str:
    """A run directory with an untrained policy snapshot at step 0."""
    config = resolve(with_overrides(PRESETS["smoke"], env=env_name, sac_normalize_obs=normalize,
                                    max_episode_steps=STEPS[env_name]))  # fmt: skip
    run_dir = str(tmp_path / env_name)
    run_files.write_json_atomic(os.path.join(run_dir, "config.json"), config.to_dict())
    env = envs.make(env_name)
    agent = learner(config, env)
    actor = agent.init(jax.random.PRNGKey(3), hyper_of(config)).actor_params
    # Large weights so the random policy's actions are far from zero.
    actor = jax.tree.map(lambda x: 2.0 * x, actor)
    rng = np.random.default_rng(0)
    obs = rng.normal(0.3, 6.0, (50, env.observation_size)).astype(np.float32)
    norm = obs_norm.update(obs_norm.init_normalizer(env.observation_size), jnp.asarray(obs))
    checkpoint.save_policy_snapshot(run_dir, 0, actor, norm)
    return run_dir


@pytest.mark.parametrize("env_name", ["hopper", "halfcheetah"])
def test_task_written_into_the_c_model_matches_mjx(env_name):
    """The perturbed C model (Gymnasium's) has the MJX model's fields under the same task,
    including the mass-derived constants MuJoCo's mj_setConst computes."""
    env = envs.make(env_name)
    task, _ = envs.parse_task(env, "mass=1.3,friction=0.8,gravity=1.1,slope=0.1")
    task = task.replace(actuator_scale=task.actuator_scale.at[0].set(0.0))
    gym_env = mujoco_engine.make_gym_env(env_name, 10, task)
    c_model = gym_env.unwrapped.model
    mjx_model = envs.apply_task(env.mjx_model, env.nominal_fields, task)
    for field in ("body_mass", "body_inertia", "geom_friction", "actuator_gainprm",
                  "body_subtreemass", "body_invweight0", "dof_invweight0"):  # fmt: skip
        np.testing.assert_allclose(getattr(c_model, field), np.asarray(getattr(mjx_model, field)),
                                   rtol=2e-5, atol=1e-6, err_msg=field)  # fmt: skip
    np.testing.assert_allclose(c_model.opt.gravity, mjx_model.opt.gravity, rtol=1e-6)
    assert c_model.actuator_gainprm[0, 0] == 0.0
    nominal = mujoco_engine.make_gym_env(env_name, 10).unwrapped.model
    assert c_model.body_mass[1] == pytest.approx(1.3 * nominal.body_mass[1])


def _independent_episode(env_name, policy_fn, seed, steps, perturb):
    """An episode written without minatt-jax's engine code: gymnasium, the numpy policy and the
    perturbation applied by hand to the C model. Returns (return, observations, actions)."""
    import gymnasium

    env = gymnasium.make(mujoco_engine.GYMNASIUM_IDS[env_name], max_episode_steps=steps)
    perturb(env.unwrapped.model)
    obs, _ = env.reset(seed=seed)
    total, seen, actions = 0.0, [], []
    for _ in range(steps):
        u = policy_fn(obs)
        seen.append(obs)
        obs, reward, terminated, truncated, _ = env.step(u.astype(np.float64))
        total += reward
        actions.append(u)
        if terminated or truncated:
            break
    return total, np.asarray(seen), np.asarray(actions)


def _feedback_by_differences(policy, obs: np.ndarray, eps: float = 1e-3) -> float:
    """||du/dx||_F^2 at ``obs`` by central differences, x the normalized observation the policy
    reads (a step eps in x is eps * std in the observation while the clip is inactive)."""
    x = (obs - policy.obs_mean) / policy.obs_std
    assert np.all(np.abs(x) < 10)
    total = 0.0
    for j in range(len(obs)):
        d = np.zeros_like(obs)
        d[j] = eps * policy.obs_std[j]
        total += float(np.sum(np.square((policy(obs + d) - policy(obs - d)) / (2 * eps))))
    return total


def _hopper_perturb(model):  # mass=1.5,slope=0.1 by hand
    model.body_mass[:] *= 1.5
    model.body_inertia[:] *= 1.5
    g = np.linalg.norm(model.opt.gravity)
    model.opt.gravity[:] = [-g * np.sin(0.1), 0.0, -g * np.cos(0.1)]
    mujoco.mj_setConst(model, mujoco.MjData(model))


def _cheetah_perturb(model):  # crippled=bthigh+bshin,friction=0.7 by hand
    for joint in ("bthigh", "bshin"):
        act = [a for a in range(model.nu) if model.actuator_trnid[a, 0] == model.joint(joint).id]
        model.actuator_gainprm[act, 0] = 0.0
    model.geom_friction[:] *= 0.7


@pytest.mark.parametrize("env_name", ["hopper", "halfcheetah"])
def test_c_engine_evaluation_matches_an_independent_rollout(tmp_path, env_name, capsys):
    """`evaluate --engine mujoco` (nominal and one perturbation) equals episodes written by hand
    with gymnasium and the exported numpy policy; its feedback norm equals a finite difference."""
    from minatt_jax.numpy_policy import load_policy

    run_dir = _make_run(tmp_path, env_name)
    out = str(tmp_path / "policy.npz")
    assert main(["export", run_dir, "--out", out]) == 0
    numpy_policy = load_policy(out)
    perturb = {"hopper": _hopper_perturb, "halfcheetah": _cheetah_perturb}[env_name]
    for task_args, fix in (([], lambda m: None), (["--task", TASKS[env_name]], perturb)):
        capsys.readouterr()
        argv = ["evaluate", run_dir, "--engine", "mujoco", "--episodes", "2", "--seed", "5",
                "--json", *task_args]  # fmt: skip
        assert main(argv) == 0
        metrics = json.loads(capsys.readouterr().out)
        assert metrics["engine"] == "mujoco" and metrics["episodes"] == 2
        returns, lengths, energies, feedback = [], [], [], []
        for i in range(2):
            ret, seen, actions = _independent_episode(
                env_name, numpy_policy, 5 + i, STEPS[env_name], fix
            )
            returns.append(ret)
            lengths.append(len(actions))
            energies.append(np.mean(np.sum(actions**2, -1)))
            feedback.append(np.mean([_feedback_by_differences(numpy_policy, o) for o in seen]))
        assert metrics["length"] == pytest.approx(np.mean(lengths))
        assert metrics["return"] == pytest.approx(np.mean(returns), rel=1e-4, abs=1e-3)
        assert metrics["energy"] == pytest.approx(np.mean(energies), rel=1e-4)
        assert metrics["energy"] > 0.05  # the policy acts (a zero policy would pass trivially)
        assert metrics["feedback_norm"] == pytest.approx(np.mean(feedback), rel=1e-2)


def test_export_round_trip_without_jax(tmp_path):
    """The exported policy's actions equal the JAX policy's, in a process where importing JAX
    fails; bad uses of `export` and `--engine` are one-line errors."""
    run_dir = _make_run(tmp_path, "hopper")
    out = str(tmp_path / "p.npz")
    assert main(["export", run_dir, "--out", out]) == 0
    policy = checkpoint.load_policy(run_dir)
    obs = np.random.default_rng(2).normal(0.0, 3.0, (16, 11)).astype(np.float32)
    expected = np.asarray(jax.vmap(policy.control)(jnp.asarray(obs)))
    np.save(tmp_path / "obs.npy", obs)
    script = (
        "import sys, numpy as np\n"
        "sys.modules['jax'] = None\n"  # any import of jax now raises ImportError
        "from minatt_jax.numpy_policy import load_policy\n"
        f"p = load_policy({out!r})\n"
        f"np.save({str(tmp_path / 'act.npy')!r}, p(np.load({str(tmp_path / 'obs.npy')!r})))\n"
        "assert 'jax' not in [m.split('.')[0] for m in sys.modules if sys.modules[m]]\n"
    )
    subprocess.run([sys.executable, "-c", script], check=True)
    actions = np.load(tmp_path / "act.npy")
    np.testing.assert_allclose(actions, expected, rtol=1e-5, atol=1e-6)
    meta = __import__("minatt_jax.numpy_policy").numpy_policy.load_policy(out).metadata
    assert meta["env"] == "hopper" and meta["obs_dim"] == 11 and meta["normalize_obs"]
    # Errors: a directory as --out, a missing step, a run without a C-engine counterpart.
    assert main(["export", run_dir, "--out", str(tmp_path)]) == 2
    assert main(["export", str(tmp_path / "nope"), "--out", out]) == 2
    with pytest.raises(ValueError, match="not a readable policy file"):
        __import__("minatt_jax.numpy_policy").numpy_policy.load_policy(str(tmp_path / "obs.npy"))
