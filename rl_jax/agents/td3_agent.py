"""TD3's agent state: parameters, targets and optimizer states (``Agent``), and what the options
keep beside them (``AgentWithOptions``): SALE's encoders, SimBa's observation statistics,
TD7's policy checkpoints and the critics' batch renormalisation statistics. Plain TD3 keeps
``Agent``, so its train state and checkpoints stay as they were before the options existed.

Policy checkpoints, and how they differ from TD7. TD7 (one env) stops training while it assesses
its actor over whole episodes, then runs all the training steps it owes at once. Here the loop
keeps its fixed number of updates per env step (a fixed-size scan, and a clock shared by every
seed under the vmap, leave no room for bursts of deferred updates). The training envs act with a
frozen copy of the actor taken when the assessment began (``PolicyCheckpoint.assessed``) while
the online actor goes on learning, and each assessment starts from the online actor of that
moment. So the acting policies, the data they collect and the number of updates follow TD7; what
differs is that each update sees the replay as it was at its env step, not after the whole
assessment. With several envs, episodes end out of step: an episode counts only if it began
under the assessed copy (envs in mid-episode when an assessment starts sit that episode out,
and the copy is retaken until an env starts an episode that counts),
episodes ending in the same env step are counted together (an assessment may run up to
``num_envs - 1`` episodes over ``checkpoint_episodes``), and the switch from 1 to
``checkpoint_episodes`` episodes (with the score scaled by ``checkpoint_reset_weight``) happens at
env step ``checkpoint_episodes_from`` (TD7 counts training steps, i.e. env steps after its
warm-up). Episodes played during the random warm-up never count (TD7 counts the one that
straddles the end of its warm-up).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from rl_jax.agents.td3_losses import CriticBatch
from rl_jax.agents.td3_networks import Networks, policy_action
from rl_jax.training import normalization, policy_checkpoints
from rl_jax.training.replay import Transition


@struct.dataclass
class Agent:
    actor: Any  # actor parameters
    critics: Any  # critic parameters, leaves [num_critics, ...]
    target_actor: Any
    target_critics: Any
    actor_opt: Any  # optax inject_hyperparams(adam) state: holds the learning rate
    critic_opt: Any


@struct.dataclass
class Encoders:
    """SALE's encoder (``networks.StateActionEncoder`` parameters) and its fixed copies."""

    online: Any  # learns every update
    fixed: Any  # what the actor and critics read: the online one at the last target update
    fixed_target: Any  # what the targets read: the fixed one before that
    opt: Any  # Adam state of ``online``


@struct.dataclass
class AgentWithOptions(Agent):
    """The agent when an option keeps state (``Config.keeps_option_state``); None where an
    option is off. Plain TD3 keeps ``Agent``, so its train state and checkpoints stay as they
    were."""

    encoders: Any = None  # sale: Encoders
    obs_stats: Any = None  # simba/normalize_obs: RunningStats of the observations acted on
    checkpoint: Any = None  # policy_checkpoints: PolicyCheckpoint
    critic_stats: Any = None  # critic_norm "batch_renorm": the critics' batch_stats [C, ...]
    value_range: Any = None  # value_clipping: ValueRange


@struct.dataclass
class ValueRange:
    """TD7's value clipping: bootstrap values are clipped to ``[low, high]``, the extremes of
    the targets seen up to the last target update (``[0, 0]`` before the first, as TD7)."""

    low: jax.Array  # [] float32
    high: jax.Array
    seen_min: jax.Array  # [] float32, the extremes of all targets so far
    seen_max: jax.Array

    @classmethod
    def initial(cls) -> ValueRange:
        zero = jnp.float32(0.0)
        no_min = jnp.float32(policy_checkpoints.NO_EPISODE)
        no_max = jnp.float32(policy_checkpoints.NO_SCORE)
        return cls(low=zero, high=zero, seen_min=no_min, seen_max=no_max)

    def seeing(self, target_range) -> ValueRange:
        low, high = target_range
        return self.replace(
            seen_min=jnp.minimum(self.seen_min, low), seen_max=jnp.maximum(self.seen_max, high)
        )


@struct.dataclass
class Policy:
    """What acting needs: actor parameters, SALE's fixed encoder and SimBa's statistics (None
    where off), so that a copy of the policy stays whole while the agent goes on learning."""

    actor: Any
    encoder: Any = None
    obs_stats: Any = None


PolicyCheckpoint = policy_checkpoints.PolicyCheckpoint  # its policies are ``Policy``


def fixed_encoders(agent: Agent) -> tuple[Any, Any]:
    """``(fixed, fixed_target)`` SALE encoder parameters, ``(None, None)`` without SALE."""
    encoders = getattr(agent, "encoders", None)
    return (None, None) if encoders is None else (encoders.fixed, encoders.fixed_target)


def hard_target_update(agent: Agent, networks: bool = True) -> Agent:
    """TD7's periodic copies: targets <- online (if there are target ``networks``); SALE's
    fixed target <- fixed <- online."""
    if networks:
        agent = agent.replace(target_actor=agent.actor, target_critics=agent.critics)
    values = getattr(agent, "value_range", None)
    if values is not None:  # the clipping range renews with the targets
        agent = agent.replace(value_range=values.replace(low=values.seen_min, high=values.seen_max))
    encoders = getattr(agent, "encoders", None)
    if encoders is None:
        return agent
    encoders = encoders.replace(fixed_target=encoders.fixed, fixed=encoders.online)
    return agent.replace(encoders=encoders)


def current_policy(agent: Any) -> Policy:
    """The online actor with what it reads."""
    obs_stats = getattr(agent, "obs_stats", None)
    return Policy(actor=agent.actor, encoder=fixed_encoders(agent)[0], obs_stats=obs_stats)


def act_with(nets: Networks, policy: Policy, obs: jax.Array) -> jax.Array:
    """``policy``'s deterministic action."""
    obs = normalization.normalize(policy.obs_stats, obs)
    return policy_action(nets, policy.actor, obs, policy.encoder)


def init_checkpoint(agent: Any, num_envs: int, learning_starts: int) -> PolicyCheckpoint:
    """The initial actor as checkpoint and as assessed copy (``policy_checkpoints.init``)."""
    return policy_checkpoints.init(current_policy(agent), num_envs, learning_starts)


def assess(agent: Any, episode_return, done, clock, config, hparams) -> PolicyCheckpoint:
    """One env step of TD7's checkpoint schedule, the online actor being the next copy to assess
    (``policy_checkpoints.assess``)."""
    return policy_checkpoints.assess(
        agent.checkpoint,
        current_policy(agent),
        episode_return,
        done,
        clock,
        config,
        hparams.checkpoint_reset_weight,
    )


# ---- observations -------------------------------------------------------------------------------
def normalized(agent: Agent, obs: jax.Array) -> jax.Array:
    """What the networks see of ``obs``: standardised under SimBa, else ``obs`` itself."""
    return normalization.normalize(getattr(agent, "obs_stats", None), obs)


def normalized_batch(agent: Agent, batch: CriticBatch) -> CriticBatch:
    """A sampled batch as the networks see it: SimBa standardises with today's statistics."""
    if getattr(agent, "obs_stats", None) is None:
        return batch
    return batch._replace(
        obs=normalized(agent, batch.obs), next_obs=normalized(agent, batch.next_obs)
    )


def observe(agent: Agent, transitions: Transition, episode_return, done, clock, config, hparams):
    """Every env step: the running statistics (SimBa's, normalize_obs) take in the observations
    acted on; policy checkpoints count the episodes that ended."""
    if config.standardizes_obs:
        mask = jnp.ones(transitions.obs.shape[:1], jnp.float32)
        agent = agent.replace(
            obs_stats=normalization.update(agent.obs_stats, transitions.obs, mask)
        )
    if config.policy_checkpoints:
        agent = agent.replace(
            checkpoint=assess(agent, episode_return, done, clock, config, hparams)
        )
    return agent
