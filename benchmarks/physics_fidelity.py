"""How far each physics preset moves the dynamics from Gym's own solver settings (C engine).

For each environment and preset, ``--episodes`` episodes of uniform random actions from Gym's reset
distribution run on the MuJoCo C engine (float64) with the preset's model, against the same
episodes on Gym's settings (RK4 where Gym has it, converged Newton, all contact pairs). Reported:
mean episode length (Hopper and Walker2d terminate), mean summed forward velocity, and the mean
max-abs state difference (qpos, qvel) from Gym's trajectory after 6 env steps.

    python benchmarks/physics_fidelity.py [--envs hopper walker2d] [--episodes 100]

Writes ``benchmarks/results/physics_fidelity.json`` and prints a table.
"""

from __future__ import annotations

import argparse
import json
import os

import mujoco
import numpy as np

import minatt_jax.envs as envs
from minatt_jax.envs.mjcf import PHYSICS_PRESETS, PhysicsOptions, load_model

RESULTS = os.path.join(os.path.dirname(__file__), "results")
COMPARED = {
    "gym": PHYSICS_PRESETS["gym"],
    "euler, converged": PhysicsOptions(integrator="euler", floor_contacts_only=True),
    "fast": PHYSICS_PRESETS["fast"],
    "newton 2 iterations": PhysicsOptions(
        integrator="euler", iterations=2, ls_iterations=4, floor_contacts_only=True
    ),
    "fastest": PHYSICS_PRESETS["fastest"],
}


def run_episodes(env: envs.LocomotionEnv, model: mujoco.MjModel, inits, actions):
    """Episode lengths, summed forward velocities and the state after 6 steps."""
    name, frame_skip = env.name, env.frame_skip
    d = mujoco.MjData(model)
    lengths, forward, early = [], [], []
    for (qpos, qvel), acts in zip(inits, actions, strict=True):
        mujoco.mj_resetData(model, d)
        d.qpos[:], d.qvel[:] = qpos, qvel
        mujoco.mj_forward(model, d)
        total, length, snapshot = 0.0, len(acts), None
        for t, a in enumerate(acts):
            x0 = d.qpos[0]
            d.ctrl[:] = a
            for _ in range(frame_skip):
                mujoco.mj_step(model, d)
            total += (d.qpos[0] - x0) / (model.opt.timestep * frame_skip)
            if t <= 5:
                snapshot = np.concatenate([d.qpos, d.qvel])
            if env.terminates and not _healthy(name, d):
                length = t + 1
                break
        lengths.append(length)
        forward.append(total)
        early.append(snapshot)
    return np.array(lengths), np.array(forward), np.array(early)


def _healthy(name: str, d: mujoco.MjData) -> bool:
    if name == "hopper":
        state = np.concatenate([d.qpos, d.qvel])[2:]
        return bool(np.all(np.abs(state) < 100) and d.qpos[1] > 0.7 and abs(d.qpos[2]) < 0.2)
    if name == "walker2d":
        return bool(0.8 < d.qpos[1] < 2.0 and -1 < d.qpos[2] < 1)
    if name == "humanoid":
        return bool(1.0 < d.qpos[2] < 2.0)
    return True


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=["hopper", "walker2d", "halfcheetah"])
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--out", default=os.path.join(RESULTS, "physics_fidelity.json"))
    args = parser.parse_args()
    rows = []
    print(f"{'env':12s} {'preset':20s} {'length':>7s} {'fwd sum':>9s} {'+-':>5s} {'dev@6':>9s}")
    for name in args.envs:
        env = envs.make(name)
        rng = np.random.default_rng(0)
        base = load_model(name, PHYSICS_PRESETS["gym"])
        c = env.reset_noise_scale
        inits = [
            (base.qpos0 + rng.uniform(-c, c, base.nq), rng.uniform(-c, c, base.nv))
            for _ in range(args.episodes)
        ]
        actions = rng.uniform(-1, 1, (args.episodes, args.steps, env.action_size))
        reference = None
        for label, options in COMPARED.items():
            model = load_model(name, options)
            lengths, forward, early = run_episodes(env, model, inits, actions)
            if reference is None:
                reference = early
            deviation = float(np.mean(np.max(np.abs(early - reference), axis=1)))
            row = {
                "env": name,
                "preset": label,
                "mean_length": float(lengths.mean()),
                "mean_forward_sum": float(forward.mean()),
                "forward_sum_sem": float(forward.std() / np.sqrt(len(forward))),
                "state_deviation_after_6_steps": deviation,
            }
            rows.append(row)
            print(
                f"{name:12s} {label:20s} {row['mean_length']:7.1f} {row['mean_forward_sum']:9.2f} "
                f"{row['forward_sum_sem']:5.2f} {deviation:9.2e}",
                flush=True,
            )
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    with open(args.out + ".tmp", "w") as f:
        json.dump({"benchmark": "physics_fidelity", "episodes": args.episodes, "rows": rows}, f,
                  indent=2)  # fmt: skip
    os.replace(args.out + ".tmp", args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
