"""The paper's numbers as data, the experiment tables' stages and arm statistics."""

from __future__ import annotations

import glob
import os
import re

import paper_numbers
import pytest
import study as xt

PAPER = glob.glob(
    os.path.join(os.path.dirname(__file__), "..", "..", "..", "shared", "paper", "*.tex")
)


@pytest.mark.skipif(not PAPER, reason="the paper's source is not beside this checkout")
def test_every_number_is_a_mean_pm_std_pair_of_the_paper() -> None:
    text = open(PAPER[0]).read()
    pairs = {(float(m), float(s)) for m, s in
             re.findall(r"(-?\d+(?:\.\d+)?)\s*\$\\pm\$\s*(\d+(?:\.\d+)?)", text)}  # fmt: skip
    rows = list(paper_numbers.TABLES.values()) + list(paper_numbers.ABLATION.values())
    missing = [v for row in rows for v in row.values() if v not in pairs]
    assert not missing, missing
    assert len(paper_numbers.TABLES) == 60  # HalfCheetah 24, three agents x 12


@pytest.mark.skipif(not PAPER, reason="the paper's source is not beside this checkout")
@pytest.mark.parametrize("label, table, columns", [
    ("table:appendix_mamba", "mamba_humanoid_dir", (0.0, 0.05, 0.01)),
    ("table:appendix_dreamer", "dreamer_cheetah_run", (0.0, 0.05)),
])  # fmt: skip
def test_world_model_tables_equal_the_papers_position_by_position(label, table, columns):
    """Tables S3 and S4: each row (its stage) and column (its alpha) against the source."""
    text = open(PAPER[0]).read()
    body = text[text.index("\\label{" + label) :].split("\\end{tabular}")[0]
    found = {}
    for line in body.splitlines():
        row = re.match(r"\s*(\d+(?:\.\d+)?)(M|K) \(", line)
        if not row:
            continue
        steps = int(float(row.group(1)) * (1_000_000 if row.group(2) == "M" else 1_000))
        pairs = re.findall(r"(-?\d+(?:\.\d+)?)\s*\$\\pm\$\s*(\d+(?:\.\d+)?)", line)
        for alpha, (mean, std) in zip(columns, pairs, strict=True):
            found[(table, steps, alpha)] = (float(mean), float(std))
    ours = {k: v for k, v in paper_numbers.WORLD_MODELS.items() if k[0] == table}
    assert len(found) == 3 * len(columns)
    assert ours == found


def test_the_papers_halfcheetah_percentages_follow_from_its_table() -> None:
    """The text: alpha = 1 gives 45% more reward, 28% less feedback and 15% less energy."""
    base = paper_numbers.reported("halfcheetah", "meta_training", 200_000, "mbmpo")
    ma = paper_numbers.reported("halfcheetah", "meta_training", 200_000, "ma", 1.0)
    assert round(100 * (ma["return"][0] / base["return"][0] - 1)) == 45
    assert round(100 * (1 - ma["feedback_norm"][0] / base["feedback_norm"][0])) == 28
    assert round(100 * (1 - ma["energy"][0] / base["energy"][0])) == 15
    assert paper_numbers.reported("hopper", "meta_training", 200_000, "ma", 0.05) is None


@pytest.mark.parametrize(
    "total, every, expected",
    [(600, 300, [600]), (50_000, 5_000, [10_000, 50_000]), (55_000, 10_000, [10_000, 60_000]),
     (200_000, 10_000, [10_000, 100_000, 200_000]), (8_000, 5_000, [10_000])],
)  # fmt: skip
def test_stages_are_the_papers_reached_on_the_evaluation_grid(total, every, expected) -> None:
    assert xt.stages(total, every) == expected


def test_arm_summary_gives_the_direction_only_when_the_interval_excludes_zero() -> None:
    lower = xt.arm_summary([1.0, 1.1, 0.9, 1.0, 1.05], [5.0, 5.2, 4.9, 5.1, 5.0])
    assert lower["vs_baseline"] == "lower" and lower["diff_ci"][1] < 0
    assert lower["n"] == 5 and lower["ci_low"] <= 1.01 <= lower["ci_high"]
    mixed = xt.arm_summary([1.0, 9.0, 2.0, 8.0, 5.0], [4.0, 6.0, 5.0, 5.5, 4.5])
    assert mixed["vs_baseline"] == "unresolved"
    assert "vs_baseline" not in xt.arm_summary([1.0, 2.0])
    assert xt.cell(None) == "-" and "n=5" in xt.cell(lower)


def test_study_overrides_reach_every_member_and_the_provenance() -> None:
    """``--set`` changes the preset every member starts from and is part of the command that
    reproduces the table; a bad override exits 2 with one line (the memory refusal advises it)."""
    import argparse

    parser = argparse.ArgumentParser()
    xt.add_study_arguments(parser, envs=["hopper"], runs="runs/x")
    args = parser.parse_args(["--scale", "smoke", "--set", "buffer_size=1234"])
    assert xt.study_preset(args).buffer_size == 1234
    assert xt.study_command("x.py", args).endswith(" --set buffer_size=1234")
    with pytest.raises(SystemExit) as stop:
        xt.study_preset(parser.parse_args(["--set", "no_such_field=1"]))
    assert stop.value.code == 2


def _fake_run(run_dir, config, steps: list[int]) -> None:
    """A run directory holding ``config`` and an evaluation record at each of ``steps``."""
    import json

    os.makedirs(run_dir)
    with open(os.path.join(run_dir, "config.json"), "w") as f:
        json.dump(config.to_dict(), f)
    with open(os.path.join(run_dir, "metrics.jsonl"), "w") as f:
        f.writelines(json.dumps({"step": s, **dict.fromkeys(paper_numbers.METRICS, float(s))})
                     + "\n" for s in steps)  # fmt: skip


def test_reuse_reads_only_members_with_the_same_settings_at_every_stage(tmp_path, capsys):
    """``--reuse`` takes another study's member only when its settings match (length and chunk
    length aside) and it was evaluated at every stage; the table reads it there, the provenance
    names the folder, and a missing folder exits 2."""
    import ablation

    from minatt_jax.config import replace_fields

    parser = ablation.build_parser()
    other = tmp_path / "meta_training"
    args = parser.parse_args(["--scale", "smoke", "--seeds", "0", "--runs", "runs/x",
                              "--reuse", str(other)])  # fmt: skip
    configs = ablation.members(args)  # full, jacobian, temporal, none (alpha 0)
    stage = xt.stages(configs[0].total_steps, configs[0].eval_every)[-1]
    # full: longer, other chunks -> reused; jacobian: another buffer; temporal: not at the
    # stage; none: reused; and a corrupt one beside them.
    _fake_run(
        other / "a",
        replace_fields(configs[0], {"total_steps": 2 * stage, "eval_every": 100}),
        [stage, 2 * stage],
    )
    _fake_run(other / "b", replace_fields(configs[1], {"buffer_size": 777}), [stage])
    _fake_run(other / "c", configs[2], [stage // 2])
    _fake_run(other / "d", configs[3], [stage])
    os.makedirs(other / "e")
    (other / "e" / "config.json").write_text("{")  # fmt: skip
    reused = xt.reused_runs(args, configs)
    assert reused == {0: str(other / "a"), 3: str(other / "d")}
    assert "note: not reading" in capsys.readouterr().err
    dirs = xt.dirs_by_arm(configs, "runs/x/smoke", ablation.SWEPT, "halfcheetah",
                          ablation.arm_of, reused)  # fmt: skip
    assert dirs["full"] == [str(other / "a")] and dirs["none"] == [str(other / "d")]
    assert dirs["jacobian"][0].startswith("runs/x/smoke/")
    assert xt.training_rows(dirs, stage)["full"]["return"]["mean"] == stage
    assert f"--reuse {other}" in xt.study_command("ablation.py", args)
    with pytest.raises(SystemExit) as stop:
        xt.reused_runs(parser.parse_args(["--reuse", str(tmp_path / "nothing")]), configs)
    assert stop.value.code == 2
