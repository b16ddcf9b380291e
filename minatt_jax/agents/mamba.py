"""``--algo mamba``: MAMBA (Rimon et al., ICLR 2024), DreamerV3 as a meta-learner, with minimum
attention on the actor.

The agent lives through meta-episodes (``TrainConfig.meta_episodes`` episodes of one task,
``envs.meta_episode``: the observation carries the reward, the previous action, the
episode-boundary flag and the episode's index); its recurrent state is reset only between
meta-episodes, so the world model's belief identifies the task and the policy adapts in context,
with no gradient step at test time. On top of DreamerV3 (``agents.dreamer``, whose networks,
distributions, losses, collector, replay and MA regularizer it runs unchanged):

* **whole meta-episodes are replayed**: each sequence starts where a meta-episode starts and
  is as long as one (``SequenceReplay.sample_starts``; ``dreamer.batch_length`` is not read);
* **the world-model horizon grows**: the losses count the first ``mamba.wm_horizon_start``
  steps of each sequence, a prefix growing linearly with the env steps to the whole
  meta-episode at ``mamba.wm_horizon_full_at`` (the recurrent state is still rolled over the
  whole sequence; the steps past the horizon are masked out of the losses);
* **subsampled states**: the prediction heads see ``mamba.head_states`` states per sequence,
  imagination starts from ``mamba.imag_starts`` of them (long sequences, bounded cost);
* **meta-test** is in context: meta-episodes on new tasks with no gradient step; evaluation
  reports each inner episode's return (``return_episode_<i>``), the adaptation curve.

Presets (``preset_settings``): ``paper`` is the official configuration (``zoharri/mamba``'s
``configs.yaml``: ``halfcircle`` for point_robot, ``humanoiddir`` for humanoid_dir) in the
units of this library, ``cpu`` a point-robot setting one CPU core trains in about 15
minutes, ``smoke`` seconds. ``DEVIATIONS`` lists what differs from the official code.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp

from minatt_jax.agents import dreamer, registry
from minatt_jax.agents.base import Adapter, PolicyFamily, abstract_hyper, zeros_like_shapes
from minatt_jax.dreamer.agent import HYPER
from minatt_jax.fields import check, setting

# What minatt-jax's MAMBA does differently from the official implementation (on top of
# ``minatt_jax.dreamer.config.DEVIATIONS``), and why.
DEVIATIONS = (
    "DreamerV3's own networks and optimizer (one LaProp chain, learning rate 4e-5 for every "
    "module, as the official DreamerV3); MAMBA's code (on dreamerv3-torch) uses Adam with a "
    "model learning rate of 1e-4 (2e-4 on humanoid-dir) and actor and critic 3e-5 (6e-5).",
    "No local reconstruction heads (its reconstruction_window 3: extra heads predicting the "
    "next 3 steps from the state and the observation's embedding); the paper's description of "
    "MAMBA does not include them.",
    "Updates interleave with collection at the same train ratio (replayed steps per env step; "
    "the official agent updates after each round of 10 meta-episodes): its train_ratio r is "
    "r x batch_size x meta-episode length / meta_episodes here (halfcircle 0.01 -> 16, "
    "humanoiddir 0.03 -> 96).",
    "The observation carries the episode's index scaled to [0, 1] and a first-step flag "
    "(envs.meta_episode) where the official wrapper adds the step within the meta-episode.",
    "Imagination and head states are drawn with replacement among the steps inside the "
    "world-model horizon; the official code draws them over the whole truncated batch (the "
    "same thing) with numpy.",
)

# The official settings (configs.yaml), as dotted fields of this library's configuration.
OFFICIAL = {
    "point_robot": {  # halfcircle
        "meta_episodes": 3, "max_episode_steps": 100, "total_steps": 2_000_000,
        "dreamer.train_ratio": 16.0, "dreamer.imag_length": 2,
        "mamba.wm_horizon_start": 300, "mamba.wm_horizon_full_at": 0,
    },
    "humanoid_dir": {  # humanoiddir
        "meta_episodes": 2, "max_episode_steps": 200, "total_steps": 30_000_000,
        "dreamer.train_ratio": 96.0, "dreamer.imag_length": 10,
        "mamba.wm_horizon_start": 50, "mamba.wm_horizon_full_at": 15_000_000,
    },
}  # fmt: skip
# Both official settings: 10 environments, batches of 16, 64 head states and 512 imagination
# starts per sequence, MLPs of 2 x 128, deter 512, 16 x 16 categoricals.
SHARED = {"num_envs": 10, "dreamer.batch_size": 16, "mamba.head_states": 64,
          "mamba.imag_starts": 512, "dreamer.layers": 2, "dreamer.units": 128,
          "dreamer.deter": 512, "dreamer.stoch": 16, "dreamer.classes": 16,
          "eval_every": 30_000, "warmup_steps": 7_500, "task_set": "train"}  # fmt: skip
# A point-robot setting one CPU core trains in about 15 minutes (meta-episodes of 3 x 50 steps,
# a small model, 60K env steps at 8x the official train ratio: 6,000 updates of 8 x 150 steps).
CPU = {
    "meta_episodes": 3, "max_episode_steps": 50, "total_steps": 60_000, "num_envs": 10,
    "eval_every": 15_000, "warmup_steps": 3_000, "task_set": "train",
    "dreamer.train_ratio": 128.0, "dreamer.imag_length": 10, "dreamer.batch_size": 8,
    "mamba.head_states": 32, "mamba.imag_starts": 64, "mamba.wm_horizon_start": 150,
    "dreamer.layers": 2, "dreamer.units": 64, "dreamer.deter": 128, "dreamer.hidden": 32,
    "dreamer.stoch": 8, "dreamer.classes": 8, "dreamer.blocks": 4, "dreamer.bins": 63,
    "dreamer.warmup": 100, "dreamer.lr": 1e-4,
}  # fmt: skip
SMOKE = {
    "meta_episodes": 2, "max_episode_steps": 20, "total_steps": 600, "eval_every": 300,
    "warmup_steps": 160, "task_set": "train", "mamba.head_states": 8,
    "mamba.imag_starts": 16, "mamba.wm_horizon_start": 20, "mamba.wm_horizon_full_at": 400,
}  # fmt: skip


@dataclasses.dataclass(frozen=True)
class MambaConfig:
    """MAMBA's own settings (the ``mamba`` group), on top of DreamerV3's ``dreamer`` group.

    Attributes:
      head_states: the decoder, reward and continue losses on this many states drawn per
        sequence (0: every state); the KL losses keep every state (MAMBA's
        ``hidden_states_subsample``, for long sequences).
      imag_starts: imagination starts from this many posterior states drawn per sequence (0:
        every state; MAMBA's ``behavior_batch_length``).
      wm_horizon_start: the world-model losses count the first ``wm_horizon_start`` steps of
        each sequence (0: the whole sequence; MAMBA's ``initial_wm_horizon``).
      wm_horizon_full_at: env steps at which that prefix has grown linearly to the whole
        sequence (MAMBA's ``reach_wm_horizon_limit``).
    """

    head_states: int = setting(0, ge=0)
    imag_starts: int = setting(0, ge=0)
    wm_horizon_start: int = setting(0, ge=0)
    wm_horizon_full_at: int = setting(0, ge=0)

    def __post_init__(self) -> None:
        check(self, "mamba")


MAMBA_SETTINGS = registry.SettingsGroup("mamba", MambaConfig)


def read_stored(stored: dict[str, Any]) -> dict[str, Any]:
    """DreamerV3's reading (``agents.dreamer.read_stored``), and MAMBA's four fields, which
    runs written before MAMBA owned its settings kept in the ``dreamer`` group."""
    stored = dreamer.read_stored(stored)
    fields = {f.name for f in dataclasses.fields(MambaConfig)}
    if "mamba" not in stored and fields & set(stored.get("dreamer", {})):
        kept = {k: v for k, v in stored["dreamer"].items() if k not in fields}
        moved = {k: v for k, v in stored["dreamer"].items() if k in fields}
        stored = {**stored, "dreamer": kept, "mamba": moved}
    return stored


def preset_settings(preset: str, env: str) -> dict[str, Any]:
    """What a preset sets for MAMBA on ``env`` (see the module docstring)."""
    if preset == "smoke":
        return dict(SMOKE)
    if preset == "cpu":
        return dict(CPU)
    official = OFFICIAL["point_robot" if env.startswith("point_robot") else "humanoid_dir"]
    return {**SHARED, **official}


def horizon_mask(length: int, start: int, full_at: int):
    """``env_steps -> (length,)`` mask of the steps inside the world-model horizon (None when
    the horizon is the whole sequence from the start): ``start`` steps, growing linearly to
    ``length`` at ``full_at`` env steps (MAMBA's ceil(start + steps x rate))."""
    if start == 0 or start >= length:
        return lambda env_steps: None
    rate = (length - start) / max(full_at, 1)

    def mask(env_steps: jax.Array) -> jax.Array:
        horizon = jnp.minimum(jnp.ceil(start + env_steps.astype(jnp.float32) * rate), length)
        return (jnp.arange(length) < horizon).astype(jnp.float32)

    return mask


def sequence_source(config: Any) -> dreamer.SequenceSource:
    """MAMBA's replay: ``batch_size`` whole meta-episodes, the world-model horizon's mask."""
    d, length = config.dreamer, config.episode_limit
    return dreamer.SequenceSource(
        length=length,
        sample=lambda replay, key: replay.sample_starts(key, d.batch_size, length),
        valid=horizon_mask(length, config.mamba.wm_horizon_start, config.mamba.wm_horizon_full_at),
    )


def make(config: Any, env: Any, task_set: Any) -> Any:
    """The mamba agent: DreamerV3's program replaying whole meta-episodes."""
    subsample = (config.mamba.head_states, config.mamba.imag_starts)
    return dreamer.make(config, env, task_set, sequence_source(config), subsample)


def defaults(config: Any) -> dict[str, Any]:
    """Derived defaults (the training task set) and MAMBA's requirements, one line each."""
    if config.meta_episodes < 2:
        raise ValueError(
            "mamba adapts across the episodes of a meta-episode: set meta_episodes to 2 or more "
            "(the presets set it for point_robot and humanoid_dir)"
        )
    length = config.episode_limit
    if config.buffer_size // config.num_envs < 2 * length:
        raise ValueError(
            f"mamba replays whole meta-episodes of {length} steps: buffer_size must hold at "
            f"least {2 * length} steps per environment ({2 * length * config.num_envs} in all)"
        )
    if config.mamba.wm_horizon_start > length:
        raise ValueError(f"mamba.wm_horizon_start ({config.mamba.wm_horizon_start}) is "
                         f"longer than a meta-episode ({length} steps)")  # fmt: skip
    return {"task_set": "train", "updates_per_step": 1}


def adapter(config: Any, env: Any, family: PolicyFamily, settings: Any) -> Adapter:
    """MAMBA's meta-test adapts in context: no gradient step (the learner is returned as it
    is); the curve over the episodes of a meta-episode is the evaluation's
    ``return_episode_<i>``."""
    shapes = jax.eval_shape(family.agent.init, jax.random.PRNGKey(0), abstract_hyper(HYPER))

    def policy_params(agent: Any) -> dict:
        return {"world_model": agent.params["world_model"], "actor": agent.params["actor"]}

    return Adapter(
        like={"agent": zeros_like_shapes(shapes)},
        prepare=lambda parts, normalizer, traj, key, refit: None,
        step=lambda learner, context, key: learner,
        policy_params=policy_params,
    )


SPEC = registry.register(
    registry.AgentSpec(
        name="mamba",
        make=make,
        policy=dreamer.policy_family,
        hyper=HYPER,
        groups=(dreamer.DREAMER_SETTINGS, MAMBA_SETTINGS),
        defaults=defaults,
        adapter=adapter,
        recurrent=True,
        preset_settings=preset_settings,
        placements=dreamer.PLACEMENTS,
        read_stored=read_stored,
    )
)
