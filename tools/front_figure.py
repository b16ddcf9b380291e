"""The front page's figure: what minimum attention does to SAC on hopper, from the committed
reading study (`experiments/results/reading_study_cpu_sac_20k.json`).

    python tools/front_figure.py [--out docs/assets/ma_hopper_sac.png]

Bars are the mean over seeds of the final deterministic evaluation at 20K env steps, whiskers
the 95% bootstrap interval of the mean that the study wrote; alpha 0 is plain SAC.
"""

from __future__ import annotations

import argparse
import json
import os

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SOURCE = "experiments/results/reading_study_cpu_sac_20k.json"
PLACEMENT = "entropy"  # the default placement
PANELS = (("return", "return", False), ("feedback_norm", "feedback norm ||du/dx||^2", True),
          ("energy", "energy ||u||^2", False))  # fmt: skip


def arms(path: str = SOURCE) -> list[dict]:
    """Hopper SAC without reward normalization: alpha 0 and the default placement's alphas."""
    with open(os.path.join(ROOT, path), encoding="utf-8") as f:
        study = json.load(f)
    chosen = [a for a in study["arms"] if a["env"] == "hopper" and not a["normalize_reward"]
              and (a["alpha"] == 0 or a["placement"] == PLACEMENT)]  # fmt: skip
    return sorted(chosen, key=lambda a: a["alpha"])


def draw(out: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = arms()
    labels = [f"alpha {a['alpha']:g}" + (" (SAC)" if a["alpha"] == 0 else "") for a in rows]
    colors = ["#7f7f7f", "#1f77b4", "#ff7f0e"][: len(rows)]
    fig, axes = plt.subplots(1, len(PANELS), figsize=(10, 3.2))
    for ax, (key, title, log) in zip(axes, PANELS, strict=True):
        means = [a[key]["mean"] for a in rows]
        low = [a[key]["mean"] - a[key]["ci_low"] for a in rows]
        high = [a[key]["ci_high"] - a[key]["mean"] for a in rows]
        ax.bar(labels, means, yerr=[low, high], color=colors, capsize=4)
        ax.set_title(title, fontsize=10)
        if log:
            ax.set_yscale("log")
        ax.tick_params(axis="x", labelsize=8)
    n = min(a["seeds"] for a in rows)
    fig.suptitle(f"SAC on hopper, 20K env steps, {n} seeds: MA ({PLACEMENT} placement) "
                 "against plain SAC (95% intervals)", fontsize=10)  # fmt: skip
    fig.tight_layout()
    os.makedirs(os.path.dirname(out) or ".", exist_ok=True)
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=os.path.join(ROOT, "docs/assets/ma_hopper_sac.png"))
    draw(parser.parse_args().out)


if __name__ == "__main__":
    main()
