"""TD7 (Fujimoto et al. 2023, "For SALE: State-Action Learned Embeddings"): TD3 with

* SALE: an encoder learns ``z_s = f(s)`` and ``z_sa = g(z_s, a)`` by regressing ``g(f(s), a)``
  on ``f(s')``; the actor reads ``[AvgL1Norm(linear(s)), z_s]`` and the critics
  ``[AvgL1Norm(linear(s, a)), z_sa, z_s]`` from a fixed copy of the encoder, renewed with the
  targets (the targets read the copy before it);
* LAP: replay draws transitions in proportion to ``max(|TD error|, 1)^lap_alpha``, and the critics
  learn with LAP's Huber-like loss;
* hard target copies every ``target_update_period`` updates, which also renew the fixed
  encoders, the value-clipping range and LAP's priority for new transitions;
* value clipping: the bootstrap value is clipped to the range of targets seen up to the last
  target update;
* policy checkpoints: evaluation uses a checkpoint of the actor, replaced only when a frozen copy
  passes an assessment over training episodes (``rl_jax.training.policy_checkpoints``).

The pure maths and the state beside the networks are ``rl_jax.agents.td7_parts``.

How policy checkpoints differ from TD7's. TD7 (one env) stops training while it assesses its
actor, then runs all the updates it owes at once. Here the loop keeps its fixed number of updates
per env step (a fixed-size scan, and a clock shared by every seed under the vmap, leave no room for
bursts of deferred updates): the training envs act with the frozen copy while the online actor
goes on learning. So the acting policies, the data they collect and the number of updates follow
TD7; each update sees the replay as it was at its env step, not after the whole assessment. With
several envs an episode counts only if it began under the assessed copy, episodes ending in the
same step count together, and the switch to ``checkpoint_episodes`` episodes happens at env step
``checkpoint_episodes_from`` (TD7 counts steps after its warm-up).
"""

from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple, cast

import jax
import jax.numpy as jnp
import optax
from flax import struct

from rl_jax.agents import actor_critic, td7_parts
from rl_jax.agents.actor_critic import (
    ActorCriticConfig,
    ActorCriticHyperparams,
    CriticBatch,
    Rate,
)
from rl_jax.agents.common import injected_step, linearly_decayed
from rl_jax.agents.td7_parts import Encoders, ValueRange
from rl_jax.envs.core.spaces import Space
from rl_jax.training import (
    episodes,
    networks,
    offpolicy,
    policy_checkpoints,
    prioritized,
    validation,
)
from rl_jax.training.networks import Params
from rl_jax.training.offpolicy import Clock
from rl_jax.training.params import Scalar
from rl_jax.training.policy_checkpoints import PolicyCheckpoint
from rl_jax.training.prioritized import PrioritizedBuffer
from rl_jax.training.recipes import Recipe, Recipes
from rl_jax.training.replay import Transition


@dataclasses.dataclass(frozen=True, kw_only=True)
class Config(ActorCriticConfig):
    """Static settings of TD7; defaults: its published ones (sfujim/TD7), on the TD3 paper's loop
    (one env, one update per env step, batch 256, 25,000 random steps)."""

    critic_activation: networks.Activation = "elu"  # TD7's critics (and encoders) use ELU
    embedding_dim: int = 256  # size of z_s and z_sa
    embedding_hidden: tuple[int, ...] = (256, 256)  # hidden widths of f and of g
    target_update_period: int = 250  # updates between hard target copies
    checkpoint_episodes: int = 20  # episodes per assessment of a policy checkpoint
    # env step from which assessments take checkpoint_episodes episodes instead of 1
    checkpoint_episodes_from: int = 750_000

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.target_update_period < 1 or self.embedding_dim < 1:
            raise ValueError("target_update_period and embedding_dim must be >= 1")
        if self.checkpoint_episodes < 1 or self.checkpoint_episodes_from < 0:
            raise ValueError("checkpoint_episodes must be >= 1, checkpoint_episodes_from >= 0")


@struct.dataclass
class Hyperparams(ActorCriticHyperparams):
    """TD7's hyperparameters: the shared ones and its own."""

    lap_alpha: Scalar = 0.4  # P(i) proportional to max(|TD error|, 1)^lap_alpha
    encoder_lr: Scalar = 3e-4  # Adam step size of the encoder
    # the checkpoint's score is multiplied by this when assessments lengthen
    checkpoint_reset_weight: Scalar = 0.9


@struct.dataclass
class Policy:
    """What acting needs: actor parameters and the fixed encoder it reads."""

    actor: Params
    encoder: Params


@struct.dataclass
class Agent:
    """Parameters, targets, optimizer states, SALE's encoders, the policy checkpoint and the
    bounds of value clipping."""

    actor: Params
    critics: Params  # leaves [num_critics, ...]
    target_actor: Params
    target_critics: Params
    actor_opt: optax.OptState
    critic_opt: optax.OptState
    encoders: Encoders
    checkpoint: PolicyCheckpoint  # of ``Policy``
    value_range: ValueRange

    def current_policy(self) -> Policy:
        """The policy acting now: the actor and the fixed encoder."""
        return Policy(actor=self.actor, encoder=self.encoders.fixed)


class Networks(NamedTuple):
    """TD7's networks: the actor and critics (with the action bounds), and SALE's encoder."""

    actor_critic: actor_critic.Networks
    sale: networks.StateActionEncoder


@functools.lru_cache(maxsize=64)
def make_networks(config: Config) -> Networks:
    """TD7's networks for ``config.env_id`` (cached)."""
    action_space = episodes.action_space(config)
    box = actor_critic.bounded_box(action_space, "TD7")
    low, high = actor_critic.bounds(box, "TD7")
    dtype = jnp.dtype(config.compute_dtype)
    init = config.network_init
    actor_layers = networks.Layers(
        hidden=config.actor_hidden,
        activation=config.actor_activation,
        initializer=init,
        dtype=dtype,
    )
    critic_layers = networks.Layers(
        hidden=config.critic_hidden,
        activation=config.critic_activation,
        initializer=init,
        dtype=dtype,
    )
    # SALE's encoders use the critics' nonlinearity (TD7's elu by default)
    encoder_layers = dataclasses.replace(critic_layers, hidden=config.embedding_hidden)
    actor = networks.Actor(layers=actor_layers, action_low=low, action_high=high)
    critic = networks.Critic(layers=critic_layers)
    encoder = networks.StateActionEncoder(layers=encoder_layers, embedding_dim=config.embedding_dim)
    nets = actor_critic.Networks(actor, critic, box.low.copy(), box.high.copy())
    return Networks(nets, encoder)


# ---- acting through the embeddings --------------------------------------------------------------
def policy_action(nets: Networks, actor: Params, encoder: Params, obs: jax.Array) -> jax.Array:
    """The deterministic action of actor parameters ``actor`` reading ``z_s`` of ``encoder``."""
    z_s = td7_parts.embed_state(nets.sale, encoder, obs)
    return actor_critic.actor_action(nets.actor_critic, actor, obs, z_s)


def act(agent: Agent, obs: jax.Array, config: Config) -> jax.Array:
    """The checkpoint's deterministic action, in the env's own units."""
    best = agent.checkpoint.best
    return policy_action(make_networks(config), best.actor, best.encoder, obs)


def explore(
    agent: Agent,
    obs: jax.Array,
    noise: jax.Array,
    key: jax.Array,
    config: Config,
    hparams: Hyperparams,
    clock: Clock,
) -> tuple[jax.Array, jax.Array]:
    """``(actions, noise)``: the copy under assessment plus AR(1) exploration noise."""
    nets = make_networks(config)
    assessed = agent.checkpoint.assessed
    action = policy_action(nets, assessed.actor, assessed.encoder, obs)
    return actor_critic.explore(action, noise, key, nets.actor_critic, hparams)


def observe(
    agent: Agent,
    transitions: Transition,
    episode_return: jax.Array,
    done: jax.Array,
    clock: Clock,
    config: Config,
    hparams: Hyperparams,
) -> Agent:
    """Every env step: the policy checkpoints count the episodes that ended."""
    checkpoint = policy_checkpoints.assess(
        agent.checkpoint,
        agent.current_policy(),
        episode_return,
        done,
        clock,
        config,
        hparams.checkpoint_reset_weight,
    )
    return dataclasses.replace(agent, checkpoint=checkpoint)


def init_agent(
    key: jax.Array, config: Config, hparams: Hyperparams, obs_space: Space, action_space: Space
) -> Agent:
    """A fresh agent: targets and all encoders copies of the new ones, a checkpoint of the
    new policy, value bounds at ``[0, 0]``."""
    nets, sale = make_networks(config)
    actor_key, critic_key = jax.random.split(key)
    obs = jnp.zeros(obs_space.shape, jnp.float32)
    action = jnp.zeros(action_space.shape, jnp.float32)
    actor = nets.actor.init(actor_key, obs, jnp.zeros(config.embedding_dim))
    extra = jnp.zeros(2 * config.embedding_dim)
    critics = networks.init_stacked(nets.critic, critic_key, config.num_critics, obs, action, extra)
    critics = dict(critics)
    adam = optax.inject_hyperparams(optax.adam)
    online = sale.init(jax.random.fold_in(key, 1), obs, action)
    encoders = Encoders(
        online=online,
        fixed=online,
        fixed_target=online,
        opt=adam(learning_rate=hparams.encoder_lr).init(online),
    )
    policy = Policy(actor=actor, encoder=online)
    return Agent(
        actor=actor,
        critics=critics,
        target_actor=actor,
        target_critics=critics,
        actor_opt=adam(learning_rate=hparams.actor_lr).init(actor),
        critic_opt=adam(learning_rate=hparams.critic_lr).init(critics),
        encoders=encoders,
        checkpoint=policy_checkpoints.init(policy, config.num_envs, config.learning_starts),
        value_range=ValueRange.initial(),
    )


# ---- losses -------------------------------------------------------------------------------------
def critic_loss_fn(
    critics: Params,
    agent: Agent,
    batch: CriticBatch,
    noise: jax.Array,
    hparams: Hyperparams,
    nets: Networks,
) -> tuple[jax.Array, tuple[jax.Array, jax.Array, tuple[jax.Array, jax.Array]]]:
    """``(loss, (q_tm1, td_tm1, (min, max) of the targets))``: LAP's loss of the critics' errors
    against the value-clipped double-Q target of the target networks, which read the fixed target
    encoder (the critics read the fixed one)."""
    fixed, fixed_target = agent.encoders.fixed, agent.encoders.fixed_target
    a_t = policy_action(nets, agent.target_actor, fixed_target, batch.next_obs)
    a_t = actor_critic.target_action(a_t, noise, hparams, nets.actor_critic)
    extra_t = td7_parts.embeddings(nets.sale, fixed_target, batch.next_obs, a_t)
    q_t = actor_critic.critic_values(
        nets.actor_critic, agent.target_critics, batch.next_obs, a_t, extra_t
    )
    extra_tm1 = td7_parts.embeddings(nets.sale, fixed, batch.obs, batch.action)
    q_tm1 = actor_critic.critic_values(
        nets.actor_critic, critics, batch.obs, batch.action, extra_tm1
    )
    bounds = agent.value_range.low, agent.value_range.high
    target = td7_parts.value_clipped_target(batch.r_t, batch.discount_t, q_t, *bounds)
    td_tm1 = q_tm1 - target[None, :]
    return td7_parts.lap_loss(td_tm1), (q_tm1, td_tm1, (jnp.min(target), jnp.max(target)))


def actor_loss_fn(
    actor: Params, critics: Params, encoder: Params, obs: jax.Array, nets: Networks
) -> jax.Array:
    """The deterministic policy gradient through the first critic, via the fixed encoder's
    embeddings of the actor's own action (the encoder itself never changes here)."""
    action = policy_action(nets, actor, encoder, obs)
    extra = td7_parts.embeddings(nets.sale, encoder, obs, action)
    q = actor_critic.first_critic_value(nets.actor_critic, critics, obs, action, extra)
    return actor_critic.deterministic_policy_loss(q)


def encoder_loss_fn(
    online: Params, batch: CriticBatch, sale: networks.StateActionEncoder
) -> jax.Array:
    """SALE's loss: ``g(f(s), a)`` against ``f(s')`` of the same (online) encoder, stopped."""
    # flax types apply's result as the output or a pair with updated state; SALE has none
    zs_t = cast(jax.Array, sale.apply(online, batch.next_obs, method="embed_state"))
    _, zsa_tm1 = cast(tuple[jax.Array, jax.Array], sale.apply(online, batch.obs, batch.action))
    return td7_parts.sale_loss(zsa_tm1, zs_t)


# ---- one update ---------------------------------------------------------------------------------
def _adam(
    grads: Params, opt_state: optax.OptState, params: Params, rate: jax.Array
) -> tuple[Params, optax.OptState]:
    return injected_step(optax.adam, grads, opt_state, params, learning_rate=rate)


def encoder_step(
    agent: Agent, batch: CriticBatch, hparams: Hyperparams, nets: Networks, rate: Rate
) -> tuple[Agent, jax.Array]:
    """``(agent, loss)`` after one Adam step of SALE's online encoder."""
    encoders = agent.encoders
    loss, grads = jax.value_and_grad(encoder_loss_fn)(encoders.online, batch, nets.sale)
    online, opt = _adam(grads, encoders.opt, encoders.online, rate(hparams.encoder_lr))
    encoders = dataclasses.replace(encoders, online=online, opt=opt)
    return dataclasses.replace(agent, encoders=encoders), loss


def critic_step(
    agent: Agent,
    batch: CriticBatch,
    key: jax.Array,
    hparams: Hyperparams,
    nets: Networks,
    rate: Rate,
) -> tuple[Agent, jax.Array, jax.Array, jax.Array]:
    """``(agent, loss, q_tm1, td_tm1)`` after one Adam step of the critics; the targets' range
    joins the value-clipping range's extremes."""
    noise = jax.random.normal(key, batch.action.shape, jnp.float32)
    (loss, (q_tm1, td_tm1, target_range)), grads = jax.value_and_grad(critic_loss_fn, has_aux=True)(
        agent.critics, agent, batch, noise, hparams, nets
    )
    critics, opt = _adam(grads, agent.critic_opt, agent.critics, rate(hparams.critic_lr))
    values = agent.value_range.seeing(target_range)
    return (
        dataclasses.replace(agent, critics=critics, critic_opt=opt, value_range=values),
        loss,
        q_tm1,
        td_tm1,
    )


def actor_step(
    agent: Agent, obs: jax.Array, hparams: Hyperparams, nets: Networks, rate: Rate
) -> tuple[Agent, jax.Array]:
    """``(agent, loss)`` after one Adam step of the actor (the targets are copied, not
    stepped)."""
    args = (agent.actor, agent.critics, agent.encoders.fixed, obs, nets)
    loss, grads = jax.value_and_grad(actor_loss_fn)(*args)
    actor, opt = _adam(grads, agent.actor_opt, agent.actor, rate(hparams.actor_lr))
    return dataclasses.replace(agent, actor=actor, actor_opt=opt), loss


def copy_targets(agent: Agent) -> Agent:
    """TD7's periodic copies: targets <- online, fixed target encoder <- fixed <- online, and
    the value-clipping range renewed."""
    return dataclasses.replace(
        agent,
        target_actor=agent.actor,
        target_critics=agent.critics,
        value_range=agent.value_range.renewed(),
        encoders=agent.encoders.renewed(),
    )


def update(
    agent: Agent,
    buffer: PrioritizedBuffer,
    key: jax.Array,
    config: Config,
    hparams: Hyperparams,
    update_index: jax.Array,
) -> tuple[Agent, PrioritizedBuffer, dict[str, jax.Array]]:
    """One encoder and critic update, with LAP's new priorities for the batch; every
    ``policy_delay``-th an actor update; every ``target_update_period``-th the hard copies (and
    LAP's priority for new transitions reset to the largest stored)."""
    nets = make_networks(config)
    sample_key, noise_key = jax.random.split(key)
    rows, columns, _ = prioritized.sample_indices(buffer, sample_key, config.batch_size, 0.0)
    batch = actor_critic.gather_batch(buffer.buffer, rows, columns, hparams.gamma)
    env_steps = offpolicy.env_steps_at_update(update_index, config)

    def rate(value: Scalar) -> jax.Array:
        return linearly_decayed(value, env_steps, hparams.lr_decay_steps)

    agent, encoder_loss = encoder_step(agent, batch, hparams, nets, rate)
    agent, critic_loss, q_tm1, td_tm1 = critic_step(agent, batch, noise_key, hparams, nets, rate)
    priorities = td7_parts.lap_priorities(td_tm1)
    buffer = prioritized.update_priorities(buffer, rows, columns, priorities, hparams.lap_alpha)
    agent, actor_loss = actor_critic.every_policy_delay(
        update_index,
        config.policy_delay,
        lambda agent: actor_step(agent, batch.obs, hparams, nets, rate),
        agent,
    )
    due = (update_index + 1) % config.target_update_period == 0
    agent = jax.lax.cond(due, copy_targets, lambda agent: agent, agent)
    reset = functools.partial(prioritized.reset_max_priority, alpha=hparams.lap_alpha)
    buffer = jax.lax.cond(due, reset, lambda buffer: buffer, buffer)
    metrics = {"encoder_loss": encoder_loss, "critic_loss": critic_loss, "actor_loss": actor_loss}
    return agent, buffer, {**metrics, "q": jnp.mean(q_tm1)}


LEARNER = offpolicy.Learner(
    init_agent,
    explore,
    act,
    update,
    ("encoder_loss", "critic_loss", "actor_loss", "q"),
    td7_parts.init_buffer,
    td7_parts.add_to_buffer,
    observe,
)


# ---- recipes ------------------------------------------------------------------------------------
# TD7's published settings, which are the Config and Hyperparams defaults, and the same learner at
# CPU sizes.
RECIPES = Recipes(
    Recipe(
        "default",
        "TD7's published settings: 256x256 networks, 256-d embeddings, LAP, hard target copies "
        "every 250 updates, value clipping, policy checkpoints on the TD3 paper's loop, rate 3e-4",
    ),
    # TD7's own sizes are too slow for a CPU (docs/learners/td7.md#how-the-recipes-were-chosen).
    Recipe(
        "cpu",
        "TD7 at CPU sizes: 128x128 networks, 128-d embeddings, the half-cheetah CPU loop (4 envs "
        "x 4 updates, batch 128, 10,000 warm-up steps), rate 3e-4",
        {
            "num_envs": 4,
            "updates_per_iteration": 4,
            "iterations_per_chunk": 1250,
            "batch_size": 128,
            "learning_starts": 10_000,
            "actor_hidden": (128, 128),
            "critic_hidden": (128, 128),
            "embedding_dim": 128,
            "embedding_hidden": (128, 128),
        },
        throughput=(61.0, 5),  # measured: docs/learners/td7.md#how-the-recipes-were-chosen
    ),
)


# ---- the Algorithm object -----------------------------------------------------------------------
class TD7(offpolicy.OffPolicyAlgorithm[Config]):
    """TD7 as an ``rl_jax.training.algorithm.Algorithm``; its policy acts with the checkpoint
    (``act``)."""

    name = "td7"
    config_type, hparams_type = Config, Hyperparams
    recipes = RECIPES
    learner = LEARNER
    ranges = {"lap_alpha": validation.UNIT, "checkpoint_reset_weight": validation.NON_NEGATIVE}


td7 = TD7()
