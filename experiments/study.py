"""The module the studies share (members -> population -> tables): stages, per-arm seed
statistics, cells, records, provenance.

The experiments under ``experiments/`` (reading study, meta-training and meta-testing tables,
ablation, ensemble size) read their members' evaluation records at the paper's stages and
summarize each arm over seeds the same way: mean +- sample std (ddof 1, as the paper's +-
values) with the 95% bootstrap interval of the mean, and the difference from a baseline arm with
its bootstrap and Welch intervals and the exact permutation test's p-value (``stats``).
"""

from __future__ import annotations

import argparse
import glob
import hashlib
import json
import os
import platform
import sys
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import paper_numbers
import stats

from minatt_jax import run_files, runner

MIN_SEEDS = 5  # fewer seeds per arm: no verdict (a bootstrap over 2-4 values says little)


def on_off(flag: bool) -> str:
    """How the tables write a switch such as reward normalization."""
    return "on" if flag else "off"


def stages(total_steps: int, eval_every: int) -> list[int]:
    """The paper's stages (10K / 100K / 200K) that a run of ``total_steps`` reaches, rounded up
    to the evaluation grid, plus its last evaluation when that is not one of them."""

    def on_grid(s: int) -> int:
        return -(-s // eval_every) * eval_every

    last = on_grid(total_steps)
    out = sorted({on_grid(s) for s in paper_numbers.STAGES if on_grid(s) <= last} | {last})
    return out


def record_at(run_dir: str, step: int) -> dict[str, Any] | None:
    """The evaluation record of ``run_dir`` at ``step`` (None when the run has not reached it)."""
    if not os.path.isdir(run_dir):
        return None
    for record in runner.read_metrics(run_dir):
        if record["step"] == step:
            return record
    return None


def training_rows(dirs_by_arm: dict[str, list[str]], step: int,
                  baseline: str | None = None) -> dict[str, Any]:  # fmt: skip
    """Per arm, the evaluation metrics at ``step`` over its seeds (the runs that reached it),
    each arm but ``baseline`` also against ``baseline``'s seeds."""
    values = {arm: [r for d in dirs if (r := record_at(d, step)) is not None]
              for arm, dirs in dirs_by_arm.items()}  # fmt: skip
    rows: dict[str, Any] = {}
    for arm, records in values.items():
        base = values.get(baseline) if baseline is not None and arm != baseline else None
        rows[arm] = {m: arm_summary([r[m] for r in records], base and [r[m] for r in base])
                     for m in paper_numbers.METRICS}  # fmt: skip
        rows[arm]["seeds"] = len(records)
    return rows


def curves(dirs: list[str], metric: str = "return") -> dict[str, list[float]]:
    """Mean and std over ``dirs`` of ``metric`` at every evaluation step all of them reached."""
    per_run = [{r["step"]: r[metric] for r in runner.read_metrics(d)} for d in dirs
               if os.path.isdir(d)]  # fmt: skip
    if not per_run:
        return {"step": [], "mean": [], "std": []}
    steps = sorted(set.intersection(*(set(p) for p in per_run)))
    values = np.array([[p[s] for s in steps] for p in per_run])
    return {
        "step": steps,
        "mean": values.mean(0).tolist(),
        "std": values.std(0, ddof=1 if len(values) > 1 else 0).tolist(),
    }


def provenance(command: str) -> dict[str, str]:
    """The command, date and device a result was made with."""
    import datetime

    import jax

    device = jax.devices()[0]
    if device.platform == "cpu":
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None
        pinned = f", {cores} core{'s' * (cores != 1)} used" if cores else ""
        name = f"a {os.cpu_count()}-core {platform.machine()} CPU{pinned}"
    else:
        name = f"{len(jax.devices())} x {device.device_kind}"
    return {"command": command, "date": datetime.date.today().isoformat(), "device": name}


def arm_summary(values: Sequence[float], baseline: Sequence[float] | None = None) -> dict:
    """``stats.summary`` of one arm's per-seed values; with ``baseline``, the interval of the
    difference of the means and its direction (lower / higher / unresolved)."""
    out = stats.summary(values)
    out["values"] = [float(v) for v in values]
    if baseline is not None and len(values) and len(baseline):
        ci = stats.bootstrap_diff_ci(values, baseline)
        out["diff_ci"] = ci
        out["vs_baseline"] = stats.direction(ci)
        out["welch_ci"] = stats.welch_ci(values, baseline)
        out["permutation_p"] = stats.permutation_p(values, baseline)
    return out


def cell(s: dict[str, Any] | None, digits: int = 4) -> str:
    """'mean +- std [lo, hi] (n)' for a markdown table ('-' for nothing)."""
    if not s or not s.get("n"):
        return "-"
    text = (f"{s['mean']:.{digits}g} +- {s['std']:.2g} [{s['ci_low']:.{digits}g}, "
            f"{s['ci_high']:.{digits}g}] n={s['n']}")  # fmt: skip
    return text + (f" ({s['vs_baseline']})" if "vs_baseline" in s else "")


def paper_cell(number: tuple[float, float] | None) -> str:
    """The paper's 'mean +- std' ('-' where it reports none)."""
    return "-" if number is None else f"{number[0]:g} +- {number[1]:g}"


def stage_label(step: int) -> str:
    """10000 -> "10K", 2500000 -> "2.5M" (the paper's way of naming its stages)."""
    if step >= 1_000_000 and step % 100_000 == 0:
        return f"{step / 1_000_000:g}M"
    return f"{step // 1000}K" if step % 1000 == 0 else str(step)


def meta_test_rows(per_seed: list[list[dict]], baseline: list[list[dict]] | None,
                   variants: list[str]) -> dict[str, Any]:  # fmt: skip
    """Meta-test statistics of one arm from ``per_seed`` lists of ``meta_test.meta_test``
    results (one per variant): per variant and averaged over variants, before and after
    adaptation and their change, over the seeds that have every variant (against
    ``baseline``'s seeds where given), and the mean adaptation curve of the return."""
    complete = [tests for tests in per_seed if len(tests) == len(variants)]
    base = [t for t in (baseline or []) if len(t) == len(variants)]
    rows: dict[str, Any] = {"seeds": len(complete)}
    for name in [*variants, "average"]:

        def chosen(tests: list[dict], name: str = name) -> list[dict]:
            return tests if name == "average" else [t for t in tests if t["variant"] == name]

        def pick(tests: list[dict], when: str, m: str) -> float:
            return float(np.mean([t["mean_over_tasks"][m][when] for t in chosen(tests)]))

        row: dict[str, Any] = {}
        for m in paper_numbers.METRICS:
            for when in ("before", "after"):
                row[f"{m}_{when}"] = arm_summary(
                    [pick(t, when, m) for t in complete],
                    [pick(t, when, m) for t in base] if baseline is not None else None,
                )
            row[f"{m}_change"] = arm_summary(
                [pick(t, "after", m) - pick(t, "before", m) for t in complete]
            )
        if complete:
            # per seed: the mean over task sets of each set's mean curve over its tasks
            curves = [np.mean([np.mean([task["return_curve"] for task in t["tasks"]], 0)
                               for t in chosen(tests)], 0) for tests in complete]  # fmt: skip
            row["return_curve_mean"] = np.mean(curves, 0).tolist()
            row["return_curve_std"] = np.std(curves, 0, ddof=1 if len(curves) > 1 else 0).tolist()
        rows[name] = row
    return rows


def add_study_arguments(parser: argparse.ArgumentParser, envs: list[str], runs: str,
                        reuse: bool = False, several_alphas: bool = False) -> None:  # fmt: skip
    """The options every study script takes: scale, length, environments, seeds, alpha (a
    list with ``several_alphas``), the reading of MA, configuration overrides, --collect-only
    and where the runs go; with ``reuse``, ``--reuse FOLDER`` (``reused_runs``)."""
    from minatt_jax.config import PRESETS

    parser.add_argument("--scale", default="cpu", choices=sorted(PRESETS))
    parser.add_argument("--steps", type=int, default=None, help="default: the scale's preset")
    parser.add_argument("--envs", nargs="+", default=envs)
    parser.add_argument("--seeds", default="0-4")
    if several_alphas:
        parser.add_argument("--alpha", type=float, nargs="+", default=[1.0],
                            help="MA weights, one MA arm each (default: 1)")  # fmt: skip
    else:
        parser.add_argument("--alpha", type=float, default=1.0)
    parser.add_argument("--placement", default=None, help="default: the library's")
    parser.add_argument("--normalize-reward", action="store_true", default=None)
    parser.add_argument("--collect-only", action="store_true",
                        help="tabulate what the runs hold now, without training")  # fmt: skip
    parser.add_argument("--runs", default=runs)
    add_set_argument(parser)
    parser.add_argument("--records", default=None, metavar="FOLDER",
                        help="keep each member's small result files (config.json, "
                             "metrics.jsonl, meta_test/) in FOLDER once it reached every "
                             "stage, and read members kept there instead of training them: "
                             "a grid run in pieces (--seeds) on machines that do not keep "
                             "runs/, e.g. experiments/records")  # fmt: skip
    add_no_tables_argument(parser)
    if reuse:
        parser.add_argument("--reuse", action="append", default=[], metavar="FOLDER",
                            help="another study's runs (e.g. runs/meta_training/halfcheetah/"
                                 "cpu_10k): its members with this study's settings that "
                                 "reached every stage are read, not trained again "
                                 "(repeatable)")  # fmt: skip


def add_set_argument(parser: argparse.ArgumentParser) -> None:
    """``--set FIELD=VALUE`` (repeatable): a configuration override for every member, read by
    ``study_preset``."""
    parser.add_argument("--set", action="append", default=[], dest="overrides",
                        metavar="FIELD=VALUE",
                        help="override a configuration field for every member, e.g. "
                             "buffer_size=10000 (repeatable)")  # fmt: skip


def add_no_tables_argument(parser: argparse.ArgumentParser) -> None:
    """``--no-tables``: train (and keep the records) only, for a piece of a grid."""
    parser.add_argument("--no-tables", action="store_true",
                        help="train (and keep the records) only: for a piece of a grid, "
                             "whose tables would hold its own members alone and overwrite "
                             "the whole grid's")  # fmt: skip


def study_preset(args: argparse.Namespace, algo: str = "mbmpo") -> Any:
    """The scale's preset for ``algo`` (the study's agent: its settings groups are what
    ``--set`` may name) with the ``--set`` overrides: what every member starts from. A bad
    override exits 2 with one line."""
    from minatt_jax.config import PRESETS, apply_overrides, with_overrides

    try:
        return apply_overrides(with_overrides(PRESETS[args.scale], algo=algo), args.overrides)
    except ValueError as e:
        print(f"{os.path.basename(sys.argv[0])}: {e}", file=sys.stderr)
        raise SystemExit(2) from None


def study_tag(args: argparse.Namespace) -> str:
    """The scale, and the length where ``--steps`` shortens it (``cpu_20k``)."""
    return args.scale if args.steps is None else f"{args.scale}_{args.steps // 1000}k"


def study_command(script: str, args: argparse.Namespace, extra: str = "") -> str:
    """The command line that reproduces a study's result (for its provenance)."""
    return (f"python experiments/{script} --scale {args.scale}"
            + (f" --steps {args.steps}" if args.steps else "")
            + f" --envs {' '.join(args.envs)} --seeds {args.seeds} --alpha "
            + " ".join(f"{a:g}" for a in np.atleast_1d(args.alpha))
            + (f" --placement {args.placement}" if args.placement else "")
            + (" --normalize-reward" if args.normalize_reward else "")
            + "".join(f" --set {o}" for o in args.overrides)
            + "".join(f" --reuse {f}" for f in getattr(args, "reuse", []))
            + (f" --records {args.records}" if getattr(args, "records", None) else "")
            + extra)  # fmt: skip


def dirs_by_arm(configs: list[Any], out_dir: str, swept: list[str], env: str,
                arm_of: Callable[[Any], str],
                reused: dict[int, str] | None = None) -> dict[str, list[str]]:  # fmt: skip
    """The run directories of ``env``'s members (``reused`` ones where they were found),
    grouped by ``arm_of(config)``."""
    from minatt_jax.population import member_name

    out: dict[str, list[str]] = {}
    for i, c in enumerate(configs):
        if c.env == env:
            d = (reused or {}).get(i) or os.path.join(out_dir, member_name(c, swept))
            out.setdefault(arm_of(c), []).append(d)
    return out


def reused_runs(args: argparse.Namespace, configs: list[Any],
                complete: Callable[[str], bool] | None = None) -> dict[int, str]:  # fmt: skip
    """Members (index -> run directory) already trained in one of the ``--reuse`` folders or
    kept anywhere under ``--records``: a run whose config.json has the member's settings (its
    length and chunk length aside), an evaluation at every stage of this study and, where
    given, ``complete(run_dir)`` (e.g. its meta-tests). A ``--reuse`` folder that is not one
    exits 2."""
    folders = []
    for folder in getattr(args, "reuse", []):
        if not os.path.isdir(folder):
            print(f"{os.path.basename(sys.argv[0])}: --reuse {folder}: no such folder",
                  file=sys.stderr)  # fmt: skip
            raise SystemExit(2)
        folders += [os.path.join(folder, name) for name in sorted(os.listdir(folder))]
    if getattr(args, "records", None):
        folders += sorted(d for d, _, files in os.walk(args.records) if "config.json" in files)
    candidates = []
    for run_dir in folders:
        if os.path.isfile(os.path.join(run_dir, "config.json")):
            try:
                candidates.append((run_dir, runner.load_config(run_dir)))
            except runner.RunError as e:  # not reusable, said once
                print(f"note: not reading {run_dir}: {e}", file=sys.stderr)
    steps = stages(configs[0].total_steps, configs[0].eval_every)
    found = {}
    for i, c in enumerate(configs):
        for d, stored in candidates:
            if (same_member(c, stored) and all(record_at(d, s) for s in steps)
                    and (complete is None or complete(d))):  # fmt: skip
                found[i] = d
                break
    return found


def write_study(results: str, name: str, result: dict[str, Any], text: str) -> None:
    """``<results>/<name>.json`` and ``.md``, atomically."""
    os.makedirs(results, exist_ok=True)
    runner.write_json_atomic(os.path.join(results, f"{name}.json"), result)
    runner.write_text_atomic(os.path.join(results, f"{name}.md"), text)


def train_study(name: str, args: argparse.Namespace, configs: list[Any], swept: list[str],
                at_stage: Callable[[int, list[str]], None] | None = None,
                reused: dict[int, str] | None = None) -> tuple[list[int], str, str]:  # fmt: skip
    """Trains (or resumes) a study's population stage by stage unless ``--collect-only``, but
    the ``reused`` members; with ``--records``, keeps the trained members' results there (and
    trains in a ``piece_folder``, so that the pieces of a grid on one machine are separate
    populations). Returns (stages, tag, runs folder). A stop or refusal exits with one line."""
    from minatt_jax.population import member_name, train_in_stages

    steps = stages(configs[0].total_steps, configs[0].eval_every)
    tag = study_tag(args)
    records = getattr(args, "records", None)
    to_train = [c for i, c in enumerate(configs) if i not in (reused or {})]
    out_dir = os.path.join(args.runs, tag)
    if records:
        out_dir = piece_folder(out_dir, [member_name(c, swept) for c in to_train])
    if reused:
        print(f"{name}: {len(reused)} members read from --reuse/--records, {len(to_train)} to "
              "train", flush=True)  # fmt: skip
    try:
        if not args.collect_only and to_train:
            train_in_stages(to_train, out_dir, swept, steps, at_stage)
    except runner.RunError as e:
        raise SystemExit(f"{name}: {e}") from None
    if records:
        keep_records([os.path.join(out_dir, member_name(c, swept)) for c in to_train], steps,
                     os.path.join(records, name, tag), name)  # fmt: skip
    return steps, tag, out_dir


def piece_folder(out_dir: str, names: list[str]) -> str:
    """``<out_dir>_<digest of the member names>``: the runs folder of one piece of a grid, so
    that pieces splitting seeds, arms, placements or normalization on one machine do not
    collide, and the same piece run again resumes."""
    return f"{out_dir}_{hashlib.sha1(' '.join(names).encode()).hexdigest()[:8]}"


def same_member(config: Any, stored: Any) -> bool:
    """Whether a run stored with config ``stored`` is the member ``config``: the same settings,
    its length and chunk length aside."""
    return runner.with_stored_schedule(config, stored).to_dict() == stored.to_dict()


def record_folder(target: str, run_dir: str) -> str:
    """Where ``run_dir``'s record goes under ``target``: the folder of the run's name that
    already holds this member's record, else ``<run name>`` when free, else ``<run name>_<digest
    of its settings>``. Why: two studies name members alike (meta_training's HalfCheetah
    baseline with and without ``--set buffer_size=10000``); one must not overwrite the other's
    record, which ``reused_runs`` finds by its settings, not its name."""
    name, config = os.path.basename(run_dir), runner.load_config(run_dir)
    held = sorted(f for f in (os.listdir(target) if os.path.isdir(target) else [])
                  if f == name or f.startswith(f"{name}_"))  # fmt: skip
    for folder in held:
        path = os.path.join(target, folder)
        if os.path.isfile(os.path.join(path, "config.json")) and same_member(
            config, runner.load_config(path)
        ):
            return path
    if name not in held:
        return os.path.join(target, name)
    digest = hashlib.sha1(json.dumps(config.to_dict(), sort_keys=True).encode()).hexdigest()
    return os.path.join(target, f"{name}_{digest[:8]}")


def checkpointed_run(run_dir: str, runs: str, step: int) -> str:
    """``run_dir`` when it holds a checkpoint at ``step`` or later, else the run that made its
    record: the same member (``same_member``) with the same evaluation at ``step`` and such a
    checkpoint, in a folder under ``runs`` (``runs/<piece>/<run>``). A record keeps no
    checkpoints, but the piece that trained it on the same machine does, and the analyze report
    needs the policies; another draw of the member (a retrained seed) is not it. ``run_dir``
    again when there is none."""
    from minatt_jax import checkpoint

    def at_step(d: str) -> bool:
        latest = checkpoint.latest_step(d)
        return latest is not None and latest >= step

    if at_step(run_dir) or not os.path.isdir(runs):
        return run_dir
    config, evaluation = runner.load_config(run_dir), record_at(run_dir, step)
    for path in sorted(glob.glob(os.path.join(glob.escape(runs), "*", "*", "config.json"))):
        d = os.path.dirname(path)
        if (same_member(config, runner.load_config(d)) and record_at(d, step) == evaluation
                and at_step(d)):  # fmt: skip
            return d
    return run_dir


def keep_records(dirs: list[str], steps: list[int], target: str, name: str) -> None:
    """Copies the result files of the runs in ``dirs`` that reached every stage in ``steps``
    to their ``record_folder`` under ``target`` (``run_files.copy_results``) and says how many."""
    done = [d for d in dirs if all(record_at(d, s) for s in steps)]
    for d in done:
        run_files.copy_results(d, record_folder(target, d))
    print(f"{name}: results of {len(done)} members kept in {target}", flush=True)
