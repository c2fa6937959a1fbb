"""PPO (Schulman et al. 2017): clipped-surrogate policy optimisation on GAE advantages.

One *iteration*: ``num_envs`` vmapped envs (autoreset) each take ``num_steps`` steps with the
current stochastic policy; the rollout's advantages come from GAE(lambda) (``ppo_losses``),
bootstrapping at the rollout's end and through time-limit truncations from the value of the true
final observation (``info["final_obs"]``), and from nothing after a termination. Then
``num_epochs`` passes over the ``num_envs * num_steps`` batch, each shuffled into
``num_minibatches`` minibatches, one Adam step on each:

    loss = L_clip(ratio, A) + vf_coef * L_value - ent_coef * entropy

with the gradient's global norm clipped to ``max_grad_norm`` and the rate decaying linearly to 0
over ``lr_decay_steps`` env steps (held for the whole iteration). Options: standardised
advantages per minibatch, a clipped value loss, observations standardised by running statistics
(acting and learning on one batch use the statistics from before it; they then take it in) and
rewards divided by a running std of discounted returns (``normalize_rewards``).

A *chunk* (one compiled call) is ``iterations_per_chunk`` iterations under ``lax.scan``, then one
evaluation of the deterministic policy (the Gaussian's clipped mean, or the most likely action):
``num_envs * num_steps * iterations_per_chunk`` env steps and ``num_epochs * num_minibatches``
gradient steps per iteration. Settings are in ``ppo_config``, the network in ``ppo_networks``,
the recipes in ``ppo_recipes``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax
from flax import struct

from rl_jax import envs
from rl_jax.agents import ppo_losses as losses
from rl_jax.agents.common import clip_by_global_norm, injected_step, linearly_decayed
from rl_jax.agents.policy_gradient import entropy, log_prob
from rl_jax.agents.ppo_config import PIXEL_ENVS, Config, Hyperparams, PixelConfig
from rl_jax.agents.ppo_networks import (
    deterministic_action,
    make_network,
    outputs,
    sample_action,
    to_env_action,
    value,
)
from rl_jax.agents.ppo_recipes import RECIPES
from rl_jax.envs.core.preprocessing import ACTION_MASK
from rl_jax.envs.core.wrappers import StatisticsState
from rl_jax.training import episodes, normalization, validation
from rl_jax.training.algorithm import ChunkMetrics, RecipeBook
from rl_jax.training.networks import Params
from rl_jax.training.normalization import RunningStats

__all__ = ["PIXEL_ENVS", "Config", "Hyperparams", "PixelConfig", "ppo"]


@struct.dataclass
class Agent:
    params: Params  # actor-critic parameters
    opt_state: optax.OptState  # optax inject_hyperparams(adam) state: holds the rate in use
    obs_stats: RunningStats | None = None  # with normalize_obs, else None


@struct.dataclass
class Clock:
    """Counters that depend only on the config (kept unbatched by ``rl_jax.training.parallel``)."""

    env_steps: jax.Array  # [] int32, env steps of one seed so far (all its envs)
    updates: jax.Array  # [] int32, gradient steps so far
    iterations: jax.Array  # [] int32


@struct.dataclass
class TrainState:
    agent: Agent
    env_state: StatisticsState  # [num_envs, ...] of the train env (episodes.make_train_env)
    obs: jax.Array  # [num_envs, *obs_shape], the observation the next action answers
    key: jax.Array
    clock: Clock
    train_return: jax.Array  # [] float32, mean return of the episodes ended in the last chunk
    return_stats: RunningStats | None = (
        None  # normalize_rewards: RunningStats of discounted returns, [1]
    )
    discounted_return: jax.Array | None = (
        None  # normalize_rewards: [num_envs], each env's running return
    )
    action_mask: jax.Array | None = None  # [num_envs, A] bool, legal actions of obs (masked envs)


class Rollout(NamedTuple):
    """``num_steps`` steps of every env, leaves ``[T, N, ...]``."""

    obs: jax.Array  # the observations acted on (raw)
    action: jax.Array  # sampled actions (a Gaussian's unclipped)
    log_mu: jax.Array  # their log-probabilities under the acting policy
    v_tm1: jax.Array  # values of obs at collection
    v_t: jax.Array  # values of the true next observations
    r_t: jax.Array  # rewards as the env gave them
    terminated: jax.Array  # bool
    truncated: jax.Array  # bool
    episode_return: jax.Array  # the return of an episode that ended at this step, else 0
    legal: jax.Array | None = None  # bool [..., A], the legal actions of obs (masked envs)


class Batch(NamedTuple):
    """What a gradient step learns from, leaves ``[B, ...]``."""

    obs: jax.Array
    action: jax.Array
    log_mu: jax.Array
    value: jax.Array  # at collection (value clipping's reference)
    advantage: jax.Array
    target: jax.Array  # the lambda-return, advantage + value
    legal: jax.Array | None = None  # bool [B, A], the legal actions of obs (masked envs)


# ---- the loss -------------------------------------------------------------------------------
def loss_fn(
    params: Params,
    batch: Batch,
    hparams: Hyperparams,
    config: Config,
    obs_stats: RunningStats | None = None,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """``(loss, metrics)`` of one minibatch (log-probabilities and entropy over the legal
    actions where the env has a mask)."""
    policy = outputs(params, obs_stats, batch.obs, config, batch.legal)
    log_pi = log_prob(policy, batch.action)
    advantage = batch.advantage
    if config.normalize_advantages:
        advantage = losses.normalize_advantages(advantage)
    policy_loss = losses.clipped_surrogate_loss(log_pi, batch.log_mu, advantage, hparams.clip_eps)
    if config.clip_value_loss:
        value_loss = losses.clipped_value_loss(
            policy["value"], batch.value, batch.target, hparams.value_clip_eps
        )
    else:
        value_loss = losses.value_loss(policy["value"], batch.target)
    mean_entropy = jnp.mean(entropy(policy))
    total = policy_loss + hparams.vf_coef * value_loss - hparams.ent_coef * mean_entropy
    metrics = {"policy_loss": policy_loss, "value_loss": value_loss, "entropy": mean_entropy}
    return total, {**metrics, **losses.policy_statistics(log_pi, batch.log_mu, hparams.clip_eps)}


# ---- acting and rollouts ----------------------------------------------------------------------
def act(agent: Agent, obs: jax.Array, config: Config, legal: jax.Array | None = None) -> jax.Array:
    """The deterministic policy: the Gaussian's mean (clipped) or the most likely (legal,
    given the env's mask ``legal``) action."""
    space = episodes.make_eval_env(config).action_space()
    return deterministic_action(outputs(agent.params, agent.obs_stats, obs, config, legal), space)


def collect(
    agent: Agent,
    env_state: StatisticsState,
    obs: jax.Array,
    key: jax.Array,
    config: Config,
    legal: jax.Array | None = None,
) -> tuple[StatisticsState, jax.Array, jax.Array | None, Rollout]:
    """``(env_state, obs, legal, Rollout)`` after ``num_steps`` steps of every env. Each step
    also values its true next observation, which differs from the next step's observation where
    an episode ended (autoreset), so that truncations can bootstrap. Where the env has an action
    mask, ``legal`` holds the legal actions of ``obs`` and the policy draws only those."""
    env = episodes.make_train_env(config)
    space = env.action_space()

    Carry = tuple[StatisticsState, jax.Array, jax.Array | None]

    def step(carry: Carry, step_key: jax.Array) -> tuple[Carry, Rollout]:
        env_state, obs, legal = carry
        action_key, env_key = jax.random.split(step_key)
        policy = outputs(agent.params, agent.obs_stats, obs, config, legal)
        action = sample_action(policy, action_key)
        keys = jax.random.split(env_key, config.num_envs)
        env_state, ts = jax.vmap(env.step)(keys, env_state, to_env_action(action, space))
        v_t = value(agent.params, agent.obs_stats, ts.info["final_obs"], config)
        ended = jnp.logical_or(ts.terminated, ts.truncated)
        row = Rollout(
            obs=obs,
            action=action,
            log_mu=log_prob(policy, action),
            v_tm1=policy["value"],
            v_t=v_t,
            r_t=ts.reward,
            terminated=ts.terminated,
            truncated=ts.truncated,
            episode_return=jnp.where(ended, ts.info["episode_return"], 0.0),
            legal=legal,
        )
        next_legal = None if legal is None else ts.info[ACTION_MASK]
        return (env_state, ts.obs, next_legal), row

    keys = jax.random.split(key, config.num_steps)
    (env_state, obs, legal), rollout = jax.lax.scan(step, (env_state, obs, legal), keys)
    return env_state, obs, legal, rollout


def targets(
    rollout: Rollout, state: TrainState, hparams: Hyperparams, config: Config
) -> tuple[jax.Array, jax.Array, TrainState]:
    """``(advantages [T, N], lambda-returns [T, N], state with new reward statistics)``."""
    ended = jnp.logical_or(rollout.terminated, rollout.truncated)
    r_t = rollout.r_t
    if config.normalize_rewards:
        assert state.discounted_return is not None  # kept with normalize_rewards
        g_t, carry = losses.discounted_returns(r_t, ended, state.discounted_return, hparams.gamma)
        assert state.return_stats is not None  # kept with normalize_rewards
        r_t, stats = losses.scale_rewards(r_t, g_t, state.return_stats, hparams.reward_clip)
        state = dataclasses.replace(state, return_stats=stats, discounted_return=carry)
    discount_t = hparams.gamma * (1.0 - rollout.terminated.astype(jnp.float32))
    trace_t = hparams.gamma * hparams.gae_lambda * (1.0 - ended.astype(jnp.float32))
    advantage = losses.generalized_advantage_estimates(
        r_t, discount_t, rollout.v_tm1, rollout.v_t, trace_t
    )
    return advantage, advantage + rollout.v_tm1, state


# ---- updates ----------------------------------------------------------------------------------
def gradient_step(
    agent: Agent, batch: Batch, hparams: Hyperparams, config: Config, rate: jax.Array
) -> tuple[Agent, dict[str, jax.Array]]:
    """One Adam step on a minibatch at ``rate``, the gradient clipped by its global norm."""
    grads, metrics = jax.grad(loss_fn, has_aux=True)(
        agent.params, batch, hparams, config, agent.obs_stats
    )
    grads, metrics["grad_norm"] = clip_by_global_norm(grads, hparams.max_grad_norm)
    params, opt_state = injected_step(
        optax.adam, grads, agent.opt_state, agent.params, learning_rate=rate, eps=hparams.adam_eps
    )
    return dataclasses.replace(agent, params=params, opt_state=opt_state), metrics


def update(
    agent: Agent,
    batch: Batch,
    key: jax.Array,
    hparams: Hyperparams,
    config: Config,
    rate: jax.Array,
) -> tuple[Agent, dict[str, jax.Array]]:
    """``num_epochs`` passes over ``batch [B, ...]``, each in ``num_minibatches`` shuffled
    minibatches; metrics are the means over all steps."""
    count = config.num_minibatches

    def epoch(agent: Agent, epoch_key: jax.Array) -> tuple[Agent, dict[str, jax.Array]]:
        order = jax.random.permutation(epoch_key, config.batch_size)
        split = jax.tree.map(lambda x: x[order].reshape(count, -1, *x.shape[1:]), batch)
        return jax.lax.scan(lambda a, b: gradient_step(a, b, hparams, config, rate), agent, split)

    agent, metrics = jax.lax.scan(epoch, agent, jax.random.split(key, config.num_epochs))
    return agent, jax.tree.map(jnp.mean, metrics)


def explained_variance(v_tm1: jax.Array, target: jax.Array) -> jax.Array:
    """``1 - var(target - v) / var(target)``: 1 for a perfect critic, 0 for a constant one."""
    return 1.0 - jnp.var(target - v_tm1) / jnp.maximum(jnp.var(target), 1e-8)


IterationMetrics = tuple[dict[str, jax.Array], tuple[jax.Array, jax.Array]]


def train_iteration(
    state: TrainState, config: Config, hparams: Hyperparams
) -> tuple[TrainState, IterationMetrics]:
    key, collect_key, update_key = jax.random.split(state.key, 3)
    env_state, obs, legal, rollout = collect(
        state.agent, state.env_state, state.obs, collect_key, config, state.action_mask
    )
    advantage, target, state = targets(rollout, state, hparams, config)
    flat = lambda x: x.reshape(config.batch_size, *x.shape[2:])  # noqa: E731
    batch = Batch(
        rollout.obs,
        rollout.action,
        rollout.log_mu,
        rollout.v_tm1,
        advantage,
        target,
        rollout.legal,
    )
    rate = linearly_decayed(hparams.learning_rate, state.clock.env_steps, hparams.lr_decay_steps)
    agent, metrics = update(
        state.agent, jax.tree.map(flat, batch), update_key, hparams, config, rate
    )
    if agent.obs_stats is not None:
        mask = jnp.ones(rollout.r_t.shape, jnp.float32)
        agent = dataclasses.replace(
            agent, obs_stats=normalization.update(agent.obs_stats, rollout.obs, mask)
        )
    metrics = {
        **metrics,
        "learning_rate": rate,
        "explained_variance": explained_variance(rollout.v_tm1, target),
    }
    clock = Clock(
        env_steps=state.clock.env_steps + config.batch_size,
        updates=state.clock.updates + config.num_epochs * config.num_minibatches,
        iterations=state.clock.iterations + 1,
    )
    state = dataclasses.replace(
        state, agent=agent, env_state=env_state, obs=obs, key=key, clock=clock
    )
    if legal is not None:
        state = dataclasses.replace(state, action_mask=legal)
    ended = jnp.logical_or(rollout.terminated, rollout.truncated)
    return state, (metrics, (jnp.sum(rollout.episode_return), jnp.sum(ended)))


def init(key: jax.Array, config: Config, hparams: Hyperparams) -> TrainState:
    """A fresh state for one seed and one hyperparameter set."""
    env = episodes.make_train_env(config)
    agent_key, env_key, key = jax.random.split(key, 3)
    env_state, ts = jax.vmap(env.reset)(jax.random.split(env_key, config.num_envs))
    space = env.observation_space()
    params = make_network(config).init(agent_key, jnp.zeros(space.shape, space.dtype))
    optimizer = optax.inject_hyperparams(optax.adam)(hparams.learning_rate, eps=hparams.adam_eps)
    obs_stats = normalization.init(space.shape[0]) if config.normalize_obs else None
    state = TrainState(
        agent=Agent(params, optimizer.init(params), obs_stats),
        env_state=env_state,
        obs=ts.obs,
        key=key,
        clock=Clock(env_steps=jnp.int32(0), updates=jnp.int32(0), iterations=jnp.int32(0)),
        train_return=jnp.float32(jnp.nan),
    )
    if envs.has_action_mask(env):
        state = dataclasses.replace(state, action_mask=ts.info[ACTION_MASK])
    if config.normalize_rewards:
        zeros = jnp.zeros(config.num_envs, jnp.float32)
        state = dataclasses.replace(
            state, return_stats=normalization.init(1), discounted_return=zeros
        )
    return state


def train_chunk(
    state: TrainState, config: Config, hparams: Hyperparams
) -> tuple[TrainState, ChunkMetrics]:
    """``iterations_per_chunk`` iterations, then one evaluation. Pure; jit outside."""
    state, (metrics, (return_sums, counts)) = jax.lax.scan(
        lambda s, _: train_iteration(s, config, hparams),
        state,
        None,
        length=config.iterations_per_chunk,
    )
    eval_key, key = jax.random.split(state.key)
    eval_return = episodes.evaluate(act, state.agent, config, eval_key)
    train_return = episodes.mean_return(return_sums, counts, state.train_return)
    state = dataclasses.replace(state, key=key, train_return=train_return)
    return state, ChunkMetrics(
        env_steps=state.clock.env_steps,
        updates=state.clock.updates,
        eval_return=eval_return,
        train_return=train_return,
        extra=jax.tree.map(jnp.mean, metrics),
    )


# ---- the Algorithm object ---------------------------------------------------------------------
class PPO(RecipeBook):
    """PPO as an ``rl_jax.training.algorithm.Algorithm``."""

    name = "ppo"
    config_type, hparams_type = Config, Hyperparams
    recipes = RECIPES
    ranges = {
        "gae_lambda": validation.UNIT,
        "clip_eps": validation.POSITIVE,
        "value_clip_eps": validation.POSITIVE,
        "adam_eps": validation.POSITIVE,
        "reward_clip": validation.NON_NEGATIVE,
    }

    def default_config(self, env_id: str, recipe: str | None = None, **overrides: Any) -> Config:
        """The recipe's ``Config``; a ``PixelConfig`` for the envs of ``PIXEL_ENVS``."""
        if env_id not in PIXEL_ENVS:
            return super().default_config(env_id, recipe, **overrides)
        values = {**self.recipe(env_id, recipe).config, **overrides}
        return PixelConfig(env_id=env_id, **values)

    def init(self, key: jax.Array, config: Config, hparams: Hyperparams) -> TrainState:
        return init(key, config, hparams)

    def train_chunk(
        self, state: TrainState, config: Config, hparams: Hyperparams
    ) -> tuple[TrainState, ChunkMetrics]:
        return train_chunk(state, config, hparams)

    def env_steps_per_chunk(self, config: Config) -> int:
        return config.batch_size * config.iterations_per_chunk

    def policy(self, state: TrainState, config: Config) -> Callable[..., jax.Array]:
        """``obs -> action`` of the deterministic policy of one seed's state; for an env with
        an action mask, ``(obs, legal) -> action``, the most likely legal action."""
        return lambda obs, legal=None: act(state.agent, obs, config, legal)

    def make_env(self, config: Config) -> envs.Environment:
        return episodes.make_eval_env(config)


ppo = PPO()
default_config, default_hyperparams = ppo.default_config, ppo.default_hyperparams
