"""How a run's policy acts, whatever trained it: SAC's feedforward actor or DreamerV3's recurrent
world-model policy.

``family(config, env)`` returns a :class:`PolicyFamily`, the one place that tells the two apart
for evaluation, ``analyze``, ``meta-test`` and the population evaluator:

* ``like``: the (params, normalizer) templates of a policy snapshot (numpy zeros);
* ``checkpoint_items`` / ``from_items``: the checkpoint items that hold the same policy, and how
  they assemble into (params, normalizer), for runs without a snapshot at a step;
* ``deterministic(params, normalizer)`` (evaluation: tanh(mean), the posterior's mode) and
  ``stochastic(params, normalizer)`` (data collection) as ``acting`` policies;
* ``recurrent``: the policy carries memory (its u(x) depends on the episode so far), so tools
  that need a memoryless u(x) (``export``, the C-engine evaluation) refuse it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import numpy as np

from minatt_jax import acting
from minatt_jax import normalizer as obs_norm
from minatt_jax.config import TrainConfig
from minatt_jax.evaluation import deterministic_of


class PolicyFamily(NamedTuple):
    """See the module docstring."""

    agent: Any  # the algorithm's agent functions (SAC, DreamerAgent)
    like: tuple[Any, Any]
    checkpoint_items: dict[str, Any]
    from_items: Callable[[dict[str, Any]], tuple[Any, Any]]
    deterministic: Callable[[Any, Any], acting.AnyPolicy]
    stochastic: Callable[[Any, Any], acting.AnyPolicy]
    recurrent: bool


def _zeros(tree: Any) -> Any:
    return jax.tree.map(lambda s: np.zeros(s.shape, s.dtype), tree)


def family(config: TrainConfig, env: Any) -> PolicyFamily:
    """The policy family of a (resolved) configuration's algorithm for ``env``."""
    if config.algo == "dreamer":
        from minatt_jax.dreamer.agent import make_agent as make_dreamer

        agent = make_dreamer(env.observation_size, env.action_size, config.dreamer, config.ma)
        params = _zeros(jax.eval_shape(agent.init, jax.random.PRNGKey(0)).params)
        names = ("world_model", "actor")
        return PolicyFamily(
            agent=agent,
            like=({name: params[name] for name in names}, {}),
            checkpoint_items={f"agent/params/{name}": params[name] for name in names},
            from_items=lambda parts: ({n: parts[f"agent/params/{n}"] for n in names}, {}),
            deterministic=lambda p, norm: agent.policy(p, False),
            stochastic=lambda p, norm: agent.policy(p, True),
            recurrent=True,
        )
    from minatt_jax.training import make_agent

    sac = make_agent(config, env)
    actor = _zeros(jax.eval_shape(sac.init, jax.random.PRNGKey(0)).actor_params)
    norm = obs_norm.init_normalizer(env.observation_size)
    normalize = config.sac.normalize_obs
    return PolicyFamily(
        agent=sac,
        like=(actor, norm),
        checkpoint_items={"agent/actor_params": actor, "data/normalizer": norm},
        from_items=lambda parts: (parts["agent/actor_params"], parts["data/normalizer"]),
        deterministic=deterministic_of(sac.control, normalize),
        stochastic=lambda p, n: acting.stochastic(sac.sample, sac.control, p, n, normalize),
        recurrent=False,
    )
