"""The envs a learner trains and is evaluated on, built from its config, and the evaluation of
its deterministic policy: the same for the off-policy loop (TD3, DDPG, DQN) and REINFORCE.

A config offers ``make_env()`` (the env as registered, or adapted: DQN discretises actions) and
``num_eval_envs``; a config whose network reads images is an ``ImageObservations``.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Hashable
from typing import Protocol, TypeVar

import jax
import jax.numpy as jnp

from rl_jax import envs
from rl_jax.envs.core.preprocessing import ACTION_MASK
from rl_jax.training.algorithm import ChunkMetrics, Clock
from rl_jax.training.replay import Transition

#: One env's (or, with a leading axis, a batch's) recurrent policy state: a pytree of arrays.
PolicyState = object
#: One policy state's type, kept through a function that only resets some of its envs.
S = TypeVar("S")


class EnvConfig(Hashable, Protocol):
    """What a learner's config offers the env builders (frozen, so hashable: they cache)."""

    @property
    def num_eval_envs(self) -> int: ...

    def make_env(self) -> envs.Environment: ...


class ImageObservations:
    """The base of a config whose network reads images (a conv torso: ``dqn.PixelConfig``): its
    envs keep the observations ``[H, W, C]``. Every other config's are flattened to one axis
    (flattening would also make a uint8 space float32)."""


# Cached: every trace asks for the env, and building one (an MJX model) can be slow. Envs are
# stateless, so sharing an instance is safe.
@functools.lru_cache(maxsize=64)
def make_eval_env(config: EnvConfig) -> envs.Environment:
    """The env as the policy sees it (obs flattened to one axis), without autoreset."""
    # The first call may come while tracing (e.g. under eval_shape): constants an env computes
    # when built (MuJoCo's initial obs, default params) must stay concrete, not leak tracers.
    with jax.ensure_compile_time_eval():
        env = config.make_env()
    keep_images = isinstance(config, ImageObservations)
    if len(env.observation_space().shape) != 1 and not keep_images:
        env = envs.FlattenObservation(env)
    return env


def action_space(config: EnvConfig) -> envs.Space:
    """The space of one action of the env the policy acts in (``make_eval_env``'s): what a
    learner sizes and bounds its network's outputs by."""
    return make_eval_env(config).action_space()


def observation_space(config: EnvConfig) -> envs.Space:
    """The space of one observation the policy sees (flattened to one axis unless the config
    reads images): what a learner sizes its network's inputs by."""
    return make_eval_env(config).observation_space()


@functools.lru_cache(maxsize=64)
def make_train_env(config: EnvConfig) -> envs.Environment:
    """Training stack: statistics outside autoreset so they see the step that ended an episode."""
    return envs.EpisodeStatistics(envs.AutoReset(make_eval_env(config)))


def example_transition(env: envs.Environment) -> Transition:
    """A zero transition of the env's spaces: the shapes and dtypes of what it gives."""
    obs_space, action_space = env.observation_space(), env.action_space()
    obs = jnp.zeros(obs_space.shape, obs_space.dtype)
    action = jnp.zeros(action_space.shape, action_space.dtype)
    false = jnp.zeros((), jnp.bool_)
    transition = Transition(obs, action, jnp.zeros((), jnp.float32), obs, false, false)
    if envs.has_action_mask(env):  # the rows keep the next obs's legal actions
        return transition._replace(next_legal=env.empty_info()[ACTION_MASK])
    return transition


def evaluate(
    act: Callable[..., jax.Array], agent: object, config: EnvConfig, key: jax.Array
) -> jax.Array:
    """Mean undiscounted return of ``num_eval_envs`` episodes of the deterministic policy
    ``act(agent, obs [N, ...], config)`` on fresh env copies (no exploration noise, no
    autoreset); [] float32. For an env with an action mask it is
    ``act(agent, obs, config, legal [N, A])``, so that it chooses among the legal actions."""
    env = make_eval_env(config)
    policy = lambda obs, *legal: act(agent, obs, config, *legal)  # noqa: E731
    return jnp.mean(episode_returns(policy, env, key, config.num_eval_envs))


def episode_returns(
    policy: Callable[..., jax.Array], env: envs.Environment, key: jax.Array, episodes: int
) -> jax.Array:
    """Undiscounted returns ``[episodes]`` of ``policy`` (``obs [N, ...] -> actions [N, ...]``)
    in ``env``: one fresh copy per episode, all stepped together until the last one ends. For
    an env with a legal-action mask (``envs.has_action_mask``) the policy is called as
    ``policy(obs, legal)``, ``legal`` the bool ``[N, A]`` mask of ``obs``. The loop is
    ``recurrent_episode_returns``'s, with no policy state to carry."""
    stateless = lambda policy_state, *obs_legal: (policy(*obs_legal), policy_state)  # noqa: E731
    return recurrent_episode_returns(stateless, (), env, key, episodes)


# ---- recurrent policies ------------------------------------------------------------------------
def batched_policy_state(initial: PolicyState, count: int) -> PolicyState:
    """``count`` copies (leading axis) of one env's initial policy state."""
    return jax.tree.map(lambda leaf: jnp.broadcast_to(leaf, (count, *jnp.shape(leaf))), initial)


def reset_policy_state(starts: jax.Array, policy_state: S, initial: S) -> S:
    """``policy_state [N, ...]`` with the envs where ``starts [N]`` (an episode begins: after an
    autoreset, ``terminated | truncated``) given ``initial`` (one env's) again."""

    def reset(leaf: jax.Array, first: jax.Array) -> jax.Array:
        where = jnp.reshape(starts, starts.shape + (1,) * (leaf.ndim - starts.ndim))
        return jnp.where(where, first, leaf)

    return jax.tree.map(reset, policy_state, initial)


def one_env_recurrent_policy(
    act: Callable[..., tuple[jax.Array, PolicyState]], agent: object, config: object
) -> Callable[[PolicyState, jax.Array], tuple[jax.Array, PolicyState]]:
    """``(policy_state, obs) -> (action, policy_state)`` for one env, from a recurrent learner's
    batched ``act(agent, policy_state [N, ...], obs [N, ...], config)``: what a learner's
    ``policy`` hook returns for evaluation, GIFs and ``load_policy``."""

    def step(policy_state: PolicyState, obs: jax.Array) -> tuple[jax.Array, PolicyState]:
        batch = jax.tree.map(lambda x: x[None], (policy_state, obs))
        action, policy_state = act(agent, batch[0], batch[1], config)
        return action[0], jax.tree.map(lambda x: x[0], policy_state)

    return step


def evaluate_recurrent(
    act: Callable[..., tuple[jax.Array, PolicyState]],
    initial: PolicyState,
    agent: object,
    config: EnvConfig,
    key: jax.Array,
) -> jax.Array:
    """``evaluate`` for a recurrent policy ``act(agent, policy_state [N, ...], obs [N, ...],
    config[, legal [N, A]]) -> (actions, policy_state)``: each episode starts from ``initial``
    (one env's state)."""
    env = make_eval_env(config)
    policy = lambda ps, obs, *legal: act(agent, ps, obs, config, *legal)  # noqa: E731
    return jnp.mean(recurrent_episode_returns(policy, initial, env, key, config.num_eval_envs))


def recurrent_episode_returns(
    policy: Callable[..., tuple[jax.Array, PolicyState]],
    initial: PolicyState,
    env: envs.Environment,
    key: jax.Array,
    episodes: int,
) -> jax.Array:
    """``episode_returns`` of a recurrent policy ``(policy_state [N, ...], obs [N, ...][, legal
    [N, A]]) -> (actions [N, ...], policy_state)``: every episode starts from ``initial`` (one
    env's state), which the policy then carries from step to step."""
    reset_key, step_key = jax.random.split(key)
    env_state, ts = jax.vmap(env.reset)(jax.random.split(reset_key, episodes))
    masked = envs.has_action_mask(env)

    #: (step, env states, policy states, observations, legal actions, alive, returns)
    Loop = tuple[jax.Array, object, object, jax.Array, jax.Array | None, jax.Array, jax.Array]

    def running(carry: Loop) -> jax.Array:
        time, _, _, _, _, alive, _ = carry
        return jnp.logical_and(time < env.max_episode_steps, jnp.any(alive))

    def step(carry: Loop) -> Loop:
        time, env_state, policy_state, obs, legal, alive, total = carry
        keys = jax.random.split(jax.random.fold_in(step_key, time), episodes)
        if masked:
            action, policy_state = policy(policy_state, obs, legal)
        else:
            action, policy_state = policy(policy_state, obs)
        env_state, ts = jax.vmap(env.step)(keys, env_state, action)
        total = total + jnp.where(alive, ts.reward, 0.0)
        alive = jnp.logical_and(alive, ~jnp.logical_or(ts.terminated, ts.truncated))
        legal = ts.info[ACTION_MASK] if masked else None
        return time + 1, env_state, policy_state, ts.obs, legal, alive, total

    alive = jnp.ones(episodes, jnp.bool_)
    total = jnp.zeros(episodes, jnp.float32)
    legal = ts.info[ACTION_MASK] if masked else None
    policy_state = batched_policy_state(initial, episodes)
    carry: Loop = (jnp.int32(0), env_state, policy_state, ts.obs, legal, alive, total)
    return jax.lax.while_loop(running, step, carry)[-1]


def mean_return(return_sums: jax.Array, counts: jax.Array, previous: jax.Array) -> jax.Array:
    """The mean return of the episodes that ended in a chunk (``return_sums`` and ``counts`` per
    iteration and env), or ``previous`` where none ended: a chunk's ``train_return``."""
    count = jnp.sum(counts)
    return jnp.where(count > 0, jnp.sum(return_sums) / jnp.maximum(count, 1), previous)


class ChunkState(Protocol):
    """What ``iterate_and_evaluate`` reads of a learner's state (a dataclass)."""

    key: jax.Array
    clock: Clock
    train_return: jax.Array


C = TypeVar("C", bound=ChunkState)
#: An iteration's outputs: ``(metrics, (return_sums, counts))`` of the episodes that ended.
IterationOutput = tuple[dict[str, jax.Array], tuple[jax.Array, jax.Array]]


def iterate_and_evaluate(
    state: C,
    iteration: Callable[[C], tuple[C, IterationOutput]],
    length: int,
    evaluate_state: Callable[[C, jax.Array], jax.Array],
) -> tuple[C, ChunkMetrics]:
    """A ``train_chunk``: ``length`` scanned iterations, then one evaluation
    (``evaluate_state(state, key)``) with a key split from the state's; the chunk's
    ``train_return`` is the mean return of the episodes that ended (``mean_return``)."""
    state, (metrics, (return_sums, counts)) = jax.lax.scan(
        lambda s, _: iteration(s), state, None, length=length
    )
    eval_key, key = jax.random.split(state.key)
    eval_return = evaluate_state(state, eval_key)
    train_return = mean_return(return_sums, counts, state.train_return)
    state = dataclasses.replace(state, key=key, train_return=train_return)  # type: ignore[type-var]
    return state, ChunkMetrics(
        env_steps=state.clock.env_steps,
        updates=state.clock.updates,
        eval_return=eval_return,
        train_return=train_return,
        extra=jax.tree.map(jnp.mean, metrics),
    )
