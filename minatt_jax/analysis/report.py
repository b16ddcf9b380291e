"""``minatt-jax analyze``: figures, tables and one self-contained report for runs of one env.

Runs are grouped by their configuration (algorithm, alpha, MA mode); the seeds of a group are
aggregated. For every group the report shows

* ``heatmap_feedback.png`` / ``heatmap_feedforward.png``: binned means of ||du/dx||_F^2 and of
  ||(u_t - u_{t-1})/dt||^2 over the states the deterministic policy visits (all seeds pooled), on
  the paper's 2D projections for the environment, groups side by side on a shared color scale;
* ``profiles.png``: return, feedback, feedforward and energy over training (``metrics.jsonl``),
  mean and std band across seeds;
* ``decomposition.png``: ||K(t)||_F and ||v(t)||_2 of u = K(t) x + v(t) along one rollout, on the
  nominal task and on a perturbed one (first seed of each group);
* ``failure_grid.png``: failure rate over (forward velocity, torso pitch rate) initial states,
  per group and the difference first group - second group (``control_analysis.failed``);
* ``maturation.png``: the feedback heatmap (first projection) from policy snapshots at chosen steps;
* ``frames.png``: six rendered frames of one episode of each group's first run (where the
  machine renders offscreen: ``minatt_jax.render``);
* ``adaptation.png`` (runs in meta-episodes only): return, feedback, feedforward and energy per
  inner episode of a meta-episode, the in-context adaptation curve (a table too);
* ``tables.md`` / ``tables.json``: meta-training rows (final evaluation) and meta-testing rows
  (from ``meta_test_<variant>.json`` files in the runs), mean and std across seeds;
* ``report.html``: all of it with the figures embedded (base64), readable offline.
"""

from __future__ import annotations

import base64
import dataclasses
import html
import json
import os
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import minatt_jax.envs as envs
from minatt_jax import acting, checkpoint, run_files, runner
from minatt_jax.agents import registry
from minatt_jax.analysis import control_analysis as ca
from minatt_jax.analysis.plots import _pyplot, save_figure
from minatt_jax.config import TrainConfig
from minatt_jax.envs.meta_episode import returns_by_episode

PROFILE_METRICS = ("return", "feedback_norm", "feedforward_norm", "energy")
FIGURES = ("heatmap_feedback.png", "heatmap_feedforward.png", "profiles.png",
           "decomposition.png", "failure_grid.png", "maturation.png")  # fmt: skip


@dataclasses.dataclass(frozen=True)
class AnalyzeConfig:
    """Sizes of the analysis (defaults: the paper's failure grid; tests shrink them)."""

    episodes: int = 5
    bins: int = 20
    grid: int = 9
    grid_rollouts: int = 20
    grid_steps: int = 100
    maturation_steps: tuple[int, ...] = (10_000, 100_000, 200_000)
    perturbation: str = "crippled"
    seed: int = 0


@dataclasses.dataclass
class Run:
    run_dir: str
    config: TrainConfig
    group: str


def group_label(config: TrainConfig) -> str:
    label = f"{config.algo} alpha={config.ma.alpha:g}"
    if config.ma.alpha > 0 and config.ma.mode != "full":
        label += f" ({config.ma.mode})"
    return label


def load_runs(run_dirs: list[str]) -> list[Run]:
    """Reads and checks the runs: one environment, each with a checkpoint."""
    runs = [Run(d, runner.load_config(d), "") for d in run_dirs]
    env_names = {r.config.env for r in runs}
    if len(env_names) > 1:
        listing = ", ".join(f"{r.run_dir} ({r.config.env})" for r in runs)
        raise runner.RunError(
            f"runs of different environments: {listing}; analyze one environment at a time"
        )
    for r in runs:
        if checkpoint.latest_policy_step(r.run_dir) is None:  # what evaluate accepts too
            raise runner.RunError(f"{r.run_dir} has no checkpoint or policy snapshot: train "
                                  "it first")  # fmt: skip
        r.group = group_label(r.config)
    return runs


def inner_episode_of(traj: acting.Trajectory) -> jax.Array:
    """The inner episode of each step (``meta_episode_index``; 0 throughout a plain episode)."""
    return traj.env_metrics.get("meta_episode_index", jnp.zeros_like(traj.reward))


def make_rollouts(env: Any, policy_of: Callable[[Any, Any], Any], steps: int) -> Callable:
    """A jitted ``(params, normalizer, keys (n,), task) -> per-step arrays (n, steps)`` of ``n``
    deterministic rollouts: observations, actions, rewards, alive mask, the inner episode of each
    step (``meta_episode_index``; 0 throughout a plain episode), ||du/dx||^2, ||du/dt||^2 and
    ||u||^2."""

    def rollout(params, norm, key, task):
        traj = acting.unroll(env, policy_of(params, norm), env.reset(key, task), steps,
                             probe_feedback=True)  # fmt: skip
        u = traj.action
        u_prev = jnp.concatenate([u[:1], u[:-1]])
        episode = inner_episode_of(traj)
        return {
            "obs": traj.obs,
            "policy_obs": traj.policy_obs,
            "u": u,
            "alive": traj.alive,
            "reward": traj.reward,
            "episode": episode.astype(jnp.int32),
            "feedback": traj.feedback,
            "feedforward": jnp.sum(jnp.square((u - u_prev) / env.dt), -1),
            "energy": jnp.sum(jnp.square(u), -1),
        }

    return jax.jit(jax.vmap(rollout, in_axes=(None, None, 0, None)))


class _GroupTools:
    """Jitted functions for one group's shapes (built once, shared by its seeds); the policy
    family (the agent's ``policy``) makes them the same for feedforward and recurrent policies."""

    def __init__(self, config: TrainConfig, settings: AnalyzeConfig) -> None:
        env = config.make_env()
        self.family = registry.get(config.algo).policy(config, env)
        self.env, self.config = env, config
        steps = config.episode_limit
        policy_of = self.family.deterministic

        def gains(params, norm, key, task):
            """One rollout with u = K(t) x + v(t)'s parts: x, u, K and alive."""
            traj = acting.unroll(env, policy_of(params, norm), env.reset(key, task), steps,
                                 probe_gain=True)  # fmt: skip
            episode = inner_episode_of(traj)
            return traj.policy_obs, traj.action, traj.gain, traj.alive, episode

        self.rollouts = make_rollouts(env, policy_of, steps)
        self.gains = jax.jit(gains)
        self.grid = ca.make_failure_grid(
            env, lambda p: policy_of(p[0], p[1]), steps=settings.grid_steps,
            rollouts=settings.grid_rollouts,
        )  # fmt: skip
        self.policy_like = self.family.like
        self.inner_episodes = config.meta_episodes

    def restore(self, run_dir: str):
        """(step, policy parameters, normalizer) of the run's latest policy (no trainer)."""
        try:
            policy = checkpoint.load_policy(run_dir)
        except checkpoint.CheckpointError as e:
            raise runner.RunError(str(e)) from None
        return policy.step, policy.actor_params, policy.normalizer

    def decompose(self, params, norm, key, task) -> dict[str, np.ndarray]:
        """u = K(t) x + v(t) along one deterministic rollout (its alive steps)."""
        x, u, gain, alive, episode = jax.device_get(self.gains(params, norm, key, task))
        keep = np.asarray(alive) > 0
        parts = jax.device_get(ca.decompose_gains(gain[keep], u[keep], x[keep]))
        return {**parts, "episode": np.asarray(episode)[keep]}


def visited_states(
    tools: _GroupTools, params: Any, norm: Any, key: jax.Array, episodes: int, task: Any
) -> dict[str, np.ndarray]:
    """The alive steps of ``episodes`` deterministic rollouts (per-step arrays), and each
    rollout's return per inner episode (``returns``: (episodes, inner episodes))."""
    out = jax.device_get(tools.rollouts(params, norm, jax.random.split(key, episodes), task))
    alive = np.asarray(out["alive"]) > 0
    episode = np.asarray(out["episode"])
    first = np.ones_like(alive)  # the feedforward term needs a previous action of its episode
    first[:, 1:] = episode[:, 1:] != episode[:, :-1]
    returns = np.asarray(returns_by_episode(out["reward"], episode, out["alive"],
                                            tools.inner_episodes))  # fmt: skip
    return {
        "obs": np.asarray(out["obs"])[alive],
        "policy_obs": np.asarray(out["policy_obs"]),
        "alive": alive,
        "episode": episode[alive],
        "feedback": np.asarray(out["feedback"])[alive],
        "feedforward": np.where(first, np.nan, np.asarray(out["feedforward"]))[alive],
        "energy": np.asarray(out["energy"])[alive],
        "returns": returns,
    }


ADAPTATION_METRICS = ("return", "feedback", "feedforward", "energy")


def by_inner_episode(visited: dict[str, np.ndarray], inner: int) -> dict[str, list[float]]:
    """One run's in-context adaptation curve: per inner episode of its meta-episodes, the mean
    return and the mean feedback, feedforward and energy over the steps of that episode."""
    out = {"return": np.mean(visited["returns"], axis=0).tolist()}
    for metric in ADAPTATION_METRICS[1:]:
        values = visited[metric]
        out[metric] = [float(np.nanmean(values[visited["episode"] == i]))
                       if np.any(visited["episode"] == i) else float("nan")
                       for i in range(inner)]  # fmt: skip
    return out


def _edges(values: list[np.ndarray], bins: int) -> np.ndarray:
    v = np.concatenate([x[np.isfinite(x)] for x in values])
    lo, hi = (float(np.min(v)), float(np.max(v))) if v.size else (0.0, 1.0)
    if hi - lo < 1e-9:
        lo, hi = lo - 0.5, hi + 0.5
    return np.linspace(lo, hi, bins + 1)


def _color_norm(finite: np.ndarray) -> Any:
    """One color scale for values of several groups: logarithmic when they are positive and span
    more than two decades (alpha = 1 feedback is ~1000x below alpha = 0's, and a linear scale
    paints it one flat color), else linear."""
    from matplotlib.colors import LogNorm, Normalize

    if finite.size == 0:
        return Normalize(0.0, 1.0)
    lo, hi = float(finite.min()), float(finite.max())
    if lo > 0 and hi / lo > 100.0:
        return LogNorm(lo, hi)
    return Normalize(lo, hi)


def _heatmap_figure(groups, states, metric, env, bins, path, title_suffix=""):
    plt = _pyplot()
    pairs = env.projection_indices()
    names = list(groups)
    fig, axes = plt.subplots(len(pairs), len(names), squeeze=False, layout="constrained",
                             figsize=(3.8 * len(names), 3.2 * len(pairs)))  # fmt: skip
    out = {}
    for row, (i, j) in enumerate(pairs):
        xe = _edges([states[g]["obs"][:, i] for g in names], bins)
        ye = _edges([states[g]["obs"][:, j] for g in names], bins)
        means = {}
        for g in names:
            v = states[g][metric]
            ok = np.isfinite(v)
            means[g], _ = ca.binned_means(states[g]["obs"][ok, i], states[g]["obs"][ok, j],
                                          v[ok], xe, ye)  # fmt: skip
        norm = _color_norm(np.concatenate([m[np.isfinite(m)] for m in means.values()]))
        for col, g in enumerate(names):
            ax = axes[row][col]
            extent = (xe[0], xe[-1], ye[0], ye[-1])
            image = ax.imshow(means[g].T, origin="lower", aspect="auto", cmap="viridis",
                              extent=extent, norm=norm)  # fmt: skip
            ax.set_xlabel(env.obs_names[i])
            ax.set_ylabel(env.obs_names[j])
            ax.set_title(f"{g}{title_suffix}", fontsize=9)
            out[f"{env.obs_names[i]}|{env.obs_names[j]}|{g}"] = means[g]
        fig.colorbar(image, ax=list(axes[row]), shrink=0.8)
    fig.suptitle(f"{metric} over visited states (binned mean, shared scale per row)", fontsize=10)
    save_figure(fig, path)
    return out


def _mean_std_table(rows: list[dict], keys: tuple[str, ...]) -> dict[str, Any]:
    out: dict[str, Any] = {"seeds": len(rows)}
    for k in keys:
        v = np.array([r[k] for r in rows if k in r], dtype=float)
        out[k] = float(np.mean(v)) if v.size else None
        out[f"{k}_std"] = float(np.std(v)) if v.size else None
    return out


def aggregate_tables(runs: list[Run]) -> dict[str, Any]:
    """Meta-training rows (final evaluation) and meta-testing rows, mean/std across seeds."""
    groups: dict[str, list[Run]] = {}
    for r in runs:
        groups.setdefault(r.group, []).append(r)
    training, testing = [], []
    for g, members in groups.items():
        finals = [runner.read_metrics(r.run_dir)[-1] for r in members
                  if runner.read_metrics(r.run_dir)]  # fmt: skip
        training.append({"group": g, "step": min((f["step"] for f in finals), default=0),
                         **_mean_std_table(finals, PROFILE_METRICS)})  # fmt: skip
        variants = sorted({f[10:-5] for r in members for f in os.listdir(r.run_dir)
                           if f.startswith("meta_test_") and f.endswith(".json")})  # fmt: skip
        for variant in variants:
            rows = []
            for r in members:
                path = os.path.join(r.run_dir, f"meta_test_{variant}.json")
                if os.path.exists(path):
                    with open(path) as f:
                        mean = json.load(f)["mean_over_tasks"]
                    rows.append(
                        {k: v["after"] for k, v in mean.items()}
                        | {f"{k}_before": v["before"] for k, v in mean.items()}
                    )
            stats = _mean_std_table(rows, (*PROFILE_METRICS, "return_before"))
            testing.append({"group": g, "variant": variant, **stats})
    return {"meta_training": training, "meta_testing": testing}


def _fmt(row: dict, k: str) -> str:
    if row.get(k) is None:
        return "-"
    return f"{row[k]:.4g} +- {row[k + '_std']:.2g}"


def tables_markdown(tables: dict[str, Any]) -> str:
    lines = ["## Meta-training (final evaluation)", "",
             "| group | seeds | step | " + " | ".join(PROFILE_METRICS) + " |",
             "|---" * (len(PROFILE_METRICS) + 3) + "|"]  # fmt: skip
    for r in tables["meta_training"]:
        lines.append(f"| {r['group']} | {r['seeds']} | {r['step']} | "
                     + " | ".join(_fmt(r, k) for k in PROFILE_METRICS) + " |")  # fmt: skip
    lines += ["", "## Meta-testing (after adaptation; return before it too)", "",
              "| group | variant | seeds | return before | " + " | ".join(PROFILE_METRICS) + " |",
              "|---" * (len(PROFILE_METRICS) + 4) + "|"]  # fmt: skip
    for r in tables["meta_testing"]:
        lines.append(f"| {r['group']} | {r['variant']} | {r['seeds']} | "
                     f"{_fmt(r, 'return_before')} | "
                     + " | ".join(_fmt(r, k) for k in PROFILE_METRICS) + " |")  # fmt: skip
    if not tables["meta_testing"]:
        lines.append("| (no meta_test_<variant>.json in these runs: run `minatt-jax meta-test`) |")
    if tables.get("in_context"):
        lines += ["", "## In-context adaptation (nominal task, per inner episode of a "
                  "meta-episode)", "", "| group | seeds | inner episode | "
                  + " | ".join(ADAPTATION_METRICS) + " |",
                  "|---" * (len(ADAPTATION_METRICS) + 3) + "|"]  # fmt: skip
        for r in tables["in_context"]:
            lines.append(f"| {r['group']} | {r['seeds']} | {r['episode']} | "
                         + " | ".join(_fmt(r, k) for k in ADAPTATION_METRICS) + " |")  # fmt: skip
    return "\n".join(lines) + "\n"


def in_context_rows(adaptation: dict[str, list[dict[str, list[float]]]]) -> list[dict[str, Any]]:
    """A row per group and inner episode (1-based): each metric's mean and std over seeds."""
    rows = []
    for g, per_seed in adaptation.items():
        for i in range(len(per_seed[0]["return"])):
            values = [{k: run[k][i] for k in ADAPTATION_METRICS} for run in per_seed]
            rows.append({"group": g, "episode": i + 1,
                         **_mean_std_table(values, ADAPTATION_METRICS)})  # fmt: skip
    return rows


def profiles_figure(runs: list[Run], path: str) -> None:
    """Return, feedback, feedforward and energy over training, mean +- std across each group's
    seeds. A metric whose positive values span more than two decades gets a log axis (alpha = 1
    feedback is ~1000x below alpha = 0's and lies flat on zero on a linear one)."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(PROFILE_METRICS), figsize=(4.2 * len(PROFILE_METRICS), 3.3))
    groups: dict[str, list[Run]] = {}
    for r in runs:
        groups.setdefault(r.group, []).append(r)
    plotted: dict[str, list[np.ndarray]] = {m: [] for m in PROFILE_METRICS}
    for g, members in groups.items():
        records = [runner.read_metrics(r.run_dir) for r in members]
        steps = sorted(set.intersection(*[{x["step"] for x in rec} for rec in records]))
        for ax, metric in zip(axes, PROFILE_METRICS, strict=True):
            values = np.array([[next(x[metric] for x in rec if x["step"] == s) for s in steps]
                               for rec in records])  # fmt: skip
            mean, std = values.mean(0), values.std(0)
            ax.plot(steps, mean, marker="o", ms=3, label=f"{g} ({len(members)} seeds)")
            ax.fill_between(steps, mean - std, mean + std, alpha=0.2)
            plotted[metric].append(mean)
    for ax, metric in zip(axes, PROFILE_METRICS, strict=True):
        means = np.concatenate(plotted[metric]) if plotted[metric] else np.zeros(0)
        means = means[np.isfinite(means)]
        if means.size and means.min() > 0 and means.max() / means.min() > 100.0:
            ax.set_yscale("log")
        ax.set_title(metric)
        ax.set_xlabel("env steps")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    save_figure(fig, path)


def check_inputs(run_dirs: list[str], out_dir: str, settings: AnalyzeConfig | None = None) -> None:
    """RunError, before any work, for a run given twice (it would count as two seeds), a report
    directory on a run's own files, a run whose records cannot be read, or (``settings`` given:
    the user chose them) a maturation step past a run's last policy snapshot."""
    seen: dict[str, str] = {}
    for d in run_dirs:
        real = os.path.realpath(d)
        if real in seen:
            raise runner.RunError(f"{d} is given twice (as {seen[real]} too): each run counts as "
                                  "one seed")  # fmt: skip
        seen[real] = d
        run_files.check_not_run_file(d, out_dir, example="report")
        if os.path.isdir(d):
            runner.read_metrics(d)  # read at the end for the tables: checked now
            steps = checkpoint.snapshot_steps(d)
            late = [s for s in (settings.maturation_steps if settings else ()) if steps
                    and s > steps[-1]]  # fmt: skip
            if late:
                raise runner.RunError(f"maturation step {late[0]} is past the last policy "
                                      f"snapshot of {d} (step {steps[-1]}); choose steps up to "
                                      "it")  # fmt: skip


@dataclasses.dataclass
class Report:
    """What ``compute_report`` computes and ``write_report`` writes: the runs by group, the
    states each group's policies visit (with their feedback and feedforward terms), the
    K(t)x + v(t) decompositions, the failure grids over (forward velocity, pitch rate), the
    visited states at earlier training steps, and the tables (``tables.json``)."""

    runs: list[Run]
    groups: dict[str, list[Run]]
    env: Any
    settings: AnalyzeConfig
    states: dict[str, dict[str, np.ndarray]]
    decomposition: dict[str, dict[str, dict[str, np.ndarray]]]
    grids: dict[str, np.ndarray]
    forward_velocity: np.ndarray
    pitch_rate: np.ndarray
    maturation: dict[str, dict[int, dict[str, np.ndarray]]]
    tables: dict[str, Any]


def analyze(
    run_dirs: list[str],
    out_dir: str,
    settings: AnalyzeConfig = AnalyzeConfig(),
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Writes every figure, the tables and report.html for ``run_dirs`` into ``out_dir``."""
    check_inputs(run_dirs, out_dir)
    report = compute_report(run_dirs, settings, log)
    os.makedirs(out_dir, exist_ok=True)
    return write_report(report, out_dir)


def compute_report(
    run_dirs: list[str], settings: AnalyzeConfig = AnalyzeConfig(), log: Callable = print
) -> Report:
    """Everything the report shows, computed from the runs' policies (nothing written)."""
    runs = load_runs(run_dirs)
    try:
        envs.check_task_set_name(settings.perturbation)
    except envs.UnknownNameError as e:
        raise runner.RunError(str(e)) from None
    groups: dict[str, list[Run]] = {}
    for r in runs:
        groups.setdefault(r.group, []).append(r)
    key = jax.random.PRNGKey(settings.seed)
    tools: dict[str, _GroupTools] = {}
    states: dict[str, dict[str, np.ndarray]] = {}
    decomposition: dict[str, dict[str, np.ndarray]] = {}
    grids: dict[str, np.ndarray] = {}
    maturation: dict[str, dict[int, dict[str, np.ndarray]]] = {}
    adaptation: dict[str, list[dict[str, list[float]]]] = {}  # meta-episode groups, per seed
    env = None
    for g, members in groups.items():
        log(f"analyzing {g}: {len(members)} run(s)")
        t = tools[g] = _GroupTools(members[0].config, settings)
        env = t.env
        nominal = env.nominal_task()
        perturbed = envs.task_list(env, settings.perturbation)[0][0]
        pooled: list[dict[str, np.ndarray]] = []
        grid_list = []
        (vx_lo, vx_hi), (w_lo, w_hi) = env.failure_grid_ranges
        vx = jnp.linspace(vx_lo, vx_hi, settings.grid)
        w = jnp.linspace(w_lo, w_hi, settings.grid)
        for n, r in enumerate(members):
            _, params, norm = t.restore(r.run_dir)
            visited = visited_states(t, params, norm, jax.random.fold_in(key, n), settings.episodes,
                               nominal)  # fmt: skip
            pooled.append(visited)
            if t.inner_episodes > 1:
                adaptation.setdefault(g, []).append(by_inner_episode(visited, t.inner_episodes))
            grid_list.append(np.asarray(t.grid((params, norm), vx, w, jax.random.fold_in(key, 7),
                                               nominal)))  # fmt: skip
            if n == 0:
                decomposition[g] = {}
                for name, task in (("nominal", nominal), (settings.perturbation, perturbed)):
                    decomposition[g][name] = t.decompose(params, norm, jax.random.fold_in(key, 99),
                                                         task)  # fmt: skip
        states[g] = {k: np.concatenate([p[k] for p in pooled])
                     for k in ("obs", "feedback", "feedforward")}  # fmt: skip
        grids[g] = np.mean(grid_list, axis=0)
        # Maturation: the snapshot of the first run nearest to each requested step.
        available = checkpoint.snapshot_steps(members[0].run_dir)
        maturation[g] = {}
        like = t.policy_like
        for want in settings.maturation_steps:
            if not available:
                break
            step = min(available, key=lambda s, want=want: abs(s - want))
            if step in maturation[g]:
                continue
            params, norm = checkpoint.load_policy_snapshot(members[0].run_dir, step, like)
            v = visited_states(t, params, norm, jax.random.fold_in(key, 5), settings.episodes,
                               nominal)  # fmt: skip
            maturation[g][step] = v

    assert env is not None
    tables = aggregate_tables(runs)
    if adaptation:
        tables["in_context"] = in_context_rows(adaptation)
    return Report(runs, groups, env, settings, states, decomposition, grids, np.asarray(vx),
                  np.asarray(w), maturation, tables)  # fmt: skip


def write_report(report: Report, out_dir: str) -> dict[str, Any]:
    """Writes a computed report's figures, ``failure_grid.json``, ``tables.md``,
    ``tables.json`` and ``report.html`` into ``out_dir``; returns what was written."""
    runs, groups, env, settings = report.runs, report.groups, report.env, report.settings
    grids, vx, w, tables = report.grids, report.forward_velocity, report.pitch_rate, report.tables
    figures = {}
    for metric in ("feedback", "feedforward"):
        path = os.path.join(out_dir, f"heatmap_{metric}.png")
        _heatmap_figure(groups, report.states, metric, env, settings.bins, path)
        figures[f"heatmap_{metric}.png"] = f"{metric} heatmaps over the paper's projections"
    profiles_figure(runs, os.path.join(out_dir, "profiles.png"))
    figures["profiles.png"] = "return, feedback, feedforward and energy over training"
    _decomposition_figure(report.decomposition, env.dt,
                          os.path.join(out_dir, "decomposition.png"))  # fmt: skip
    figures["decomposition.png"] = "||K(t)||_F and ||v(t)|| of u = K(t)x + v(t) along a rollout"
    _failure_figure(grids, vx, w, runs[0].config.env, os.path.join(out_dir, "failure_grid.png"))
    figures["failure_grid.png"] = "failure rate over initial forward velocity x pitch rate"
    runner.write_json_atomic(
        os.path.join(out_dir, "failure_grid.json"),
        {"forward_velocity": vx.tolist(), "pitch_rate": w.tolist(),
         "failure_rate": {g: grids[g].tolist() for g in grids}},  # [vx index][pitch-rate index]
    )  # fmt: skip
    _maturation_figure(report.maturation, env, settings.bins,
                       os.path.join(out_dir, "maturation.png"))  # fmt: skip
    figures["maturation.png"] = "feedback heatmap (first projection) at earlier training steps"
    if "in_context" in tables:
        _adaptation_figure(tables["in_context"], os.path.join(out_dir, "adaptation.png"))
        figures["adaptation.png"] = (
            "return, feedback, feedforward and energy per inner "
            "episode of a meta-episode (in-context adaptation)"
        )
    if _frames_figure(groups, os.path.join(out_dir, "frames.png")):
        figures["frames.png"] = (
            "six frames of one episode of each group's first run (its "
            "deterministic policy on the nominal task)"
        )
    markdown = tables_markdown(tables)
    runner.write_text_atomic(os.path.join(out_dir, "tables.md"), markdown)
    runner.write_json_atomic(os.path.join(out_dir, "tables.json"), tables)
    _write_html(out_dir, figures, markdown, runs)
    return {"out_dir": out_dir, "figures": list(figures), "groups": list(groups),
            "tables": tables, "failure_rates": {g: grids[g].tolist() for g in grids}}  # fmt: skip


def _frames_figure(groups: dict[str, list[Run]], path: str, count: int = 6) -> bool:
    """A strip of ``count`` frames per group (``render``): what each group's policy does. False,
    with nothing written, where no offscreen OpenGL (EGL or OSMesa) is installed."""
    from minatt_jax import render

    rows = []
    try:
        for g, members in groups.items():
            r = render.rollout(members[0].run_dir, variant="nominal", label=g)
            stride = max(r.length // count, 1)
            frames = render.body_frames(r, 200, 150, stride=stride)[:count]
            rows.append((g, r.length, frames))
    except runner.RunError:
        return False
    plt = _pyplot()
    fig, axes = plt.subplots(len(rows), count, squeeze=False, layout="constrained",
                             figsize=(1.9 * count, 1.6 * len(rows)))  # fmt: skip
    for (g, length, frames), row in zip(rows, axes, strict=True):
        for i, ax in enumerate(row):
            ax.axis("off")
            if i < len(frames):
                ax.imshow(frames[i])
                ax.set_title(f"step {i * max(length // count, 1)}", fontsize=7)
        row[0].text(-0.05, 0.5, g, transform=row[0].transAxes, rotation=90, ha="right",
                    va="center", fontsize=8)  # fmt: skip
    save_figure(fig, path)
    return True


def _adaptation_figure(rows: list[dict[str, Any]], path: str) -> None:
    plt = _pyplot()
    columns = len(ADAPTATION_METRICS)
    fig, axes = plt.subplots(1, columns, squeeze=False, figsize=(3.6 * columns, 3.2),
                             layout="constrained")  # fmt: skip
    for g in dict.fromkeys(r["group"] for r in rows):
        mine = [r for r in rows if r["group"] == g]
        x = [r["episode"] for r in mine]
        for ax, metric in zip(axes[0], ADAPTATION_METRICS, strict=True):
            mean = np.array([r[metric] for r in mine], dtype=float)
            std = np.array([r[f"{metric}_std"] for r in mine], dtype=float)
            ax.errorbar(x, mean, yerr=std, marker="o", capsize=3,
                        label=f"{g} ({mine[0]['seeds']} seeds)")  # fmt: skip
    for ax, metric in zip(axes[0], ADAPTATION_METRICS, strict=True):
        ax.set_title(metric, fontsize=9)
        ax.set_xlabel("inner episode")
        ax.set_xticks(sorted({r["episode"] for r in rows}))
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.suptitle("in-context adaptation: each episode of a meta-episode (mean +- std over "
                 "seeds)", fontsize=10)  # fmt: skip
    save_figure(fig, path)


def _decomposition_figure(decomposition, dt, path):
    plt = _pyplot()
    tasks = list(next(iter(decomposition.values())))
    fig, axes = plt.subplots(len(tasks), 2, figsize=(10, 3.0 * len(tasks)), squeeze=False,
                             layout="constrained")  # fmt: skip
    for row, task in enumerate(tasks):
        for g, parts in decomposition.items():
            d = parts[task]
            t = np.arange(len(d["K_norm"])) * dt
            axes[row][0].plot(t, d["K_norm"], label=g)
            axes[row][1].plot(t, d["v_norm"], label=g)
            for boundary in t[1:][np.diff(d["episode"]) != 0]:  # inner episodes of a meta-episode
                for ax in axes[row]:
                    ax.axvline(boundary, color="gray", linestyle=":", linewidth=0.8)
        axes[row][0].set_title(f"||K(t)||_F, {task}")
        axes[row][1].set_title(f"||v(t)||_2, {task}")
        for ax in axes[row]:
            ax.set_xlabel("time (s)")
            ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    save_figure(fig, path)


def _failure_figure(grids, vx, w, env_name, path):
    plt = _pyplot()
    names = list(grids)
    panels = names + (["difference"] if len(names) >= 2 else [])
    fig, axes = plt.subplots(1, len(panels), figsize=(4.0 * len(panels), 3.4), squeeze=False)
    extent = (vx[0], vx[-1], w[0], w[-1])
    for i, (ax, name) in enumerate(zip(axes[0], panels, strict=True)):
        if name == "difference":
            data, cmap, lim = grids[names[0]] - grids[names[1]], "RdBu_r", (-1, 1)
            title = f"{names[0]} - {names[1]}"
        else:
            data, cmap, lim, title = grids[name], "magma", (0, 1), name
        image = ax.imshow(data.T, origin="lower", aspect="auto", extent=extent, cmap=cmap,
                          vmin=lim[0], vmax=lim[1])  # fmt: skip
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("initial forward velocity (m/s)")
        if i == 0:  # one y label: the others would collide with the colorbar on their left
            ax.set_ylabel("initial pitch rate (rad/s)")
        fig.colorbar(image, ax=ax, shrink=0.8)
    criterion = ("torso z < -0.42 or |pitch| > 1.1" if env_name == "halfcheetah"
                 else "the environment's termination")  # fmt: skip
    fig.suptitle(f"failure rate ({criterion})", fontsize=10)
    save_figure(fig, path)


def _maturation_figure(maturation, env, bins, path):
    plt = _pyplot()
    i, j = env.projection_indices()[0]
    names = list(maturation)
    cols = max(1, max(len(v) for v in maturation.values()))
    fig, axes = plt.subplots(len(names), cols, figsize=(3.6 * cols, 3.0 * len(names)),
                             squeeze=False, layout="constrained")  # fmt: skip
    everything = [v["obs"] for m in maturation.values() for v in m.values()]
    if not everything:
        axes[0][0].text(0.5, 0.5, "no policy snapshots in these runs", ha="center")
        save_figure(fig, path)
        return
    xe = _edges([o[:, i] for o in everything], bins)
    ye = _edges([o[:, j] for o in everything], bins)
    values = [ca.binned_means(v["obs"][:, i], v["obs"][:, j], v["feedback"], xe, ye)[0]
              for m in maturation.values() for v in m.values()]  # fmt: skip
    norm = _color_norm(np.concatenate([x[np.isfinite(x)] for x in values]))
    image = None
    for row, g in enumerate(names):
        for col, (step, v) in enumerate(sorted(maturation[g].items())):
            means, _ = ca.binned_means(v["obs"][:, i], v["obs"][:, j], v["feedback"], xe, ye)
            ax = axes[row][col]
            image = ax.imshow(means.T, origin="lower", aspect="auto", norm=norm, cmap="viridis",
                              extent=(xe[0], xe[-1], ye[0], ye[-1]))  # fmt: skip
            ax.set_title(f"{g}, step {step}", fontsize=8)
            ax.set_xlabel(env.obs_names[i])
            ax.set_ylabel(env.obs_names[j])
    if image is not None:
        fig.colorbar(image, ax=axes.ravel().tolist(), shrink=0.8)
    fig.suptitle("feedback ||du/dx||^2 as training matures (shared scale)", fontsize=10)
    save_figure(fig, path)


_STYLE = """
body{font-family:system-ui,sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;color:#222}
h1{font-size:1.6em} h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:1.6em}
table{border-collapse:collapse;margin:.6em 0;font-size:.88em;display:block;overflow-x:auto}
th,td{border:1px solid #ddd;padding:.3em .6em;text-align:right;white-space:nowrap}
th{background:#f2f4f8} td:first-child,th:first-child{text-align:left}
tr:nth-child(even) td{background:#fafafa}
figure{margin:1.2em 0} figcaption{color:#555;font-size:.9em;margin-top:.3em}
img{max-width:100%} code{background:#f4f4f4;padding:0 .2em}
details{margin:.4em 0} summary{cursor:pointer}
"""


def _write_html(out_dir: str, figures: dict[str, str], markdown: str, runs: list[Run]) -> None:
    """report.html: one self-contained page (styles, figures embedded) with the runs and their
    settings, the tables as HTML tables and each figure with its caption."""
    import markdown as md

    parts = [
        "<!doctype html><html><head><meta charset='utf-8'>",
        "<title>minatt-jax analysis report</title>",
        f"<style>{_STYLE}</style></head><body>",
        "<h1>minatt-jax analysis report</h1>",
        "<h2>Runs</h2>",
        "<table><tr><th>run</th><th>group</th><th>seed</th><th>settings</th></tr>",
    ]
    for r in runs:
        settings = html.escape(json.dumps(r.config.to_dict(), indent=1))
        parts.append(f"<tr><td>{html.escape(r.run_dir)}</td><td>{html.escape(r.group)}</td>"
                     f"<td>{r.config.seed}</td><td style='text-align:left'><details><summary>"
                     f"config.json</summary><pre>{settings}</pre></details></td></tr>")  # fmt: skip
    parts.append("</table><h2>Figures</h2><ul>")
    parts += [f"<li><a href='#{name}'>{name}</a>: {html.escape(text)}</li>"
              for name, text in figures.items()]  # fmt: skip
    parts.append("</ul>")
    for name, text in figures.items():
        with open(os.path.join(out_dir, name), "rb") as f:
            data = base64.b64encode(f.read()).decode()
        caption = f"<figcaption><b>{name}</b>: {html.escape(text)}</figcaption>"
        image = f"<img alt='{name}' src='data:image/png;base64,{data}'>"
        parts.append(f"<figure id='{name}'>{image}{caption}</figure>")
    parts.append("<h2>Tables</h2>" + md.markdown(_demoted(markdown), extensions=["tables"]))
    parts.append("</body></html>")
    runner.write_text_atomic(os.path.join(out_dir, "report.html"), "\n".join(parts))


def _demoted(markdown: str) -> str:
    """``tables.md`` with its headings one level down (they sit under the page's "Tables")."""
    return "\n".join("#" + line if line.startswith("#") else line for line in markdown.split("\n"))
