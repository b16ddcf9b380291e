"""The ``minatt-jax`` command line: envs, rollout, train, evaluate, meta-test, analyze, inspect.

Every user error (unknown name, invalid number, unwritable output) prints one line starting with
``minatt-jax: error:`` and exits with status 2, without a traceback.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
from collections.abc import Sequence
from typing import Any, NoReturn

EXIT_USER_ERROR = 2
FLOAT32_MAX = 3.4028234663852886e38


class UserError(Exception):
    """An error reported in one line: the user's input (exit status 2), or a run that stopped
    (diverged: 3; SIGINT: 130; SIGTERM: 143)."""

    def __init__(self, message: str, exit_status: int = EXIT_USER_ERROR) -> None:
        super().__init__(message)
        self.exit_status = exit_status


class _Parser(argparse.ArgumentParser):
    """argparse that reports errors in one line (no usage block) with exit status 2."""

    def error(self, message: str) -> NoReturn:
        sys.stderr.write(f"minatt-jax: error: {message}\n")
        raise SystemExit(EXIT_USER_ERROR)


def _number(kind: type, minimum: float, strict: bool, label: str):
    """An argparse type: ``kind`` (int or float) above ``minimum`` (strictly or not), finite."""

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {label}, got {text!r}") from None
        too_small = value <= minimum if strict else value < minimum
        if too_small or value != value or value in (float("inf"), float("-inf")):
            raise argparse.ArgumentTypeError(f"expected {label}, got {text!r}")
        if kind is float and abs(value) > FLOAT32_MAX:
            raise argparse.ArgumentTypeError(f"{text} overflows float32 (training runs in float32)")
        if kind is int and value >= 2**31:
            raise argparse.ArgumentTypeError(f"{text} is too large (at most {2**31 - 1})")
        return value

    return parse


_positive_int = _number(int, 0, True, "a positive integer")
_non_negative_int = _number(int, 0, False, "an integer >= 0")
_non_negative_float = _number(float, 0.0, False, "a finite number >= 0")


def _plugin_option() -> argparse.ArgumentParser:
    """``--plugin MODULE``, on every command: a module to import first (it registers agents or
    environments); ``MINATT_JAX_PLUGINS`` names more (comma-separated)."""
    parent = argparse.ArgumentParser(add_help=False)
    parent.add_argument(
        "--plugin", action="append", default=argparse.SUPPRESS, metavar="MODULE",
        help="import MODULE first: it registers an agent or environment (repeatable; also "
        "MINATT_JAX_PLUGINS=mod1,mod2; installed plugins and a run's own agent load by "
        "themselves)",
    )  # fmt: skip
    return parent


_PLUGINS = _plugin_option()


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("minatt-jax")
    except PackageNotFoundError:
        return "unknown (not installed)"


def settings_epilog() -> str:
    """Every setting ``--set`` and ``--sweep`` take (the common ones, then each known agent's
    groups), with its rule and its cpu-preset value, from the field declarations."""
    from minatt_jax.config import settings_by_owner

    lines = ["settings (--set GROUP.FIELD=VALUE, --sweep GROUP.FIELD=V1,V2; cpu preset values):"]
    for owner, rows in settings_by_owner():
        lines.append(f"\n  {owner if owner == 'common' else '--algo ' + owner}:")
        for row in rows:
            default = row["default"]
            shown = ",".join(map(str, default)) if isinstance(default, tuple) else default
            meaning = f"  {row['meaning']}" if row["meaning"] else ""
            lines.append(f"    {row['name']} = {shown}  ({row['rule'] or row['type']}){meaning}")
    return "\n".join(lines)


def _load_plugins(argv: Sequence[str]) -> None:
    """Imports the ``--plugin`` modules of ``argv`` and ``MINATT_JAX_PLUGINS``'s before the
    parser is built (so ``--algo`` and ``--help`` know their agents)."""
    from minatt_jax.agents import registry

    pre = argparse.ArgumentParser(add_help=False, parents=[_PLUGINS])
    known, _ = pre.parse_known_args(list(argv))
    try:
        registry.load_plugins(getattr(known, "plugin", []))
    except registry.PluginError as e:
        raise UserError(str(e)) from None


def build_parser(settings_help: bool = False) -> argparse.ArgumentParser:
    """The argument parser for all subcommands (``settings_help``: ``train --help`` lists every
    setting of every known agent, from the field declarations)."""
    from minatt_jax.agents import registry
    from minatt_jax.envs import ENV_NAMES, PHYSICS_PRESETS, TARGET_SET_NAMES, TASK_SET_NAMES

    parser = _Parser(prog="minatt-jax", description=__doc__.splitlines()[0], parents=[_PLUGINS])
    parser.add_argument("--version", action="version", version=f"minatt-jax {_version()}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    add_parser = sub.add_parser
    sub.add_parser = lambda *a, **k: add_parser(*a, parents=[_PLUGINS], **k)  # type: ignore

    p_envs = sub.add_parser("envs", help="list environments, dimensions and task sets")
    p_envs.add_argument("--json", action="store_true", help="print one JSON object")

    p_roll = sub.add_parser("rollout", help="run a zero or random policy on a task set")
    p_roll.add_argument("--env", required=True, help=f"one of {', '.join(ENV_NAMES)}")
    p_roll.add_argument(
        "--variant",
        default="nominal",
        help=f"task set: one of {', '.join(TASK_SET_NAMES + TARGET_SET_NAMES)}",
    )
    p_roll.add_argument(
        "--task", action="append", default=[], metavar="SPEC",
        help="a custom task, e.g. mass=1.25,slope=0.1 (repeat for more)",
    )  # fmt: skip
    p_roll.add_argument("--steps", type=_positive_int, default=1000, help="env steps per task")
    p_roll.add_argument("--policy", choices=("zero", "random"), default="random")
    p_roll.add_argument("--seed", type=_non_negative_int, default=0)
    p_roll.add_argument(
        "--physics",
        default=None,
        help=f"solver preset: one of {', '.join(PHYSICS_PRESETS)} (default: the environment's)",
    )
    p_roll.add_argument("--out", default=None, help="write the summary as JSON to this file")
    p_roll.add_argument("--json", action="store_true", help="print the summary as JSON")

    from minatt_jax.config import PRESETS
    from minatt_jax.min_attention import ESTIMATORS, MODES, PLACEMENTS, TEMPORAL_READINGS

    p_train = sub.add_parser(
        "train", help="train an agent (writes a run directory)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=settings_epilog() if settings_help else None,
    )  # fmt: skip
    p_train.add_argument("--env", default=None, help=f"one of {', '.join(ENV_NAMES)}")
    p_train.add_argument("--algo", default=None, help=f"one of {', '.join(registry.names())}")
    p_train.add_argument("--preset", default=None, choices=tuple(PRESETS),
                         help="default cpu: the paper appendix's values at 50K env steps, "
                         "model fits capped to fit a CPU (docs: Model-based meta-RL)")  # fmt: skip
    p_train.add_argument("--alpha", type=_non_negative_float, default=None, help="MA weight")
    p_train.add_argument("--ma-mode", choices=MODES, default=None)
    p_train.add_argument("--estimator", choices=ESTIMATORS, default=None)
    p_train.add_argument("--probes", type=_positive_int, default=None)
    p_train.add_argument("--subsample", type=_non_negative_int, default=None, help="0 = batch")
    p_train.add_argument("--interval", type=_positive_int, default=None)
    p_train.add_argument("--temporal", choices=TEMPORAL_READINGS, default=None)
    p_train.add_argument("--placement", choices=PLACEMENTS, default=None)
    p_train.add_argument("--caps-lambda-t", type=_non_negative_float, default=None)
    p_train.add_argument("--caps-lambda-s", type=_non_negative_float, default=None)
    p_train.add_argument("--noise", choices=("gaussian", "ou"), default=None)
    p_train.add_argument(
        "--variant",
        default=None,
        help="task set to train on (default: the agent's: train for mbmpo, else nominal)",
    )
    p_train.add_argument(
        "--task",
        action="append",
        default=[],
        metavar="SPEC",
        help="a custom training task, e.g. mass=1.25 (repeat for more tasks)",
    )
    p_train.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        dest="set",
        help="set any config field, e.g. ma.alpha=0.5 or mb.meta_inner_lr=1e-3",
    )
    p_train.add_argument("--steps", type=_positive_int, default=None, help="total env steps")
    p_train.add_argument("--eval-every", type=_positive_int, default=None)
    p_train.add_argument("--num-envs", type=_positive_int, default=None)
    p_train.add_argument("--seed", type=_non_negative_int, default=None)
    p_train.add_argument("--normalize-obs", action="store_true", default=None)
    p_train.add_argument("--normalize-reward", action="store_true", default=None,
                         help="SAC batches' rewards on the return's running scale")  # fmt: skip
    p_train.add_argument("--ensemble-size", type=_positive_int, default=None, help="M members")
    p_train.add_argument("--elites", type=_positive_int, default=None, help="elites = mbmpo tasks")
    p_train.add_argument("--rollout-batch", type=_positive_int, default=None)
    p_train.add_argument("--updates-per-step", type=_positive_int, default=None)
    p_train.add_argument("--inner-lr", type=_non_negative_float, default=None, help="mbmpo beta")
    p_train.add_argument("--first-order", action="store_true", default=None, help="FO-MAML")
    p_train.add_argument("--inner", choices=("sac", "vpg"), default=None, help="mbmpo inner step")
    p_train.add_argument("--outer", choices=("sac", "trpo"), default=None, help="mbmpo outer step")
    p_train.add_argument("--out", default=None, help="run directory (default runs/<name>)")
    p_train.add_argument("--resume", action="store_true", help="continue the run in --out")
    p_train.add_argument(
        "--seeds",
        default=None,
        metavar="0-9",
        help="train a population: these seeds (ranges and lists: 0-4,7)",
    )
    p_train.add_argument("--sweep", action="append", default=[], metavar="KEY=V1,V2",
                         help="population: every value of a field (repeat for a grid)")  # fmt: skip
    p_train.add_argument("--distributed", action="store_true",
                         help="population over several processes or hosts (jax.distributed; the "
                              "cluster is read from SLURM, Open MPI, ... variables)")  # fmt: skip
    p_train.add_argument("--coordinator", default=None, metavar="HOST:PORT",
                         help="population over processes started by hand: process 0's address "
                              "(with --num-processes and --process-id)")  # fmt: skip
    p_train.add_argument("--num-processes", type=_positive_int, default=None, metavar="P")
    p_train.add_argument("--process-id", type=_non_negative_int, default=None, metavar="I")

    _state_defaults(p_train)

    p_meta = sub.add_parser("meta-test", help="adapt a trained run to each task of a variant")
    p_meta.add_argument("run_dir")
    p_meta.add_argument("--variant", default=None, help="mass, crippled, slope, ...")
    p_meta.add_argument(
        "--task",
        action="append",
        default=[],
        metavar="SPEC",
        help="a custom task instead of a variant (repeat for more tasks)",
    )
    p_meta.add_argument("--shots", type=_positive_int, default=1, help="real episodes per task")
    p_meta.add_argument("--adapt-steps", type=_non_negative_int, default=10)
    p_meta.add_argument("--episodes", type=_positive_int, default=5, help="per evaluation")
    p_meta.add_argument("--updates-per-step", type=_positive_int, default=20, help="sac runs")
    p_meta.add_argument("--seed", type=_non_negative_int, default=0)
    p_meta.add_argument("--inner-lr", type=_non_negative_float, default=None,
                        help="model-based runs: the adaptation's inner step size (default: "
                        "the run's mb.meta_inner_lr)")  # fmt: skip
    p_meta.add_argument("--adapt-alpha", type=_non_negative_float, default=None,
                        help="MA's weight in the adaptation updates (default: the run's "
                        "alpha; 0 adapts without the penalty)")  # fmt: skip
    p_meta.add_argument("--no-refit", action="store_true",
                        help="model-based runs: adapt in the trained ensemble instead of one "
                        "refitted on the collected episodes")  # fmt: skip
    p_meta.add_argument("--out", default=None, help="directory for meta_test_<variant>.json/png")
    p_meta.add_argument("--json", action="store_true", help="print the result as JSON")

    p_an = sub.add_parser("analyze", help="figures, tables and report.html for runs of one env")
    p_an.add_argument("run_dirs", nargs="+")
    p_an.add_argument("--out", required=True, help="report directory")
    p_an.add_argument("--episodes", type=_positive_int, default=5, help="rollouts per run")
    p_an.add_argument("--bins", type=_positive_int, default=20, help="heatmap bins per axis")
    p_an.add_argument("--grid", type=_positive_int, default=9, help="failure grid size per axis")
    p_an.add_argument("--grid-rollouts", type=_positive_int, default=20)
    p_an.add_argument("--grid-steps", type=_positive_int, default=100)
    p_an.add_argument("--maturation-steps", type=_positive_int, nargs="+",
                      help="training steps whose policy snapshots the maturation figure shows "
                      "(default 10000 100000 200000, each the nearest snapshot; given steps must "
                      "lie within the runs)")  # fmt: skip
    p_an.add_argument("--perturbation", default="crippled", help="task set for K(t)/v(t)")

    p_eval = sub.add_parser("evaluate", help="evaluate a run's latest checkpoint")
    p_eval.add_argument("run_dir")
    p_eval.add_argument("--variant", default=None, help="task set (default: the run's)")
    p_eval.add_argument(
        "--task",
        action="append",
        default=[],
        metavar="SPEC",
        help="a custom task, e.g. crippled=thigh_joint (repeat for more tasks)",
    )
    p_eval.add_argument("--episodes", type=_positive_int, default=None)
    p_eval.add_argument("--seed", type=_non_negative_int, default=0)
    p_eval.add_argument(
        "--engine",
        choices=("mjx", "mujoco"),
        default="mjx",
        help="mjx: the run's own environment; mujoco: Gymnasium's v5 environment on the MuJoCo "
        "C engine, same tasks and metrics (needs the mujoco-engine extra)",
    )
    p_eval.add_argument("--json", action="store_true")

    p_exp = sub.add_parser(
        "export", help="write a run's policy to one .npz that runs with numpy alone"
    )
    p_exp.add_argument("run_dir")
    p_exp.add_argument("--out", required=True, help="the .npz file to write")
    p_exp.add_argument("--step", type=_non_negative_int, default=None, help="default: latest")

    p_ren = sub.add_parser(
        "render", help="a video of runs' policies side by side, their controls drawn beneath"
    )
    p_ren.add_argument("run_dirs", nargs="+", metavar="run_dir")
    p_ren.add_argument("--out", required=True, help="the video to write: .gif (Pillow) or .mp4")
    p_ren.add_argument("--variant", default=None, help="task set, its first task (default: the "
                       "run's)")  # fmt: skip
    p_ren.add_argument("--task", action="append", default=[], metavar="SPEC",
                       help="a custom task instead, e.g. crippled=thigh_joint")  # fmt: skip
    p_ren.add_argument("--steps", type=_positive_int, default=None,
                       help="steps to roll out (default: an episode)")  # fmt: skip
    p_ren.add_argument("--seed", type=_non_negative_int, default=0)
    p_ren.add_argument("--stride", type=_positive_int, default=2,
                       help="render every stride-th step (plays in real time)")  # fmt: skip
    p_ren.add_argument("--width", type=_positive_int, default=320)
    p_ren.add_argument("--height", type=_positive_int, default=240)
    p_ren.add_argument("--label", action="append", default=None, metavar="TEXT",
                       help="a run's label in the video (once per run; default: algo, alpha, "
                       "seed)")  # fmt: skip
    p_ren.add_argument("--json", action="store_true")

    p_insp = sub.add_parser("inspect", help="list the items saved in a run's checkpoint")
    p_insp.add_argument("run_dir")
    p_insp.add_argument("--step", type=_non_negative_int, default=None, help="default: latest")
    p_insp.add_argument("--json", action="store_true")
    return parser


def _cmd_render(args: argparse.Namespace) -> dict[str, Any]:
    from minatt_jax import render, run_files, runner

    if args.label is not None and len(args.label) != len(args.run_dirs):
        raise UserError(f"give --label once per run ({len(args.run_dirs)}), or not at all")
    if os.path.splitext(args.out)[1].lower() not in render.VIDEO_SUFFIXES:
        raise UserError(f"cannot tell the video format of {args.out}: end it in .gif or .mp4")
    try:
        for d in args.run_dirs:
            run_files.check_run_dir(d)
            run_files.check_not_run_file(d, args.out, example="policy.gif")
    except runner.RunError as e:
        raise UserError(str(e)) from None
    _check_out_file(args.out)
    try:
        info = render.render_runs(args.run_dirs, args.out, args.variant, tuple(args.task),
                                  args.steps, args.seed, args.width, args.height, args.stride,
                                  args.label)  # fmt: skip
    except runner.RunError as e:
        raise UserError(str(e)) from None
    if args.json:
        print(json.dumps(info))
    else:
        for r in info["runs"]:
            print(f"{r['label']}: {r['length']} steps, return {r['return']:.1f}, feedback "
                  f"norm {r['feedback_norm']:.3g}")  # fmt: skip
        print(f"wrote {args.out}: {info['frames']} frames of {info['size'][0]}x"
              f"{info['size'][1]} at {info['fps']:.1f} fps")  # fmt: skip
    return info


def _cmd_envs(args: argparse.Namespace) -> dict[str, Any]:
    from minatt_jax import summaries

    table = summaries.environments()
    print(
        json.dumps(table, indent=2) if args.json else "\n".join(summaries.environment_lines(table))
    )
    return table


def _cmd_rollout(args: argparse.Namespace) -> dict[str, Any]:
    import minatt_jax.envs as envs
    from minatt_jax.evaluation import baseline_rollouts

    if args.out:
        _check_out_file(args.out)
    try:
        envs.check_task_set_name(args.variant)
        env = envs.make(args.env, args.physics)
        tasks, labels = envs.resolve_tasks(env, args.variant, args.task)
    except (envs.UnknownNameError, envs.TaskSpecError) as e:
        raise UserError(str(e)) from None
    print(f"compiling {args.env} rollout ({len(tasks)} tasks x {args.steps} steps) ...", flush=True)
    result = baseline_rollouts(env, tasks, labels, args.policy, args.steps, args.seed)
    summary = {"env": args.env, "variant": args.variant if not args.task else ";".join(labels),
               "policy": args.policy, "steps": args.steps, "seed": args.seed,
               "physics": args.physics or env.default_physics, **result}  # fmt: skip
    from minatt_jax.summaries import rollout_lines

    print(json.dumps(summary, indent=2) if args.json else "\n".join(rollout_lines(summary)))
    if args.out:
        _write_json_atomic(args.out, summary)
        print(f"wrote {args.out}")
    return summary


_TRAIN_FLAGS = {
    # CLI flag (argparse dest) -> the config field it is an alias of
    "env": "env", "algo": "algo", "alpha": "ma.alpha", "ma_mode": "ma.mode",
    "estimator": "ma.estimator", "probes": "ma.probes", "subsample": "ma.subsample",
    "interval": "ma.interval", "temporal": "ma.temporal", "placement": "ma.placement",
    "caps_lambda_t": "caps.lambda_t", "caps_lambda_s": "caps.lambda_s", "noise": "noise",
    "variant": "task_set", "steps": "total_steps", "eval_every": "eval_every",
    "num_envs": "num_envs", "seed": "seed", "normalize_obs": "sac.normalize_obs",
    "normalize_reward": "sac.normalize_reward",
    "ensemble_size": "model.ensemble_size", "elites": "model.num_elites",
    "rollout_batch": "mb.rollout_batch", "updates_per_step": "updates_per_step",
    "inner_lr": "mb.meta_inner_lr", "first_order": "mb.meta_first_order",
    "inner": "mb.meta_inner", "outer": "mb.meta_outer",
}  # fmt: skip


def _state_defaults(p_train: argparse.ArgumentParser) -> None:
    """Append each alias flag's default (cpu preset) and where it comes from, as its field
    declares them, to its help."""
    from minatt_jax.config import default_note

    for action in p_train._actions:
        if action.dest in _TRAIN_FLAGS and action.dest not in ("variant",):
            note = default_note(_TRAIN_FLAGS[action.dest])
            action.help = f"{action.help}; {note}" if action.help else note


def _train_config(args: argparse.Namespace):
    """The run's configuration from the flags (``runner.command_config``)."""
    from minatt_jax import runner

    aliases = {key: getattr(args, dest) for dest, key in _TRAIN_FLAGS.items()
               if getattr(args, dest) is not None}  # fmt: skip
    if args.task:
        aliases["tasks"] = tuple(args.task)
    if args.resume and args.out is None:
        raise UserError("--resume needs --out RUN_DIR")
    try:
        return runner.command_config(args.preset, args.set, aliases,
                                     args.out if args.resume else None)  # fmt: skip
    except runner.RunError as e:
        raise UserError(str(e)) from None


_PROCESS_FLAGS = ("coordinator", "num_processes", "process_id")


def _join_processes(args: argparse.Namespace) -> None:
    """``jax.distributed.initialize`` for a population over several processes, before any
    JAX computation: from ``--coordinator/--num-processes/--process-id`` or, with
    ``--distributed``, from the cluster's environment."""
    given = [f for f in _PROCESS_FLAGS if getattr(args, f) is not None]
    if not given and not args.distributed:
        return
    if given and len(given) < 3:
        raise UserError("--coordinator, --num-processes and --process-id go together")
    if given and args.process_id >= args.num_processes:
        raise UserError(f"--process-id {args.process_id} is not below --num-processes "
                        f"{args.num_processes}")  # fmt: skip
    import jax

    kwargs = {f: getattr(args, f) for f in _PROCESS_FLAGS}
    try:
        jax.distributed.initialize(
            coordinator_address=kwargs["coordinator"], num_processes=kwargs["num_processes"],
            process_id=kwargs["process_id"], initialization_timeout=120,
        )  # fmt: skip
    except (RuntimeError, ValueError) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise UserError(f"cannot join the other processes: {first}") from None


def _cmd_train_population(args: argparse.Namespace) -> list[dict[str, Any]]:
    """``train --seeds/--sweep``: every member in one program per group (``population``)."""
    from minatt_jax import population, runner

    if args.out is None:
        raise UserError("a population needs --out DIR (one run directory per member inside)")
    _join_processes(args)
    index_path = os.path.join(args.out, "population.json")
    if args.resume:
        if args.seeds is not None or args.sweep:
            raise UserError("--resume takes the members from population.json; drop --seeds/--sweep")
        try:
            members, swept = population.stored_members(args.out, args.steps)
        except runner.RunError as e:
            raise UserError(str(e)) from None
    else:
        if args.seed is not None:
            raise UserError("--seed names one run; a population takes --seeds (e.g. 0-9)")
        base = _train_config(args)
        try:
            seeds = population.parse_seeds(args.seeds) if args.seeds is not None else [base.seed]
            members = population.expand(base, seeds, args.sweep)
        except ValueError as e:
            raise UserError(str(e)) from None
        swept = [sweep.partition("=")[0].strip() for sweep in args.sweep]
    _refuse_dangling_link(args.out, f"--out {args.out}")
    if os.path.exists(args.out) and not os.path.isdir(args.out):
        raise UserError(f"--out {args.out} is a file, not a directory")
    groups = population.groups(members)
    print(f"population of {len(members)} members in {len(groups)} compiled program(s) -> "
          f"{args.out}", flush=True)  # fmt: skip
    try:
        records = population.train_population(
            members, args.out, swept, resume=args.resume, log=lambda m: print(m, flush=True)
        )
    except runner.RunError as e:
        raise UserError(str(e), e.exit_status) from None
    from minatt_jax.summaries import population_lines

    names = [population.member_name(m, swept) for m in members]
    print("\n".join(population_lines(names, records)))
    print(f"\nindex: {index_path}; each member's directory reads like a single run "
          "(evaluate, meta-test, analyze)")  # fmt: skip
    return records


def _cmd_train(args: argparse.Namespace) -> dict[str, Any]:
    from minatt_jax import runner

    population_dir = args.out and os.path.exists(os.path.join(args.out, "population.json"))
    if args.seeds is not None or args.sweep or (args.resume and population_dir):
        return _cmd_train_population(args)
    if args.distributed or any(getattr(args, f) is not None for f in _PROCESS_FLAGS):
        raise UserError("--distributed and --coordinator split a population (--seeds/--sweep) "
                        "over processes; a single run takes one")  # fmt: skip
    config = _train_config(args)
    out = args.out or os.path.join(
        "runs", f"{config.env}_{config.algo}_alpha{config.ma.alpha:g}_seed{config.seed}"
    )
    if not args.resume and os.path.exists(os.path.join(out, "config.json")):
        raise UserError(f"{out} already holds a run; pass --resume or choose another --out")
    made = not os.path.lexists(out)
    _make_out_dir(out)
    print(
        f"training {config.algo} on {config.env} ({config.task_set}) for {config.total_steps} "
        f"env steps, preset {config.preset}, MA alpha {config.ma.alpha:g} ({config.ma.mode})"
        f" -> {out}",
        flush=True,
    )
    try:
        record = runner.train(config, out, resume=args.resume, log=lambda m: print(m, flush=True))
    except runner.RunError as e:
        if made and os.path.isdir(out) and set(os.listdir(out)) <= {".lock"}:
            shutil.rmtree(out, ignore_errors=True)  # refused before writing: no folder left
        raise UserError(str(e), e.exit_status) from None
    if record:
        from minatt_jax.summaries import final_evaluation_lines

        print("\n".join(final_evaluation_lines(config, record)))
    print(f"\nfiles in {out}: config.json, metrics.jsonl, tensorboard/, checkpoints/, "
          "policy_snapshots/")  # fmt: skip
    return record


def _cmd_evaluate(args: argparse.Namespace) -> dict[str, Any]:
    from minatt_jax import runner

    try:
        metrics = runner.evaluate_run(args.run_dir, args.variant, args.episodes, args.seed,
                                      tuple(args.task), args.engine)  # fmt: skip
    except runner.RunError as e:
        raise UserError(str(e)) from None
    from minatt_jax.summaries import evaluation_lines

    print(json.dumps(metrics) if args.json else "\n".join(evaluation_lines(args.run_dir, metrics)))
    return metrics


def _cmd_meta_test(args: argparse.Namespace) -> dict[str, Any]:
    from minatt_jax import runner
    from minatt_jax.meta_test import MetaTestConfig, meta_test

    settings = MetaTestConfig(
        shots=args.shots, adapt_steps=args.adapt_steps, episodes=args.episodes,
        updates_per_step=args.updates_per_step, seed=args.seed, inner_lr=args.inner_lr,
        adapt_alpha=args.adapt_alpha, refit_model=not args.no_refit,
    )  # fmt: skip
    if (args.variant is None) == (not args.task):
        raise UserError("meta-test needs either --variant NAME or --task SPEC (one or more)")
    variant = args.variant or "custom"
    if args.out:
        _make_out_dir(args.out)
    elif os.path.isdir(args.run_dir) and not os.access(args.run_dir, os.W_OK):
        raise UserError(f"cannot write the results into {args.run_dir}: not writable; give "
                        "--out DIR")  # fmt: skip
    log = (lambda m: None) if args.json else (lambda m: print(m, flush=True))
    try:
        result = meta_test(args.run_dir, variant if args.variant else "nominal", settings,
                           log=log, task_specs=tuple(args.task))  # fmt: skip
    except runner.RunError as e:
        raise UserError(str(e)) from None
    result["variant"] = variant
    out = args.out or args.run_dir
    path = os.path.join(out, f"meta_test_{variant}.json")
    _write_json_atomic(path, result)
    png = os.path.join(out, f"meta_test_{variant}.png")
    from minatt_jax.analysis.plots import plot_meta_test

    try:
        plot_meta_test(result, png)
    except OSError as e:
        raise UserError(f"cannot write {png}: {e.strerror or e} ({path} is written)") from None
    if args.json:
        print(json.dumps(result))
    else:
        from minatt_jax.summaries import meta_test_lines

        print("\n".join(meta_test_lines(result)))
        print(f"wrote {path} and {png}")
    return result


def _cmd_analyze(args: argparse.Namespace) -> dict[str, Any]:
    from minatt_jax import runner
    from minatt_jax.analysis.report import AnalyzeConfig, analyze, check_inputs

    maturation = {"maturation_steps": tuple(args.maturation_steps)} if args.maturation_steps else {}
    settings = AnalyzeConfig(
        episodes=args.episodes, bins=args.bins, grid=args.grid, grid_rollouts=args.grid_rollouts,
        grid_steps=args.grid_steps, perturbation=args.perturbation, **maturation,
    )  # fmt: skip
    try:
        check_inputs(args.run_dirs, args.out, settings if args.maturation_steps else None)
    except runner.RunError as e:
        raise UserError(str(e)) from None
    _make_out_dir(args.out)
    try:
        result = analyze(args.run_dirs, args.out, settings, log=lambda m: print(m, flush=True))
    except runner.RunError as e:
        raise UserError(str(e)) from None
    print(f"wrote {os.path.join(args.out, 'report.html')} with: " + ", ".join(result["figures"])
          + ", tables.md, tables.json")  # fmt: skip
    return result


def _cmd_inspect(args: argparse.Namespace) -> dict[str, Any]:
    from minatt_jax import checkpoint, run_files, runner

    try:
        run_files.read_config_json(args.run_dir)  # any run, its agent installed or not
        manifest = checkpoint.describe(args.run_dir, args.step)
    except (runner.RunError, checkpoint.CheckpointError) as e:
        raise UserError(str(e)) from None
    if args.json:
        print(json.dumps(manifest, indent=2))
    else:
        items = manifest["items"]
        print(f"{args.run_dir}: checkpoint {manifest['step']} (format {manifest['format']}), "
              f"{len(items)} arrays")  # fmt: skip
        for name, meta in items.items():
            print(f"  {name:70s} {str(tuple(meta['shape'])):>18s} {meta['dtype']}")
    return manifest


def _cmd_export(args: argparse.Namespace) -> dict[str, Any]:
    from minatt_jax import checkpoint, runner
    from minatt_jax.export import export_policy

    _check_out_file(args.out)
    try:
        metadata = export_policy(args.run_dir, args.out, args.step)
    except (runner.RunError, checkpoint.CheckpointError) as e:
        raise UserError(str(e)) from None
    except OSError as e:
        raise UserError(f"cannot write {args.out}: {e.strerror or e}") from None
    print(f"wrote {args.out}: {metadata['env']} policy at step {metadata['step']} "
          f"({metadata['obs_dim']} observations -> {metadata['act_dim']} actions); load it with "
          "minatt_jax.numpy_policy.load_policy (numpy only)")  # fmt: skip
    return metadata


def _make_out_dir(path: str, file: str | None = None) -> None:
    """Creates an output directory (``--out``, or the folder of the output ``file``) before any
    long work, or says in one line why it cannot be."""
    subject, cannot = (path, f"cannot write {file}: ") if file else (f"--out {path}", "cannot ")
    _refuse_dangling_link(path, subject)
    if os.path.exists(path) and not os.path.isdir(path):
        raise UserError(f"{cannot if file else ''}{subject} is a file, not a directory")
    try:
        os.makedirs(path, exist_ok=True)
    except OSError as e:
        reason = e.strerror or e
        raise UserError(f"{cannot}{'' if file else 'create '}{subject}: {reason}") from None
    if not os.access(path, os.W_OK):
        raise UserError(f"{cannot}{'' if file else 'write into '}{subject}: not writable")


def _refuse_dangling_link(path: str, subject: str) -> None:
    """A symbolic link that leads nowhere (a loop, a missing target) is said as such, not as
    the "File exists" that creating a folder there raises."""
    if os.path.islink(path) and not os.path.exists(path):
        raise UserError(f"{subject} is a symbolic link that leads nowhere (a loop or a missing "
                        "target); give a folder")  # fmt: skip


def _check_out_file(path: str) -> None:
    """Checks, before any long work, that ``path`` can be written as a file."""
    if os.path.isdir(path):
        raise UserError(f"--out {path} is a directory; give the file to write")
    _make_out_dir(os.path.dirname(os.path.abspath(path)), file=path)


def _write_json_atomic(path: str, obj: Any) -> None:
    """Writes JSON atomically; an unwritable path is a user error."""
    from minatt_jax.runner import write_json_atomic

    try:
        write_json_atomic(path, obj)
    except OSError as e:
        raise UserError(f"cannot write {path}: {e.strerror or e}") from None


def _ended(status: int, console: bool) -> int:
    """``status`` for a command ended by a signal. As the console command, the process exits at
    once (``os._exit``, after flushing): XLA's threads may be compiling, and tearing the
    interpreter down around them can crash it (SIGSEGV) after the one line was printed; every
    file a command writes is written atomically, so nothing is left half-written."""
    if console:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)
    return status


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``minatt-jax`` console script; returns the exit status.

    Ctrl-C (SIGINT) and SIGTERM at any moment, from the imports on, end the command with one line
    and exit status 130 / 143 (training stops after its current chunk, checkpoint written)."""
    from minatt_jax import gl, run_guard

    # Only `render` renders (offscreen, EGL); for every other command OpenGL stays off: without
    # this, importing mujoco probes for an OpenGL library in a child process (glfw), which
    # outlives a signal that ends the command during imports.
    words = sys.argv[1:] if argv is None else list(argv)
    os.environ.setdefault("MUJOCO_GL", gl.default_gl() if "render" in words else "disable")
    console = argv is None
    guard = run_guard.exit_on_signals() if console else run_guard.sigterm_raises()
    try:
        with guard:
            argv = sys.argv[1:] if argv is None else list(argv)
            _load_plugins(argv)
            wants_help = "train" in argv and ("-h" in argv or "--help" in argv)
            args = build_parser(settings_help=wants_help).parse_args(argv)
            commands = {
                "envs": _cmd_envs,
                "rollout": _cmd_rollout,
                "train": _cmd_train,
                "evaluate": _cmd_evaluate,
                "meta-test": _cmd_meta_test,
                "analyze": _cmd_analyze,
                "inspect": _cmd_inspect,
                "export": _cmd_export,
                "render": _cmd_render,
            }
            commands[args.command](args)
    except UserError as e:
        label = "error" if e.exit_status == EXIT_USER_ERROR else "stopped"
        sys.stderr.write(f"minatt-jax: {label}: {e}\n")
        return e.exit_status if label == "error" else _ended(e.exit_status, console)
    except KeyboardInterrupt:  # Ctrl-C outside training's own handler (start-up, evaluation)
        sys.stderr.write("minatt-jax: interrupted\n")
        return _ended(130, console)
    except run_guard.TerminatedError:
        sys.stderr.write("minatt-jax: terminated\n")
        return _ended(143, console)
    except BrokenPipeError:  # output piped into a reader that stopped (``| head``): not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return 0


if __name__ == "__main__":
    sys.exit(main())
