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
# # Analysis: heatmaps, K(t) x + v(t), the failure grid and the HTML report
#
# `minatt_jax.analysis.report.analyze` (the `minatt-jax analyze` command) reads run directories
# (single runs or population members), groups them by configuration and writes figures, tables
# and one self-contained `report.html`. Here on two short Hopper SAC runs, alpha 0 and 1.
# `SMOKE=1` takes a few minutes on a CPU; a GPU shortens the failure grid's thousands of rollouts
# most.

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
STEPS = 300 if SMOKE else 20_000
OUT = os.environ.get("MINATT_OUT", "runs/notebooks")

# %% Two runs to compare
import minatt_jax as mj

runs = []
for alpha in (0.0, 1.0):
    out = f"{OUT}/analysis_alpha{alpha:g}"
    runs.append(mj.train(preset=PRESET, env="hopper", ma_alpha=alpha, total_steps=STEPS, out=out,
                         resume=os.path.exists(f"{out}/config.json")))  # fmt: skip

# %% Analyze
from minatt_jax.analysis.report import AnalyzeConfig, analyze

settings = AnalyzeConfig(
    episodes=2 if SMOKE else 5, bins=8 if SMOKE else 20, grid=3 if SMOKE else 9,
    grid_rollouts=2 if SMOKE else 20, grid_steps=20 if SMOKE else 100,
    maturation_steps=(STEPS,),
)  # fmt: skip
report_dir = f"{OUT}/analysis_report"
result = analyze([r.run_dir for r in runs], report_dir, settings, log=lambda m: None)
print("figures:", ", ".join(result["figures"]))

# %% The figures inline (as a script: their paths)
try:
    from IPython.display import HTML, Image, display
except ImportError:
    HTML = Image = None
    display = print

for name in result["figures"]:
    path = f"{report_dir}/{name}"
    display(Image(filename=path) if Image else path)

# %% The whole report inline (also at report.html, readable offline)
with open(f"{report_dir}/report.html") as f:
    page = f.read()
display(HTML(page) if HTML else f"{report_dir}/report.html: {len(page) // 1024} KiB")
