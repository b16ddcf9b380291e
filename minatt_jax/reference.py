"""Measured runs to read a new run against: the committed reading study of SAC on hopper,
packaged as ``reference_runs.json`` (written by ``tools/reference_runs.py``).

``minatt-jax train`` prints the rows whose settings equal its run's, so a user sees what MA did
against plain SAC (alpha 0) trained the same way, over several seeds.
"""

from __future__ import annotations

import json
from importlib import resources
from typing import Any

METRICS = ("return", "feedback_norm", "energy")


def reference_runs() -> dict[str, Any]:
    """The packaged reference file: ``source``, ``command``, ``device`` and ``rows``."""
    text = resources.files("minatt_jax").joinpath("reference_runs.json").read_text("utf-8")
    return json.loads(text)


def matching_rows(config: Any) -> list[dict[str, Any]]:
    """Rows trained with this run's algorithm, environment, preset, length and reward
    normalization: alpha 0 and every alpha with this run's MA placement, by alpha."""
    # The reference rows are SAC's; a run of another agent reads no sac group and matches none.
    normalize_reward = config.to_dict().get(config.algo, {}).get("normalize_reward")
    rows = [r for r in reference_runs()["rows"]
            if (r["algo"], r["env"], r["preset"], r["total_steps"], r["normalize_reward"])
            == (config.algo, config.env, config.preset, config.total_steps, normalize_reward)
            and (r["alpha"] == 0 or r["placement"] == config.ma.placement)]  # fmt: skip
    return sorted(rows, key=lambda r: r["alpha"])


def comparison_lines(config: Any, record: dict[str, Any]) -> list[str]:
    """Lines that set this run's final evaluation beside the matching reference rows, or one
    line saying what the references cover when nothing matches (mode and task set must be the
    defaults for a like comparison)."""
    rows = matching_rows(config)
    default = config.ma.mode == "full" and not config.tasks and config.task_set == "nominal"
    if not rows or not default:
        ref = reference_runs()
        cover = sorted({f"{r['algo']} on {r['env']} ({r['preset']}, {r['total_steps']:,} steps)"
                        for r in ref["rows"]})  # fmt: skip
        return [
            f"\nno measured reference for these settings (the reference runs cover "
            f"{'; '.join(cover)}, the default MA mode and task set); the studies of "
            "experiments/results/ and the docs' Results page measure other settings"
        ]
    ref = reference_runs()
    head = f"{'':22s}" + "".join(f"{m:>22s}" for m in METRICS)
    lines = [f"\nthe same settings, measured ({ref['command']}; mean +- std over seeds):", head]
    lines.append(f"{'this run, alpha ' + format(config.ma.alpha, 'g'):22s}"
                 + "".join(f"{record[m]:22.4g}" for m in METRICS))  # fmt: skip
    for r in rows:
        label = f"alpha {r['alpha']:g} ({r['seeds']} seeds)"
        lines.append(f"{label:22s}" + "".join(
            f"{format(r[m]['mean'], '.4g') + ' +- ' + format(r[m]['std'], '.2g'):>22s}"
            for m in METRICS))  # fmt: skip
    lines.append("alpha 0 is plain SAC; larger alphas cut the feedback norm further and cost "
                 "return (docs: Training with minimum attention)")  # fmt: skip
    return lines
