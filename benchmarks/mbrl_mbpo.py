"""mbrl-lib's MBPO (PyTorch) driven step by step on Hopper-v5, for a side-by-side timing.

Optional: needs ``pip install --no-deps mbrl==0.2.0`` beside hydra-core 1.3, omegaconf 2.3, torch,
termcolor, tqdm and imageio (mbrl's own pins break on Python 3.11). The loop follows
``mbrl.algorithms.mbpo.train`` with its own components (``ModelTrainer``, ``ModelEnv``, the
pranz24 SAC agent and its replay buffers), without per-epoch evaluation or saving, so only the
work both implementations share is timed: env steps, model fits, model rollouts, SAC updates.
"""

from __future__ import annotations

import time
from typing import Any


def available() -> str | None:
    """None when mbrl-lib can be imported, else the reason it cannot."""
    try:
        import mbrl.algorithms.mbpo  # noqa: F401
        import torch  # noqa: F401
    except Exception as e:  # noqa: BLE001 (any import failure means: not available)
        return f"{type(e).__name__}: {e}"
    return None


def run(
    warmup: int = 5000,
    steps: int = 1000,
    ensemble_size: int = 7,
    num_elites: int = 5,
    hidden: int = 200,
    layers: int = 4,
    model_epochs: int = 20,
    train_every: int = 250,
    rollout_batch: int = 100_000,
    rollout_length: int = 1,
    sac_updates_per_step: int = 2,
    sac_hidden: int = 256,
    real_ratio: float = 0.05,
    seed: int = 0,
    threads: int = 2,
) -> dict[str, Any]:
    """Times ``steps`` MBPO env steps after ``warmup`` random ones; returns rates and parts."""
    import gymnasium as gym
    import mbrl.env.termination_fns as term_fns
    import mbrl.models
    import mbrl.planning
    import mbrl.util.common
    import numpy as np
    import omegaconf
    import torch
    from mbrl.algorithms.mbpo import rollout_model_and_populate_sac_buffer
    from mbrl.planning.sac_wrapper import SACAgent
    from mbrl.third_party.pytorch_sac_pranz24.sac import SAC

    torch.set_num_threads(threads)
    torch.manual_seed(seed)
    env = gym.make("Hopper-v5")
    env.reset(seed=seed)
    obs_shape, act_shape = env.observation_space.shape, env.action_space.shape
    cfg = omegaconf.OmegaConf.create(
        {
            "seed": seed,
            "device": "cpu",
            "dynamics_model": {
                "_target_": "mbrl.models.GaussianMLP",
                "_recursive_": False,
                "device": "cpu",
                "num_layers": layers,
                "in_size": obs_shape[0] + act_shape[0],
                "out_size": obs_shape[0] + 1,
                "ensemble_size": ensemble_size,
                "hid_size": hidden,
                "deterministic": False,
                "propagation_method": "random_model",
                "learn_logvar_bounds": True,
                "activation_fn_cfg": {"_target_": "torch.nn.SiLU"},
            },
            "algorithm": {
                "learned_rewards": True,
                "target_is_delta": True,
                "normalize": True,
                "normalize_double_precision": True,
                "dataset_size": warmup + steps,
            },
            "overrides": {
                "num_elites": num_elites,
                "model_batch_size": 256,
                "validation_ratio": 0.2,
                "num_epochs_train_model": model_epochs,
                "patience": 10**6,  # a fixed number of epochs: equal work in both
            },
        }
    )
    model = mbrl.util.common.create_one_dim_tr_model(cfg, obs_shape, act_shape)
    rng = np.random.default_rng(seed)
    real = mbrl.util.common.create_replay_buffer(cfg, obs_shape, act_shape, rng=rng)
    args = omegaconf.OmegaConf.create(
        {
            "gamma": 0.99, "tau": 0.005, "alpha": 0.2, "policy": "Gaussian",
            "target_update_interval": 1, "automatic_entropy_tuning": True,
            "target_entropy": -float(act_shape[0]), "hidden_size": sac_hidden, "device": "cpu",
            "lr": 3e-4,
        }
    )  # fmt: skip
    agent = SACAgent(SAC(obs_shape[0], env.action_space, args))
    mbrl.util.common.rollout_agent_trajectories(
        env, warmup, mbrl.planning.RandomAgent(env), {}, replay_buffer=real
    )
    generator = torch.Generator(device="cpu")
    generator.manual_seed(seed)
    model_env = mbrl.models.ModelEnv(env, model, term_fns.hopper, None, generator=generator)
    trainer = mbrl.models.ModelTrainer(model, optim_lr=1e-3, weight_decay=1e-5)
    trains = -(-steps // train_every)
    sac_buffer = mbrl.util.ReplayBuffer(
        rollout_length * rollout_batch * trains, obs_shape, act_shape, rng=rng
    )
    parts = {"env_s": 0.0, "model_s": 0.0, "rollout_s": 0.0, "agent_s": 0.0}
    batches = [0]

    def count_batch(*_):
        batches[0] += 1

    obs, _ = env.reset(seed=seed)
    done = False
    start = time.perf_counter()
    for step in range(steps):
        t = time.perf_counter()
        if done:
            obs, _ = env.reset()
        next_obs, _, terminated, truncated, _ = mbrl.util.common.step_env_and_add_to_buffer(
            env, obs, agent, {}, real
        )
        done = terminated or truncated
        obs = next_obs
        parts["env_s"] += time.perf_counter() - t
        if (step + 1) % train_every == 0:
            t = time.perf_counter()
            train, val = mbrl.util.common.get_basic_buffer_iterators(
                real, 256, 0.2, ensemble_size=len(model), shuffle_each_epoch=True
            )
            model.update_normalizer(real.get_all())
            trainer.train(train, dataset_val=val, num_epochs=model_epochs, patience=10**6,
                          batch_callback=count_batch)  # fmt: skip
            parts["model_s"] += time.perf_counter() - t
            t = time.perf_counter()
            rollout_model_and_populate_sac_buffer(
                model_env, real, agent, sac_buffer, True, rollout_length, rollout_batch
            )
            parts["rollout_s"] += time.perf_counter() - t
        t = time.perf_counter()
        for _ in range(sac_updates_per_step):
            which = real if rng.random() < real_ratio else sac_buffer
            if len(which) < 256:
                break
            agent.sac_agent.update_parameters(which, 256, step, None, reverse_mask=True)
        parts["agent_s"] += time.perf_counter() - t
    total = time.perf_counter() - start
    return {
        "env_steps_per_s": steps / total,
        "total_s": total,
        **parts,
        "model_batches": batches[0],
        "model_batches_per_s": batches[0] / max(parts["model_s"], 1e-9),
    }


if __name__ == "__main__":
    import json

    reason = available()
    print(json.dumps(run(steps=500, model_epochs=5) if reason is None else {"skipped": reason}))
