"""Figures (PNG, matplotlib with the non-interactive Agg backend) for meta-tests and reports."""

from __future__ import annotations

import os
import tempfile
from typing import Any

from minatt_jax import run_files


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig: Any, path: str) -> None:
    """Writes a PNG atomically (temporary file, then rename) and closes the figure."""
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    # A unique temporary name: two processes writing the same figure must not share one.
    fd, tmp = tempfile.mkstemp(dir=directory, suffix=".tmp.png")
    os.fchmod(fd, run_files.file_mode())
    os.close(fd)
    try:
        fig.savefig(tmp, dpi=110, bbox_inches="tight", format="png")
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    _pyplot().close(fig)


def plot_meta_test(result: dict[str, Any], path: str) -> None:
    """Return, feedback, feedforward and energy against adaptation steps, one line per task."""
    plt = _pyplot()
    metrics = ("return", "feedback_norm", "feedforward_norm", "energy")
    fig, axes = plt.subplots(1, len(metrics), figsize=(4.2 * len(metrics), 3.4))
    for ax, metric in zip(axes, metrics, strict=True):
        for row in result["tasks"]:
            curve = row[f"{metric}_curve"]
            ax.plot(range(len(curve)), curve, marker="o", ms=3, label=row["task"])
        ax.set_xlabel("adaptation step")
        ax.set_title(metric)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=6, loc="best")
    fig.suptitle(
        f"{result['env']} {result['algo']} alpha={result['alpha']:g}: meta-test on "
        f"{result['variant']} ({result['settings']['shots']} shot(s), step {result['step']})",
        fontsize=10,
    )
    save_figure(fig, path)
