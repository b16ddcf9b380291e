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
# # The minimum-attention regularizer on a policy of your own
#
# `minatt_jax.min_attention` works with any JAX control law `u(params, x)`. Here: a small flax
# MLP policy, the penalty's estimators side by side (cost and error against the exact value),
# and the decomposition u(x) = K(x) x + v(x) along states. No environment, no GPU needed; on a
# GPU the estimators' costs change ratio (the exact Jacobian gets relatively cheaper).

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
BATCH = 64 if SMOKE else 256
REPEATS = 3 if SMOKE else 20

# %% A policy of your own
import time

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from minatt_jax import min_attention as ma
from minatt_jax.analysis import control_analysis


class Policy(nn.Module):
    @nn.compact
    def __call__(self, x):
        x = nn.tanh(nn.Dense(64)(x))
        return jnp.tanh(nn.Dense(3)(x))


net = Policy()
obs_dim = 11
params = net.init(jax.random.PRNGKey(0), jnp.zeros(obs_dim))


def u(p, x):
    return net.apply(p, x)


states = jax.random.normal(jax.random.PRNGKey(1), (BATCH, obs_dim))

# %% [markdown]
# ## The feedback term ||du/dx||_F^2: exact against stochastic estimators
# `jacfwd` and `jacrev` are exact; `hutchinson` uses k Rademacher probes (one VJP each) and is
# unbiased. The cost is per call on the CPU running the notebook, after compilation.

# %%
exact = float(jnp.mean(ma.feedback_exact(u, params, states)))
rows = []
for estimator, probes in (("jacfwd", 1), ("jacrev", 1), ("hutchinson", 1), ("hutchinson", 8)):
    config = ma.MAConfig(
        alpha=1.0, estimator=estimator, probes=probes, subsample=0, mode="jacobian"
    )
    fn = jax.jit(lambda p, k, config=config: ma.feedback_term(config, u, p, states, k))
    fn(params, jax.random.PRNGKey(0)).block_until_ready()
    t = time.perf_counter()
    values = [float(fn(params, jax.random.PRNGKey(i))) for i in range(REPEATS)]
    ms = 1e3 * (time.perf_counter() - t) / REPEATS
    rows.append((f"{estimator} x{probes}", np.mean(values), np.std(values), ms))
print(f"exact mean ||du/dx||^2 = {exact:.4f}")
print(f"{'estimator':16s} {'mean':>9s} {'std':>9s} {'ms/call':>8s}")
for name, mean, std, ms in rows:
    print(f"{name:16s} {mean:9.4f} {std:9.4f} {ms:8.3f}")

# %% [markdown]
# ## The penalty in a training loss
# `ma.penalty` returns alpha * (feedback + temporal) and its parts; its gradient lowers the
# feedback norm. A few gradient steps on the penalty alone:

# %%
config = ma.MAConfig(alpha=1.0, mode="jacobian", estimator="jacrev", subsample=0)


@jax.jit
def step(p, key):
    def loss_of(q):
        return ma.penalty(config, u, q, states, key, alpha=config.alpha)[0]

    loss, grads = jax.value_and_grad(loss_of)(p)
    return jax.tree.map(lambda a, g: a - 0.05 * g, p, grads), loss


p = params
for i in range(10 if SMOKE else 100):
    p, loss = step(p, jax.random.PRNGKey(i))
after = float(jnp.mean(ma.feedback_exact(u, p, states)))
print(f"feedback norm {exact:.4f} -> {after:.4f} after the penalty's gradient steps")

# %% [markdown]
# ## u(x) = K(x) x + v(x)
# K is the exact Jacobian at each state and v the rest, so the identity holds by construction.
# ||K||_F is the feedback gain, ||v|| the feedforward part.

# %%
import matplotlib.pyplot as plt

parts = control_analysis.decompose(u, params, states[:50])
error = float(jnp.max(jnp.abs(jnp.einsum("tao,to->ta", parts["K"], states[:50]) + parts["v"]
                              - parts["u"])))  # fmt: skip
print(f"max |K x + v - u| = {error:.2e}")
fig, ax = plt.subplots(figsize=(6, 3))
ax.plot(np.asarray(parts["K_norm"]), label="||K||_F")
ax.plot(np.asarray(parts["v_norm"]), label="||v||")
ax.set_xlabel("state")
ax.legend()
fig
