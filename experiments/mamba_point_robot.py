"""MAMBA on point_robot: does it adapt in context, and is that adaptation in its memory?

    python experiments/mamba_point_robot.py [--seeds 0-5] [--alphas 0 0.05]
        [--steps 60000] [--agents mamba [dreamer]] [--runs runs/mamba_point_robot]
        [--set mamba.train_ratio=...] [--train-only] [--collect-only]

Trains (or resumes: run it again after a stop) each agent's runs, each alpha's seeds one
population under ``--runs/<agent>/alpha<alpha>`` (with ``--train-only``, two alphas train side by
side, each pinned to its own core: ``taskset -c 0 ... --alphas 0 --train-only`` beside
``taskset -c 1 ... --alphas 0.05 --train-only``; a last command with every alpha evaluates), at
the cpu preset's MAMBA setting (``minatt_jax.agents.mamba.CPU``: meta-episodes of 3
episodes of 50 steps) on ``point_robot_dense`` (the goal on the half circle, reward minus the
distance: the sparse reward of ``point_robot`` gave no learning signal in 150K steps) on the 16
training goals of the upper half circle. ``--agents dreamer`` adds DreamerV3 on plain 50-step
episodes (``--dreamer-steps``): a reference for the return, not a control for adaptation (its
memory is reset every episode, so its adaptation is 0 by construction).

Then evaluates each run's final policy (deterministic) on every training goal
(``--episodes-per-goal`` each) and on the 6 out-of-distribution goals of the lower half circle,
under four conditions (``CONDITIONS``) that separate adaptation from what else could make a later
episode better:

* **as trained**: memory over the whole meta-episode, the true episode index in the observation;
* **memory reset**: the same policy with its memory reset at every inner episode's first step:
  nothing can be carried from one episode to the next, so a gain left here is not in-context;
* **index withheld**: the episode-index input always reads 0 (episode 1): a policy that acts
  differently in episode 3 because the index says 3 loses that gain here;
* **index shuffled**: the index input is a random permutation of the episodes' indices.

A uniform random policy's episodes give the size of the start-state noise. Per arm and condition
the table gives episode 1, episode k and their paired difference per seed (the adaptation): mean
over seeds, the 95% t interval and the exact sign-flip p (6 seeds: the smallest p is 2/64); the
memory's own share is the paired difference of the adaptation as trained minus under memory
reset. Writes ``experiments/results/mamba_point_robot.{json,md}`` and ``mamba_point_robot_report/``
(the ``analyze`` report of every run).
"""

from __future__ import annotations

import argparse
import os
import shutil
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import stats

import minatt_jax.envs as envs
from minatt_jax import acting, checkpoint, evaluation, population, runner
from minatt_jax.analysis.report import AnalyzeConfig, analyze
from minatt_jax.config import preset_config, replace_fields, resolve
from minatt_jax.envs.meta_episode import returns_by_episode

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")
NAME = "mamba_point_robot"
ENV = "point_robot_dense"  # the dense reward: learnable at a CPU's step budget
GOALS = {"train": 16, "ood": 6}  # goals of each task set
CONDITIONS = ("as trained", "memory reset", "index withheld", "index shuffled")
SHARE = "memory's share"  # the adaptation as trained minus under memory reset, per seed


def population_dir(runs: str, agent: str, alpha: float) -> str:
    """The folder of one agent's population at one alpha (its seeds), under ``runs``."""
    return os.path.join(runs, agent, f"alpha{alpha:g}")


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


class EpisodeIndexView:
    """A meta-episode environment whose episode-index input is withheld (always 0, the first
    episode's) or shuffled (a random permutation of the episodes' indices, drawn per
    meta-episode); everything else, the reward included, is the wrapped environment's."""

    def __init__(self, env: Any, mode: str) -> None:
        if mode not in ("withheld", "shuffled"):
            raise ValueError(f"mode must be 'withheld' or 'shuffled', got {mode!r}")
        self.env, self.mode = env, mode

    def __getattr__(self, name: str) -> Any:
        return getattr(self.env, name)

    def _view(self, state: Any, order: jax.Array) -> Any:
        index = state.info["meta_index"]
        shown = jnp.zeros_like(index) if self.mode == "withheld" else order[index]
        scale = 1.0 / max(self.env.episodes - 1, 1)
        obs = state.obs.at[-1].set((shown * scale).astype(state.obs.dtype))
        return state.replace(obs=obs, info={**state.info, "index_order": order})

    def reset(self, rng: jax.Array, task: Any = None) -> Any:
        order = jax.random.permutation(jax.random.fold_in(rng, 1), self.env.episodes)
        return self._view(self.env.reset(rng, task), order)

    def step(self, state: Any, action: jax.Array) -> Any:
        order = state.info["index_order"]
        info = {k: v for k, v in state.info.items() if k != "index_order"}
        return self._view(self.env.step(state.replace(info=info), action), order)


def reset_each_episode(policy: acting.RecurrentPolicy, first_step_input: int
                       ) -> acting.RecurrentPolicy:  # fmt: skip
    """``policy`` with its memory reset to its initial memory wherever the policy input
    ``first_step_input`` (the meta-episode's first-step flag) is set: each inner episode then
    starts as the meta-episode's first did, with nothing carried over."""
    initial = policy.memory

    def fresh(memory: Any, x: jax.Array) -> Any:
        first = x[first_step_input] > 0.5
        return jax.tree.map(lambda i, m: jnp.where(first, i, m), initial, memory)

    def at(memory: Any) -> acting.Policy:
        inner = policy.at(memory)
        return acting.Policy(
            act=lambda x, k: policy.at(fresh(memory, x)).act(x, k),
            control=lambda x: policy.at(fresh(memory, x)).control(x),
            prepare=inner.prepare,
        )

    def remember(memory: Any, x: jax.Array, action: jax.Array, key: jax.Array | None) -> Any:
        return policy.remember(fresh(memory, x), x, action, key)

    return acting.RecurrentPolicy(initial, at, remember)


def condition_setup(condition: str, env: Any, policy_of: Callable) -> tuple[Any, Callable]:
    """(environment, policy_of) of an evaluation condition (``CONDITIONS``)."""
    if condition == "memory reset":
        first_step = env.observation_size - 2  # ..., reward, first_step, episode_index
        return env, lambda params, norm: reset_each_episode(policy_of(params, norm), first_step)
    if condition.startswith("index "):
        return EpisodeIndexView(env, condition.split()[1]), policy_of
    return env, policy_of


_EVALUATORS: dict = {}


def evaluate_condition(run_dir: str, task_set: str, episodes: int, condition: str,
                       seed: int) -> dict[str, Any]:  # fmt: skip
    """Each inner episode's mean return, the feedback norm and the energy of the run's final
    deterministic policy on ``task_set`` under ``condition`` (one compiled evaluator per
    program, condition and episode count: runs of one program reuse it)."""
    policy = checkpoint.load_policy(run_dir)
    env, policy_of = condition_setup(condition, policy.env, policy.family.deterministic)
    key = (runner.program_key(policy.config), condition, episodes)
    if key not in _EVALUATORS:
        _EVALUATORS[key] = evaluation.make_evaluator(env, policy_of, policy.config.episode_limit,
                                                     episodes)  # fmt: skip
    tasks, _ = envs.resolve_tasks(policy.env, task_set, ())
    result = _EVALUATORS[key](policy.actor_params, policy.normalizer,
                              jax.random.PRNGKey(100 + seed), envs.stack_tasks(tasks))  # fmt: skip
    m = evaluation.summarize(jax.device_get(result), policy.env.dt)
    k = policy.config.meta_episodes
    by_episode = ([m[f"return_episode_{i + 1}"] for i in range(k)] if k > 1
                  else [m["return"]] * k)  # fmt: skip
    return {"step": policy.step, "by_episode": by_episode, "feedback_norm": m["feedback_norm"],
            "energy": m["energy"]}  # fmt: skip


def random_policy_returns(config, task_set: str, episodes: int) -> dict[str, Any]:
    """A uniform random policy in meta-episodes: each inner episode's mean return and the
    adaptation (episode k - episode 1) with its t interval over episodes."""
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
    returns = np.asarray(jax.jit(jax.vmap(one))(keys, jnp.arange(episodes)))
    diff = returns[:, -1] - returns[:, 0]
    return {"by_episode": [float(x) for x in returns.mean(0)], "episodes": episodes,
            "adaptation": {"mean": float(diff.mean()), "ci": stats.t_interval(diff)}}  # fmt: skip


def paired(values: np.ndarray) -> dict[str, Any]:
    """Mean over seeds of paired values, their 95% t interval and the exact sign-flip p."""
    values = np.asarray(values, np.float64)
    return {"mean": float(values.mean()), "ci": stats.t_interval(values),
            "sign_flip_p": stats.sign_flip_p(values), "n": int(values.size),
            "values": [float(v) for v in values]}  # fmt: skip


MA_METRICS = ("episode_1", "adaptation", "feedback_norm", "energy")


def ma_effects(summaries: dict[str, dict]) -> dict[str, dict]:
    """Each MA arm against the same agent at alpha 0, as trained: per task set and metric, the
    difference of the seed means, Welch's 95% interval and the exact permutation p (seeds are
    independent runs, not pairs)."""
    out: dict[str, dict] = {}
    for arm, by_task in summaries.items():
        agent, alpha = arm.split(" alpha=")
        base = summaries.get(f"{agent} alpha=0")
        if float(alpha) == 0 or base is None:
            continue
        out[arm] = {}
        for task_set, by_condition in by_task.items():
            mine, theirs = by_condition["as trained"], base[task_set]["as trained"]
            out[arm][task_set] = {}
            for metric in MA_METRICS:
                out[arm][task_set][metric] = stats.difference(mine[metric]["values"],
                                                              theirs[metric]["values"])  # fmt: skip
    return out


def reading(result: dict, k: int, level: float = 0.05) -> list[str]:
    """What the tests resolve, in sentences written from the numbers: adaptation where its
    sign-flip p is below ``level``, the memory's share likewise, MA's effects by permutation
    p; everything else is named unresolved."""

    def resolved(s: dict, key: str = "sign_flip_p") -> bool:
        return s[key] < level

    lines = ["## Reading\n", f"Resolved means p < {level:g} for that one test (no correction "
             "across the rows).\n"]  # fmt: skip
    for task_set in result["goals"]:
        rand = result["random_policy"][task_set]["adaptation"]
        for arm, by_condition in result["summaries"].items():
            t = by_condition[task_set]
            if "memory reset" not in t:
                continue
            a, share = t["as trained"]["adaptation"], t[SHARE]
            text = (f"- {task_set} goals, {arm}: episode {k} minus episode 1 is {a['mean']:.2f} "
                    f"[{a['ci'][0]:.2f}, {a['ci'][1]:.2f}] (p {a['sign_flip_p']:.3g}, "
                    f"{a['n']} seeds): ")  # fmt: skip
            if not resolved(a):
                text += "no adaptation is resolved"
            else:
                text += "resolved " + ("above" if a["mean"] > 0 else "below") + " 0"
            text += (f"; the memory's share {share['mean']:.2f} [{share['ci'][0]:.2f}, "
                     f"{share['ci'][1]:.2f}] (p {share['sign_flip_p']:.3g}) ")  # fmt: skip
            reset = t["memory reset"]["adaptation"]
            if resolved(share) and share["mean"] > 0 and resolved(a) and a["mean"] > 0:
                text += (f"is resolved: the gain from episode 1 to {k} depends on what the "
                         "memory carries between episodes, in-context adaptation")  # fmt: skip
            elif resolved(share) and share["mean"] > 0:
                text += (f"is resolved, but episode {k} is not resolved above episode 1: "
                         f"resetting the memory makes episode {k} worse (by {-reset['mean']:.2f}"
                         "), so the policy relies on its memory without improving on episode 1 "
                         "with it")  # fmt: skip
            elif resolved(share):
                text += "is resolved below 0: carrying the memory makes later episodes worse"
            else:
                text += "is not resolved: the controls do not show in-context adaptation"
            text += (f". A random policy's own episode {k} minus episode 1 is {rand['mean']:.2f} "
                     f"[{rand['ci'][0]:.2f}, {rand['ci'][1]:.2f}].")  # fmt: skip
            lines.append(text)
    for arm, by_task in result.get("ma_effects", {}).items():
        for task_set, metrics in by_task.items():
            parts = []
            for metric, e in metrics.items():
                low, high = e["welch_ci"]
                verdict = "resolved" if resolved(e, "permutation_p") else "not resolved"
                parts.append(f"{metric.replace('_', ' ')} {e['diff']:+.3g} (Welch [{low:.3g}, "
                             f"{high:.3g}], p {e['permutation_p']:.3g}, {verdict})")  # fmt: skip
            lines.append(f"- {task_set} goals, {arm} minus alpha 0 (as trained): "
                         + "; ".join(parts) + ".")  # fmt: skip
    return lines + [""]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0-5")
    parser.add_argument("--alphas", type=float, nargs="+", default=[0.0, 0.05])
    parser.add_argument("--agents", nargs="+", default=["mamba"], choices=["mamba", "dreamer"])
    parser.add_argument("--steps", type=int, default=None,
                        help="env steps per run (default: the cpu preset's, 60K)")  # fmt: skip
    parser.add_argument("--dreamer-steps", type=int, default=None,
                        help="env steps per DreamerV3 run (default: --steps)")  # fmt: skip
    parser.add_argument("--episodes-per-goal", type=int, default=4,
                        help="evaluation meta-episodes per goal and condition")  # fmt: skip
    parser.add_argument("--runs", default="runs/mamba_point_robot")
    parser.add_argument("--set", action="append", default=[], dest="overrides")
    parser.add_argument("--train-only", action="store_true", help="train, then stop")
    parser.add_argument("--collect-only", action="store_true",
                        help="tabulate the runs as they stand, without training")  # fmt: skip
    parser.add_argument("--no-report", action="store_true", help="skip the analyze report")
    args = parser.parse_args()
    seeds = population.parse_seeds(args.seeds)
    reference = run_config("mamba", 0.0, 0, args.steps, args.overrides)
    k = reference.meta_episodes
    members_of = {}
    for agent in args.agents:
        # every (alpha, seed) of an agent in one program (population): seeds and alphas are data
        steps = args.dreamer_steps if agent == "dreamer" and args.dreamer_steps else args.steps
        members_of[agent] = [run_config(agent, alpha, seed, steps, args.overrides)
                             for alpha in args.alphas for seed in seeds]  # fmt: skip
        for alpha in args.alphas if not args.collect_only else ():
            # each alpha's seeds one population: two alphas can train in two pinned lanes
            out = population_dir(args.runs, agent, alpha)
            resume = os.path.exists(os.path.join(out, "population.json"))
            members = [c for c in members_of[agent] if c.ma.alpha == alpha]
            population.train_population(members, out, ["ma.alpha"], resume=resume,
                                        log=lambda m: print(m, flush=True))  # fmt: skip
    if args.train_only:
        return
    arms: dict[str, list[dict]] = {}
    for agent, members in members_of.items():
        for config in members:
            out = population_dir(args.runs, agent, config.ma.alpha)
            run_dir = os.path.join(out, population.member_name(config, ["ma.alpha"]))
            records = runner.read_metrics(run_dir)
            row: dict[str, Any] = {
                "seed": config.seed,
                "run": os.path.relpath(run_dir, args.runs),  # under --runs
                "updates": int(sum(r["updates"] for r in records)),  # a record counts its chunk's
                "curve": [{"step": r["step"], "return": r["return"]} for r in records],
            }
            conditions = CONDITIONS if agent == "mamba" else CONDITIONS[:1]
            for task_set, goals in GOALS.items():
                row[task_set] = {}
                for condition in conditions:
                    m = evaluate_condition(run_dir, task_set, goals * args.episodes_per_goal,
                                           condition, config.seed)  # fmt: skip
                    row["step"] = m.pop("step")
                    row[task_set][condition] = m
            print(f"evaluated {row['run']}", flush=True)
            arms.setdefault(f"{agent} alpha={config.ma.alpha:g}", []).append(row)
    random = {s: random_policy_returns(reference, s, 64 * goals) for s, goals in GOALS.items()}
    summaries: dict[str, dict] = {}
    for arm, rows in arms.items():
        summaries[arm] = {}
        for task_set in GOALS:
            summaries[arm][task_set] = {}
            for condition in rows[0][task_set]:
                per_seed = np.asarray([r[task_set][condition]["by_episode"] for r in rows])
                summaries[arm][task_set][condition] = {
                    "episode_1": paired(per_seed[:, 0]),
                    f"episode_{k}": paired(per_seed[:, -1]),
                    "adaptation": paired(per_seed[:, -1] - per_seed[:, 0]),
                    "feedback_norm": paired(
                        [r[task_set][condition]["feedback_norm"] for r in rows]
                    ),  # fmt: skip
                    "energy": paired([r[task_set][condition]["energy"] for r in rows]),
                }
            if "memory reset" in rows[0][task_set]:
                gain = np.asarray([
                    (r[task_set]["as trained"]["by_episode"][-1]
                     - r[task_set]["as trained"]["by_episode"][0])
                    - (r[task_set]["memory reset"]["by_episode"][-1]
                       - r[task_set]["memory reset"]["by_episode"][0]) for r in rows
                ])  # fmt: skip
                summaries[arm][task_set][SHARE] = paired(gain)
    effects = ma_effects(summaries)
    command = ("python experiments/mamba_point_robot.py --seeds " + args.seeds + " --alphas "
               + " ".join(f"{a:g}" for a in args.alphas) + f" --steps {reference.total_steps}"
               + (" --agents " + " ".join(args.agents) if args.agents != ["mamba"] else "")
               + (f" --dreamer-steps {args.dreamer_steps}" if args.dreamer_steps else "")
               + f" --episodes-per-goal {args.episodes_per_goal}"
               + "".join(f" --set {o}" for o in args.overrides))  # fmt: skip
    result = {**study_provenance(command), "meta_episode": f"{k} x {reference.max_episode_steps} "
              "steps", "goals": GOALS, "episodes_per_goal": args.episodes_per_goal,
              "random_policy": random, "summaries": summaries, "ma_effects": effects,
              "runs": arms}  # fmt: skip
    os.makedirs(RESULTS, exist_ok=True)
    runner.write_json_atomic(os.path.join(RESULTS, f"{NAME}.json"), result)
    text = table(result, k)
    runner.write_text_atomic(os.path.join(RESULTS, f"{NAME}.md"), text)
    print(text)
    if not args.no_report:
        run_dirs = [os.path.join(args.runs, r["run"]) for rows in arms.values() for r in rows]
        write_report(run_dirs, os.path.join(args.runs, "report"), command)


def study_provenance(command: str) -> dict[str, Any]:
    """The command and the device it ran on (``study.provenance``)."""
    import study

    return study.provenance(command)


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
    """The results as markdown: mean over seeds [95% t interval] and the exact sign-flip p."""

    def cell(s: dict, p: bool = False) -> str:
        text = f"{s['mean']:.2f} [{s['ci'][0]:.2f}, {s['ci'][1]:.2f}]"
        return text + (f" (p {s['sign_flip_p']:.3g})" if p else "")

    lines = [
        f"# MAMBA on {ENV}: in-context adaptation and its controls\n",
        f"`{result['command']}` on {result['device']}; meta-episodes of "
        f"{result['meta_episode']}. Deterministic evaluation of each run's final policy, "
        f"{result['episodes_per_goal']} meta-episodes per goal; mean over seeds with the 95% t "
        f"interval. Adaptation: episode {k} minus episode 1, paired per seed, with the exact "
        "sign-flip p. Conditions: *as trained*; *memory reset* at every inner episode (nothing "
        "carried between episodes); *index withheld* (the episode-index input reads episode 1 "
        "throughout); *index shuffled* (a random permutation of the indices). *Memory's share*: "
        "the adaptation as trained minus under memory reset, paired per seed.\n",
    ]
    for task_set in result["goals"]:
        rand = result["random_policy"][task_set]
        ra = rand["adaptation"]
        lines += [
            f"## {task_set} goals\n",
            f"Random policy ({rand['episodes']} meta-episodes): episode 1 "
            f"{rand['by_episode'][0]:.2f}, episode {k} {rand['by_episode'][-1]:.2f}, "
            f"adaptation {ra['mean']:.2f} [{ra['ci'][0]:.2f}, {ra['ci'][1]:.2f}].\n",
            f"| arm | condition | seeds | episode 1 | episode {k} | adaptation (sign-flip p) | "
            "feedback | energy |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for arm, by_condition in result["summaries"].items():
            for condition, t in by_condition[task_set].items():
                if condition == SHARE:
                    continue
                lines.append(f"| {arm} | {condition} | {t['adaptation']['n']} | "
                             f"{cell(t['episode_1'])} | {cell(t[f'episode_{k}'])} | "
                             f"{cell(t['adaptation'], p=True)} | {cell(t['feedback_norm'])} | "
                             f"{cell(t['energy'])} |")  # fmt: skip
        lines.append("")
        for arm, by_condition in result["summaries"].items():
            share = by_condition[task_set].get(SHARE)
            if share is not None:
                lines.append(f"- {arm}, memory's share of the adaptation: {cell(share, p=True)}")
        lines.append("")
    lines += reading(result, k)
    lines += ["## Learning curves (training goals, mean over seeds)\n",
              f"Deterministic evaluation during training: MAMBA's return is a meta-episode's ({k} "
              "episodes), DreamerV3's one episode's.\n"]  # fmt: skip
    for arm, rows in result["runs"].items():
        steps = [p["step"] for p in rows[0]["curve"]]
        means = np.mean([[p["return"] for p in r["curve"]] for r in rows], 0)
        lines.append(
            f"- {arm} ({np.mean([r['updates'] for r in rows]):.0f} updates): "
            + ", ".join(f"{s // 1000}K {m:.2f}" for s, m in zip(steps, means, strict=True))
        )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
