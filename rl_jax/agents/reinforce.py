"""REINFORCE (Williams 1992): Monte-Carlo policy gradient on whole episodes.

Each *iteration* resets ``num_envs`` vmapped envs, runs them to the end of every episode (up to
the env's step limit; a mask is 0 from the step after each episode's end on, and finished envs
are frozen), then takes one AdamW step on

    loss = -1/N sum_episodes sum_t log pi(a_t | s_t) (G_t - b_t)  [+ value_coef * value loss]

with the discounted reward-to-go ``G_t = sum_{k>=t} gamma^(k-t) r_k`` (masked). Options:
``normalize_returns`` (standardise ``G`` over the batch's valid steps) and ``baseline``: ``"none"``,
``"mean"`` (the batch mean of ``G``) or ``"value"`` (a learned state-value head on the policy's
torso, trained by squared error to ``G``; the advantage does not differentiate through it).

Policies (``rl_jax.training.networks.StochasticPolicy``): a diagonal Gaussian for ``Box`` actions,
with mean and state-dependent std heads, ``std = softplus(raw) + std_floor`` (the floor is on the
std, so the density stays finite; the mean is untouched); the sampled action is clipped to the
bounds for the env step, its log-probability is that of the unclipped sample. A categorical policy
for ``Discrete`` actions. Evaluation acts with the mean (clipped) or the most likely action.

The default network is the one of gymnasium's REINFORCE tutorial for the inverted pendulum: tanh
layers of 16 and 32 units, AdamW; ``hidden`` takes deeper nets. A truncated episode is treated as
ended (no bootstrap): REINFORCE has no critic to bootstrap from.

Env steps. Episodes end at different times in every seed, but the run machinery (plans, curves
over seeds, results) needs one step axis shared by all seeds. So ``ChunkMetrics.env_steps`` (the
logged ``step``, ``--total-steps``) counts env step *slots*: ``num_envs * max_episode_steps`` per
update, the most a batch can take (exact once episodes run to the time limit, an overcount while
they end early). The real count of env steps inside episodes is logged as ``env_steps_taken``.

Beside this module: its settings (``reinforce_config``), its policy network and the episodes it
collects (``reinforce_policy``), its recipes per env (``reinforce_recipes``) and its pure maths
(``policy_gradient``).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import optax
from flax import struct
from jax.typing import ArrayLike

from rl_jax import envs
from rl_jax.agents.common import clip_by_global_norm, injected_step, linearly_decayed
from rl_jax.agents.policy_gradient import (
    entropy,
    log_prob,
    normalize,
    policy_gradient_loss,
    reward_to_go,
)
from rl_jax.agents.reinforce_config import Config, Hyperparams
from rl_jax.agents.reinforce_policy import (
    Trajectory,
    make_network,
    policy_outputs,
    rollout,
    to_env_action,
)
from rl_jax.agents.reinforce_recipes import RECIPES
from rl_jax.training import episodes, normalization
from rl_jax.training.algorithm import ChunkMetrics, RecipeBook


@struct.dataclass
class Agent:
    params: optax.Params  # policy (and value head) parameters
    opt_state: optax.InjectStatefulHyperparamsState  # adamw's: holds the rates in use
    obs_stats: normalization.RunningStats | None = None  # with normalize_obs, else None


@struct.dataclass
class Clock:
    """Counters that depend only on the config (kept unbatched by ``rl_jax.training.parallel``)."""

    updates: jax.Array  # [] int32


@struct.dataclass
class TrainState:
    agent: Agent
    key: jax.Array
    clock: Clock
    env_steps: jax.Array  # [] int32, real env steps so far (episodes differ in length per seed)
    train_return: jax.Array  # [] float32, mean return of the last batch of episodes


# ---- the loss -------------------------------------------------------------------------------
def loss_fn(
    params: optax.Params,
    trajectory: Trajectory,
    hparams: Hyperparams,
    config: Config,
    obs_stats: normalization.RunningStats | None = None,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """``(loss, metrics)`` of one batch of whole episodes (``obs_stats``: the statistics the
    episodes were collected with, ``None`` without observation normalisation)."""
    policy = policy_outputs(params, obs_stats, trajectory.obs, config)
    mask = trajectory.mask
    returns = reward_to_go(trajectory.reward, mask, hparams.gamma)
    if config.normalize_returns:
        returns = normalize(returns, mask)
    count = jnp.maximum(jnp.sum(mask), 1.0)
    value_loss = jnp.float32(0.0)
    if config.baseline == "mean":
        advantage = returns - jnp.sum(returns * mask) / count
    elif config.baseline == "value":
        advantage = returns - policy["value"]
        value_loss = jnp.sum(mask * (policy["value"] - returns) ** 2) / count
    else:
        advantage = returns
    loss = policy_gradient_loss(log_prob(policy, trajectory.action), advantage, mask)
    mean_entropy = jnp.sum(mask * entropy(policy)) / count
    total = loss + hparams.value_coef * value_loss - hparams.entropy_coef * mean_entropy
    return total, {"loss": loss, "value_loss": value_loss, "entropy": mean_entropy}


# ---- acting and rollouts ----------------------------------------------------------------------
def act(agent: Agent, obs: jax.Array, config: Config) -> jax.Array:
    """The deterministic policy: the Gaussian's mean (clipped) or the most likely action."""
    policy = policy_outputs(agent.params, agent.obs_stats, obs, config)
    if "logits" in policy:
        return jnp.argmax(policy["logits"], axis=-1).astype(jnp.int32)
    space = episodes.make_eval_env(config).action_space()
    return to_env_action(policy["mean"], space)


# ---- training ---------------------------------------------------------------------------------
def _adamw(learning_rate: ArrayLike, weight_decay: ArrayLike) -> optax.GradientTransformation:
    return optax.adamw(learning_rate, weight_decay=weight_decay)


def learning_rate(hparams: Hyperparams, updates: jax.Array) -> jax.Array:
    """The rate of update number ``updates``: linear decay to 0 over ``lr_decay_updates``."""
    return linearly_decayed(hparams.learning_rate, updates, hparams.lr_decay_updates)


def update(
    agent: Agent,
    trajectory: Trajectory,
    hparams: Hyperparams,
    config: Config,
    updates: jax.Array | int = 0,
) -> tuple[Agent, dict[str, jax.Array]]:
    """One AdamW step on a batch of episodes at the hyperparameters' rates; the observation
    statistics then take in the batch."""
    grads, metrics = jax.grad(loss_fn, has_aux=True)(
        agent.params, trajectory, hparams, config, agent.obs_stats
    )
    grads, metrics["grad_norm"] = clip_by_global_norm(grads, hparams.max_grad_norm)
    params, opt_state = injected_step(
        _adamw,
        grads,
        agent.opt_state,
        agent.params,
        learning_rate=learning_rate(hparams, updates),
        weight_decay=hparams.weight_decay,
    )
    obs_stats = agent.obs_stats
    if obs_stats is not None:
        obs_stats = normalization.update(obs_stats, trajectory.obs, trajectory.mask)
    return Agent(params, opt_state, obs_stats), metrics


def train_iteration(
    state: TrainState, config: Config, hparams: Hyperparams
) -> tuple[TrainState, dict[str, jax.Array]]:
    key, rollout_key = jax.random.split(state.key)
    trajectory = rollout(state.agent.params, rollout_key, config, state.agent.obs_stats)
    agent, metrics = update(state.agent, trajectory, hparams, config, state.clock.updates)
    episode_return = jnp.sum(trajectory.reward) / config.num_envs
    state = TrainState(
        agent=agent,
        key=key,
        clock=Clock(updates=state.clock.updates + 1),
        env_steps=state.env_steps + jnp.sum(trajectory.mask).astype(jnp.int32),
        train_return=episode_return,
    )
    return state, metrics


def init(key: jax.Array, config: Config, hparams: Hyperparams) -> TrainState:
    """A fresh state for one seed and one hyperparameter set."""
    env = episodes.make_eval_env(config)
    agent_key, key = jax.random.split(key)
    params = make_network(config).init(agent_key, jnp.zeros(env.observation_space().shape))
    optimizer = optax.inject_hyperparams(_adamw)(hparams.learning_rate, hparams.weight_decay)
    obs_dim = env.observation_space().shape[0]
    obs_stats = normalization.init(obs_dim) if config.normalize_obs else None
    return TrainState(
        agent=Agent(params, optimizer.init(params), obs_stats),
        key=key,
        clock=Clock(updates=jnp.int32(0)),
        env_steps=jnp.int32(0),
        train_return=jnp.float32(jnp.nan),
    )


def train_chunk(
    state: TrainState, config: Config, hparams: Hyperparams
) -> tuple[TrainState, ChunkMetrics]:
    """``iterations_per_chunk`` rollouts and updates, then one evaluation. Pure; jit outside."""
    state, metrics = jax.lax.scan(
        lambda s, _: train_iteration(s, config, hparams),
        state,
        None,
        length=config.iterations_per_chunk,
    )
    eval_key, key = jax.random.split(state.key)
    eval_return = episodes.evaluate(act, state.agent, config, eval_key)
    state = state.replace(key=key)
    extra = {**jax.tree.map(jnp.mean, metrics), "env_steps_taken": state.env_steps}
    return state, ChunkMetrics(
        env_steps=state.clock.updates * step_slots_per_update(config),
        updates=state.clock.updates,
        eval_return=eval_return,
        train_return=state.train_return,
        extra=extra,
    )


def step_slots_per_update(config: Config) -> int:
    """``num_envs * max_episode_steps``: the env steps of a batch whose episodes all run to the
    time limit (the unit of the shared step axis, see the module docstring)."""
    return config.num_envs * episodes.make_eval_env(config).max_episode_steps


# ---- the Algorithm object ---------------------------------------------------------------------
class Reinforce(RecipeBook):
    """REINFORCE as an ``rl_jax.training.algorithm.Algorithm``."""

    name = "reinforce"
    config_type, hparams_type = Config, Hyperparams
    recipes = RECIPES

    def init(self, key: jax.Array, config: Config, hparams: Hyperparams) -> TrainState:
        return init(key, config, hparams)

    def train_chunk(
        self, state: TrainState, config: Config, hparams: Hyperparams
    ) -> tuple[TrainState, ChunkMetrics]:
        return train_chunk(state, config, hparams)

    def env_steps_per_chunk(self, config: Config) -> int:
        """Env step slots per chunk (see the module docstring)."""
        return step_slots_per_update(config) * config.iterations_per_chunk

    def policy(self, state: TrainState, config: Config) -> Callable[[jax.Array], jax.Array]:
        """``obs -> action`` of the deterministic policy of one seed's state."""
        return lambda obs: act(state.agent, obs, config)

    def make_env(self, config: Config) -> envs.Environment:
        return episodes.make_eval_env(config)


reinforce = Reinforce()
default_config, default_hyperparams = reinforce.default_config, reinforce.default_hyperparams
