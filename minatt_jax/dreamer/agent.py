"""DreamerV3's learner: world-model loss, imagination, actor-critic losses, one update.

``make_agent(obs_size, action_size, config, ma_config)`` returns a :class:`DreamerAgent` of pure
functions over an :class:`AgentState` pytree. One ``update(state, batch, key)``:

1. **World model** on a batch of replayed sequences (B, T): tokens of symlog(obs); the RSSM's
   posterior rolled over time from a zero state (reset where ``is_first``); losses: decoder MSE in
   symlog space, two-hot reward, continue (Bernoulli), KL balance (dyn 1.0, rep 0.1, free nats 1).
2. **Imagination** from every posterior state of the batch (no gradient into the model): H steps
   of the actor's samples through the prior; rewards and continuation flags from the heads.
3. **Critic**: two-hot cross-entropy toward the lambda-returns (bootstrapped with the critic) plus
   ``slowreg`` times that toward the slow critic's prediction; the slow critic is an EMA.
4. **Actor**: REINFORCE, advantages (R - V) / max(1, P95 - P5) of the returns (percentile EMA),
   plus the entropy bonus, weighted by the cumulative discount; and the **minimum-attention
   penalty** alpha (||du/ds||^2 + temporal) of the deterministic control u(s) = tanh(mean(s)) on
   the model states s = [h, z] the actor reads (``min_attention.make_regularizer``: the same code
   as SAC's). The Jacobian trained is with respect to s (``jacrev``: one VJP per action dimension);
   the Jacobian reported in evaluation is with respect to the observation, through the encoder and
   the posterior's probabilities (``observation_control``).

All modules share one optimizer chain (per-tensor adaptive gradient clipping, RMS scaling with
bias correction, momentum, linear warm-up): the official LaProp setting.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax
from flax import struct

from minatt_jax import acting
from minatt_jax import min_attention as ma
from minatt_jax.dreamer import distributions as dist
from minatt_jax.dreamer.config import DreamerConfig
from minatt_jax.dreamer.networks import Actor, Critic, WorldModel, feature

sg = jax.lax.stop_gradient


@struct.dataclass
class Latent:
    """The RSSM state: deterministic h (..., deter) and one-hot z (..., stoch, classes)."""

    deter: jax.Array
    stoch: jax.Array


@struct.dataclass
class AgentState:
    """Everything the learner carries between updates (saved whole in checkpoints)."""

    params: dict[str, Any]  # {"world_model", "actor", "critic"}
    slow_critic: Any
    prev_actor: Any  # actor parameters before the last update (MA's temporal term)
    opt_state: Any
    return_scale: dist.ReturnScale
    updates: jax.Array
    # The values a population sweeps, read by the losses: "alpha" (the MA weight) and
    # "ma_terms" (the MA mode's (feedback, temporal) 0/1 weights).
    hyper: dict[str, jax.Array]


class Batch(NamedTuple):
    """Replayed sequences (B, T, ...): obs_t, the action before it, the reward on arriving at
    it, whether it starts an episode, and 1 - terminal."""

    obs: jax.Array
    prev_action: jax.Array
    reward: jax.Array
    is_first: jax.Array
    cont: jax.Array


class DreamerAgent(NamedTuple):
    """The learner's pure functions (see the module docstring)."""

    config: DreamerConfig
    world_model: WorldModel
    actor: Actor
    critic: Critic
    init: Callable[[jax.Array, dict[str, jax.Array]], AgentState]
    update: Callable[..., tuple[AgentState, dict]]  # (state, batch, key, valid=None)
    initial_latent: Callable[[tuple[int, ...]], Latent]
    observe_step: Callable[..., tuple[Latent, jax.Array]]
    observe: Callable[..., Latent]
    act: Callable[..., jax.Array]
    control: Callable[[Any, jax.Array], jax.Array]
    observation_control: Callable[[dict, Latent, jax.Array], jax.Array]
    world_model_loss: Callable[..., tuple[jax.Array, tuple]]
    imagine: Callable[..., dict]
    lambda_returns: Callable[..., jax.Array]
    policy: Callable[[dict, bool], acting.RecurrentPolicy]


HYPER = {"alpha": "ma.alpha", "ma_terms": "ma.mode"}


def adaptive_clip(clip: float, floor: float = 1e-3) -> optax.GradientTransformation:
    """Scales each tensor's gradient so its norm is at most ``clip * max(||w||, floor)``."""

    def update(updates, state, params):
        def one(g, w):
            limit = clip * jnp.maximum(jnp.linalg.norm(w), floor)
            return g * jnp.minimum(1.0, limit / (jnp.linalg.norm(g) + 1e-12))

        return jax.tree.map(one, updates, params), state

    return optax.GradientTransformation(lambda params: optax.EmptyState(), update)


def make_optimizer(c: DreamerConfig) -> optax.GradientTransformation:
    """AGC -> RMS scaling (beta2, bias-corrected) -> momentum (beta1) -> lr with warm-up."""
    schedule = optax.linear_schedule(0.0, c.lr, max(c.warmup, 1))
    return optax.chain(
        adaptive_clip(c.agc),
        optax.scale_by_rms(decay=c.beta2, eps=c.eps, eps_in_sqrt=False, bias_correction=True),
        optax.ema(c.beta1, debias=True),
        optax.scale_by_learning_rate(schedule),
    )


def masked_mean(x: jax.Array, weight: jax.Array | None) -> jax.Array:
    """The mean of ``x`` (B, T) over the steps where ``weight`` is 1 (None: every step)."""
    if weight is None:
        return jnp.mean(x)
    return jnp.sum(x * weight) / jnp.maximum(jnp.sum(weight), 1.0)


def draw_states(
    key: jax.Array, valid: jax.Array | None, b: int, t: int, count: int
) -> Callable[[jax.Array], jax.Array]:
    """A function taking ``count`` states per sequence from arrays (B, T, ...): time indices
    drawn uniformly, with replacement, among the ``valid`` steps (every step if None)."""
    logits = jnp.zeros((b, t)) if valid is None else jnp.where(valid > 0, 0.0, -jnp.inf)
    index = jax.random.categorical(key, logits[:, None, :], shape=(b, count))
    return lambda x: x[jnp.arange(b)[:, None], index]


def make_agent(
    obs_size: int,
    action_size: int,
    config: DreamerConfig,
    ma_config: ma.MAConfig,
    head_states: int = 0,
    imag_starts: int = 0,
) -> DreamerAgent:
    """The DreamerV3 learner for ``obs_size`` observations and ``action_size`` actions in
    [-1, 1], with the MA penalty of ``ma_config`` on the actor. For long sequences (MAMBA):
    ``head_states`` > 0 trains the decoder, reward and continue heads on that many states drawn
    per sequence (the KL losses keep every state; MAMBA's ``hidden_states_subsample``), and
    ``imag_starts`` > 0 starts imagination from that many posterior states drawn per sequence
    (MAMBA's ``behavior_batch_length``); 0: every state."""
    c = config
    wm = WorldModel(obs_size, c.deter, c.hidden, c.stoch, c.classes, c.blocks, c.units,
                    c.layers, c.bins)  # fmt: skip
    actor = Actor(action_size, c.layers, c.units)
    critic = Critic(c.layers, c.units, c.bins)
    bins = dist.twohot_bins(c.bins)
    optimizer = make_optimizer(c)
    feat_size = c.deter + c.stoch * c.classes

    def probs(logits: jax.Array) -> jax.Array:
        return dist.unimix_probs(logits, c.unimix)

    def control(actor_params: Any, feat: jax.Array) -> jax.Array:
        """The deterministic control tanh(mean) at model states (any leading axes)."""
        raw_mean, _ = actor.apply(actor_params, feat)
        return jnp.tanh(raw_mean)

    regularizer = ma.make_regularizer(control, ma_config)

    def init(key: jax.Array, hyper: dict[str, jax.Array]) -> AgentState:
        """Fresh parameters; ``hyper`` (``HYPER``'s names) is required: none defaults."""
        k_wm, k_actor, k_critic = jax.random.split(key, 3)
        params = {
            "world_model": wm.init(k_wm, jnp.zeros((1, obs_size)), jnp.zeros((1, action_size))),
            "actor": actor.init(k_actor, jnp.zeros((1, feat_size))),
            "critic": critic.init(k_critic, jnp.zeros((1, feat_size))),
        }
        return AgentState(
            params=params,
            slow_critic=params["critic"],
            prev_actor=params["actor"],
            opt_state=optimizer.init(params),
            return_scale=dist.ReturnScale.create(),
            updates=jnp.zeros((), jnp.int32),
            hyper={k: jnp.asarray(v, jnp.float32) for k, v in hyper.items()},
        )

    def initial_latent(batch: tuple[int, ...]) -> Latent:
        return Latent(jnp.zeros((*batch, c.deter)), jnp.zeros((*batch, c.stoch, c.classes)))

    def core(
        wm_params: dict, latent: Latent, prev_action: jax.Array, is_first: jax.Array
    ) -> jax.Array:
        """The recurrent state h_t from (h, z)_{t-1} and a_{t-1}, both zeroed where
        ``is_first``: what the step knows before its observation."""
        keep = (1.0 - is_first)[..., None]
        return wm.apply(wm_params, latent.deter * keep, latent.stoch * keep[..., None],
                        prev_action * keep, method=WorldModel.core)  # fmt: skip

    def posterior(
        wm_params: dict, deter: jax.Array, token: jax.Array, key: jax.Array | None
    ) -> tuple[Latent, jax.Array]:
        """(latent, posterior probabilities) at h_t given the observation's token; ``key`` None
        takes the posterior's mode."""
        post = probs(wm.apply(wm_params, deter, token, method=WorldModel.posterior))
        if key is None:
            stoch = jax.nn.one_hot(jnp.argmax(post, -1), c.classes)
        else:
            stoch = dist.sample_onehot(key, post)
        return Latent(deter, stoch), post

    def observe_step(
        wm_params: dict, latent: Latent, token: jax.Array, prev_action: jax.Array,
        is_first: jax.Array, key: jax.Array | None,
    ) -> tuple[Latent, jax.Array]:  # fmt: skip
        """One posterior step: (new latent, posterior probabilities) (``core``, ``posterior``)."""
        return posterior(wm_params, core(wm_params, latent, prev_action, is_first), token, key)

    def observe(
        wm_params: dict, latent: Latent, obs: jax.Array, prev_action: jax.Array,
        is_first: jax.Array, key: jax.Array | None,
    ) -> Latent:  # fmt: skip
        """``observe_step`` on a raw observation (encoded here): the acting policy's filter."""
        token = wm.apply(wm_params, obs, method=WorldModel.encode)
        return observe_step(wm_params, latent, token, prev_action, is_first, key)[0]

    def sample_action(actor_params: Any, latent: Latent, key: jax.Array) -> jax.Array:
        """A sample of the bounded normal, unclipped (its log-probability is the actor's)."""
        feat = feature(latent.deter, latent.stoch)
        mean, std = dist.bounded_normal(*actor.apply(actor_params, feat), c.min_std, c.max_std)
        return mean + std * jax.random.normal(key, mean.shape)

    def act(actor_params: Any, latent: Latent, key: jax.Array | None) -> jax.Array:
        """An action of the policy at a latent state: a sample (clipped to [-1, 1]) or, with
        ``key`` None, the deterministic control tanh(mean)."""
        if key is None:
            return control(actor_params, feature(latent.deter, latent.stoch))
        return jnp.clip(sample_action(actor_params, latent, key), -1.0, 1.0)

    def world_model_loss(
        wm_params: dict, batch: Batch, key: jax.Array, valid: jax.Array | None = None
    ) -> tuple[jax.Array, tuple]:
        """Mean world-model loss over the batch; aux: (posterior latents (B, T), metrics).

        ``valid`` (B, T), 1 where a step's losses count (MAMBA's growing horizon; None: every
        step); with ``head_states`` the prediction heads see that many valid states per
        sequence, drawn uniformly, and the KL terms every valid state."""
        b, t = batch.reward.shape
        tokens = wm.apply(wm_params, batch.obs, method=WorldModel.encode)
        keys = jax.random.split(key, t)

        def step(latent, inputs):
            token, prev_action, is_first, k = inputs
            latent, post = observe_step(wm_params, latent, token, prev_action, is_first, k)
            return latent, (latent, post)

        time_major = jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1),
                                  (tokens, batch.prev_action, batch.is_first))  # fmt: skip
        _, (latents, post) = jax.lax.scan(step, initial_latent((b,)), (*time_major, keys))
        latents, post = jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), (latents, post))
        prior = probs(wm.apply(wm_params, latents.deter, method=WorldModel.prior))
        feat = feature(latents.deter, latents.stoch)
        targets = (batch.obs, batch.reward, batch.cont)
        head_weight = valid
        if head_states:
            rows = draw_states(jax.random.fold_in(key, t), valid, b, t, head_states)
            feat, targets = jax.tree.map(rows, (feat, targets))
            head_weight = None  # every drawn state is valid
        obs, reward, cont = targets
        decoded, reward_logits, cont_logit = wm.apply(wm_params, feat, method=WorldModel.heads)
        rec = jnp.sum(jnp.square(decoded - dist.symlog(obs)), -1)
        rew = dist.twohot_loss(reward_logits, reward, bins)
        con = optax.sigmoid_binary_cross_entropy(cont_logit, cont)
        dyn, rep = dist.kl_balance(post, prior, c.free_nats)
        if valid is None and not head_states:
            loss = jnp.mean(rec + rew + con + c.loss_dyn * dyn + c.loss_rep * rep)
        else:
            loss = (masked_mean(rec + rew + con, head_weight)
                    + masked_mean(c.loss_dyn * dyn + c.loss_rep * rep, valid))  # fmt: skip
        metrics = {
            "wm_loss": loss, "rec_loss": masked_mean(rec, head_weight),
            "reward_loss": masked_mean(rew, head_weight),
            "cont_loss": masked_mean(con, head_weight), "dyn_loss": masked_mean(dyn, valid),
            "rep_loss": masked_mean(rep, valid),
            "prior_entropy": masked_mean(dist.categorical_entropy(prior), valid),
            "post_entropy": masked_mean(dist.categorical_entropy(post), valid),
        }  # fmt: skip
        return loss, (latents, metrics)

    def imagine(
        wm_params: dict, actor_params: Any, start: Latent, start_cont: jax.Array, key: jax.Array
    ) -> dict:
        """H steps of the actor in the model from ``start`` (N states); returns features
        (H+1, N, F), actions (H, N, A), rewards and continuation (H+1, N) (index 0: the start's
        own continue flag; rewards[0] unused)."""

        def step(latent, k):
            k_act, k_z = jax.random.split(k)
            action = sample_action(actor_params, latent, k_act)
            deter = wm.apply(wm_params, latent.deter, latent.stoch, action,
                             method=WorldModel.core)  # fmt: skip
            prior = probs(wm.apply(wm_params, deter, method=WorldModel.prior))
            nxt = Latent(deter, dist.sample_onehot(k_z, prior))
            return nxt, (feature(nxt.deter, nxt.stoch), action)

        _, (feats, actions) = jax.lax.scan(step, start, jax.random.split(key, c.imag_length))
        feats = jnp.concatenate([feature(start.deter, start.stoch)[None], feats], 0)
        _, reward_logits, cont_logit = wm.apply(wm_params, feats, method=WorldModel.heads)
        reward = dist.twohot_mean(reward_logits, bins)
        cont = jnp.concatenate([start_cont[None], (cont_logit[1:] > 0).astype(jnp.float32)], 0)
        return {"feat": feats, "action": actions, "reward": reward, "cont": cont}

    def lambda_returns(reward: jax.Array, cont: jax.Array, value: jax.Array) -> jax.Array:
        """R_t = r_{t+1} + gamma c_{t+1} ((1 - lam) V_{t+1} + lam R_{t+1}), R_H = V_H; for
        t = 0..H-1 (arrays (H+1, ...))."""
        disc = c.gamma * cont[1:]

        def back(ret, inputs):
            r, d, v = inputs
            ret = r + d * ((1.0 - c.lam) * v + c.lam * ret)
            return ret, ret

        _, rets = jax.lax.scan(back, value[-1], (reward[1:], disc, value[1:]), reverse=True)
        return rets

    def update(
        state: AgentState, batch: Batch, key: jax.Array, valid: jax.Array | None = None
    ) -> tuple[AgentState, dict]:
        """One update of every module on ``batch`` (B, T); ``valid`` as ``world_model_loss``'s;
        imagination starts from every posterior state, or from ``imag_starts`` valid ones
        drawn per sequence."""
        k_wm, k_img, k_ma = jax.random.split(key, 3)
        params = state.params
        (_, (latents, wm_metrics)), wm_grads = jax.value_and_grad(world_model_loss, has_aux=True)(
            params["world_model"], batch, k_wm, valid
        )
        start_cont = batch.cont
        if imag_starts:
            b, t = batch.reward.shape
            rows = draw_states(jax.random.fold_in(k_img, 1), valid, b, t, imag_starts)
            latents, start_cont = jax.tree.map(rows, (latents, start_cont))
        n = start_cont.size
        start = jax.tree.map(lambda x: sg(x.reshape(n, *x.shape[2:])), latents)
        traj = imagine(sg(params["world_model"]), sg(params["actor"]), start,
                       start_cont.reshape(n), k_img)  # fmt: skip
        traj = jax.tree.map(sg, traj)
        critic_mean = lambda p, f: dist.twohot_mean(critic.apply(p, f), bins)  # noqa: E731
        value = critic_mean(params["critic"], traj["feat"])
        slow_value = critic_mean(state.slow_critic, traj["feat"][:-1])
        returns = lambda_returns(traj["reward"], traj["cont"], value)
        weight = jnp.cumprod(c.gamma * traj["cont"], 0) / c.gamma
        return_scale = dist.update_return_scale(state.return_scale, returns, c.retnorm_rate)
        scale = dist.return_normalizer(return_scale, c.retnorm_limit)
        advantage = (returns - value[:-1]) / scale

        def actor_loss(actor_params):
            raw = actor.apply(actor_params, traj["feat"][:-1])
            mean, std = dist.bounded_normal(*raw, c.min_std, c.max_std)
            logp = dist.normal_log_prob(mean, std, traj["action"])
            entropy = dist.normal_entropy(std)
            loss = jnp.mean(weight[:-1] * (-logp * advantage - c.actent * entropy))
            starts = traj["feat"][0]
            penalty, ma_metrics = regularizer.actor_penalty(
                actor_params, starts, None, (k_ma, k_ma), prev_params=state.prev_actor,
                update_step=state.updates, alpha=state.hyper["alpha"],
                terms=state.hyper["ma_terms"],
            )  # fmt: skip
            metrics = {"actor_loss": loss, "policy_entropy": jnp.mean(entropy),
                       "policy_std": jnp.mean(std), **ma_metrics}  # fmt: skip
            return loss + penalty, metrics

        def critic_loss(critic_params):
            logits = critic.apply(critic_params, traj["feat"][:-1])
            loss = dist.twohot_loss(logits, returns, bins)
            loss = loss + c.slowreg * dist.twohot_loss(logits, slow_value, bins)
            return jnp.mean(weight[:-1] * loss)

        (_, actor_metrics), actor_grads = jax.value_and_grad(actor_loss, has_aux=True)(
            params["actor"]
        )
        critic_value, critic_grads = jax.value_and_grad(critic_loss)(params["critic"])
        grads = {"world_model": wm_grads, "actor": actor_grads, "critic": critic_grads}
        updates, opt_state = optimizer.update(grads, state.opt_state, params)
        new_params = optax.apply_updates(params, updates)
        slow = jax.tree.map(lambda s, p: (1 - c.slow_rate) * s + c.slow_rate * p,
                            state.slow_critic, new_params["critic"])  # fmt: skip
        new_state = state.replace(
            params=new_params, slow_critic=slow, prev_actor=params["actor"], opt_state=opt_state,
            return_scale=return_scale, updates=state.updates + 1,
        )  # fmt: skip
        metrics = {
            **wm_metrics, **actor_metrics, "critic_loss": critic_value,
            "imag_return": jnp.mean(returns), "imag_reward": jnp.mean(traj["reward"][1:]),
            "return_scale": scale, "value_mean": jnp.mean(value),
        }  # fmt: skip
        return new_state, metrics

    def observation_control(params: dict, latent: Latent, obs: jax.Array) -> jax.Array:
        """u(obs) at a fixed recurrent state: tanh(mean) of the actor at [h, q(z | h, obs)],
        the posterior's probabilities standing for the one-hot sample (the gradient path of
        straight-through training); ``latent.deter`` is h after this time's core step and
        ``params`` holds the world model's and the actor's parameters."""
        token = wm.apply(params["world_model"], obs, method=WorldModel.encode)
        post = probs(wm.apply(params["world_model"], latent.deter, token,
                              method=WorldModel.posterior))  # fmt: skip
        return control(params["actor"], feature(latent.deter, post))

    def policy(params: dict, stochastic: bool) -> acting.RecurrentPolicy:
        """The acting policy of ``params`` (``{"world_model", "actor"}``, a policy snapshot's):
        memory (latent, previous action, is_first), reset to the initial latent at an episode's
        start. Deterministic: the posterior's mode and tanh(mean); stochastic: a posterior sample
        and the actor's clipped sample, from keys folded out of the step's key (the same in
        ``act`` and ``remember``, so the remembered latent is the one that acted). The control
        law probed is ``observation_control`` at the step's h_t."""
        wm_params = params["world_model"]

        def latent_after(memory, obs, key):
            latent, prev_action, first = memory
            k_post = jax.random.fold_in(key, 0) if stochastic else None
            return observe(wm_params, latent, obs, prev_action, first, k_post)

        def at(memory) -> acting.Policy:
            latent, prev_action, first = memory
            h = Latent(core(wm_params, latent, prev_action, first), latent.stoch)

            def act_fn(obs, key):
                k_action = jax.random.fold_in(key, 1) if stochastic else None
                return act(params["actor"], latent_after(memory, obs, key), k_action)

            return acting.Policy(act=act_fn, control=lambda o: observation_control(params, h, o))

        def remember(memory, obs, action, key):
            return latent_after(memory, obs, key), action, jnp.zeros(())

        memory = (initial_latent(()), jnp.zeros((action_size,)), jnp.ones(()))
        return acting.RecurrentPolicy(memory=memory, at=at, remember=remember)

    return DreamerAgent(
        config=c, world_model=wm, actor=actor, critic=critic, init=init, update=update,
        initial_latent=initial_latent, observe_step=observe_step, observe=observe, act=act,
        control=control,
        observation_control=observation_control, world_model_loss=world_model_loss,
        imagine=imagine, lambda_returns=lambda_returns, policy=policy,
    )  # fmt: skip
