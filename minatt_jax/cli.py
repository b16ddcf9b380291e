"""The ``minatt-jax`` command line: ``envs`` and ``rollout`` (training comes with the SAC issue).

Every user error (unknown name, invalid number, unwritable output) prints one line starting with
``minatt-jax: error:`` and exits with status 2, without a traceback.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from typing import Any, NoReturn

EXIT_USER_ERROR = 2


class UserError(Exception):
    """An error caused by the user's input; reported in one line, exit status 2."""


class _Parser(argparse.ArgumentParser):
    """argparse that reports errors in one line (no usage block) with exit status 2."""

    def error(self, message: str) -> NoReturn:
        sys.stderr.write(f"minatt-jax: error: {message}\n")
        raise SystemExit(EXIT_USER_ERROR)


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return value


def _non_negative_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}")
    return value


def build_parser() -> argparse.ArgumentParser:
    """The argument parser for all subcommands."""
    from minatt_jax.envs import ENV_NAMES, PHYSICS_PRESETS, TASK_SET_NAMES

    parser = _Parser(prog="minatt-jax", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    p_envs = sub.add_parser("envs", help="list environments, dimensions and task sets")
    p_envs.add_argument("--json", action="store_true", help="print one JSON object")

    p_roll = sub.add_parser("rollout", help="run a zero or random policy on a task set")
    p_roll.add_argument("--env", required=True, help=f"one of {', '.join(ENV_NAMES)}")
    p_roll.add_argument(
        "--variant", default="nominal", help=f"task set: one of {', '.join(TASK_SET_NAMES)}"
    )
    p_roll.add_argument("--steps", type=_positive_int, default=1000, help="env steps per task")
    p_roll.add_argument("--policy", choices=("zero", "random"), default="random")
    p_roll.add_argument("--seed", type=_non_negative_int, default=0)
    p_roll.add_argument(
        "--physics", default="fast", help=f"solver preset: one of {', '.join(PHYSICS_PRESETS)}"
    )
    p_roll.add_argument("--out", default=None, help="write the summary as JSON to this file")
    p_roll.add_argument("--json", action="store_true", help="print the summary as JSON")
    return parser


def _cmd_envs(args: argparse.Namespace) -> dict[str, Any]:
    import minatt_jax.envs as envs

    table = {}
    for name in envs.ENV_NAMES:
        env = envs.make(name)
        table[name] = {
            "observation_size": env.observation_size,
            "action_size": env.action_size,
            "dt": env.dt,
            "frame_skip": env.frame_skip,
            "task_sets": {s: envs.task_list(env, s)[1] for s in envs.TASK_SET_NAMES},
        }
    if args.json:
        print(json.dumps(table, indent=2))
    else:
        print(f"{'env':12s} {'obs':>4s} {'act':>4s} {'dt':>6s}  task sets (tasks)")
        for name, row in table.items():
            sets = ", ".join(f"{s} ({len(t)})" for s, t in row["task_sets"].items())
            print(
                f"{name:12s} {row['observation_size']:4d} {row['action_size']:4d} "
                f"{row['dt']:6.3f}  {sets}"
            )
    return table


def _cmd_rollout(args: argparse.Namespace) -> dict[str, Any]:
    import jax
    import jax.numpy as jnp

    import minatt_jax.envs as envs
    from minatt_jax.rollout import make_rollout, random_policy, zero_policy

    try:
        envs.check_task_set_name(args.variant)
        env = envs.make(args.env, args.physics)
    except envs.UnknownNameError as e:
        raise UserError(str(e)) from None
    tasks, labels = envs.task_list(env, args.variant)
    task_set = envs.stack_tasks(tasks)
    make_policy = random_policy if args.policy == "random" else zero_policy
    rollout = jax.vmap(make_rollout(env, make_policy(env.action_size), args.steps))
    keys = jax.random.split(jax.random.PRNGKey(args.seed), len(tasks))
    print(f"compiling {args.env} rollout ({len(tasks)} tasks x {args.steps} steps) ...", flush=True)
    t0 = time.perf_counter()
    compiled = jax.jit(rollout).lower(keys, task_set).compile()
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    result = jax.block_until_ready(compiled(keys, task_set))
    run_s = time.perf_counter() - t0
    steps_per_s = len(tasks) * args.steps / run_s
    rows = [
        {
            "task": label,
            "return": float(result.episode_return[i]),
            "length": int(result.length[i]),
            "forward_reward": float(result.forward_reward[i]),
            "ctrl_reward": float(result.ctrl_reward[i]),
        }
        for i, label in enumerate(labels)
    ]
    summary = {
        "env": args.env,
        "variant": args.variant,
        "policy": args.policy,
        "steps": args.steps,
        "seed": args.seed,
        "physics": args.physics,
        "compile_s": compile_s,
        "run_s": run_s,
        "env_steps_per_s": steps_per_s,
        "physics_steps_per_s": steps_per_s * env.frame_skip,
        "mean_return": float(jnp.mean(result.episode_return)),
        "tasks": rows,
    }
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(f"{'task':40s} {'return':>10s} {'length':>7s}")
        for row in rows:
            print(f"{row['task']:40s} {row['return']:10.2f} {row['length']:7d}")
        print(
            f"mean return {summary['mean_return']:.2f} | {steps_per_s:,.0f} env steps/s "
            f"({len(tasks)} envs in one vmapped call) | compile {compile_s:.1f} s"
        )
    if args.out:
        _write_json_atomic(args.out, summary)
        print(f"wrote {args.out}")
    return summary


def _write_json_atomic(path: str, obj: Any) -> None:
    """Writes JSON through a temporary file and a rename, so a crash never leaves half a file."""
    import os
    import tempfile

    directory = os.path.dirname(os.path.abspath(path))
    try:
        os.makedirs(directory, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=directory, suffix=".tmp")
        with os.fdopen(fd, "w") as f:
            json.dump(obj, f, indent=2)
        os.replace(tmp, path)
    except OSError as e:
        raise UserError(f"cannot write {path}: {e.strerror or e}") from None


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``minatt-jax`` console script; returns the exit status."""
    args = build_parser().parse_args(argv)
    commands = {"envs": _cmd_envs, "rollout": _cmd_rollout}
    try:
        commands[args.command](args)
    except UserError as e:
        sys.stderr.write(f"minatt-jax: error: {e}\n")
        return EXIT_USER_ERROR
    return 0


if __name__ == "__main__":
    sys.exit(main())
