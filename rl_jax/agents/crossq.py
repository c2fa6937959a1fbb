"""CrossQ (Bhatt et al. 2024) on TD3's deterministic actor: no target networks, and batch
renormalisation in the critics.

Without targets the bootstrap uses the online actor (with TD3's target smoothing) and critics.
The critics see the batch's ``(s, a)`` and ``(s', a')`` in one forward pass, so that batch
renormalisation's statistics cover both (the ``(s', a')`` half enters as data: no gradient
reaches the actor through it). The critics learn in training mode; the actor's gradient reads
them in evaluation mode (the running statistics). Adam's first-moment decay is 0.5 (``adam_b1``),
so that a step follows the latest gradients of a critic that has no target network to slow it.
The actor updates after every ``policy_delay`` (CrossQ: 3) critic updates.

Batch renormalisation itself is ``rl_jax.training.batch_renorm``; its statistics are state
beside the critics' parameters (the optimizer never sees them).
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import optax
from flax import struct

from rl_jax.agents import actor_critic
from rl_jax.agents.actor_critic import (
    ActorCriticConfig,
    ActorCriticHyperparams,
    CriticBatch,
    Networks,
    Rate,
)
from rl_jax.agents.common import injected_step, linearly_decayed
from rl_jax.envs.core.spaces import Space
from rl_jax.training import batch_renorm, episodes, networks, offpolicy, replay, validation
from rl_jax.training.networks import Params
from rl_jax.training.offpolicy import Clock
from rl_jax.training.params import Scalar
from rl_jax.training.recipes import Recipe, Recipes
from rl_jax.training.replay import ReplayBuffer, Transition


@dataclasses.dataclass(frozen=True, kw_only=True)
class Config(ActorCriticConfig):
    """Static settings of CrossQ; defaults: its published ones (wide critics, policy delay 3)."""

    critic_hidden: tuple[int, ...] = (2048, 2048)
    policy_delay: int = 3
    # critic updates of plain batch norm (no r/d corrections) while the running statistics
    # settle (CrossQ's implementation: 100,000)
    renorm_warmup: int = 100_000
    adam_b1: float = 0.5  # Adam's first-moment decay for actor and critics (Adam's own: 0.9)


@struct.dataclass
class Hyperparams(ActorCriticHyperparams):
    """CrossQ's rates: 1e-3 (no targets: nothing to step slowly)."""

    actor_lr: Scalar = 1e-3
    critic_lr: Scalar = 1e-3


@struct.dataclass
class Agent:
    """Parameters, optimizer states and the critics' batch statistics (CrossQ keeps no targets)."""

    actor: Params
    critics: Params  # parameters, leaves [num_critics, ...]
    actor_opt: optax.OptState
    critic_opt: optax.OptState
    critic_stats: Params  # batch renormalisation's statistics, leaves [num_critics, ...]


@functools.lru_cache(maxsize=64)
def make_networks(config: Config) -> Networks:
    """The actor and the batch-renormalised critics for ``config.env_id`` (cached)."""
    action_space = episodes.action_space(config)
    box = actor_critic.bounded_box(action_space, "CrossQ")
    low, high = actor_critic.bounds(box, "CrossQ")
    dtype = jnp.dtype(config.compute_dtype)
    actor_layers = networks.Layers(
        hidden=config.actor_hidden,
        activation=config.actor_activation,
        initializer=config.network_init,
        dtype=dtype,
    )
    critic_layers = networks.Layers(
        hidden=config.critic_hidden,
        activation=config.critic_activation,
        initializer=config.network_init,
        norm="batch_renorm",
        dtype=dtype,
        renorm_warmup=config.renorm_warmup,
    )
    actor = networks.Actor(layers=actor_layers, action_low=low, action_high=high)
    critic = networks.Critic(layers=critic_layers)
    return Networks(actor, critic, box.low.copy(), box.high.copy())


def act(agent: Agent, obs: jax.Array, config: Config) -> jax.Array:
    """The deterministic policy, in the env's own action units."""
    return actor_critic.actor_action(make_networks(config), agent.actor, obs)


def explore(
    agent: Agent,
    obs: jax.Array,
    noise: jax.Array,
    key: jax.Array,
    config: Config,
    hparams: Hyperparams,
    clock: Clock,
) -> tuple[jax.Array, jax.Array]:
    """``(actions, noise)``: the policy plus AR(1) exploration noise, clipped to the bounds."""
    action = act(agent, obs, config)
    return actor_critic.explore(action, noise, key, make_networks(config), hparams)


def adam(learning_rate: Scalar, b1: Scalar = 0.9) -> optax.GradientTransformation:
    """Adam whose numbers are state (``optax.inject_hyperparams``): a checkpoint records them,
    and each step reads them there."""
    return optax.inject_hyperparams(optax.adam)(learning_rate=learning_rate, b1=b1)


def init_agent(
    key: jax.Array, config: Config, hparams: Hyperparams, obs_space: Space, action_space: Space
) -> Agent:
    """A fresh agent: new actor and critics, their Adam states and batch statistics."""
    nets = make_networks(config)
    actor_key, critic_key = jax.random.split(key)
    obs = jnp.zeros(obs_space.shape, jnp.float32)
    action = jnp.zeros(action_space.shape, jnp.float32)
    actor = nets.actor.init(actor_key, obs)
    critics = dict(networks.init_stacked(nets.critic, critic_key, config.num_critics, obs, action))
    stats = critics.pop("batch_stats")
    return Agent(
        actor=actor,
        critics=critics,
        actor_opt=adam(learning_rate=hparams.actor_lr).init(actor),
        critic_opt=adam(learning_rate=hparams.critic_lr).init(critics),
        critic_stats=stats,
    )


# ---- losses -------------------------------------------------------------------------------------
def critic_loss_fn(
    critics: Params,
    agent: Agent,
    batch: CriticBatch,
    noise: jax.Array,
    hparams: Hyperparams,
    nets: Networks,
) -> tuple[jax.Array, tuple[jax.Array, Params]]:
    """``(loss, (q_tm1, new stats))``: the squared error to the clipped double-Q target, both
    halves from one forward pass over ``[(s, a); (s', a')]`` (``batch_renorm.joint_pass``)."""
    a_t = actor_critic.actor_action(nets, agent.actor, batch.next_obs)
    a_t = jax.lax.stop_gradient(actor_critic.target_action(a_t, noise, hparams, nets))
    q_tm1, q_t, stats = batch_renorm.joint_pass(
        nets.critic, critics, agent.critic_stats, batch.obs, batch.action, batch.next_obs, a_t
    )
    return actor_critic.critic_loss(q_tm1, batch.r_t, batch.discount_t, q_t), (q_tm1, stats)


def actor_loss_fn(actor: Params, agent: Agent, obs: jax.Array, nets: Networks) -> jax.Array:
    """The deterministic policy gradient through the first critic in evaluation mode."""
    action = actor_critic.actor_action(nets, actor, obs)
    critics = {**agent.critics, "batch_stats": agent.critic_stats}
    q = actor_critic.first_critic_value(nets, critics, obs, action)
    return actor_critic.deterministic_policy_loss(q)


# ---- one update ---------------------------------------------------------------------------------
def _adam(
    grads: Params, opt_state: optax.OptState, params: Params, rate: jax.Array, b1: float
) -> tuple[Params, optax.OptState]:
    """Adam at ``rate`` and ``b1``, both written into the injected state (which a checkpoint
    records) before the step reads them."""
    beta1 = jnp.asarray(b1, jnp.float32)
    return injected_step(optax.adam, grads, opt_state, params, learning_rate=rate, b1=beta1)


def critic_step(
    agent: Agent,
    batch: CriticBatch,
    key: jax.Array,
    hparams: Hyperparams,
    config: Config,
    rate: Rate,
) -> tuple[Agent, jax.Array, jax.Array]:
    """``(agent, loss, q_tm1)`` after one Adam step of the critics and their statistics'."""
    nets = make_networks(config)
    noise = jax.random.normal(key, batch.action.shape, jnp.float32)
    (loss, (q_tm1, stats)), grads = jax.value_and_grad(critic_loss_fn, has_aux=True)(
        agent.critics, agent, batch, noise, hparams, nets
    )
    critic_lr = rate(hparams.critic_lr)
    critics, opt = _adam(grads, agent.critic_opt, agent.critics, critic_lr, config.adam_b1)
    return (
        dataclasses.replace(agent, critics=critics, critic_opt=opt, critic_stats=stats),
        loss,
        q_tm1,
    )


def actor_step(
    agent: Agent, obs: jax.Array, hparams: Hyperparams, config: Config, rate: Rate
) -> tuple[Agent, jax.Array]:
    """``(agent, loss)`` after one Adam step of the actor."""
    nets = make_networks(config)
    loss, grads = jax.value_and_grad(actor_loss_fn)(agent.actor, agent, obs, nets)
    actor_lr = rate(hparams.actor_lr)
    actor, opt = _adam(grads, agent.actor_opt, agent.actor, actor_lr, config.adam_b1)
    return dataclasses.replace(agent, actor=actor, actor_opt=opt), loss


def update(
    agent: Agent,
    buffer: ReplayBuffer[Transition],
    key: jax.Array,
    config: Config,
    hparams: Hyperparams,
    update_index: jax.Array,
) -> tuple[Agent, ReplayBuffer[Transition], dict[str, jax.Array]]:
    """One critic update; every ``policy_delay``-th also an actor update."""
    sample_key, noise_key = jax.random.split(key)
    rows, columns = replay.sample_indices(buffer, sample_key, config.batch_size)
    batch = actor_critic.gather_batch(buffer, rows, columns, hparams.gamma)
    env_steps = offpolicy.env_steps_at_update(update_index, config)

    def rate(value: Scalar) -> jax.Array:
        return linearly_decayed(value, env_steps, hparams.lr_decay_steps)

    agent, critic_loss, q_tm1 = critic_step(agent, batch, noise_key, hparams, config, rate)
    agent, actor_loss = actor_critic.every_policy_delay(
        update_index,
        config.policy_delay,
        lambda agent: actor_step(agent, batch.obs, hparams, config, rate),
        agent,
    )
    return agent, buffer, {"critic_loss": critic_loss, "actor_loss": actor_loss, "q": q_tm1.mean()}


LEARNER = offpolicy.Learner(init_agent, explore, act, update, ("critic_loss", "actor_loss", "q"))

# The half-cheetah CPU loop (4 envs x 4 updates per iteration, batch 128, 10,000 random steps).
_CPU_LOOP = {
    "num_envs": 4,
    "updates_per_iteration": 4,
    "iterations_per_chunk": 1250,
    "batch_size": 128,
    "learning_starts": 10_000,
}
RECIPES = Recipes(
    Recipe(
        "default",
        "CrossQ's published settings: 2048-wide critics, policy delay 3, rate 1e-3, Adam b1 0.5, "
        "on the TD3 paper's loop",
    ),
    Recipe(
        "cpu",
        "CrossQ's ideas at CPU sizes: 128x128 actor and critics in the half-cheetah CPU loop",
        {**_CPU_LOOP, "actor_hidden": (128, 128), "critic_hidden": (128, 128)},
    ),
)


class CrossQ(offpolicy.OffPolicyAlgorithm[Config]):
    """CrossQ as an ``rl_jax.training.algorithm.Algorithm``."""

    name = "crossq"
    config_type, hparams_type = Config, Hyperparams
    recipes = RECIPES
    learner = LEARNER
    ranges = {
        "renorm_warmup": validation.NON_NEGATIVE,
        "adam_b1": validation.Range(0.0, 1.0, high_open=True),
    }


crossq = CrossQ()
