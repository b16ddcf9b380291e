"""Which reading of the paper's MA? Placement x reward normalization x alpha, seeds as populations.

    python experiments/reading_study.py [--scale smoke|cpu|paper] [--envs hopper halfcheetah]
        [--algo mbmpo] [--seeds 0-4] [--alphas 0.01 0.05 1 5]
        [--placements actor_loss reward entropy] [--normalize off on] [--steps N]
        [--runs runs/reading_study] [--records experiments/records] [--set FIELD=VALUE ...]

The paper puts the MA penalty in three places (added to the reward, to the policy loss, inside
the SAC objective beside the entropy) and says rewards were normalized. Arms: every placement x
reward normalization (off / on, ``sac.normalize_reward``) x alpha, against the alpha = 0 baseline
of the same normalization, on every environment, every arm with all seeds. All of it is one
population (``population.train_population``: a compiled program per environment, placement and
normalization, its seeds and alphas vmapped in it), so running the command again resumes it.

Per arm (the final deterministic evaluation of each seed): return, feedback, feedforward and
energy, mean +- std with 95% bootstrap intervals, and the difference from the baseline with its
interval (``stats``). An arm goes the **paper's direction** when feedback and energy
are lower (intervals below zero) and the return is not lower (its interval reaches zero or
above); with fewer than 5 seeds in an arm or its baseline there is no verdict. Contrasts answer
the study's other questions with intervals: normalization on minus off for each arm (the
baseline included) and each pair of placements at the same normalization and alpha. Writes
``experiments/results/reading_study_<scale>.{json,md}``, each arm with its seeds' values.

Arms that the runs folder does not hold (``--normalize on`` alone, or runs trained on another
machine and not copied here) keep their rows from the results file already written, marked
"stored": the runs are git-ignored, the results are not, so a study can be finished in parts.
Finer pieces (some seeds of an arm here, the others elsewhere) go through ``--records FOLDER``:
each member that finished keeps its config.json and metrics.jsonl in
``FOLDER/reading_study/<tag>/<member>``, members found there are read, not trained, and a
piece trains in a runs folder of its own (named by its members' digest).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
from typing import Any

import stats
import study as xt

from minatt_jax import population, runner
from minatt_jax.config import PRESETS, resolve, with_overrides

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")
METRICS = ("return", "feedback_norm", "feedforward_norm", "energy")
SWEPT = ["env", "ma.placement", "sac.normalize_reward", "ma.alpha"]
MIN_SEEDS = xt.MIN_SEEDS  # fewer seeds per arm: no verdict


def members(args: argparse.Namespace) -> list[Any]:
    """Every (environment, normalization, placement, alpha, seed); alpha 0 once per
    environment and normalization (no penalty: the placement does not matter)."""
    preset = xt.study_preset(args, args.algo)
    out = []
    for env in args.envs:
        for norm in (n == "on" for n in args.normalize):
            arms = [("actor_loss", 0.0)]
            arms += [(p, a) for p in args.placements for a in args.alphas if a > 0]
            for placement, alpha in arms:
                for seed in population.parse_seeds(args.seeds):
                    out.append(resolve(with_overrides(
                        preset, env=env, algo=args.algo, seed=seed,
                        ma_alpha=alpha, ma_placement=placement, sac_normalize_reward=norm,
                        total_steps=args.steps,
                    )))  # fmt: skip
    return out


def final_values(run_dir: str) -> dict[str, float] | None:
    """The last evaluation record's metrics (None before the first evaluation)."""
    records = runner.read_metrics(run_dir)
    if not records:
        return None
    return {"step": records[-1]["step"], **{m: records[-1][m] for m in METRICS}}


ARM_FIELDS = ("env", "normalize_reward", "placement", "alpha")


def arm_of(c: Any) -> dict[str, Any]:
    """The fields that name a member's arm (every seed of an arm shares them)."""
    return {"env": c.env, "normalize_reward": c.sac.normalize_reward,
            "placement": c.ma.placement, "alpha": c.ma.alpha}  # fmt: skip


def arm_key(row: dict[str, Any]) -> tuple:
    return tuple(row[f] for f in ARM_FIELDS)


def analyse(configs: list[Any], dirs: list[str]) -> list[dict[str, Any]]:
    """One row per arm (members ``configs`` in run directories ``dirs``): statistics over
    seeds and the difference from the baseline."""
    arms: dict[tuple, list[dict[str, float]]] = {}
    for c, run_dir in zip(configs, dirs, strict=True):
        values = final_values(run_dir)
        if values is not None and values["step"] >= c.total_steps:  # finished members only
            arms.setdefault(arm_key(arm_of(c)), []).append(values)
    rows = []
    for key, seeds in sorted(arms.items()):
        row: dict[str, Any] = {**dict(zip(ARM_FIELDS, key, strict=True)), "seeds": len(seeds),
                               "step": min(s["step"] for s in seeds)}  # fmt: skip
        alpha = row["alpha"]
        base = arms.get(arm_key({**row, "placement": "actor_loss", "alpha": 0.0}), [])
        for m in METRICS:
            values = [s[m] for s in seeds]
            row[m] = {**stats.summary(values), "values": values}
            if alpha > 0 and base:
                ci = stats.bootstrap_diff_ci(values, [b[m] for b in base])
                row[m]["diff_ci"] = ci
                row[m]["vs_baseline"] = stats.direction(ci)
        if alpha > 0 and min(len(seeds), len(base)) < MIN_SEEDS:
            row["paper_direction"] = None  # intervals from so few seeds say little
        elif alpha > 0 and base:
            row["paper_direction"] = (
                row["feedback_norm"]["vs_baseline"] == "lower"
                and row["energy"]["vs_baseline"] == "lower"
                and row["return"]["vs_baseline"] != "lower"
            )
        rows.append(row)
    return rows


def _contrast(kind: str, a: dict[str, Any], b: dict[str, Any], held: dict[str, Any],
              fixed: str, label: str) -> dict[str, Any]:  # fmt: skip
    """Arm ``a`` minus arm ``b``: per metric the difference of the seed means and its interval.
    ``held`` names what the two arms share (as fields), ``fixed`` says it for the table."""
    out: dict[str, Any] = {"env": a["env"], "kind": kind, "contrast": label, "fixed": fixed,
                           "held": held, "seeds": [a["seeds"], b["seeds"]]}  # fmt: skip
    resolved = min(a["seeds"], b["seeds"]) >= MIN_SEEDS
    for m in METRICS:
        ci = stats.bootstrap_diff_ci(a[m]["values"], b[m]["values"])
        out[m] = {"diff": a[m]["mean"] - b[m]["mean"], "diff_ci": list(ci),
                  "direction": stats.direction(ci) if resolved else None}  # fmt: skip
    return out


def contrasts(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The study's other two questions, with intervals: what reward normalization does to an
    arm (on minus off, same placement and alpha, the alpha-0 baseline included), and how the
    placements differ (each pair at the same normalization and alpha). Arms without their
    seeds' values (rows stored by an older version) are left out."""
    arms = {arm_key(r): r for r in rows if all("values" in r[m] for m in METRICS)}
    out = []
    for (env, norm, placement, alpha), row in sorted(arms.items()):
        off = arms.get((env, False, placement, alpha))
        if norm and off is not None:
            fixed = "alpha 0" if alpha == 0 else f"{placement}, alpha {alpha:g}"
            held = {"placement": placement, "alpha": alpha}
            out.append(_contrast("normalization", row, off, held, fixed, "on - off"))
    by_setting: dict[tuple, list[str]] = {}  # (env, norm, alpha) -> its placements, sorted
    for env, norm, placement, alpha in sorted(arms):
        if alpha > 0:
            by_setting.setdefault((env, norm, alpha), []).append(placement)
    for (env, norm, alpha), placements in by_setting.items():
        held = {"normalize_reward": norm, "alpha": alpha}
        fixed = f"norm {xt.on_off(norm)}, alpha {alpha:g}"
        for p, q in itertools.combinations(placements, 2):
            a, b = arms[(env, norm, p, alpha)], arms[(env, norm, q, alpha)]
            out.append(_contrast("placement", a, b, held, fixed, f"{p} - {q}"))
    return out


def contrasts_markdown(found: list[dict[str, Any]]) -> str:
    """The contrasts as a table: difference of means [95% interval] (direction)."""
    if not found:
        return ""
    lines = ["## Contrasts", "",
             "Arm minus arm, seeds resampled within each arm: difference of the means [95% "
             "bootstrap interval] (lower / higher when the interval excludes zero; no direction "
             f"under {MIN_SEEDS} seeds in either arm).", "",
             "| env | contrast | held fixed | seeds | " + " | ".join(METRICS) + " |",
             "|---" * (len(METRICS) + 4) + "|"]  # fmt: skip
    for c in found:
        cells = []
        for m in METRICS:
            lo, hi = c[m]["diff_ci"]
            direction = f" ({c[m]['direction']})" if c[m]["direction"] else ""
            cells.append(f"{c[m]['diff']:.4g} [{lo:.4g}, {hi:.4g}]{direction}")
        seeds = f"{c['seeds'][0]} / {c['seeds'][1]}"
        lines.append(f"| {c['env']} | {c['contrast']} | {c['fixed']} | {seeds} | "
                     + " | ".join(cells) + " |")  # fmt: skip
    return "\n".join(lines) + "\n"


def with_stored(rows: list[dict[str, Any]], path: str) -> list[dict[str, Any]]:
    """``rows`` and, for arms they lack, the rows of the results file at ``path`` (marked
    ``"stored": True``); an arm measured now replaces its stored row."""
    if not os.path.exists(path):
        return rows
    with open(path) as f:
        stored = json.load(f).get("arms", [])
    fresh = {arm_key(r) for r in rows}
    kept = [{**r, "stored": True} for r in stored if arm_key(r) not in fresh]
    return sorted(rows + kept, key=arm_key)


def markdown(rows: list[dict[str, Any]], header: str) -> str:
    def cell(s: dict[str, float]) -> str:
        text = f"{s['mean']:.4g} +- {s['std']:.2g} [{s['ci_low']:.4g}, {s['ci_high']:.4g}]"
        return text + (f" ({s['vs_baseline']})" if "vs_baseline" in s else "")

    lines = [header, "", "| env | reward norm | placement | alpha | seeds | step | "
             + " | ".join(METRICS) + " | paper's direction |",
             "|---" * (len(METRICS) + 7) + "|"]  # fmt: skip
    for r in rows:
        verdict = {True: "yes", False: "no", None: f"(< {MIN_SEEDS} seeds)"}.get(
            r.get("paper_direction", "baseline"), "baseline"
        )
        lines.append(
            f"| {r['env']} | {xt.on_off(r['normalize_reward'])} | {r['placement']} | "
            f"{r['alpha']:g} | {r['seeds']}{' (stored)' if r.get('stored') else ''} | "
            f"{r['step']} | " + " | ".join(cell(r[m]) for m in METRICS) + f" | {verdict} |"
        )
    return "\n".join(lines) + "\n"


def member_dirs(args: argparse.Namespace, configs: list[Any], tag: str) -> list[str]:
    """Trains (or resumes) the members, unless ``--analyse-only``, and returns each one's run
    directory. With ``--records``: members kept there are read, not trained; the others train
    in a runs folder named by the piece's members and are kept there too, each group as it
    finishes (a machine lost mid-piece loses only the group in progress)."""
    reused = xt.reused_runs(args, configs) if args.records else {}
    every_name = [population.member_name(c, SWEPT) for c in configs]
    to_train = [c for i, c in enumerate(configs) if i not in reused]
    names = [n for i, n in enumerate(every_name) if i not in reused]
    out_dir = os.path.join(args.runs, tag)
    keep = None
    if args.records:  # a piece of the study: a population of its own
        # Named by all its members, kept or not: groups kept as they finish leave the folder
        # where it is, so the same piece run again resumes the group in progress.
        out_dir = xt.piece_folder(out_dir, every_name)
        steps = xt.stages(configs[0].total_steps, configs[0].eval_every)
        target = os.path.join(args.records, "reading_study", tag)

        def keep(dirs: list[str]) -> None:
            xt.keep_records(dirs, steps, target, "reading_study")

        print(f"reading_study: {len(reused)} members read from {args.records}, "
              f"{len(to_train)} to train in {out_dir}", flush=True)  # fmt: skip
    if not args.analyse_only and to_train:
        resume = os.path.exists(os.path.join(out_dir, "population.json"))
        try:
            population.train_population(to_train, out_dir, SWEPT, resume=resume,
                                        after_group=keep)  # fmt: skip
        except runner.RunError as e:  # a stop or a refusal: one line; run again to resume
            raise SystemExit(f"reading_study: {e}") from None
    # Again for all: members trained before this call, found by --analyse-only, or trained by
    # another process of a split population (after_group sees this process's share alone);
    # re-copying a group kept a moment ago costs about 10 KB a member.
    if keep is not None:
        keep([os.path.join(out_dir, n) for n in names])
    return [reused.get(i) or os.path.join(out_dir, n) for i, n in enumerate(every_name)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", default="cpu", choices=sorted(PRESETS))
    parser.add_argument("--envs", nargs="+", default=["hopper", "halfcheetah"])
    parser.add_argument("--algo", default="mbmpo")
    parser.add_argument("--seeds", default="0-4")
    parser.add_argument("--alphas", type=float, nargs="+", default=[0.01, 0.05, 1.0, 5.0])
    parser.add_argument("--placements", nargs="+", default=["actor_loss", "reward", "entropy"])
    parser.add_argument("--normalize", nargs="+", default=["off", "on"], choices=["off", "on"],
                        help="reward normalization arms to train (default: both)")  # fmt: skip
    parser.add_argument("--steps", type=int, default=None,
                        help="env steps per member (default: the scale's preset)")  # fmt: skip
    parser.add_argument("--runs", default="runs/reading_study")
    parser.add_argument("--analyse-only", action="store_true",
                        help="tabulate what the runs hold now, without training")  # fmt: skip
    parser.add_argument("--records", default=None, metavar="FOLDER",
                        help="keep finished members' result files in FOLDER and read "
                             "members kept there instead of training them: the study in "
                             "pieces on machines that do not keep runs/ "
                             "(experiments/records)")  # fmt: skip
    xt.add_set_argument(parser)
    xt.add_no_tables_argument(parser)
    args = parser.parse_args()
    configs = members(args)
    tag = args.scale if args.steps is None else f"{args.scale}_{args.algo}_{args.steps // 1000}k"
    dirs = member_dirs(args, configs, tag)
    if args.no_tables:
        return
    rows = with_stored(analyse(configs, dirs), os.path.join(RESULTS, f"reading_study_{tag}.json"))
    command = ("python experiments/reading_study.py --scale "
               f"{args.scale} --envs {' '.join(args.envs)} --algo {args.algo} --seeds "
               f"{args.seeds} --alphas {' '.join(f'{a:g}' for a in args.alphas)} "
               f"--placements {' '.join(args.placements)} --normalize {' '.join(args.normalize)}"
               + (f" --steps {args.steps}" if args.steps else "")
               + "".join(f" --set {o}" for o in args.overrides)
               + (f" --records {args.records}" if args.records else ""))  # fmt: skip
    found = contrasts(rows)
    result = {**xt.provenance(command), "arms": rows, "contrasts": found}
    header = (f"# Reading study ({tag})\n\n`{command}` on {result['device']}. "
              "Final deterministic evaluation per seed; mean +- std over seeds [95% bootstrap "
              "interval of the mean] (direction against alpha = 0 with the same reward "
              "normalization, when its interval excludes zero). Seeds marked (stored): the arm's "
              "row as an earlier run wrote it (its runs are not in this runs folder).")  # fmt: skip
    text = markdown(rows, header) + "\n" + contrasts_markdown(found)
    xt.write_study(RESULTS, f"reading_study_{tag}", result, text)
    print(text)


if __name__ == "__main__":
    main()
