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
# # Populations: seeds x alphas in one compiled program
#
# `mj.train_population` trains every member (seed x swept value) in one program: the members'
# states are stacked and each step is vmapped over them, so the sweep never recompiles. Each
# member still gets its own run directory. On a CPU a population of small networks beats running
# the members one after another; on a GPU it is how the device pays (one hopper SAC run uses a
# sliver of an H100; 128 members in one program were measured at about 59x one run's rate).
# With several devices the members are split over them.

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
SEEDS = [0, 1] if SMOKE else [0, 1, 2, 3, 4]
ALPHAS = "0,1" if SMOKE else "0,0.05,1"
OUT = os.environ.get("MINATT_OUT", "runs/notebooks")

# %%
import jax

import minatt_jax as mj

print("devices:", jax.devices())
out = f"{OUT}/population"
members = mj.train_population(
    preset=PRESET, env="hopper", total_steps=STEPS, seeds=SEEDS, sweep=[f"ma.alpha={ALPHAS}"],
    out=out, resume=os.path.exists(f"{out}/population.json"),
)  # fmt: skip
print(f"{len(members)} members in {out}")

# %% [markdown]
# ## The members' curves, grouped by alpha (mean and std band over seeds)

# %%
import matplotlib.pyplot as plt

fig, axes = plt.subplots(1, 3, figsize=(15, 3.4))
for ax, metric in zip(axes, ("return", "feedback_norm", "energy"), strict=True):
    mj.plot_curves(members, metric, ax=ax)
fig

# %% [markdown]
# Each member is an ordinary run: evaluate one, or hand them all to `minatt-jax analyze`.

# %%
print(members[-1].label, members[-1].evaluate(episodes=2)["feedback_norm"])
