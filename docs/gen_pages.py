"""The documentation's results and benchmark pages, written from the committed JSON files.

`mkdocs build` runs this script (the mkdocs-gen-files plugin), so the numbers on those pages are
read from `experiments/results/*.json` and `benchmarks/results/*.json` at every build and cannot
drift from them. `tests/test_docs.py` calls the page functions directly.
"""

from __future__ import annotations

import glob
import json
import math
import os
import sys
from collections import Counter
from typing import Any

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "experiments"))  # the studies' helpers: stage names

from study import stage_label as stage_name  # noqa: E402

REPO_URL = "https://github.com/minatt-jax/minatt-jax/blob/main"
VERDICTS = ("reproduced", "not reproduced", "inconclusive at this scale", "not tested",
            "no claim in the paper")  # fmt: skip
METRICS = ("return", "feedback_norm", "feedforward_norm", "energy")


def fmt(value: Any) -> str:
    """A number to four significant digits (integers as they are); anything else as text."""
    if isinstance(value, bool) or value is None:
        return "-" if value is None else str(value)
    if isinstance(value, int):
        return f"{value:,}"
    if isinstance(value, float):
        if math.isnan(value):
            return "-"
        return f"{value:.4g}"
    return str(value).replace("|", "\\|").replace("\n", " ")


def table(header: list[str], rows: list[list[Any]]) -> str:
    """A markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(fmt(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)


def load(path: str) -> Any:
    with open(os.path.join(ROOT, path), encoding="utf-8") as f:
        return json.load(f)


def stat(s: dict[str, Any] | None) -> str:
    """mean +- std (n) of one arm's summary."""
    if not s:
        return "-"
    return f"{fmt(s['mean'])} +- {fmt(s['std'])} (n={s['n']})"


def claims_section(claims: dict[str, Any]) -> list[str]:
    """The paper's claims: summary, verdict counts, headline claims, world models, cells."""
    cells = claims["cells"]
    counts = Counter(c["verdict"] for c in cells)
    out = ["## The paper's claims", "", "\n\n".join(claims["summary"]), "",
           table(["verdict", "table cells"], [[v, counts.get(v, 0)] for v in VERDICTS]), "",
           "### Headline claims", "",
           table(["claim", "paper", "ours", "verdict", "why"],
                 [[h["claim"], h["paper"], h["ours"], h["verdict"], h["reason"]]
                  for h in claims["headline"]]), "",
           "### World-model agents (Tables S3, S4)", "",
           table(["table", "stage", "alpha", "paper", "ours", "status", "why"],
                 [[w["table"], stage_name(w["stage"]), w["alpha"],
                   f"{fmt(w['paper'][0])} +- {fmt(w['paper'][1])}", w["ours"], w["status"],
                   w["reason"]] for w in claims["world_models"]]), "",
           "### Every table cell", "",
           "Paper: MB-MPO and MA as mean +- std over the paper's seeds; `p (paper)` is Welch's "
           "test on the paper's own numbers. Ours: the stage our runs reached, mean +- std (n); "
           "`p` is the exact permutation test of the difference of means, `p Holm` corrected "
           "within the cell's family.", ""]  # fmt: skip
    rows = []
    for c in cells:
        ours = c.get("ours") or {}
        rows.append([
            c["env"], c["phase"], stage_name(c["stage"]), c["alpha"], c["metric"],
            f"{fmt(c['paper_mbmpo'][0])} / {fmt(c['paper_ma'][0])}", c.get("claimed", "-"),
            c.get("paper_p"), stage_name(ours["stage"]) if "stage" in ours else "-",
            stat(ours.get("mbmpo")), stat(ours.get("ma")), c.get("p"), c.get("p_holm"),
            c["verdict"],
        ])  # fmt: skip
    out.append(table(["env", "phase", "stage", "alpha", "metric", "paper MB-MPO / MA", "claimed",
                      "p (paper)", "our stage", "our MB-MPO", "our MA", "p", "p Holm", "verdict"],
                     rows))  # fmt: skip
    return out


def study_sections() -> list[str]:
    """Every study's table from its JSON: arms (reading studies) or per-stage arms (tables)."""
    out = ["## The studies", ""]
    for path in sorted(glob.glob(os.path.join(ROOT, "experiments/results/*.json"))):
        data = load(path)
        name = os.path.splitext(os.path.basename(path))[0]
        if not isinstance(data, dict) or "command" not in data or name == "paper_claims":
            continue
        rows = study_rows(data)
        if not rows:
            continue
        out += [f"### {name}", "", f"`{data['command']}` on {data.get('device', '-')}.", "",
                table(["env", "arm", "phase", "stage", *METRICS], rows), ""]  # fmt: skip
    return out


def study_rows(data: dict[str, Any]) -> list[list[Any]]:
    """Rows of mean +- std (n) per metric, from a reading study's ``arms`` or a table study's
    ``tables`` (env -> phase -> stage -> arm -> metric)."""
    rows = []
    for arm in data.get("arms", []):
        label = (f"{arm.get('placement', '')} alpha {fmt(arm.get('alpha'))}"
                 f"{', reward norm' if arm.get('normalize_reward') else ''}")  # fmt: skip
        rows.append([arm.get("env", "-"), label, "training", stage_name(arm.get("step", 0)),
                     *[stat(arm.get(m)) for m in METRICS]])  # fmt: skip
    for env, phases in (data.get("tables") or {}).items():
        if not isinstance(phases, dict):
            continue
        for phase, stages in phases.items():
            if not isinstance(stages, dict):
                continue
            for stage, arms in stages.items():
                if not isinstance(arms, dict) or not stage.isdigit():
                    continue
                for arm, metrics in arms.items():
                    if isinstance(metrics, dict) and any(m in metrics for m in METRICS):
                        rows.append([env, arm, phase, stage_name(int(stage)),
                                     *[stat(metrics.get(m)) for m in METRICS]])  # fmt: skip
    return rows


def results_page() -> str:
    """The results page: the paper's claims and every study, from experiments/results/."""
    claims = load("experiments/results/paper_claims.json")
    head = ["# Results", "",
            "Generated from `experiments/results/*.json` at every build of this site. How the "
            "runs were made, and the commands that resume or extend them, are on "
            "[Reproducing the paper](reproducing.md). Metric scales differ from the paper's by "
            "10x to 10,000x (the paper's own energy for one agent reads 4.54 in its Table 1 and "
            "363 in Table S5), so MA's effect is compared by its direction against MB-MPO, not "
            "by magnitude.",
            f"The full verdict table with each cell's reasoning is "
            f"[paper_claims.md]({REPO_URL}/experiments/results/paper_claims.md).", ""]  # fmt: skip
    return "\n".join(head + claims_section(claims) + [""] + study_sections()) + "\n"


def benchmark_page() -> str:
    """One section per `benchmarks/results/*.json`: where and how it was measured, its rows."""
    out = ["# Benchmark results", "",
           "Generated from `benchmarks/results/*.json` at every build of this site; what each "
           "benchmark measures is on [Benchmarks](benchmarks.md). Each section names the "
           "command and the machine it ran on. Compare ratios measured in one run: timings on "
           "a shared machine vary by up to 15% from run to run.", ""]  # fmt: skip
    for path in sorted(glob.glob(os.path.join(ROOT, "benchmarks/results/*.json"))):
        data = load(path)
        name = os.path.basename(path)
        out += [f"## {os.path.splitext(name)[0]}", ""]
        facts = [[k, v] for k, v in data.items() if not isinstance(v, (dict, list))]
        facts += [[k, ", ".join(f"{a}: {b}" for a, b in v.items())] for k, v in data.items()
                  if isinstance(v, dict) and all(not isinstance(b, (dict, list))
                                                 for b in v.values())]  # fmt: skip
        out += [table(["field", "value"], facts), ""]
        for key, value in data.items():
            if isinstance(value, list) and value and all(isinstance(r, dict) for r in value):
                out += [f"**{key}**", "", rows_table(value), ""]
            elif isinstance(value, dict) and any(isinstance(b, dict) for b in value.values()):
                out += [f"**{key}**", "", nested_table(value), ""]
    return "\n".join(out) + "\n"


def rows_table(rows: list[dict[str, Any]]) -> str:
    """A list of flat records as one table (nested values are left out)."""
    keys = list(dict.fromkeys(k for r in rows for k, v in r.items()
                              if not isinstance(v, (dict, list))))  # fmt: skip
    return table(keys, [[r.get(k) for k in keys] for r in rows])


def nested_table(value: dict[str, Any]) -> str:
    """A mapping of name -> record (or scalar) as one table, nested records flattened once."""
    rows = []
    for name, record in value.items():
        if isinstance(record, dict):
            flat = {}
            for k, v in record.items():
                if isinstance(v, dict):
                    flat.update({f"{k}.{a}": b for a, b in v.items()
                                 if not isinstance(b, (dict, list))})  # fmt: skip
                elif not isinstance(v, list):
                    flat[k] = v
            rows.append({"name": name, **flat})
        else:
            rows.append({"name": name, "value": record})
    return rows_table(rows)


PAGES = {"results.md": results_page, "benchmark-results.md": benchmark_page}

try:  # under `mkdocs build`: write the pages into the site's virtual docs folder
    import mkdocs_gen_files
except ImportError:  # imported by a test or run by hand
    mkdocs_gen_files = None
if mkdocs_gen_files is not None and __name__ in ("__main__", "<run_path>"):
    for page, make in PAGES.items():
        with mkdocs_gen_files.open(page, "w") as f:
            f.write(make())
