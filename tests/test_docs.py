"""The front page and the documentation site: the site builds with warnings as errors, its
generated pages carry the committed JSON's numbers, and the README's figures and results come
from the committed files."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from collections import Counter

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def load_module(path: str, name: str):
    spec = importlib.util.spec_from_file_location(name, os.path.join(ROOT, path))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def read(path: str) -> str:
    with open(os.path.join(ROOT, path), encoding="utf-8") as f:
        return f.read()


def test_the_site_builds_with_warnings_as_errors(tmp_path):
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1", "DISABLE_MKDOCS_2_WARNING": "true"}
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-d",
                           str(tmp_path / "site")], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=600)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-4000:]
    for page in ("index.html", "results/index.html", "benchmark-results/index.html",
                 "api/index.html"):  # fmt: skip
        assert (tmp_path / "site" / page).is_file(), page
    # the API reference was generated from the docstrings
    assert "make_config" in (tmp_path / "site" / "api" / "index.html").read_text()


def test_a_broken_link_fails_the_build(tmp_path):
    docs = tmp_path / "docs"
    docs.mkdir()
    (docs / "index.md").write_text("# x\n\n[gone](missing.md)\n")
    (tmp_path / "mkdocs.yml").write_text("site_name: x\nstrict: true\n")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1", "DISABLE_MKDOCS_2_WARNING": "true"}
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "-d", str(tmp_path / "s")],
                          cwd=tmp_path, env=env, capture_output=True, text=True)  # fmt: skip
    assert proc.returncode != 0 and "missing.md" in proc.stderr


def test_the_results_page_is_the_committed_claims():
    pages = load_module("docs/gen_pages.py", "gen_pages")
    claims = json.loads(read("experiments/results/paper_claims.json"))
    page = pages.results_page()
    for line in claims["summary"]:
        assert line in page
    counts = Counter(c["verdict"] for c in claims["cells"])
    for verdict, n in counts.items():
        assert f"| {verdict} | {n} |" in page
    # one row per cell, each with its verdict in the last column
    assert page.count(" |\n") >= len(claims["cells"])
    # a study's numbers, formatted from its JSON
    study = json.loads(read("experiments/results/reading_study_cpu_sac_20k.json"))
    arm = study["arms"][0]
    assert f"{arm['return']['mean']:.4g} +- {arm['return']['std']:.4g}" in page


def test_the_benchmark_page_names_every_result_files_command_and_figures():
    pages = load_module("docs/gen_pages.py", "gen_pages")
    page = pages.benchmark_page()
    results = os.path.join(ROOT, "benchmarks", "results")
    for name in sorted(os.listdir(results)):
        data = json.loads(read(os.path.join("benchmarks", "results", name)))
        assert f"## {os.path.splitext(name)[0]}" in page
        if "command" in data:
            assert data["command"].replace("|", "\\|") in page
    overhead = json.loads(read("benchmarks/results/ma_overhead.json"))
    first = overhead["rows"][0]
    number = next(v for v in first.values() if isinstance(v, float))
    assert f"{number:.4g}" in page


def test_readme_is_a_front_page_with_the_committed_results():
    readme = read("README.md")
    assert len(readme.splitlines()) <= 200
    assert "docs/assets/ma_hopper_sac.png" in readme
    assert os.path.isfile(os.path.join(ROOT, "docs", "assets", "ma_hopper_sac.png"))
    claims = json.loads(read("experiments/results/paper_claims.json"))
    for line in claims["summary"]:  # regenerate paper_claims.md, then copy its summary here
        assert line in readme, line
    # every docs link of the README points at a page of the site
    import re

    for target in re.findall(r"\]\((docs/[^)#]+)", readme):
        assert os.path.isfile(os.path.join(ROOT, target)), target


def test_front_figure_plots_the_studys_arms():
    figure = load_module("tools/front_figure.py", "front_figure")
    arms = figure.arms()
    assert [a["alpha"] for a in arms] == [0.0, 0.05, 1.0]
    assert all(not a["normalize_reward"] for a in arms)
    assert arms[1]["feedback_norm"]["mean"] < arms[0]["feedback_norm"]["mean"] / 10


def test_packaged_reference_runs_equal_the_study():
    tool = load_module("tools/reference_runs.py", "reference_runs")
    from minatt_jax.reference import reference_runs

    assert reference_runs() == json.loads(json.dumps(tool.reference_rows()))


def test_train_prints_the_matching_reference_rows_and_says_what_they_cover_otherwise():
    from minatt_jax.config import PRESETS, resolve, with_overrides
    from minatt_jax.reference import comparison_lines, reference_runs

    config = resolve(with_overrides(PRESETS["cpu"], env="hopper", total_steps=20_000,
                                    ma_alpha=0.05))  # fmt: skip
    record = {"return": 250.0, "feedback_norm": 9.0, "energy": 0.6}
    lines = comparison_lines(config, record)
    rows = {
        r["alpha"]: r
        for r in reference_runs()["rows"]
        if not r["normalize_reward"] and (r["alpha"] == 0 or r["placement"] == "entropy")
    }
    assert len(lines) == 3 + len(rows) + 1
    assert lines[3].startswith("alpha 0 (5 seeds)")
    assert f"{rows[0.0]['return']['mean']:.4g}" in lines[3]
    assert "this run, alpha 0.05" in lines[2] and "250" in lines[2]
    for other in (dict(total_steps=50_000), dict(env="walker2d"), dict(ma_mode="jacobian")):
        lines = comparison_lines(resolve(with_overrides(config, **other)), record)
        assert len(lines) == 1 and "no measured reference for these settings" in lines[0]
        assert "sac on hopper (cpu, 20,000 steps)" in lines[0], other
    normalized = resolve(with_overrides(config, sac_normalize_reward=True))
    baseline = next(r for r in reference_runs()["rows"]
                    if r["normalize_reward"] and r["alpha"] == 0)  # fmt: skip
    assert f"{baseline['return']['mean']:.4g}" in comparison_lines(normalized, record)[3]


@pytest.mark.parametrize("flag", ["--alpha", "--placement", "--steps", "--normalize-reward"])
def test_train_help_states_each_default_and_its_source(flag):
    from minatt_jax.cli import build_parser

    train = next(a for a in build_parser()._subparsers._group_actions[0].choices.items()
                 if a[0] == "train")[1]  # fmt: skip
    action = next(a for a in train._actions if flag in a.option_strings)
    assert "default" in action.help and ":" in action.help.split("default", 1)[1]
