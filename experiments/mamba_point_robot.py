"""MAMBA against DreamerV3 and a random policy on point_robot: does it adapt in context?

    python experiments/mamba_point_robot.py [--seeds 0 1 2] [--alphas 0 0.05]
        [--steps 60000] [--dreamer-steps 25000] [--runs runs/mamba_point_robot]
        [--set dreamer.train_ratio=...]

Trains (or resumes: run it again after a stop) each agent's runs, every (alpha, seed), as one
population at the cpu preset's MAMBA setting (``minatt_jax.agents.mamba.CPU``: meta-episodes of 3
episodes of 50 steps) on ``point_robot_dense`` (the goal on the half circle, reward minus the
distance: the sparse reward of ``point_robot`` gave no learning signal in 150K steps here), on
the 16 training goals of the upper half circle:

* **mamba**: memory over the whole meta-episode;
* **dreamer**: DreamerV3 with the same model and train ratio on plain 50-step episodes, its
  memory reset every episode (each episode is a first episode: its return is the same for every
  k by construction). Its replayed sequences are k times shorter, so at the same train ratio
  it makes more updates per env step: ``--dreamer-steps`` sets its env steps apart (the tables
  give each arm's updates, to compare at equal updates);
* **random**: a uniform random policy, in meta-episodes.

Then evaluates each run's final policy (deterministic) on every training goal and on the 6
out-of-distribution goals of the lower half circle, and writes
``experiments/results/mamba_point_robot.{json,md}`` (and ``mamba_point_robot_report/``, the
``analyze`` report of every run): the return of episode 1 and of episode k of
a meta-episode, their paired difference per seed (in-context adaptation), learning curves,
feedback norm and energy, each as the mean over seeds with its 95% bootstrap interval.
"""

from __future__ import annotations

import argparse
import os
import shutil

import jax
import jax.numpy as jnp
import numpy as np
import stats

import minatt_jax.envs as envs
from minatt_jax import acting, checkpoint, population, runner
from minatt_jax.analysis.report import AnalyzeConfig, analyze
from minatt_jax.config import preset_config, replace_fields, resolve
from minatt_jax.envs.meta_episode import returns_by_episode

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")
NAME = "mamba_point_robot"
ENV = "point_robot_dense"  # the dense reward: learnable at a CPU's step budget
TASK_SETS = {"train": 16, "ood": 12}  # evaluation episodes: every goal once (ood: twice)


def run_config(agent: str, alpha: float, seed: int, steps: int | None, overrides: list[str]):
    """The run's configuration: MAMBA's cpu setting; DreamerV3 on its plain episodes."""
    fields = {"env": ENV, "algo": "mamba", "ma.alpha": alpha, "seed": seed}
    if steps is not None:
        fields["total_steps"] = steps
    config = preset_config("cpu", overrides, fields)
    if agent == "dreamer":
        config = replace_fields(config, {
            "algo": "dreamer", "meta_episodes": 1,
            "dreamer.batch_length": config.max_episode_steps,
        })  # fmt: skip
    return resolve(config)


def episode_returns(metrics: dict, episodes: int) -> list[float]:
    """The mean return of each episode of a meta-episode (a plain run: its return, k times)."""
    if "return_episode_1" in metrics:
        return [metrics[f"return_episode_{i + 1}"] for i in range(episodes)]
    return [metrics["return"]] * episodes


def random_policy_returns(config, task_set: str, episodes: int) -> list[float]:
    """Each inner episode's mean return of a uniform random policy in meta-episodes."""
    env = config.make_env()
    tasks = envs.stack_tasks(envs.resolve_tasks(env, task_set, ())[0])
    count = envs.num_tasks(tasks)
    policy = acting.random_policy(env.action_size)

    def one(key, i):
        task = jax.tree.map(lambda x: x[i % count], tasks)
        k_reset, k_act = jax.random.split(key)
        traj = acting.unroll(env, policy, env.reset(k_reset, task), config.episode_limit,
                             key=k_act)  # fmt: skip
        return returns_by_episode(traj.reward, traj.env_metrics["meta_episode_index"],
                                  traj.alive, config.meta_episodes)  # fmt: skip

    keys = jax.random.split(jax.random.PRNGKey(7), episodes)
    returns = jax.jit(jax.vmap(one))(keys, jnp.arange(episodes))
    return [float(x) for x in np.asarray(returns).mean(0)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--alphas", type=float, nargs="+", default=[0.0, 0.05])
    parser.add_argument("--agents", nargs="+", default=["mamba", "dreamer"],
                        choices=["mamba", "dreamer"])  # fmt: skip
    parser.add_argument("--steps", type=int, default=None,
                        help="env steps per run (default: the cpu preset's, 60K)")  # fmt: skip
    parser.add_argument("--dreamer-steps", type=int, default=None,
                        help="env steps per DreamerV3 run (default: --steps)")  # fmt: skip
    parser.add_argument("--runs", default="runs/mamba_point_robot")
    parser.add_argument("--set", action="append", default=[], dest="overrides")
    parser.add_argument("--collect-only", action="store_true",
                        help="tabulate the runs as they stand, without training")  # fmt: skip
    args = parser.parse_args()
    reference = run_config("mamba", 0.0, 0, args.steps, args.overrides)
    k = reference.meta_episodes
    arms: dict[str, list[dict]] = {}
    for agent in args.agents:
        # every (alpha, seed) of an agent in one program (population): seeds and alphas are data
        steps = args.dreamer_steps if agent == "dreamer" and args.dreamer_steps else args.steps
        members = [run_config(agent, alpha, seed, steps, args.overrides)
                   for alpha in args.alphas for seed in args.seeds]  # fmt: skip
        out = os.path.join(args.runs, agent)
        if not args.collect_only:
            resume = os.path.exists(os.path.join(out, "population.json"))
            population.train_population(members, out, ["ma.alpha"], resume=resume)
        for config in members:
            alpha, seed = config.ma.alpha, config.seed
            run_dir = os.path.join(out, population.member_name(config, ["ma.alpha"]))
            records = runner.read_metrics(run_dir)
            row = {
                "seed": seed,
                "run": os.path.relpath(run_dir, args.runs),  # under --runs
                "updates": int(sum(r["updates"] for r in records)),  # a record counts its chunk's
                "curve": [{"step": r["step"], "return": r["return"]} for r in records],
            }
            for task_set, episodes in TASK_SETS.items():
                m = runner.evaluate_run(run_dir, task_set, episodes, seed=100 + seed)
                row["step"] = m["step"]
                row[task_set] = {"by_episode": episode_returns(m, k),
                                 "feedback_norm": m["feedback_norm"],
                                 "energy": m["energy"]}  # fmt: skip
            arms.setdefault(f"{agent} alpha={alpha:g}", []).append(row)
    random = {s: random_policy_returns(reference, s, n) for s, n in TASK_SETS.items()}
    summaries = {}
    for arm, rows in arms.items():
        summaries[arm] = {}
        for task_set in TASK_SETS:
            per_seed = np.asarray([r[task_set]["by_episode"] for r in rows])  # (seeds, k)
            summaries[arm][task_set] = {
                "episode_1": stats.summary(per_seed[:, 0]),
                f"episode_{k}": stats.summary(per_seed[:, -1]),
                "adaptation": stats.summary(per_seed[:, -1] - per_seed[:, 0]),
                "feedback_norm": stats.summary([r[task_set]["feedback_norm"] for r in rows]),
                "energy": stats.summary([r[task_set]["energy"] for r in rows]),
            }
    command = ("python experiments/mamba_point_robot.py --seeds "
               + " ".join(map(str, args.seeds)) + " --alphas "
               + " ".join(f"{a:g}" for a in args.alphas) + f" --steps {reference.total_steps}"
               + (f" --dreamer-steps {args.dreamer_steps}" if args.dreamer_steps else "")
               + "".join(f" --set {o}" for o in args.overrides))  # fmt: skip
    device = jax.devices()[0]
    result = {"command": command, "device": f"{device.platform} ({device.device_kind})",
              "meta_episode": f"{k} x {reference.max_episode_steps} steps",
              "random_policy": random, "summaries": summaries, "runs": arms}  # fmt: skip
    os.makedirs(RESULTS, exist_ok=True)
    runner.write_json_atomic(os.path.join(RESULTS, f"{NAME}.json"), result)
    text = table(result, k)
    runner.write_text_atomic(os.path.join(RESULTS, f"{NAME}.md"), text)
    print(text)
    run_dirs = [os.path.join(args.runs, r["run"]) for rows in arms.values() for r in rows]
    write_report(run_dirs, os.path.join(args.runs, "report"), command)


def write_report(run_dirs: list[str], out: str, command: str) -> None:
    """``minatt-jax analyze`` of every run (the in-context table and ``adaptation.png`` for the
    MAMBA arms); its figures and tables go to ``results/<NAME>_report/``, ``report.html`` (the
    same, embedded) stays under ``--runs``."""
    steps = max(checkpoint.latest_policy_step(d) or 0 for d in run_dirs)
    settings = AnalyzeConfig(grid=3, grid_rollouts=2,  # the point robot never fails
                             maturation_steps=(steps // 4, steps // 2, steps))  # fmt: skip
    analyze(run_dirs, out, settings)
    target = os.path.join(RESULTS, f"{NAME}_report")
    os.makedirs(target, exist_ok=True)
    for name in os.listdir(out):
        if name.endswith((".png", ".md", ".json")):
            shutil.copy(os.path.join(out, name), os.path.join(target, name))
    runner.write_text_atomic(os.path.join(target, "README.md"), (
        f"# Analysis report: MAMBA and DreamerV3 on {ENV}\n\n"
        f"Written by `{command}` (`minatt-jax analyze` of every run, maturation at "
        f"{steps // 4}, {steps // 2} and {steps} env steps, a 3 x 3 failure grid: the point "
        "robot never fails); figures and tables only, `report.html` stays under the runs "
        "directory. `tables.md` ends with the in-context table: each inner episode of a "
        "meta-episode on the nominal goal, mean +- std over seeds (`adaptation.png`).\n"
    ))  # fmt: skip


def table(result: dict, k: int) -> str:
    """The results as markdown (mean over seeds [95% bootstrap interval])."""

    def cell(s: dict) -> str:
        return f"{s['mean']:.2f} [{s['ci_low']:.2f}, {s['ci_high']:.2f}]"

    lines = [
        f"# MAMBA on {ENV}: in-context adaptation\n",
        f"`{result['command']}` on {result['device']}; meta-episodes of "
        f"{result['meta_episode']}. Deterministic evaluation of each run's final policy on every "
        "goal of the task set; mean over seeds with the 95% bootstrap interval. Adaptation: "
        f"episode {k} minus episode 1, paired per seed (DreamerV3's memory is reset every "
        "episode: its episodes are all first episodes).\n",
    ]
    for task_set in TASK_SETS:
        rand = result["random_policy"][task_set]
        lines += [
            f"## {task_set} goals\n",
            f"Random policy: episode 1 {rand[0]:.2f}, episode {k} {rand[-1]:.2f}.\n",
            f"| arm | env steps | updates | seeds | episode 1 | episode {k} | adaptation | "
            "feedback | energy |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
        for arm, s in result["summaries"].items():
            t = s[task_set]
            steps = "/".join(sorted({f"{r['step'] // 1000}K" for r in result["runs"][arm]}))
            updates = np.mean([r["updates"] for r in result["runs"][arm]])
            lines.append(f"| {arm} | {steps} | {updates:.0f} | {t['episode_1']['n']} | "
                         f"{cell(t['episode_1'])} | "
                         f"{cell(t[f'episode_{k}'])} | {cell(t['adaptation'])} | "
                         f"{cell(t['feedback_norm'])} | {cell(t['energy'])} |")  # fmt: skip
        lines.append("")
    lines += ["## Learning curves (training goals, mean over seeds)\n",
              f"Deterministic evaluation during training: MAMBA's return is a meta-episode's ({k} "
              "episodes), DreamerV3's one episode's.\n"]  # fmt: skip
    for arm, rows in result["runs"].items():
        steps = [p["step"] for p in rows[0]["curve"]]
        means = np.mean([[p["return"] for p in r["curve"]] for r in rows], 0)
        lines.append(
            f"- {arm}: "
            + ", ".join(f"{s // 1000}K {m:.2f}" for s, m in zip(steps, means, strict=True))
        )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
