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
    """A progress log for ``train``'s ``log``.

    Returns:
        A function of one line: printed in a terminal; in a notebook, shown as one line
        updated in place with a progress bar (``[#####.....] step 5000/20000 | ...``).
    """
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
    """A run directory: its configuration, metrics, policy and evaluations.

    Attributes:
        run_dir: the directory ``train`` wrote (``config.json``, ``metrics.jsonl``,
            ``checkpoints/``, ``policy_snapshots/``).
    """

    run_dir: str

    @property
    def config(self) -> TrainConfig:
        """The resolved configuration the run was made with (its ``config.json``)."""
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
        """One metric over training.

        Args:
            metric: a key of the records (``"return"``, ``"feedback_norm"``, ``"energy"``, ...).

        Returns:
            The env steps of the evaluations and the metric's value at each.
        """
        records = self.metrics
        return [r["step"] for r in records], [r[metric] for r in records]

    def policy(self, step: int | None = None) -> checkpoint.Policy:
        """The policy at a step, read without building a trainer or allocating buffers.

        Args:
            step: a checkpoint's or policy snapshot's env step; None for the latest.

        Returns:
            A ``checkpoint.Policy``: configuration, step, environment, parameters, normalizer
            and ``control(obs)``, the deterministic action on raw observations.
        """
        return checkpoint.load_policy(self.run_dir, step)

    def evaluate(
        self,
        variant: str | None = None,
        tasks: Sequence[str] = (),
        episodes: int | None = None,
        seed: int = 0,
    ) -> dict[str, Any]:
        """Evaluates the latest policy deterministically in the run's MJX environment.

        Args:
            variant: a task set (``"nominal"``, ``"mass"``, ``"crippled"``, ``"slope"``, ...);
                None for the run's own.
            tasks: custom task specs instead (``"mass=1.25,slope=0.1"``), one task each.
            episodes: episodes per task (a positive integer); None for the run's
                ``eval_episodes``.
            seed: the evaluation's random seed.

        Returns:
            The metrics (``return``, ``feedback_norm``, ``feedforward_norm``, ``energy``,
            ``jerk``, ``length``, each with ``_std``), the step and the variant.

        Raises:
            runner.RunError: a bad variant, task or episode count, or an unreadable run.
        """
        from minatt_jax import runner

        return runner.evaluate_run(self.run_dir, variant, episodes, seed, tuple(tasks))

    def meta_test(self, variant: str, **settings: Any) -> dict[str, Any]:
        """Adapts the trained policy to every task of ``variant`` and records the curves.

        Args:
            variant: the task set to adapt to (``"mass"``, ``"crippled"``, ...).
            **settings: ``meta_test.MetaTestConfig`` fields (``shots``, ``adapt_steps``,
                ``episodes``, ``inner_lr``, ...).

        Returns:
            Per task, the return, feedback norm and energy before and after each adaptation
            step (what ``meta-test`` writes as JSON).
        """
        from minatt_jax.meta_test import MetaTestConfig, meta_test

        return meta_test(self.run_dir, variant, MetaTestConfig(**settings), log=lambda m: None)

    def render(self, out: str, beside: Sequence[Run] = (), **settings: Any) -> dict[str, Any]:
        """Renders this run's deterministic policy, and others beside it, into a video.

        Args:
            out: the video file, ``.gif`` (Pillow) or ``.mp4`` (imageio-ffmpeg).
            beside: runs shown to the right, on the same task.
            **settings: ``render.render_runs``'s (``variant``, ``task_specs``, ``steps``,
                ``seed``, ``stride``, ``width``, ``height``, ``labels``).

        Returns:
            The video's frame count, size and frame rate, and each run's episode length,
            return and mean feedback norm along the rendered episode.
        """
        from minatt_jax.render import render_runs

        return render_runs([self.run_dir, *[r.run_dir for r in beside]], out, **settings)

    @property
    def label(self) -> str:
        """``"<algo> alpha=<alpha> seed=<seed>"``: what plots and tables call the run."""
        c = self.config
        return f"{c.algo} alpha={c.ma.alpha:g} seed={c.seed}"


def make_config(preset: str = "cpu", overrides: Sequence[str] = (), **fields: Any) -> TrainConfig:
    """A resolved configuration.

    Args:
        preset: ``"smoke"``, ``"cpu"`` or ``"paper"``.
        overrides: dotted settings, ``"ma.alpha=1"``, ``"sac.hidden=64,64"`` (the
            command line's ``--set``).
        **fields: the same as keywords, a group's fields joined by ``_``: ``ma_alpha=1.0``,
            ``env="walker2d"``, ``total_steps=10_000``, ``algo="ppo"``.

    Returns:
        The ``TrainConfig``, resolved (``config.resolve``: derived values filled in).

    Raises:
        ValueError: an unknown setting or a value outside its rule (one line naming it).
    """
    return resolve(preset_config(preset, list(overrides), dotted_fields(**fields)))


def train(
    config: TrainConfig | None = None,
    *,
    out: str | None = None,
    resume: bool = False,
    log: Callable[[str], None] | None = None,
    **fields: Any,
) -> Run:
    """Trains one run, or resumes it.

    Args:
        config: the configuration; None to make one from ``**fields`` (``make_config``).
        out: the run directory; None for ``runs/<env>_<algo>_alpha<alpha>_seed<seed>``.
        resume: go on from the run's latest checkpoint (its stored settings; the length and
            the hyper values may change).
        log: where progress lines go; None for the terminal, or one updated line in a
            notebook.
        **fields: ``make_config``'s keywords (``preset``, ``env``, ``ma_alpha``, ...).

    Returns:
        The ``Run``.

    Raises:
        runner.RunError: a bad setting or run directory (``DivergedError``: training
            diverged, the last good checkpoint kept; ``StoppedError``: a signal stopped it).
    """
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
    """Trains seeds x swept values, every group of members as one program.

    Args:
        config: the base configuration; None to make one from ``**fields``.
        seeds: the members' seeds, integers or the command line's form (``"0-4,7"``).
        sweep: swept settings, ``"ma.alpha=0,0.05,1"`` (one member per combination and seed).
        out: the population's directory (one run directory per member inside).
        resume: go on from every member's latest checkpoint.
        log: where progress lines go (as ``train``).
        **fields: ``make_config``'s keywords.

    Returns:
        One ``Run`` per member, in the order seeds x swept values.
    """
    from minatt_jax import population

    config = resolve(config) if config is not None else make_config(**fields)
    seeds = population.parse_seeds(seeds) if isinstance(seeds, str) else list(seeds)
    members = population.expand(config, seeds, list(sweep))
    swept = [s.partition("=")[0].strip() for s in sweep]
    population.train_population(members, out, swept, resume=resume, log=log or progress_logger())
    return [Run(os.path.join(out, population.member_name(m, swept))) for m in members]


def load_run(run_dir: str) -> Run:
    """An existing run directory.

    Args:
        run_dir: a directory ``train`` (or the command line) wrote.

    Returns:
        Its ``Run``.

    Raises:
        runner.RunError: no such directory, or no readable ``config.json`` in it.
    """
    run_files.load_config(run_dir)
    return Run(run_dir)


def plot_curves(runs: Sequence[Run], metric: str = "return", ax: Any = None) -> Any:
    """Plots a metric over training, runs grouped by their label without the seed.

    Args:
        runs: the runs (several seeds of a group become a mean line and a +-std band).
        metric: a key of the records.
        ax: a matplotlib axes to draw into; None for a new figure.

    Returns:
        The matplotlib figure.
    """
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
