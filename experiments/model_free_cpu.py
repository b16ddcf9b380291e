"""PPO or SAC with and without minimum attention on the CPU: each alpha's seeds as one population.

    python experiments/model_free_cpu.py --algo ppo --env hopper --alphas 0 0.05 --steps 1024000
    python experiments/model_free_cpu.py --algo sac --env hopper --alphas 0 0.05 --steps 100000

Every member is the ``cpu`` preset's agent (PPO: brax's published settings, 32 environments,
10,240 env steps per update; SAC: 256x256, one update per env step after 5,000 random steps) at
its seed and alpha. Each alpha's seeds train as one program, a population under
``--runs/<algo>_cpu/<env><name>/alpha<alpha>`` (resumable: run the same command again); with
``--train-only`` a command trains and stops, so two alphas can train side by side, each pinned to
its own core (``taskset -c 0 ... --alphas 0 --train-only`` beside ``taskset -c 1 ... --alphas 0.05
--train-only``), and a last command with every alpha reads them. The final deterministic
evaluation of each member on minatt-jax's MJX environment and in Gymnasium's v5 environment on
the MuJoCo C engine, per arm the mean with a 95% t interval over seeds, each MA arm against alpha
0 (Welch's interval of the difference and the exact permutation p), and the learning curves go to
``experiments/results/<algo>_cpu_<env><name>.{json,md,png}``.
"""

from __future__ import annotations

import argparse
import os

import numpy as np
import stats
import study

from minatt_jax import population, runner
from minatt_jax.config import PRESETS, resolve, with_overrides

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")
METRICS = ("return", "feedback_norm", "energy", "feedforward_norm")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algo", choices=("ppo", "sac"), default="ppo")
    parser.add_argument("--env", default="hopper")
    parser.add_argument("--seeds", default="0-4")
    parser.add_argument("--alphas", type=float, nargs="+", default=[0.0, 0.05])
    parser.add_argument("--steps", type=int, default=1_024_000)
    parser.add_argument("--episodes", type=int, default=5, help="C-engine episodes per member")
    parser.add_argument("--runs", default="runs")
    parser.add_argument("--name", default="", help="results file suffix (a sweep: --name _sweep)")
    parser.add_argument("--train-only", action="store_true",
                        help="train or resume the populations; no report")  # fmt: skip
    args = parser.parse_args()
    base = resolve(with_overrides(PRESETS["cpu"], algo=args.algo, env=args.env,
                                  total_steps=args.steps))  # fmt: skip
    seeds = population.parse_seeds(args.seeds)
    trained = [(m, run_dir) for alpha in args.alphas
               for m, run_dir in _train_arm(base, seeds, alpha, args)]  # fmt: skip
    if args.train_only:
        return
    arms: dict[str, dict] = {}
    for m, run_dir in trained:
        record = runner.read_metrics(run_dir)[-1]
        c_engine = runner.evaluate_run(run_dir, None, args.episodes, engine="mujoco")
        arm = arms.setdefault(f"{m.ma.alpha:g}", {"seeds": [], "curves": [], "c_engine": {}})
        arm["seeds"].append({"seed": m.seed, **{k: record[k] for k in METRICS}})
        arm["curves"].append([r["return"] for r in runner.read_metrics(run_dir)])
        for k in METRICS:
            arm["c_engine"].setdefault(k, []).append(c_engine[k])
    steps = [r["step"] for r in runner.read_metrics(run_dir)]
    rows = []
    for alpha, arm in arms.items():
        row: dict = {"env": args.env, "alpha": float(alpha), "placement": "", "step": steps[-1]}
        for k in METRICS:
            values = [s[k] for s in arm["seeds"]]
            row[k] = {"mean": float(np.mean(values)), "std": float(np.std(values, ddof=1)),
                      "n": len(values), "ci": stats.t_interval(values),
                      "values": values}  # fmt: skip
            row[f"c_engine_{k}"] = {"mean": float(np.mean(arm["c_engine"][k])),
                                    "ci": stats.t_interval(arm["c_engine"][k]),
                                    "values": [float(v) for v in arm["c_engine"][k]]}  # fmt: skip
        if alpha != "0" and "0" in arms:
            for k in METRICS:
                a, b = row[k]["values"], [s[k] for s in arms["0"]["seeds"]]
                row[f"{k}_vs_alpha0"] = stats.difference(a, b)
        rows.append(row)
    command = (f"python experiments/model_free_cpu.py --algo {args.algo} --env {args.env} "
               f"--seeds {args.seeds} --alphas "
               f"{' '.join(f'{a:g}' for a in args.alphas)} --steps {args.steps}"
               + (f" --name {args.name}" if args.name else ""))  # fmt: skip
    result = {**study.provenance(command), "algo": args.algo, "env": args.env, "steps": steps,
              "arms": rows,
              "curves": {a: arm["curves"] for a, arm in arms.items()}}  # fmt: skip
    lines = [f"# {args.algo.upper()} on {args.env}, {steps[-1]:,} env steps, seeds {args.seeds}",
             "",
             f"`{command}` on {result['device']}.", "",
             "Mean over seeds [95% t interval]; C engine: Gymnasium's v5 environment on the "
             "MuJoCo C engine.", "", "| alpha | " + " | ".join(METRICS) + " | C-engine return |",
             "|---|" + "---|" * (len(METRICS) + 1)]  # fmt: skip
    for row in rows:
        cells = [f"{row[k]['mean']:.4g} [{row[k]['ci'][0]:.4g}, {row[k]['ci'][1]:.4g}]"
                 for k in (*METRICS, "c_engine_return")]  # fmt: skip
        lines.append(f"| {row['alpha']:g} | " + " | ".join(cells) + " |")
    for row in rows:
        for k in METRICS:
            if f"{k}_vs_alpha0" in row:
                d = row[f"{k}_vs_alpha0"]
                low, high = d["welch_ci"]
                lines.append(f"- alpha {row['alpha']:g} - alpha 0, {k}: Welch 95% [{low:.4g}, "
                             f"{high:.4g}], permutation p {d['permutation_p']:.3g}")  # fmt: skip
    stem = f"{args.algo}_cpu_{args.env}{args.name}"
    study.write_study(RESULTS, stem, result, "\n".join(lines) + "\n")
    _figure(result, os.path.join(RESULTS, f"{stem}.png"))
    print("\n".join(lines))


def _train_arm(base, seeds: list[int], alpha: float, args) -> list[tuple]:
    """Train (or resume, or only read when finished) one alpha's seeds as one population."""
    members = population.expand(base, seeds, [f"ma.alpha={alpha:g}"])
    out = os.path.join(args.runs, f"{args.algo}_cpu", args.env + args.name, f"alpha{alpha:g}")
    resume = os.path.exists(os.path.join(out, "population.json"))
    if resume:
        members, _ = population.stored_members(out, args.steps)
    run_dirs = [os.path.join(out, population.member_name(m, ["ma.alpha"])) for m in members]
    done = resume and all(
        (runner.read_metrics(d) or [{"step": 0}])[-1]["step"] >= m.planned_steps
        for m, d in zip(members, run_dirs, strict=True)
    )
    if not done:  # a finished population is only read again
        population.train_population(members, out, ["ma.alpha"], resume=resume,
                                    log=lambda m: print(m, flush=True))  # fmt: skip
    return list(zip(members, run_dirs, strict=True))


def _figure(result: dict, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 3.6), layout="constrained")
    steps = np.asarray(result["steps"])
    for alpha, curves in result["curves"].items():
        values = np.asarray(curves, float)
        mean = values.mean(0)
        ci = np.asarray([stats.t_interval(list(values[:, i])) for i in range(values.shape[1])])
        ax.plot(steps, mean, marker="o", ms=3, label=f"alpha {alpha} (n={len(values)})")
        ax.fill_between(steps, ci[:, 0], ci[:, 1], alpha=0.2)
    ax.set_xlabel("env steps")
    ax.set_ylabel("return (deterministic evaluation)")
    algo = result.get("algo", "ppo").upper()
    ax.set_title(f"{algo} on {result['env']}: mean and 95% t interval over seeds", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    main()
