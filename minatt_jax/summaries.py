"""What the commands print, as lines computed from what the library returns: the environment
table, a rollout's summary, a run's final evaluation, a population's table, an evaluation and a
meta-test. The command line prints these lines and computes nothing; scripts and notebooks get
the same text.
"""

from __future__ import annotations

from typing import Any

EVALUATED = ("return", "feedback_norm", "feedforward_norm", "energy", "jerk", "smoothness")


def environments() -> dict[str, dict[str, Any]]:
    """Every environment's dimensions, dt and task sets (or why it is unavailable)."""
    import minatt_jax.envs as envs

    table: dict[str, dict[str, Any]] = {}
    for name in envs.environment_names():
        try:
            env = envs.make(name)
        except envs.UnavailableEnvError as e:
            table[name] = {"unavailable": str(e)}
            continue
        table[name] = {
            "observation_size": env.observation_size,
            "action_size": env.action_size,
            "dt": env.dt,
            "frame_skip": env.frame_skip,
            "task_sets": {s: envs.task_list(env, s)[1] for s in envs.task_set_names(env)},
        }
    return table


def environment_lines(table: dict[str, dict[str, Any]]) -> list[str]:
    """``environments()`` as a table, a line per environment."""
    lines = [f"{'env':12s} {'obs':>4s} {'act':>4s} {'dt':>6s}  task sets (tasks)"]
    for name, row in table.items():
        if "unavailable" in row:
            lines.append(f"{name:12s} {row['unavailable']}")
            continue
        sets = ", ".join(f"{s} ({len(t)})" for s, t in row["task_sets"].items())
        lines.append(f"{name:12s} {row['observation_size']:4d} {row['action_size']:4d} "
                     f"{row['dt']:6.3f}  {sets}")  # fmt: skip
    return lines


def rollout_lines(summary: dict[str, Any]) -> list[str]:
    """A baseline rollout's table: return and length per task, the mean and the speed."""
    lines = [f"{'task':40s} {'return':>10s} {'length':>7s}"]
    lines += [f"{row['task']:40s} {row['return']:10.2f} {row['length']:7d}"
              for row in summary["tasks"]]  # fmt: skip
    lines.append(f"mean return {summary['mean_return']:.2f} | "
                 f"{summary['env_steps_per_s']:,.0f} env steps/s ({len(summary['tasks'])} envs "
                 f"in one vmapped call) | compile {summary['compile_s']:.1f} s")  # fmt: skip
    return lines


def final_evaluation_lines(config: Any, record: dict[str, Any]) -> list[str]:
    """A run's last record: the evaluation metrics with their spread, the speed, the model's
    fit where there is one, and the measured reference runs of the same settings."""
    from minatt_jax.reference import comparison_lines

    lines = ["", "final evaluation (deterministic policy, mean +- std over episodes)"]
    lines += [f"  {key:18s} {record[key]:12.4f} +- {record[key + '_std']:.4f}" for key in EVALUATED]
    lines.append(f"  {'env_steps_per_s':18s} {record['env_steps_per_s']:12.1f}")
    lines.append(f"  {'updates_per_s':18s} {record['updates_per_s']:12.1f}")
    if "model_holdout_mse" in record:
        lines.append(f"  {'model_holdout_mse':18s} {record['model_holdout_mse']:12.4f} "
                     f"(elites {record['model_elites']})")  # fmt: skip
        lines.append(f"  {'imagined_per_s':18s} {record['imagined_per_s']:12.1f}")
    return lines + comparison_lines(config, record)


def population_lines(names: list[str], records: list[dict[str, Any]]) -> list[str]:
    """A population's final return, feedback norm and energy, a line per trained member."""
    lines = ["", f"{'member':40s} {'return':>10s} {'feedback':>10s} {'energy':>8s}"]
    lines += [f"{name:40s} {r['return']:10.2f} {r['feedback_norm']:10.3f} {r['energy']:8.3f}"
              for name, r in zip(names, records, strict=True) if r]  # fmt: skip
    return lines


def evaluation_lines(run_dir: str, metrics: dict[str, Any]) -> list[str]:
    """An evaluation's metrics with their spread over episodes."""
    lines = [f"{run_dir} at step {metrics['step']} on {metrics['variant']} "
             f"({metrics['episodes']} episodes, {metrics['engine']})"]  # fmt: skip
    keys = ("return", "length", *EVALUATED[1:])
    lines += [f"  {k:18s} {metrics[k]:12.4f} +- {metrics[k + '_std']:.4f}" for k in keys]
    return lines


def meta_test_lines(result: dict[str, Any]) -> list[str]:
    """A meta-test's means over tasks, before and after the adaptation steps."""
    steps = result["settings"]["adapt_steps"]
    lines = [f"mean over {len(result['tasks'])} tasks, before -> after {steps} adaptation steps:"]
    lines += [f"  {key:18s} {v['before']:12.4f} -> {v['after']:12.4f}"
              for key, v in result["mean_over_tasks"].items()]  # fmt: skip
    return lines
