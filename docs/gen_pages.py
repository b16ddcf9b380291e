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

# Links into the repository where the site's builder names it (mkdocs.yml reads the same
# variable for the header link); without it, paths are given as text.
REPO_URL = os.environ.get("MINATT_JAX_REPO_URL", "").rstrip("/")
VERDICTS = ("reproduced", "not reproduced", "inconclusive at this scale", "not tested",
            "no claim in the paper")  # fmt: skip
METRICS = ("return", "feedback_norm", "feedforward_norm", "energy")


def repo_link(path: str) -> str:
    """A link to a committed file where the repository's address is known, else its path."""
    return f"[`{path}`]({REPO_URL}/blob/main/{path})" if REPO_URL else f"`{path}`"


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
           "### Findings", "",
           "Each effect of MA once, with the cells that measure it (tested: at the paper's own "
           "stage with >= 5 seeds per arm; per-row Holm and Benjamini-Hochberg over all tested "
           "cells are the two families).", "",
           table(["finding", "claims of the paper", "tested", "ours significant: lower / higher",
                  "paper's direction there: lower / higher", "Holm: reproduced / other way",
                  "BH: reproduced / other way"],
                 [[f["finding"], f["claims"], f["tested"],
                   f"{f['ours_lower']} / {f['ours_higher']}",
                   f"{f['paper_lower']} / {f['paper_higher']}",
                   f"{f['reproduced_holm']} / {f['other_way_holm']}",
                   f"{f['reproduced_bh']} / {f['other_way_bh']}"]
                  for f in claims.get("findings", []) if "tested" in f]), "",
           "### How the paper's +- is read", "",
           "Whether a cell is a claim depends on reading the paper's \"+-\"; the verdicts use "
           "the main text's (one standard deviation over 10 seeds; Table S3's 5 for MAMBA).", "",
           table(["reading", "claim cells (Tables 1, S1-S8)", "claim rows (S3, S4)"],
                 [[r["reading"], r["table_cells"], r["world_model_rows"]]
                  for r in claims.get("sensitivity", {}).get("rows", [])]), "",
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
        body = [f"`{data['command']}` on {data.get('device', '-')}.", "",
                table(["env", "arm", "phase", "stage", *METRICS], rows)]  # fmt: skip
        if data.get("arms"):
            FIGURES[f"figures/{name}.png"] = lambda path, d=data, n=name: arm_figure(d, n, path)
            body = [f"![{name}: return and feedback norm per arm](figures/{name}.png)", "", *body]
        title = data.get("title") or name.replace("_", " ")
        out += [f'??? note "{title} ({len(rows)} rows)"', ""]
        out += ["    " + line if line else "" for line in "\n".join(body).split("\n")] + [""]
    return out


def t_interval(summary: dict[str, Any]) -> tuple[float, float]:
    """The 95% t interval of a mean from its summary (mean, std, n)."""
    from scipy import stats as scipy_stats

    n, mean, std = summary.get("n", 0), summary["mean"], summary.get("std", 0.0)
    if not n or n < 2:
        return mean, mean
    half = scipy_stats.t.ppf(0.975, n - 1) * std / math.sqrt(n)
    return mean - half, mean + half


def arm_figure(data: dict[str, Any], name: str, path: str) -> None:
    """Each arm's return and feedback norm, mean and 95% t interval over seeds (a reading
    study's ``arms``), alpha 0 drawn in black: where MA moves them and by how much."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    arms = [a for a in data["arms"] if isinstance(a.get("return"), dict)]
    labels = [f"{a.get('env', '')} {a.get('placement', '')} a{fmt(a.get('alpha'))}"
              f"{' rn' if a.get('normalize_reward') else ''}" for a in arms]  # fmt: skip
    fig, axes = plt.subplots(1, 2, figsize=(9, 0.22 * len(arms) + 1.2), sharey=True,
                             layout="constrained")  # fmt: skip
    for ax, metric in zip(axes, ("return", "feedback_norm"), strict=True):
        for i, a in enumerate(arms):
            if not isinstance(a.get(metric), dict):
                continue
            low, high = t_interval(a[metric])
            color = "black" if not a.get("alpha") else "tab:blue"
            ax.plot([low, high], [i, i], color=color, lw=1.5)
            ax.plot(a[metric]["mean"], i, "o", color=color, ms=3)
        ax.set_title(f"{metric} (mean, 95% t interval)", fontsize=8)
        ax.tick_params(labelsize=6)
        ax.grid(alpha=0.3)
    axes[1].set_xscale("log")
    axes[0].set_yticks(range(len(arms)), labels)
    axes[0].invert_yaxis()
    fig.suptitle(name, fontsize=9)
    fig.savefig(path, dpi=110)
    plt.close(fig)


# Figures the pages show, drawn at build time from committed files: virtual path -> draw(path).
FIGURES: dict[str, Any] = {}


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
            "The full verdict table with each cell's reasoning is "
            + repo_link("experiments/results/paper_claims.md") + ".", ""]  # fmt: skip
    FIGURES["figures/claims_by_finding.png"] = lambda path: findings_figure(claims, path)
    figure = [
        "![each tested cell's difference, by finding](figures/claims_by_finding.png)",
        "",
        "*Every cell tested at the paper's stage: MA's difference from MB-MPO relative to "
        "MB-MPO's mean, with Welch's 95% interval, grouped by finding; the marker says "
        "the verdict under per-row Holm, the colour which way the paper claims.*",
        "",
    ]
    return "\n".join(head + figure + claims_section(claims) + [""] + study_sections()) + "\n"


def findings_figure(claims: dict[str, Any], path: str) -> None:
    """The tested cells' relative differences with their Welch intervals, one row per cell,
    grouped by finding: how large MA's effects are and how they line up with the verdicts."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = []
    for metric in ("feedback_norm", "return", "energy", "feedforward_norm"):
        for c in claims["cells"]:
            t, ours = c.get("tests"), c.get("ours") or {}
            if c["metric"] != metric or not t or ours.get("stage") != c["stage"]:
                continue
            if c["verdict"] == "no claim in the paper" or math.isnan(c.get("p_holm", math.nan)):
                continue
            scale = abs(ours["mbmpo"]["mean"]) or 1.0
            rows.append((metric, c, t["diff"] / scale, [v / scale for v in t["welch_ci"]]))
    fig, ax = plt.subplots(figsize=(7.5, 0.2 * len(rows) + 1.2), layout="constrained")
    marks = {"reproduced": "o", "not reproduced": "x"}
    for i, (_, c, diff, (low, high)) in enumerate(rows):
        color = "tab:green" if c["claimed"] == "lower" else "tab:purple"
        ax.plot([low, high], [i, i], color=color, lw=1.2)
        ax.plot(diff, i, marks.get(c["verdict"], "."), color=color, ms=5)
    ax.axvline(0, color="black", lw=0.6)
    ax.set_yticks(range(len(rows)), [f"{m} {c['env']} {c['phase'][5:9]} a{fmt(c['alpha'])}"
                                     for m, c, _, _ in rows], fontsize=6)  # fmt: skip
    ax.invert_yaxis()
    ax.set_xlabel("(MA - MB-MPO) / |MB-MPO mean|, Welch 95% interval", fontsize=8)
    ax.set_title("tested cells by finding (o reproduced, x other way, . inconclusive; green: "
                 "paper claims lower, purple: higher)", fontsize=7)  # fmt: skip
    ax.set_xlim(-1.5, 1.5)
    ax.grid(alpha=0.3)
    fig.savefig(path, dpi=110)
    plt.close(fig)


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


def settings_page() -> str:
    """Every configuration field (``--set GROUP.FIELD=VALUE``, ``mj.train(**fields)``), from the
    field declarations: its type and rule, its value in each preset, what it means."""
    from minatt_jax.config import PRESETS, settings_by_owner

    lines = ["# Settings", "",
             "Every field a run's configuration holds, generated from the field declarations at "
             "every build of this site. On the command line `--set GROUP.FIELD=VALUE` (and "
             "`--sweep GROUP.FIELD=V1,V2` for a population) sets one; in Python "
             "`minatt_jax.make_config(preset, overrides=[\"GROUP.FIELD=VALUE\"])` or "
             "`mj.train(group_field=value)`. A value outside a field's rule is refused in one "
             "line naming the field. The presets are `smoke` (tests), `cpu` (the default) and "
             "`paper` (the paper's appendix); a group belongs to the agents named in its "
             "heading, and a blank value is derived from the others (`resolve`). "
             "`minatt-jax train --help` prints the same list.", ""]  # fmt: skip
    for owner, rows in settings_by_owner(builtin_only=True):
        title = "Common to every agent" if owner == "common" else f"`--algo {owner}` adds"
        header = ["setting", "rule", *PRESETS, "meaning (where the default comes from)"]
        body = [[f"`{r['name']}`", r["rule"] or r["type"],
                 *[_shown(r["presets"][p]) for p in PRESETS],
                 r["meaning"] + (f" ({r['why']})" if r.get("why") else "")]
                for r in rows]  # fmt: skip
        lines += [f"## {title}", "", table(header, body), ""]
    return "\n".join(lines)


def _shown(value: Any) -> str:
    if value is None:
        return ""
    return ",".join(map(str, value)) if isinstance(value, tuple) else str(value)


def example_figures() -> dict[str, str]:
    """The committed example reports' figures the analysis page shows: virtual path -> file."""
    out = {}
    for report, names in (("hopper_sac20k_report", ("heatmap_feedback.png", "profiles.png",
                                                    "decomposition.png", "failure_grid.png")),
                          ("mamba_point_robot_report", ("adaptation.png",))):  # fmt: skip
        for name in names:
            out[f"figures/{report}/{name}"] = os.path.join(ROOT, "experiments/results", report,
                                                           name)  # fmt: skip
    return out


def front_figure(path: str) -> None:
    """The home page's figure, drawn from the committed reading study (tools/front_figure.py)."""
    sys.path.insert(0, os.path.join(ROOT, "tools"))
    import front_figure as tool

    tool.draw(path)


def changelog_page() -> str:
    """CHANGELOG.md, under the version this site documents."""
    from minatt_jax import __version__

    with open(os.path.join(ROOT, "CHANGELOG.md")) as f:
        text = f.read()
    return text.replace("# Changelog", f"# Changelog\n\nThis site documents minatt-jax "
                        f"{__version__} (`minatt-jax --version`).", 1)  # fmt: skip


PAGES = {"results.md": results_page, "benchmark-results.md": benchmark_page,
         "settings.md": settings_page, "changelog.md": changelog_page}  # fmt: skip

try:  # under `mkdocs build`: write the pages into the site's virtual docs folder
    import mkdocs_gen_files
except ImportError:  # imported by a test or run by hand
    mkdocs_gen_files = None
if mkdocs_gen_files is not None and __name__ in ("__main__", "<run_path>"):
    import tempfile

    for page, make in PAGES.items():
        with mkdocs_gen_files.open(page, "w") as f:
            f.write(make())
    FIGURES["figures/ma_hopper_sac.png"] = front_figure
    with tempfile.TemporaryDirectory() as tmp:
        drawn = {}
        for target, draw in FIGURES.items():
            drawn[target] = os.path.join(tmp, os.path.basename(target))
            draw(drawn[target])
        for target, source in {**drawn, **example_figures()}.items():
            with open(source, "rb") as src, mkdocs_gen_files.open(target, "wb") as f:
                f.write(src.read())
