"""PPO (Schulman et al. 2017): clipped-surrogate policy optimisation on GAE advantages.

One *iteration*: ``num_envs`` vmapped envs (autoreset) each take ``num_steps`` steps with the
current stochastic policy; the rollout's advantages come from GAE(lambda) (``ppo_parts``),
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
gradient steps per iteration.

Here: its settings (``Config``, ``PixelConfig`` for envs seen as frames, ``Hyperparams``), the
network built for a config, the loss, rollouts and updates, its recipes per env and the learner
object. Beside it: the maths and the actor-critic network module (``ppo_parts``).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct

from rl_jax import envs
from rl_jax.agents import ppo_parts
from rl_jax.agents.common import clip_by_global_norm, injected_step, linearly_decayed
from rl_jax.agents.policy_gradient import entropy, log_prob
from rl_jax.agents.ppo_parts import (
    ActorCritic,
    deterministic_action,
    sample_action,
    to_env_action,
)
from rl_jax.envs.core.preprocessing import ACTION_MASK
from rl_jax.envs.core.wrappers import StatisticsState
from rl_jax.training import conv, episodes, networks, normalization, params, validation
from rl_jax.training.algorithm import ChunkMetrics, Clock, RecipeBook
from rl_jax.training.episodes import ImageObservations
from rl_jax.training.networks import Params
from rl_jax.training.normalization import RunningStats
from rl_jax.training.params import Scalar
from rl_jax.training.recipes import Recipe, Recipes, Setting

__all__ = ["IMAGE_ENVS", "PIXEL_ENVS", "Config", "Hyperparams", "ImageConfig", "PixelConfig", "ppo"]


# ---- settings -------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True, kw_only=True)
class Config:
    """Static settings (changing one recompiles)."""

    env_id: str
    num_envs: int = 8  # envs stepped together (vmapped), each with its own episode
    num_steps: int = 128  # steps of every env per rollout: a batch is num_envs * num_steps
    num_epochs: int = 4  # passes over each batch
    num_minibatches: int = 4  # gradient steps per pass (they must split the batch evenly)
    iterations_per_chunk: int = 1  # rollouts and updates per compiled call; eval after each call
    num_eval_envs: int = 10  # episodes of the deterministic policy per evaluation
    hidden: tuple[int, ...] = (
        64,
        64,
    )  # hidden layers of the actor and of the critic (each its own)
    activation: networks.Activation = "tanh"  # see rl_jax.training.networks.ACTIVATIONS
    initial_std: float = 1.0  # Gaussian policy: the state-independent std before training
    normalize_obs: bool = False  # standardise observations by running mean and variance
    normalize_rewards: bool = False  # divide rewards by a running std of discounted returns
    normalize_advantages: bool = True  # standardise the advantages of each minibatch
    clip_value_loss: bool = True  # keep the value within value_clip_eps of its old value
    # the env's constructor keywords, "name=value, name=value": envs.make(env_id, **them)
    env_kwargs: str = ""

    def __post_init__(self) -> None:
        envs.parse_keywords(self.env_kwargs)  # a ValueError names what is wrong
        for name in (
            "num_envs",
            "num_steps",
            "num_epochs",
            "num_minibatches",
            "iterations_per_chunk",
            "num_eval_envs",
        ):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.batch_size % self.num_minibatches:
            raise ValueError(
                f"num_minibatches ({self.num_minibatches}) must divide the batch of num_envs x "
                f"num_steps = {self.batch_size} env steps"
            )
        if self.activation not in networks.ACTIVATIONS:
            raise ValueError(f"activation must be one of {list(networks.ACTIVATIONS)}")
        if self.initial_std <= 0.0:
            raise ValueError(f"initial_std must be > 0, got {self.initial_std}")

    @property
    def batch_size(self) -> int:
        """Transitions per rollout: ``num_envs * num_steps``."""
        return self.num_envs * self.num_steps

    def make_env(self) -> envs.Environment:
        """The registered env, built with ``env_kwargs``."""
        return envs.make(self.env_id, **envs.parse_keywords(self.env_kwargs))


#: Envs observed as stacked frames: their config is a ``PixelConfig`` (the Atari games: the
#: Nature DQN torso is ``--conv-layers 32,8,4,64,4,2,64,3,1 --hidden 512``).
PIXEL_ENVS = ("rl_jax/CartPolePixels-v1", *envs.ATARI_IDS)


@dataclasses.dataclass(frozen=True, kw_only=True)
class PixelConfig(Config, ImageObservations):
    """PPO on frames (``PIXEL_ENVS``): a conv torso (``conv.ConvTorso``, DQN's) and the
    ``hidden`` layers after it are shared by actor and critic, each then one linear head (as in
    the PPO paper's Atari network). Observations are not standardised: the torso scales the
    uint8 pixels to [0, 1] itself."""

    hidden: tuple[int, ...] = (256,)
    activation: networks.Activation = "relu"
    frame_size: int = 84  # frames are frame_size x frame_size grayscale pixels
    frame_stack: int = 4  # the last frame_stack frames are the observation's channels
    # (features, kernel, stride) per conv layer: the 2013 DQN paper's torso, as DQN's pixel config
    conv_layers: tuple[int, ...] = (16, 8, 4, 32, 4, 2)
    # the torso sees only the frame rows the env ever draws on (as DQN's crop_drawn_rows)
    crop_drawn_rows: bool = True

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.normalize_obs:
            raise ValueError(
                "normalize_obs is for vector observations; frames are scaled to [0, 1]"
            )
        if self.frame_size < 1 or self.frame_stack < 1:
            raise ValueError("frame_size and frame_stack must be >= 1")
        conv.check_conv_layers(self.conv_layers, self.frame_size)
        first, stop = self.conv_rows() or (0, self.frame_size)
        conv.check_conv_layers(self.conv_layers, stop - first)

    def conv_rows(self) -> tuple[int, ...]:
        """``(first, stop)``, the frame rows the conv torso sees, or ``()`` for all."""
        env = self.make_env()
        if not self.crop_drawn_rows or not hasattr(env, "drawn_rows"):
            return ()
        return conv.covering_rows(self.conv_layers, *env.drawn_rows(), self.frame_size)

    def make_env(self) -> envs.Environment:
        """The registered env rendering ``frame_stack`` stacked frames of ``frame_size`` pixels."""
        return envs.make(
            self.env_id,
            frame_size=self.frame_size,
            frame_stack=self.frame_stack,
            **envs.parse_keywords(self.env_kwargs),
        )


#: Envs observed as images that are not frames (MinAtar's 10x10xC grids of 0/1): their config is
#: an ``ImageConfig``.
IMAGE_ENVS = envs.MINATAR_IDS


@dataclasses.dataclass(frozen=True, kw_only=True)
class ImageConfig(Config, ImageObservations):
    """PPO on image observations (``IMAGE_ENVS``): as ``PixelConfig``, a conv torso and hidden
    layers shared by actor and critic, by default the MinAtar paper's network (16 3x3 filters of
    stride 1, then 128 units). The torso scales observations by the space's upper bound. Without
    conv layers (``conv_layers=()``) the actor and the critic are MLPs of their own on the
    flattened image (gymnax-blines' MinAtar network: ``hidden=(256, 256)``)."""

    hidden: tuple[int, ...] = (128,)
    activation: networks.Activation = "relu"
    conv_layers: tuple[int, ...] = (16, 3, 1)  # (features, kernel, stride) per conv layer

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.normalize_obs:
            raise ValueError("normalize_obs is for vector observations; images are scaled")
        shape = self.make_env().observation_space().shape
        if len(shape) != 3:
            raise ValueError(f"{self.env_id} observations are not images: shape {shape}")
        conv.check_conv_layers(self.conv_layers, min(shape[0], shape[1]))


@struct.dataclass
class Hyperparams(params.HyperparamsMethods):
    """What a sweep may vary without recompiling."""

    learning_rate: Scalar = 2.5e-4  # Adam step size at the start
    lr_decay_steps: Scalar = (
        0.0  # env steps (one seed, all envs) over which it falls to 0 (0: constant)
    )
    gamma: Scalar = 0.99  # discount
    gae_lambda: Scalar = 0.95  # GAE's lambda: 0 one-step TD errors, 1 Monte-Carlo returns
    clip_eps: Scalar = 0.2  # the surrogate's ratio is clipped to [1 - clip_eps, 1 + clip_eps]
    value_clip_eps: Scalar = 0.2  # clip_value_loss: how far a value may move from its old value
    vf_coef: Scalar = 0.5  # weight of the value loss
    ent_coef: Scalar = 0.01  # weight of the policy's mean entropy, subtracted from the loss
    max_grad_norm: Scalar = 0.5  # clip the gradient's global norm to this (0: no clipping)
    adam_eps: Scalar = 1e-5  # Adam's epsilon (PPO implementations use 1e-5, not optax's 1e-8)
    reward_clip: Scalar = 10.0  # normalize_rewards: scaled rewards are clipped to +-this (0: not)


# ---- the network (ppo_parts) ----------------------------------------------------------------
@functools.lru_cache(maxsize=64)
def make_network(config: Config) -> ActorCritic:
    """The network for ``config`` (cached: called at every trace)."""
    space = episodes.action_space(config)
    discrete = isinstance(space, envs.Discrete)
    conv_layers = config.conv_layers if isinstance(config, PixelConfig | ImageConfig) else ()
    layers = networks.Layers(
        hidden=config.hidden, activation=config.activation, initializer="orthogonal"
    )
    return ActorCritic(
        layers=layers,
        action_dim=1 if discrete else space.shape[0],
        num_actions=space.n if isinstance(space, envs.Discrete) else None,
        initial_std=config.initial_std,
        conv_layers=conv_layers,
        conv_rows=config.conv_rows() if isinstance(config, PixelConfig) and conv_layers else (),
        obs_high=_obs_high(config) if isinstance(config, ImageConfig) else 255.0,
        flatten_image=isinstance(config, ImageConfig) and not conv_layers,
    )


def _obs_high(config: Config) -> float:
    """The largest value of the observation space (255 where it has no bound)."""
    space = episodes.observation_space(config)
    return float(np.max(space.high)) if isinstance(space, envs.Box) else 255.0


def outputs(
    params: Params,
    obs_stats: RunningStats | None,
    obs: jax.Array,
    config: Config,
    legal: jax.Array | None = None,
) -> dict[str, jax.Array]:
    """The network's outputs on observations standardised by ``obs_stats`` (``None``: as they
    are), the categorical over the ``legal`` actions alone where given (``ppo_parts.outputs``)."""
    return ppo_parts.outputs(make_network(config), params, obs_stats, obs, legal)


def value(
    params: Params, obs_stats: RunningStats | None, obs: jax.Array, config: Config
) -> jax.Array:
    """The critic alone on (standardised) observations: ``[...]``."""
    return ppo_parts.value(make_network(config), params, obs_stats, obs)


# ---- state ----------------------------------------------------------------------------------
@struct.dataclass
class Agent:
    """Actor-critic parameters, the optimizer state and, with ``normalize_obs``, observation
    statistics."""

    params: Params  # actor-critic parameters
    opt_state: optax.OptState  # optax inject_hyperparams(adam) state: holds the rate in use
    obs_stats: RunningStats | None = None  # with normalize_obs, else None


@struct.dataclass
class TrainState:
    """One seed's training state: the agent, the train envs and their last observations."""

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
        advantage = ppo_parts.normalize_advantages(advantage)
    policy_loss = ppo_parts.clipped_surrogate_loss(
        log_pi, batch.log_mu, advantage, hparams.clip_eps
    )
    if config.clip_value_loss:
        value_loss = ppo_parts.clipped_value_loss(
            policy["value"], batch.value, batch.target, hparams.value_clip_eps
        )
    else:
        value_loss = ppo_parts.value_loss(policy["value"], batch.target)
    mean_entropy = jnp.mean(entropy(policy))
    total = policy_loss + hparams.vf_coef * value_loss - hparams.ent_coef * mean_entropy
    metrics = {"policy_loss": policy_loss, "value_loss": value_loss, "entropy": mean_entropy}
    return total, {**metrics, **ppo_parts.policy_statistics(log_pi, batch.log_mu, hparams.clip_eps)}


# ---- acting and rollouts ----------------------------------------------------------------------
def act(agent: Agent, obs: jax.Array, config: Config, legal: jax.Array | None = None) -> jax.Array:
    """The deterministic policy: the Gaussian's mean (clipped) or the most likely (legal,
    given the env's mask ``legal``) action."""
    space = episodes.action_space(config)
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
    return ppo_parts.lambda_targets(
        state,
        rollout.r_t,
        rollout.terminated,
        rollout.truncated,
        rollout.v_tm1,
        rollout.v_t,
        hparams.gamma,
        hparams.gae_lambda,
        hparams.reward_clip,
        config.normalize_rewards,
    )


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
    """One rollout, its GAE advantages and targets, and the epochs of minibatch updates;
    also the rollout's summed episode returns and ended-episode count."""
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
        state = ppo_parts.with_reward_scale(state, config.num_envs)
    return state


def train_chunk(
    state: TrainState, config: Config, hparams: Hyperparams
) -> tuple[TrainState, ChunkMetrics]:
    """``iterations_per_chunk`` iterations, then one evaluation. Pure; jit outside."""
    return episodes.iterate_and_evaluate(
        state,
        lambda s: train_iteration(s, config, hparams),
        config.iterations_per_chunk,
        lambda s, key: episodes.evaluate(act, s.agent, config, key),
    )


# ---- recipes --------------------------------------------------------------------------------
# Whole, named settings per env (rl_jax.training.recipes), over the defaults of Config and
# Hyperparams. Envs without a recipe of their own train on those defaults. How they were chosen:
# docs/learners/ppo.md#how-the-recipes-were-chosen.

MUJOCO = tuple(
    f"rl_jax/{name}-v5"
    for name in (
        "InvertedPendulum",
        "InvertedDoublePendulum",
        "HalfCheetah",
        "Hopper",
        "Walker2d",
        "Swimmer",
        "Reacher",
        "Ant",
        "Humanoid",
    )
)
# Their position-only variants (envs/memory/masked.py, Ni et al. 2022's "-P" tasks): the
# vectorised recipe below applies to them unchanged, so feed-forward PPO's rows there are
# comparable with recurrent_ppo's recipe for them (PPO's settings with an LSTM).
MUJOCO_POSITIONS = tuple(
    f"rl_jax/{name}-P-v5" for name in ("Hopper", "Walker2d", "HalfCheetah", "Ant")
)

# CleanRL's ppo_continuous_action.py (its Args and make_env), setting by setting: the reference
# the MuJoCo rows compare with.
CLEANRL_CONFIG: dict[str, Setting] = {
    "num_envs": 1,
    "num_steps": 2048,
    "num_epochs": 10,
    "num_minibatches": 32,
    "iterations_per_chunk": 5,  # evaluated every 10,240 env steps
    "hidden": (64, 64),
    "activation": "tanh",
    "initial_std": 1.0,
    "normalize_obs": True,
    "normalize_rewards": True,
    "normalize_advantages": True,
    "clip_value_loss": True,
}
CLEANRL_HPARAMS: dict[str, Setting] = {
    "learning_rate": 3e-4,
    "lr_decay_steps": 1_000_000.0,
    "gamma": 0.99,
    "gae_lambda": 0.95,
    "clip_eps": 0.2,
    "value_clip_eps": 0.2,
    "vf_coef": 0.5,
    "ent_coef": 0.0,
    "max_grad_norm": 0.5,
    "adam_eps": 1e-5,
    "reward_clip": 10.0,
}

# Vectorised: CleanRL's 2,048-step batch from 64 envs x 32 steps, chosen on half cheetah by
# return against wall-clock (RESULTS.md#ppos-vectorised-recipe).
MUJOCO_CONFIG: dict[str, Setting] = {
    **CLEANRL_CONFIG,
    "num_envs": 64,
    "num_steps": 32,
    "iterations_per_chunk": 10,  # 10 evaluation episodes cost about 10,240 steps of training
}

# CartPole: rl-baselines3-zoo's tuned settings, chosen over three others by 30-seed runs
# (RESULTS.md#sac-and-ppo-first-measurements-and-ppo-on-cartpole).
CARTPOLE_CONFIG: dict[str, Setting] = {
    "num_envs": 16,
    "num_steps": 32,
    "num_epochs": 10,
    "num_minibatches": 2,
    "iterations_per_chunk": 10,  # evaluated every 5,120 env steps
    "clip_value_loss": False,
}
CARTPOLE_HPARAMS: dict[str, Setting] = {
    "learning_rate": 1e-3,
    "lr_decay_steps": 100_000.0,
    "gamma": 0.98,
    "gae_lambda": 0.8,
    "ent_coef": 0.0,
}

# Frames: DQN's conv torso at DQN's pixel budget, otherwise untuned (RESULTS.md#ppo-from-pixels).
PIXELS_CONFIG: dict[str, Setting] = {
    "normalize_rewards": True,  # unscaled, the value loss's gradient fills the clipped norm
    "num_envs": 8,
    "num_steps": 128,
    "num_epochs": 4,
    "num_minibatches": 4,
    "iterations_per_chunk": 5,
}
PIXELS_HPARAMS: dict[str, Setting] = {"learning_rate": 2.5e-4, "lr_decay_steps": 200_000.0}

# MinAtar: gymnax-blines' PPO (agents/<game>-MinAtar/ppo.yaml: 64 envs x 128 steps, 4 epochs x 8
# minibatches, gamma 0.999, lambda 0.95, clip 0.2, entropy 0.01, value 0.5, norm 0.5) on its
# network, an MLP of 2 x 256 ReLU units on the flattened grid for the actor and another for the
# critic, without its 5% warm-up of the rate; each game at the rate of its better released agent
# (1e-3 on Breakout and Asterix, 3e-4 on SpaceInvaders and Freeway), falling linearly to 0 over
# the 10M steps where gymnax-blines keeps it constant: at a constant rate the final policies
# swung between evaluations. The MinAtar paper's conv torso shared by actor and critic
# (conv_layers=(16, 3, 1), hidden=(128,)) stays one flag away; RESULTS.md ("MinAtar inside the
# program") says why neither is as gymnax-blines has it.
MINATAR_CONFIG: dict[str, Setting] = {
    "num_envs": 64,
    "num_steps": 128,
    "num_epochs": 4,
    "num_minibatches": 8,
    "iterations_per_chunk": 25,  # evaluated every 204,800 env steps, about 2% of the budget
    "hidden": (256, 256),
    "activation": "relu",
    "conv_layers": (),
    "clip_value_loss": True,
}
MINATAR_HPARAMS: dict[str, Setting] = {
    "learning_rate": 1e-3,
    "lr_decay_steps": 10_000_000.0,
    "gamma": 0.999,
    "gae_lambda": 0.95,
    "clip_eps": 0.2,
    "ent_coef": 0.01,
    "vf_coef": 0.5,
    "max_grad_norm": 0.5,
}
#: the games whose better gymnax-blines agent was trained at 3e-4 rather than 1e-3
MINATAR_SLOWER = ("rl_jax/SpaceInvaders-MinAtar", "rl_jax/Freeway-MinAtar")

RECIPES = Recipes(
    Recipe(
        "default",
        "gymnax-blines' PPO: 64 envs x 128, 4 x 8, actor and critic MLPs 2 x 256, rate 1e-3 to 0",
        MINATAR_CONFIG,
        MINATAR_HPARAMS,
        envs=tuple(env for env in IMAGE_ENVS if env not in MINATAR_SLOWER),
        total_steps=10_000_000,
    ),
    Recipe(
        "default",
        "gymnax-blines' PPO: 64 envs x 128, 4 x 8, actor and critic MLPs 2 x 256, rate 3e-4 to 0",
        MINATAR_CONFIG,
        {**MINATAR_HPARAMS, "learning_rate": 3e-4},
        envs=MINATAR_SLOWER,
        total_steps=10_000_000,
    ),
    Recipe(
        "default",
        "16 envs x 32 steps, 10 epochs x 2 minibatches, rate 1e-3 to 0 over 100k steps",
        CARTPOLE_CONFIG,
        CARTPOLE_HPARAMS,
        envs=("rl_jax/CartPole-v1",),
        total_steps=100_000,
    ),
    Recipe(
        "default",
        "conv torso shared by actor and critic, 8 envs x 128 steps (untuned)",
        PIXELS_CONFIG,
        PIXELS_HPARAMS,
        envs=("rl_jax/CartPolePixels-v1",),
        total_steps=200_000,
    ),
    Recipe(
        "default",
        "64 envs x 32 steps, 10 epochs x 32 minibatches, CleanRL's rates and norms",
        MUJOCO_CONFIG,
        CLEANRL_HPARAMS,
        envs=MUJOCO + MUJOCO_POSITIONS,
        total_steps=1_000_000,
    ),
    Recipe(
        "cleanrl",
        "CleanRL's ppo_continuous_action.py: 1 env x 2048 steps, 10 epochs x 32 minibatches",
        CLEANRL_CONFIG,
        CLEANRL_HPARAMS,
        envs=MUJOCO,
        total_steps=1_000_000,
    ),
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
        """The recipe's ``Config``; a ``PixelConfig`` for the envs of ``PIXEL_ENVS``, an
        ``ImageConfig`` for those of ``IMAGE_ENVS``."""
        if env_id not in PIXEL_ENVS + IMAGE_ENVS:
            return super().default_config(env_id, recipe, **overrides)
        values = {**self.recipe(env_id, recipe).config, **overrides}
        if env_id in IMAGE_ENVS:
            return ImageConfig(env_id=env_id, **values)
        return PixelConfig(env_id=env_id, **values)

    def init(self, key: jax.Array, config: Config, hparams: Hyperparams) -> TrainState:
        """A fresh state for one seed and one hyperparameter set."""
        return init(key, config, hparams)

    def train_chunk(
        self, state: TrainState, config: Config, hparams: Hyperparams
    ) -> tuple[TrainState, ChunkMetrics]:
        """``iterations_per_chunk`` iterations, then one evaluation."""
        return train_chunk(state, config, hparams)

    def env_steps_per_chunk(self, config: Config) -> int:
        """Env steps per seed in one chunk: ``batch_size * iterations_per_chunk``."""
        return config.batch_size * config.iterations_per_chunk

    def policy(self, state: TrainState, config: Config) -> Callable[..., jax.Array]:
        """``obs -> action`` of the deterministic policy of one seed's state; for an env with
        an action mask, ``(obs, legal) -> action``, the most likely legal action."""
        return lambda obs, legal=None: act(state.agent, obs, config, legal)

    def make_env(self, config: Config) -> envs.Environment:
        """The env the policy acts in, for rendering."""
        return episodes.make_eval_env(config)


ppo = PPO()
default_config, default_hyperparams = ppo.default_config, ppo.default_hyperparams
