"""Meta-test and analyze the hopper mbmpo runs of ``hopper_model_based.py`` (alpha 0 against 1).

    python experiments/hopper_meta_test.py [--steps 50000] [--seeds 0 1 2] [--grid 9]

For every mbmpo run (alpha 0 and 1) whose training reached ``--steps``: ``minatt-jax meta-test``
on the mass and crippled task sets (1 shot, 10 adaptation steps, 5 evaluation episodes; skipped
when the run already holds a meta-test of that checkpoint), then ``minatt-jax analyze`` on all of
them together. Writes ``experiments/results/hopper_mbmpo_report/`` (the report's figures and
tables; ``report.html`` stays under ``runs/``) and
``experiments/results/hopper_meta_test.{json,md}`` (before/after adaptation per run and task).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys

import numpy as np

from minatt_jax import runner

HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, "results")
VARIANTS = ("mass", "crippled")
ALPHAS = (0.0, 1.0)
METRICS = ("return", "feedback_norm", "feedforward_norm", "energy")


def run_dir(runs: str, alpha: float, seed: int) -> str:
    return os.path.join(runs, f"hopper_mbmpo_alpha{alpha:g}_seed{seed}")


def finished(directory: str, steps: int) -> bool:
    records = runner.read_metrics(directory) if os.path.isdir(directory) else []
    return bool(records) and records[-1]["step"] >= steps


def _read(path: str) -> dict:
    with open(path) as f:
        return json.load(f)


def cli(*args: str) -> None:
    print("$ minatt-jax " + " ".join(args), flush=True)
    subprocess.run([sys.executable, "-m", "minatt_jax.cli", *args], check=True)


def meta_test_table(entries: list[dict]) -> list[str]:
    """Mean over tasks before and after adaptation per alpha and variant (+- std over seeds)."""
    lines = ["| variant | alpha | seeds | " + " | ".join(
        f"{m} before | {m} after" for m in METRICS) + " |",
        "|---" * (3 + 2 * len(METRICS)) + "|"]  # fmt: skip
    for variant in VARIANTS:
        for alpha in ALPHAS:
            rows = [e for e in entries if e["variant"] == variant and e["alpha"] == alpha]
            if not rows:
                continue
            cells = []
            for m in METRICS:
                for when in ("before", "after"):
                    v = np.array([e["mean_over_tasks"][m][when] for e in rows])
                    cells.append(f"{v.mean():.4g} +- {v.std():.2g}")
            lines.append(f"| {variant} | {alpha:g} | {len(rows)} | " + " | ".join(cells) + " |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=50_000)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--runs", default="runs/hopper_model_based")
    parser.add_argument("--grid", type=int, default=9)
    args = parser.parse_args()
    dirs = [run_dir(args.runs, a, s) for a in ALPHAS for s in args.seeds]
    dirs = [d for d in dirs if finished(d, args.steps)]
    if not dirs:
        sys.exit(f"no mbmpo run under {args.runs} has reached {args.steps} steps yet")
    entries = []
    for d in dirs:
        for variant in VARIANTS:
            path = os.path.join(d, f"meta_test_{variant}.json")
            if not (os.path.exists(path) and _read(path)["step"] >= args.steps):
                cli("meta-test", d, "--variant", variant)
            result = _read(path)
            entries.append({"run": os.path.basename(d), "variant": variant,
                            "alpha": result["alpha"], "step": result["step"],
                            "mean_over_tasks": result["mean_over_tasks"],
                            "tasks": result["tasks"]})  # fmt: skip
    os.makedirs(RESULTS, exist_ok=True)
    runner.write_json_atomic(os.path.join(RESULTS, "hopper_meta_test.json"), entries)
    lines = meta_test_table(entries)
    runner.write_text_atomic(
        os.path.join(RESULTS, "hopper_meta_test.md"),
        "# Hopper mbmpo meta-test: alpha 0 against alpha 1\n\n"
        f"`python experiments/hopper_meta_test.py --steps {args.steps}`: runs "
        + ", ".join(os.path.basename(d) for d in dirs) + ". Mean over the tasks of each set, "
        "before adaptation and after 10 adaptation steps from 1 real episode per task "
        "(deterministic evaluation, 5 episodes); mean +- std over seeds.\n\n"
        + "\n".join(lines) + "\n"
    )  # fmt: skip
    print("\n".join(lines), flush=True)
    report = os.path.join("runs", "hopper_mbmpo_report")
    steps = [str(args.steps // 5), str(args.steps // 2), str(args.steps)]  # 10K, 25K, 50K
    cli("analyze", *dirs, "--out", report, "--grid", str(args.grid), "--maturation-steps", *steps)
    target = os.path.join(RESULTS, "hopper_mbmpo_report")
    os.makedirs(target, exist_ok=True)
    for name in os.listdir(report):
        if name.endswith((".png", ".md", ".json")):
            shutil.copy(os.path.join(report, name), os.path.join(target, name))


if __name__ == "__main__":
    main()
