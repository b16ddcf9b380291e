"""Reference SAC baseline: Stable-Baselines3 SAC on Gymnasium's Hopper (MuJoCo C engine).

    python experiments/sb3_sac_hopper.py [--steps 100000] [--seed 0] [--env-id Hopper-v5]

Checks whether a weak minatt-jax SAC hopper curve comes from our SAC or from the task: same
settings as the cpu preset (256x256, Adam 3e-4, batch 256, gamma 0.99, tau 0.005, automatic
entropy with target -act_dim, 5,000 uniform random warm-up steps, one update per step) and the
same evaluation (5 deterministic episodes every 5,000 steps). The default Hopper-v5 is the
environment ``experiments/model_free_cpu.py`` evaluates minatt-jax's final policies in, so the
final rows compare on one engine and one task; Hopper-v4 is the Gym v3 Hopper that
``envs/hopper.py`` rebuilds in MJX. Needs ``stable-baselines3`` and ``torch``, which minatt-jax
does not depend on; writes ``experiments/results/sb3_sac_hopper_seed{seed}.json``. At every
evaluation the model and its replay buffer are saved under ``--checkpoints`` (default
``runs/sb3_sac_hopper/seed{seed}``): the same command resumes a stopped run from there (the
environment's own random stream restarts, so a resumed run is not bit-identical to one made in
one go).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

RESULTS = os.path.join(os.path.dirname(__file__), "results")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=100_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--eval-every", type=int, default=5_000)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--env-id", default="Hopper-v5", help="Gymnasium environment id")
    parser.add_argument("--checkpoints", default=None,
                        help="resumable state (runs/sb3_sac_hopper/seed<N>)")  # fmt: skip
    args = parser.parse_args()
    folder = args.checkpoints or os.path.join("runs", "sb3_sac_hopper", f"seed{args.seed}")
    try:
        import gymnasium as gym
        import torch
        from stable_baselines3 import SAC
        from stable_baselines3.common.callbacks import BaseCallback
    except ImportError as e:
        print(f"error: this reference run needs stable-baselines3 and torch ({e})", file=sys.stderr)
        sys.exit(2)
    torch.set_num_threads(args.threads)
    env = gym.make(args.env_id)
    eval_env = gym.make(args.env_id)
    out = os.path.join(RESULTS, f"sb3_sac_hopper_seed{args.seed}.json")
    state = os.path.join(folder, "state.json")
    resumed = os.path.exists(state)
    records: list[dict] = []
    if resumed:
        with open(state) as f:
            records = json.load(f)["records"]
    start = time.perf_counter() - (records[-1]["wall_s"] if records else 0.0)

    def evaluate(model, step: int) -> None:
        returns, lengths = [], []
        for episode in range(5):
            obs, _ = eval_env.reset(seed=10_000 + 100 * args.seed + episode)
            total, n, done = 0.0, 0, False
            while not done:
                action, _ = model.predict(obs, deterministic=True)
                obs, reward, terminated, truncated, _ = eval_env.step(action)
                total, n, done = total + float(reward), n + 1, terminated or truncated
            returns.append(total)
            lengths.append(n)
        records.append({
            "step": step, "return": float(np.mean(returns)), "return_std": float(np.std(returns)),
            "length": float(np.mean(lengths)), "wall_s": time.perf_counter() - start,
        })  # fmt: skip
        print(f"step {step:7d} | return {np.mean(returns):8.1f} | length {np.mean(lengths):6.1f}"
              f" | {time.perf_counter() - start:6.0f} s", flush=True)  # fmt: skip
        # The model and buffer first, then the records: a stop in between loses this
        # evaluation's record, not the run.
        os.makedirs(folder, exist_ok=True)
        model.save(os.path.join(folder, "model.zip"))
        model.save_replay_buffer(os.path.join(folder, "buffer.pkl"))
        result = {"env": args.env_id, "seed": args.seed, "steps": args.steps,
                  "command": " ".join(["python", *sys.argv]), "records": records}  # fmt: skip
        for path in (state, out):
            os.makedirs(os.path.dirname(path), exist_ok=True)
            with open(path + ".tmp", "w") as f:
                json.dump(result, f, indent=1)
            os.replace(path + ".tmp", path)

    class EvalEvery(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps % args.eval_every == 0:
                evaluate(self.model, self.num_timesteps)
            return True

    if resumed:
        model = SAC.load(os.path.join(folder, "model.zip"), env=env)
        model.load_replay_buffer(os.path.join(folder, "buffer.pkl"))
        print(f"resumed at env step {model.num_timesteps} from {folder}", flush=True)
    else:
        model = SAC(
            "MlpPolicy", env, learning_rate=3e-4, buffer_size=1_000_000, learning_starts=5_000,
            batch_size=256, tau=0.005, gamma=0.99, train_freq=1, gradient_steps=1,
            ent_coef="auto", policy_kwargs={"net_arch": [256, 256]}, seed=args.seed, verbose=0,
        )  # fmt: skip
    if model.num_timesteps < args.steps:
        model.learn(total_timesteps=args.steps - model.num_timesteps, callback=EvalEvery(),
                    reset_num_timesteps=not resumed)  # fmt: skip


if __name__ == "__main__":
    main()
