"""TD3's agent state: parameters, targets and optimizer states (``Agent``), and what the options
keep beside them (``AgentWithOptions``): SALE's encoders and SimBa's observation statistics.
Plain TD3 keeps ``Agent``, so its train state and checkpoints stay as they were before the
options existed.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from rl_jax.agents.td3_losses import CriticBatch
from rl_jax.training import normalization
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
    obs_stats: Any = None  # simba: normalization.RunningStats of the observations acted on


def fixed_encoders(agent: Agent) -> tuple[Any, Any]:
    """``(fixed, fixed_target)`` SALE encoder parameters, ``(None, None)`` without SALE."""
    encoders = getattr(agent, "encoders", None)
    return (None, None) if encoders is None else (encoders.fixed, encoders.fixed_target)


def hard_target_update(agent: Agent) -> Agent:
    """TD7's periodic copies: targets <- online; SALE's fixed target <- fixed <- online."""
    agent = agent.replace(target_actor=agent.actor, target_critics=agent.critics)
    encoders = getattr(agent, "encoders", None)
    if encoders is None:
        return agent
    encoders = encoders.replace(fixed_target=encoders.fixed, fixed=encoders.online)
    return agent.replace(encoders=encoders)


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
    """Every env step: SimBa's statistics take in the observations acted on."""
    if config.network == "simba":
        mask = jnp.ones(transitions.obs.shape[:1], jnp.float32)
        agent = agent.replace(
            obs_stats=normalization.update(agent.obs_stats, transitions.obs, mask)
        )
    return agent
