"""Why does meta-test adaptation lower the return? Adaptation curves against the inner step size.

    python experiments/adaptation_step.py RUN_DIR [RUN_DIR ...] [--variant mass]
        [--inner-lrs 1e-3 1e-4 0] [--adapt-steps 10] [--name NAME]

Meta-tests each model-based run (its latest checkpoint) on ``--variant`` once per inner step
size beta (``meta_test.MetaTestConfig.inner_lr``; 0 leaves the policy where it was, so its curve
is the evaluation noise), with the same seed, collected episode and refit model, and records per
task the return after each adaptation step and how far the adapted policy's parameters moved
from the trained ones. Writes ``experiments/results/<name>.{json,md,png}``.
"""

from __future__ import annotations

import argparse
import itertools
import os

import numpy as np
import study as xt

from minatt_jax import meta_test, runner
from minatt_jax.analysis import plots

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dirs", nargs="+")
    parser.add_argument("--variant", default="mass")
    parser.add_argument("--inner-lrs", type=float, nargs="+", default=[1e-3, 1e-4, 0.0])
    parser.add_argument("--adapt-steps", type=int, default=10)
    parser.add_argument("--adapt-alphas", type=float, nargs="+", default=[None],
                        help="MA's weight in the adaptation (default: the run's)")  # fmt: skip
    parser.add_argument("--name", default="adaptation_step")
    args = parser.parse_args()
    rows = []
    for run_dir in args.run_dirs:
        for beta, adapt_alpha in itertools.product(args.inner_lrs, args.adapt_alphas):
            settings = meta_test.MetaTestConfig(adapt_steps=args.adapt_steps, inner_lr=beta,
                                                adapt_alpha=adapt_alpha)  # fmt: skip
            try:
                result = meta_test.meta_test(run_dir, args.variant, settings, log=lambda _: None)
            except runner.RunError as e:
                raise SystemExit(f"adaptation_step: {e}") from None
            for task in result["tasks"]:
                rows.append({"run": os.path.basename(os.path.normpath(run_dir)),
                             "step": result["step"], "alpha": result["alpha"], "inner_lr": beta,
                             "adapt_alpha": result["alpha"] if adapt_alpha is None
                             else adapt_alpha,
                             "task": task["task"], "return": task["return_curve"],
                             "energy": task["energy_curve"],
                             "distance": task["policy_distance_curve"]})  # fmt: skip
            print(f"{run_dir} beta {beta:g} adapt alpha {adapt_alpha}: return "
                  f"{result['mean_over_tasks']['return']['before']:.1f} -> "
                  f"{result['mean_over_tasks']['return']['after']:.1f}", flush=True)  # fmt: skip
    command = (f"python experiments/adaptation_step.py {' '.join(args.run_dirs)} --variant "
               f"{args.variant} --inner-lrs {' '.join(f'{b:g}' for b in args.inner_lrs)} "
               f"--adapt-steps {args.adapt_steps} --name {args.name}"
               + ("" if args.adapt_alphas == [None] else " --adapt-alphas "
                  + " ".join(f"{a:g}" for a in args.adapt_alphas)))  # fmt: skip
    result = {**xt.provenance(command), "variant": args.variant, "rows": rows}
    lines = [f"# Adaptation against the inner step size ({args.variant})", "",
             f"`{command}` on {result['device']}, {result['date']}. Per run, task and beta: "
             "the return before adaptation, after 1, 2, 5 and 10 steps, and the distance the "
             "adapted policy's parameters moved from the trained ones after 1 and 10 steps.", "",
             "| run | step | beta | MA alpha in adaptation | task | return 0 / 1 / 2 / 5 / 10 | "
             "energy 0 -> 10 | distance 1 / 10 |", "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for r in rows:
        ret = " / ".join(f"{r['return'][i]:.0f}" for i in (0, 1, 2, 5, -1) if i < len(r["return"]))
        lines.append(f"| {r['run']} | {r['step']} | {r['inner_lr']:g} | {r['adapt_alpha']:g} | "
                     f"{r['task']} | {ret} | "
                     f"{r['energy'][0]:.2f} -> {r['energy'][-1]:.2f} | "
                     f"{r['distance'][0]:.3g} / {r['distance'][-1]:.3g} |")  # fmt: skip
    text = "\n".join(lines) + "\n"
    xt.write_study(RESULTS, args.name, result, text)
    plt = plots._pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.5))
    for beta, adapt_alpha in sorted({(r["inner_lr"], r["adapt_alpha"]) for r in rows}):
        chosen = [r for r in rows if (r["inner_lr"], r["adapt_alpha"]) == (beta, adapt_alpha)]
        for ax, key in zip(axes, ("return", "distance"), strict=True):
            curve = np.mean([r[key] for r in chosen], 0)
            x = np.arange(len(curve)) + (key == "distance")
            ax.plot(x, curve, marker="o", label=f"beta {beta:g}, alpha {adapt_alpha:g}")
    axes[0].set_title(f"return, mean over tasks ({args.variant})")
    axes[1].set_title("||theta' - theta||, mean over tasks")
    for ax in axes:
        ax.set_xlabel("adaptation step")
    axes[0].legend()
    plots.save_figure(fig, os.path.join(RESULTS, f"{args.name}.png"))
    print(text)


if __name__ == "__main__":
    main()
