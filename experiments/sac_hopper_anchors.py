"""SAC on hopper at 100K env steps beside its anchors: Stable-Baselines3 SAC and a public figure.

    python experiments/sac_hopper_anchors.py

Reads ``experiments/results/sac_cpu_hopper.json`` (``model_free_cpu.py --algo sac``: minatt-jax's
final policies on MJX and on Gymnasium's Hopper-v5, the C engine) and
``experiments/results/sb3_sac_hopper_seed*.json`` (``sb3_sac_hopper.py``: Stable-Baselines3's SAC
with the same settings, trained and evaluated on Hopper-v5) and compares them on one engine at
one step: per arm the final deterministic return, mean over seeds with the 95% t interval, and
minatt-jax's alpha-0 arm against SB3 by Welch's interval and the exact permutation p. An SB3 seed
that has not reached the step is listed with its last evaluation and left out of the statistics.
The public figure (SAC on Hopper at 100K env steps, about 1,100 in SimbaV2's table) has no
spread here: it is shown, not tested. Writes ``experiments/results/sac_hopper_anchors.{json,md}``.
"""

from __future__ import annotations

import glob
import json
import os
import re
from typing import Any

import numpy as np
import stats
import study

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")
STEP = 100_000
PUBLIC = {"figure": 1100, "source": "SimbaV2's table of SAC on Hopper at 100K env steps"}


def sb3_runs(results: str = RESULTS) -> list[dict[str, Any]]:
    """Each SB3 seed's last evaluation and, where it reached ``STEP``, the return there."""
    runs = []
    for path in sorted(glob.glob(os.path.join(results, "sb3_sac_hopper_seed*.json"))):
        with open(path) as f:
            data = json.load(f)
        records = data["records"]
        at = [r for r in records if r["step"] == STEP]
        runs.append({"seed": int(re.search(r"seed(\d+)", path).group(1)),
                     "env": data.get("env", "Hopper-v4"), "last_step": records[-1]["step"],
                     "last_return": records[-1]["return"],
                     "return": at[0]["return"] if at else None})  # fmt: skip
    return runs


def compare(ours: list[float], sb3: list[float]) -> dict[str, Any]:
    """Ours minus SB3: the difference of means, Welch's 95% interval, the exact permutation p
    (``None`` where either side has fewer than 2 seeds)."""
    if len(ours) < 2 or len(sb3) < 2:
        return {"diff": None, "welch_ci": None, "permutation_p": None}
    return stats.difference(ours, sb3)


def arm_cell(values: list[float]) -> str:
    if not values:
        return "-"
    if len(values) < 2:
        return f"{values[0]:.0f} (1 seed)"
    low, high = stats.t_interval(values)
    return f"{np.mean(values):.0f} [{low:.0f}, {high:.0f}] (n={len(values)})"


def main() -> None:
    with open(os.path.join(RESULTS, "sac_cpu_hopper.json")) as f:
        ours = json.load(f)
    arms = {f"{a['alpha']:g}": a for a in ours["arms"] if a["step"] == STEP}
    sb3 = [r for r in sb3_runs() if r["env"] == "Hopper-v5"]
    sb3_values = [r["return"] for r in sb3 if r["return"] is not None]
    rows = []
    for alpha, arm in arms.items():
        rows.append({"arm": f"minatt-jax SAC, alpha {alpha}",
                     "mjx": arm["return"]["values"],
                     "c_engine": arm["c_engine_return"].get("values", [])})  # fmt: skip
    rows.append({"arm": "Stable-Baselines3 SAC", "mjx": [], "c_engine": sb3_values})
    plain = rows[0]["c_engine"] if arms else []
    result = {**study.provenance("python experiments/sac_hopper_anchors.py"), "step": STEP,
              "rows": rows, "sb3_runs": sb3, "public": PUBLIC,
              "alpha0_minus_sb3_c_engine": compare(plain, sb3_values)}  # fmt: skip
    lines = [f"# SAC on hopper at {STEP:,} env steps beside its anchors\n",
             f"`{result['command']}`: minatt-jax's runs from `sac_cpu_hopper.json`, "
             "Stable-Baselines3's from `sb3_sac_hopper_seed*.json` (same settings, trained on "
             "Hopper-v5). Final deterministic return, mean over seeds [95% t interval]; C "
             "engine: Gymnasium's Hopper-v5.\n",
             "| arm | MJX | C engine (Hopper-v5) |", "|---|---|---|"]  # fmt: skip
    for row in rows:
        lines.append(f"| {row['arm']} | {arm_cell(row['mjx'])} | {arm_cell(row['c_engine'])} |")
    lines.append(f"| public figure ({PUBLIC['source']}) | - | about {PUBLIC['figure']:,} |")
    d = result["alpha0_minus_sb3_c_engine"]
    lines.append("")
    if d["diff"] is not None:
        lines.append(f"minatt-jax alpha 0 minus SB3 on the C engine: {d['diff']:+.0f} (Welch "
                     f"[{d['welch_ci'][0]:.0f}, {d['welch_ci'][1]:.0f}], exact permutation p "
                     f"{d['permutation_p']:.3g}).")  # fmt: skip
    else:
        lines.append("minatt-jax alpha 0 against SB3: not tested (SB3 has fewer than 2 seeds at "
                     f"{STEP:,} steps).")  # fmt: skip
    short = [r for r in sb3 if r["return"] is None]
    if short:
        lines.append("SB3 seeds short of the step (left out): " + ", ".join(
            f"seed {r['seed']} at {r['last_step']:,} ({r['last_return']:.0f})" for r in short
        ) + "; `python experiments/sb3_sac_hopper.py --seed N` resumes each.")  # fmt: skip
    study.write_study(RESULTS, "sac_hopper_anchors", result, "\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
