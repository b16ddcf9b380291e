# ---
# jupyter:
#   jupytext:
#     formats: ipynb,py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
#       format_version: '1.3'
#       jupytext_version: 1.19.7
# ---

# %% [markdown]
# # minatt-jax quickstart: SAC with minimum attention on Hopper
#
# Minimum attention (MA) penalizes how much a control law changes with state and time,
# alpha * (||du/dx||^2 + ||du/dt||^2). This notebook trains SAC on the MJX Hopper with and
# without MA, compares feedback norm, energy and return, and looks at a rollout.
#
# Runs on a CPU: the `SMOKE` setting (environment variable `MINATT_SMOKE=1`) takes about a
# minute; the full setting (20K steps per run) about 5 minutes per run on 2 cores. A GPU makes one
# run only about 1.5x faster (one agent is latency-bound); it pays with populations
# (`05_populations`).

# %% Install (Colab): the package, when it is not importable yet.
import importlib.util
import os
import subprocess
import sys

SOURCE = os.environ.get("MINATT_JAX_SOURCE", "")  # minatt-jax's source: git URL, path or wheel
if importlib.util.find_spec("minatt_jax") is None:
    if not SOURCE:
        raise RuntimeError("minatt_jax is not installed: set SOURCE to where its source lives")
    subprocess.check_call([sys.executable, "-m", "pip", "install", "-q", SOURCE])

# %% Parameters
SMOKE = os.environ.get("MINATT_SMOKE") == "1"
PRESET = "smoke" if SMOKE else "cpu"
STEPS = 600 if SMOKE else 20_000
OUT = os.environ.get("MINATT_OUT", "runs/notebooks")
ALPHAS = (0.0, 1.0)

# %% [markdown]
# ## Train: alpha = 0 (plain SAC) and alpha = 1
# `mj.train` writes an ordinary run directory (the same as `minatt-jax train`); progress updates
# in place. Running the cell again continues the runs from their checkpoints.

# %%
import minatt_jax as mj

runs = {}
for alpha in ALPHAS:
    out = f"{OUT}/quickstart_alpha{alpha:g}"
    done = os.path.exists(f"{out}/config.json")
    runs[alpha] = mj.train(preset=PRESET, env="hopper", ma_alpha=alpha, total_steps=STEPS,
                           out=out, resume=done)  # fmt: skip

# %% Learning curves
fig = mj.plot_curves(list(runs.values()), "return")
fig

# %% [markdown]
# ## Compare: feedback norm, energy and return of the final policies

# %%
print(f"{'alpha':>6s} {'return':>9s} {'feedback':>10s} {'energy':>8s} {'feedforward':>12s}")
results = {}
for alpha, run in runs.items():
    r = run.evaluate(episodes=2 if SMOKE else 5)
    results[alpha] = r
    print(f"{alpha:6g} {r['return']:9.1f} {r['feedback_norm']:10.3f} {r['energy']:8.3f} "
          f"{r['feedforward_norm']:12.2f}")  # fmt: skip

# %% [markdown]
# ## Watch a rollout
# The joint angles of one deterministic episode of each policy (a gait plot), and a strip of
# rendered frames where MuJoCo can render offscreen (a GL backend: EGL or OSMesa); without one
# the frames are skipped.

# %%
import jax
import matplotlib.pyplot as plt

from minatt_jax import acting

fig, axes = plt.subplots(1, len(runs), figsize=(5 * len(runs), 3), squeeze=False)
trajectories = {}
for ax, (alpha, run) in zip(axes[0], runs.items(), strict=True):
    policy = run.policy()
    env = policy.env
    act = policy.acting_policy()  # the deterministic policy, its own normalization included
    steps = 100 if SMOKE else 300
    traj = jax.jit(lambda k, env=env, act=act, steps=steps: acting.unroll(
        env, act, env.reset(k), steps))(jax.random.PRNGKey(0))  # fmt: skip
    trajectories[alpha] = traj
    for j, name in enumerate(env.obs_names[2:5], start=2):
        ax.plot(traj.obs[:, j], label=name)
    ax.set_title(f"alpha={alpha:g}")
    ax.set_xlabel("step")
    ax.legend(fontsize=7)
fig

# %%
try:
    import mujoco

    model = runs[ALPHAS[-1]].policy().env.mj_model
    renderer = mujoco.Renderer(model, 120, 160)
    data = mujoco.MjData(model)
    traj = trajectories[ALPHAS[-1]]
    frames = []
    qpos = jax.device_get(traj.obs)  # observations start at qpos[1]: x is not observed
    for t in range(0, len(qpos), max(len(qpos) // 6, 1))[:6]:
        data.qpos[1:] = qpos[t][: model.nq - 1]
        mujoco.mj_forward(model, data)
        renderer.update_scene(data)
        frames.append(renderer.render())
    fig, axes = plt.subplots(1, len(frames), figsize=(2 * len(frames), 1.8))
    for ax, frame in zip(axes, frames, strict=True):
        ax.imshow(frame)
        ax.axis("off")
    fig
except Exception as e:  # noqa: BLE001 - no GL backend here: rendering is optional
    print(f"no offscreen rendering here ({type(e).__name__}); the gait plot above shows the motion")
