"""A Python API for notebooks and scripts: train, load, evaluate, plot, in a few short calls.

    import minatt_jax as mj
    run = mj.train(preset="smoke", env="hopper", ma_alpha=1.0, out="runs/demo")
    run.metrics               # list of dicts (run.dataframe() if pandas is installed)
    run.evaluate(variant="crippled")
    mj.plot_curves([run], "feedback_norm")
    runs = mj.train_population(preset="smoke", seeds=[0, 1], sweep=["ma.alpha=0,1"], out="runs/p")

Everything goes through the same code as the command line (``config.resolve``, ``runner``,
``population``, ``checkpoint.load_policy``), so a run made here is a run directory like any
other. Progress is a line per evaluation in a terminal and one line updated in place in a
Jupyter/Colab notebook.
"""

from __future__ import annotations

import dataclasses
import os
import re
import sys
from collections.abc import Callable, Sequence
from typing import Any

from minatt_jax import checkpoint, run_files
from minatt_jax.config import TrainConfig, dotted_fields, preset_config, resolve


def _in_notebook() -> bool:
    shell = sys.modules.get("IPython")
    if shell is None:
        return False
    ip = shell.get_ipython() if hasattr(shell, "get_ipython") else None
    return ip is not None and "IPKernelApp" in getattr(ip, "config", {})


def progress_logger() -> Callable[[str], None]:
    """Prints lines in a terminal; in a notebook, one line updated in place with a progress bar
    (``[#####.....] step 5000/20000 | ...``)."""
    if not _in_notebook():
        return lambda message: print(message, flush=True)
    from IPython.display import display

    handle = display("starting ...", display_id=True)

    def update(message: str) -> None:
        match = re.search(r"step\s+(\d+)/(\d+)", message)
        if match:
            done, total = int(match.group(1)), int(match.group(2))
            filled = round(30 * done / max(total, 1))
            message = f"[{'#' * filled}{'.' * (30 - filled)}] {message}"
        handle.update(message)

    return update


@dataclasses.dataclass
class Run:
    """A run directory: its configuration, metrics, policy and evaluations."""

    run_dir: str

    @property
    def config(self) -> TrainConfig:
        return run_files.load_config(self.run_dir)

    @property
    def metrics(self) -> list[dict[str, Any]]:
        """The evaluation records of ``metrics.jsonl``, one dict per evaluation."""
        return run_files.read_metrics(self.run_dir)

    def dataframe(self) -> Any:
        """``metrics`` as a pandas DataFrame (needs pandas)."""
        import pandas as pd

        return pd.DataFrame(self.metrics)

    def curve(self, metric: str) -> tuple[list[int], list[float]]:
        """(steps, values) of one metric over training."""
        records = self.metrics
        return [r["step"] for r in records], [r[metric] for r in records]

    def policy(self, step: int | None = None) -> checkpoint.Policy:
        """The policy at ``step`` (default: latest), without building a trainer."""
        return checkpoint.load_policy(self.run_dir, step)

    def evaluate(
        self,
        variant: str | None = None,
        tasks: Sequence[str] = (),
        episodes: int | None = None,
        seed: int = 0,
    ) -> dict[str, Any]:
        """Deterministic evaluation on a task set (``variant``) or custom ``tasks`` specs."""
        from minatt_jax import runner

        return runner.evaluate_run(self.run_dir, variant, episodes, seed, tuple(tasks))

    def meta_test(self, variant: str, **settings: Any) -> dict[str, Any]:
        """Adaptation curves on every task of ``variant`` (``meta_test.MetaTestConfig`` fields)."""
        from minatt_jax.meta_test import MetaTestConfig, meta_test

        return meta_test(self.run_dir, variant, MetaTestConfig(**settings), log=lambda m: None)

    def render(self, out: str, beside: Sequence[Run] = (), **settings: Any) -> dict[str, Any]:
        """A video (``out``: .gif or .mp4) of this run's deterministic policy, with ``beside``'s
        to its right, their controls u(t) and feedback norms drawn beneath; ``settings`` are
        ``render.render_runs``'s (``variant``, ``task_specs``, ``steps``, ``stride``, ...).
        Returns each run's episode length, return and feedback norm in the video."""
        from minatt_jax.render import render_runs

        return render_runs([self.run_dir, *[r.run_dir for r in beside]], out, **settings)

    @property
    def label(self) -> str:
        c = self.config
        return f"{c.algo} alpha={c.ma.alpha:g} seed={c.seed}"


def make_config(preset: str = "cpu", overrides: Sequence[str] = (), **fields: Any) -> TrainConfig:
    """A resolved configuration: a preset, dotted ``overrides`` ("ma.alpha=1") and keyword
    fields (``ma_alpha=1.0``, ``env="walker2d"``, ``total_steps=10_000``)."""
    return resolve(preset_config(preset, list(overrides), dotted_fields(**fields)))


def train(
    config: TrainConfig | None = None,
    *,
    out: str | None = None,
    resume: bool = False,
    log: Callable[[str], None] | None = None,
    **fields: Any,
) -> Run:
    """Trains one run (``config``, or ``make_config(**fields)``) into ``out`` and returns it."""
    from minatt_jax import runner

    config = resolve(config) if config is not None else make_config(**fields)
    out = out or os.path.join(
        "runs", f"{config.env}_{config.algo}_alpha{config.ma.alpha:g}_seed{config.seed}"
    )
    os.makedirs(out, exist_ok=True)
    runner.train(config, out, resume=resume, log=log or progress_logger())
    return Run(out)


def train_population(
    config: TrainConfig | None = None,
    *,
    seeds: Sequence[int] | str = (0,),
    sweep: Sequence[str] = (),
    out: str,
    resume: bool = False,
    log: Callable[[str], None] | None = None,
    **fields: Any,
) -> list[Run]:
    """Trains seeds x swept values in one program per group (``population``); one Run each.
    ``seeds``: integers, or the command line's form ("0-4,7")."""
    from minatt_jax import population

    config = resolve(config) if config is not None else make_config(**fields)
    seeds = population.parse_seeds(seeds) if isinstance(seeds, str) else list(seeds)
    members = population.expand(config, seeds, list(sweep))
    swept = [s.partition("=")[0].strip() for s in sweep]
    population.train_population(members, out, swept, resume=resume, log=log or progress_logger())
    return [Run(os.path.join(out, population.member_name(m, swept))) for m in members]


def load_run(run_dir: str) -> Run:
    """An existing run directory (checked: it must hold a config.json)."""
    run_files.load_config(run_dir)
    return Run(run_dir)


def plot_curves(runs: Sequence[Run], metric: str = "return", ax: Any = None) -> Any:
    """``metric`` over training, runs grouped by label without the seed: mean line and a
    +-std band across seeds. Returns the matplotlib figure."""
    import matplotlib.pyplot as plt
    import numpy as np

    if ax is None:
        fig, ax = plt.subplots(figsize=(5.5, 3.6))
    else:
        fig = ax.figure
    groups: dict[str, list[Run]] = {}
    for run in runs:
        groups.setdefault(run.label.rsplit(" seed=", 1)[0], []).append(run)
    for label, members in groups.items():
        curves = [run.curve(metric) for run in members]
        length = min(len(steps) for steps, _ in curves)
        if length == 0:
            continue
        steps = np.asarray(curves[0][0][:length])
        values = np.asarray([v[:length] for _, v in curves], float)
        mean, std = values.mean(0), values.std(0)
        ax.plot(steps, mean, marker="o", ms=3, label=f"{label} (n={len(members)})")
        ax.fill_between(steps, mean - std, mean + std, alpha=0.2)
    ax.set_xlabel("env steps")
    ax.set_ylabel(metric)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    return fig
