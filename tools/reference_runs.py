"""Write `minatt_jax/reference_runs.json`: the measured runs that `minatt-jax train` prints beside
its own result when its settings match (the package carries them, so an installed copy without
the experiments folder can compare).

    python tools/reference_runs.py

The rows come from the committed reading study of SAC on hopper
(`experiments/results/reading_study_cpu_sac_20k.json`); `tests/test_reference_runs.py` checks
that the packaged file equals what this script writes from it.
"""

from __future__ import annotations

import json
import os

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SOURCE = "experiments/results/reading_study_cpu_sac_20k.json"
TARGET = os.path.join(ROOT, "minatt_jax", "reference_runs.json")
METRICS = ("return", "feedback_norm", "feedforward_norm", "energy")


def reference_rows() -> dict:
    """The study's arms as reference rows (mean and sample std per metric, seeds, settings)."""
    with open(os.path.join(ROOT, SOURCE), encoding="utf-8") as f:
        study = json.load(f)
    rows = []
    for arm in study["arms"]:
        rows.append({
            "algo": "sac", "env": arm["env"], "preset": "cpu", "total_steps": arm["step"],
            "normalize_reward": arm["normalize_reward"], "placement": arm["placement"],
            "alpha": arm["alpha"], "seeds": arm["seeds"],
            **{m: {"mean": arm[m]["mean"], "std": arm[m]["std"]} for m in METRICS},
        })  # fmt: skip
    return {"source": SOURCE, "command": study["command"], "device": study["device"],
            "rows": rows}  # fmt: skip


def main() -> None:
    text = json.dumps(reference_rows(), indent=1) + "\n"
    with open(TARGET, "w", encoding="utf-8") as f:
        f.write(text)
    print(f"wrote {TARGET}")


if __name__ == "__main__":
    main()
