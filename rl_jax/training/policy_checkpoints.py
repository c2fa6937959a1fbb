"""TD7's policy checkpoints (Fujimoto et al. 2023) for any off-policy learner: the policy that
evaluation, ``best/`` and loaded policies use is not the latest one but a checkpoint, replaced
only when an *assessment* of a frozen copy over training episodes has a lowest return at least the
checkpoint's score; one episode below the score ends an assessment early.

A learner keeps a ``PolicyCheckpoint`` in its agent, acts in its training envs with
``assessed`` (exploration on top, as usual), evaluates ``best``, and calls ``assess`` from its
``observe`` hook at every env step with the policy it would act with now. The policy is any
pytree (TD3: its actor with what it reads; DQN: the Q-network's parameters). How this differs
from TD7's one env and deferred updates: ``rl_jax.agents.td7``'s docstring.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Generic, Protocol, TypeVar, cast

import jax
import jax.numpy as jnp
from flax import struct
from jax.typing import ArrayLike

from rl_jax.training.offpolicy import Clock

#: TD7's start values: a checkpoint score below any return, an assessment minimum above any.
NO_SCORE, NO_EPISODE = -1e8, 1e8

#: the parameters the policy acts with (DQN's network; TD7's actor and encoder)
PolicyT = TypeVar("PolicyT")


@struct.dataclass
class PolicyCheckpoint(Generic[PolicyT]):
    best: PolicyT  # the checkpoint: what evaluation, best/ and loaded policies use
    assessed: PolicyT  # the frozen copy acting in the training envs during an assessment
    score: jax.Array  # [] float32, the lowest return of the checkpoint's assessment
    lowest: jax.Array  # [] float32, the lowest return so far in this assessment
    episodes: jax.Array  # [] int32, episodes counted so far in this assessment
    counting: jax.Array  # [num_envs] bool, whether each env's episode began under ``assessed``


def assess_episodes(
    lowest: jax.Array,
    episodes: jax.Array,
    score: jax.Array,
    returns: jax.Array,
    counted: jax.Array,
    required: jax.Array,
) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """One env step of an assessment: ``returns`` [N] of the episodes that ended, ``counted``
    [N] those that count. Returns ``(lowest, episodes, passed, ended)``: the lowest return and the
    number of episodes so far; ``passed`` when ``required`` episodes have all stayed at or above
    ``score`` (the assessed policy becomes the checkpoint), ``ended`` also when one fell below."""
    lowest = jnp.minimum(lowest, jnp.min(jnp.where(counted, returns, NO_EPISODE)))
    episodes = episodes + jnp.sum(counted, dtype=jnp.int32)
    failed = lowest < score
    passed = jnp.logical_and(~failed, episodes >= required)
    return lowest, episodes, passed, jnp.logical_or(failed, passed)


def init(policy: PolicyT, num_envs: int, learning_starts: int) -> PolicyCheckpoint[PolicyT]:
    """The initial policy as checkpoint and as assessed copy; envs count from their first
    episode that starts after the random warm-up."""
    return PolicyCheckpoint(
        best=policy,
        assessed=policy,
        score=jnp.float32(NO_SCORE),
        lowest=jnp.float32(NO_EPISODE),
        episodes=jnp.int32(0),
        counting=jnp.full(num_envs, learning_starts == 0),
    )


class CheckpointSchedule(Protocol):
    """The settings ``assess`` reads of a learner's config (TD7's and DQN's have them)."""

    @property
    def num_envs(self) -> int: ...
    @property
    def learning_starts(self) -> int: ...
    @property
    def checkpoint_episodes(self) -> int: ...
    @property
    def checkpoint_episodes_from(self) -> int: ...


def _where(flag: jax.Array, a: PolicyT, b: PolicyT) -> PolicyT:
    return jax.tree.map(lambda x, y: jnp.where(flag, x, y), a, b)


def assess(
    ckpt: PolicyCheckpoint[PolicyT],
    current: PolicyT,
    episode_return: jax.Array,
    done: jax.Array,
    clock: Clock,
    config: CheckpointSchedule,
    reset_weight: ArrayLike,
) -> PolicyCheckpoint[PolicyT]:
    """One env step of TD7's checkpoint schedule: count the episodes that ended, and when an
    assessment ends, keep its copy if it passed and take ``current`` as the new copy. Until an
    assessment's first episode begins (no env counting: after the warm-up, or while every env
    finishes an episode begun before), the copy keeps following ``current``. ``config`` gives
    ``num_envs``, ``learning_starts``, ``checkpoint_episodes`` (episodes per assessment from env
    step ``checkpoint_episodes_from``; 1 before it, when the score is scaled by
    ``reset_weight``)."""
    after = clock.env_steps + config.num_envs
    start = config.checkpoint_episodes_from
    lengthen = jnp.logical_and(clock.env_steps < start, after >= start)
    score = jnp.where(lengthen, ckpt.score * reset_weight, ckpt.score)
    required = jnp.where(after >= start, config.checkpoint_episodes, 1)
    counted = jnp.logical_and(done, ckpt.counting)
    lowest, episodes, passed, ended = assess_episodes(
        ckpt.lowest, ckpt.episodes, score, episode_return, counted, required
    )
    renew = jnp.logical_or(ended, ~jnp.any(ckpt.counting))
    # After an assessment only fresh episodes count; none while actions are still random.
    counting = jnp.where(ended, done, jnp.logical_or(ckpt.counting, done))
    counting = jnp.logical_and(counting, after >= config.learning_starts)
    return PolicyCheckpoint(
        best=_where(passed, ckpt.assessed, ckpt.best),
        assessed=_where(renew, current, ckpt.assessed),
        score=jnp.where(passed, lowest, score),
        lowest=jnp.where(ended, jnp.float32(NO_EPISODE), lowest),
        episodes=jnp.where(ended, 0, episodes),
        counting=counting,
    )


class OnlineCheckpointing(CheckpointSchedule, Protocol):
    """A config whose ``policy_checkpoints`` switch the checkpoints on (DQN's, R2D2's)."""

    @property
    def policy_checkpoints(self) -> bool:
        """Whether the checkpoints are on."""
        ...


class OnlineAgent(Protocol):
    """An agent whose policy is its ``online`` network, with its ``checkpoint`` (None when off)."""

    @property
    def online(self) -> object:
        """The online network's parameters: the policy, and the next copy to assess."""
        ...

    @property
    def checkpoint(self) -> object:
        """The ``PolicyCheckpoint`` (None without ``policy_checkpoints``)."""
        ...


AgentT = TypeVar("AgentT", bound=OnlineAgent)


def observe_online(
    agent: AgentT,
    episode_return: jax.Array,
    done: jax.Array,
    clock: Clock,
    config: OnlineCheckpointing,
    reset_weight: ArrayLike,
) -> AgentT:
    """A learner's ``observe`` hook where the policy is the agent's ``online`` network: with
    ``policy_checkpoints``, one env step of ``assess`` with the online network as the next copy;
    without, the agent as it is."""
    if not config.policy_checkpoints:
        return agent
    current = cast(PolicyCheckpoint[object], agent.checkpoint)
    checkpoint = assess(current, agent.online, episode_return, done, clock, config, reset_weight)
    return cast(AgentT, dataclasses.replace(cast(Any, agent), checkpoint=checkpoint))
