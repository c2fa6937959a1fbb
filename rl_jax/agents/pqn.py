"""PQN (Gallici et al. 2024, "Simplifying Deep Temporal Difference Learning"): Q-learning from
many vmapped envs with no replay buffer and no target network, kept stable by LayerNorm in the
Q-network.

One *iteration*: ``num_envs`` vmapped envs (autoreset) each take ``num_steps`` epsilon-greedy
steps of the current Q-network (epsilon falling linearly over env steps). The rollout's targets
are Q(lambda) returns (``q_lambda_targets``), computed backwards over each env's steps: every
step bootstraps from ``max_a Q`` of its true next observation (``info["final_obs"]`` where an
episode ended, so a time-limit truncation bootstraps and a termination does not), and the
lambda-mixture is cut where an episode ended. Then ``num_epochs`` passes over the ``num_envs *
num_steps`` batch, each shuffled into ``num_minibatches`` minibatches, one RAdam (or Adam) step
on each of

    loss = mean 0.5 (Q(s, a) - G)^2

with the gradient's global norm clipped to ``max_grad_norm`` and the rate falling linearly to 0
over ``lr_decay_steps`` env steps (held for the whole iteration). The targets use the network
of the rollout and stay fixed through the epochs: that is all the "target network" PQN has.

For envs with a legal-action mask (``info["action_mask"]``), acting (greedy and random) and the
bootstrap's max run over the legal actions only (``rl_jax.agents.q_learning``'s ``masked_*``).

A *chunk* (one compiled call) is ``iterations_per_chunk`` iterations under ``lax.scan``, then one
evaluation of the greedy policy: ``num_envs * num_steps * iterations_per_chunk`` env steps and
``num_epochs * num_minibatches`` gradient steps per iteration.

The Q-network: ``hidden`` Dense layers, each followed by LayerNorm and ReLU, then a linear head
with one output per action. Envs observed as images (MinAtar's 10x10 grids, CartPole's frames)
put ``conv.ConvTorso`` first, with LayerNorm over its flattened features.

Usage is PPO's::

    config = pqn.default_config("rl_jax/CartPole-v1")
    hparams = pqn.default_hyperparams("rl_jax/CartPole-v1")
    state = pqn.init(jax.random.key(0), config, hparams)
    state, metrics = jax.jit(pqn.train_chunk, static_argnums=1)(state, config, hparams)
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import NamedTuple, cast

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct

from rl_jax import envs
from rl_jax.agents.common import clip_by_global_norm, injected_step, linearly_decayed
from rl_jax.agents.q_learning import (
    linear_schedule,
    masked_argmax,
    masked_epsilon_greedy,
    masked_max,
)
from rl_jax.envs.core.preprocessing import ACTION_MASK
from rl_jax.envs.core.wrappers import FINAL_ACTION_MASK, StatisticsState
from rl_jax.training import conv, episodes, params, validation
from rl_jax.training.algorithm import ChunkMetrics, Clock, RecipeBook
from rl_jax.training.episodes import ImageObservations
from rl_jax.training.params import Scalar
from rl_jax.training.recipes import Recipe, Recipes, Setting

__all__ = [
    "IMAGE_ENVS",
    "PIXEL_ENVS",
    "Config",
    "Hyperparams",
    "ImageConfig",
    "PixelConfig",
    "pqn",
    "q_lambda_targets",
]

OPTIMIZERS: dict[str, Callable[..., optax.GradientTransformation]] = {
    "radam": optax.radam,
    "adam": optax.adam,
}


# ---- settings -------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True, kw_only=True)
class Config:
    """Static settings (changing one recompiles)."""

    env_id: str
    num_envs: int = 32  # envs stepped together (vmapped), each with its own episode
    num_steps: int = 64  # steps of every env per rollout: a batch is num_envs * num_steps
    num_epochs: int = 4  # passes over each batch
    num_minibatches: int = 16  # gradient steps per pass (they must split the batch evenly)
    iterations_per_chunk: int = 8  # rollouts and updates per compiled call; eval after each call
    num_eval_envs: int = 10  # episodes of the greedy policy per evaluation
    hidden: tuple[int, ...] = (256, 256)  # hidden layers: Dense, LayerNorm, ReLU each
    layer_norm: bool = True  # LayerNorm before every hidden ReLU (and after a conv torso)
    optimizer: str = "radam"  # "radam" (the paper's code) or "adam"
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
        if self.optimizer not in OPTIMIZERS:
            raise ValueError(f"optimizer must be one of {list(OPTIMIZERS)}, got {self.optimizer!r}")

    @property
    def batch_size(self) -> int:
        """Transitions per rollout: ``num_envs * num_steps``."""
        return self.num_envs * self.num_steps

    def make_env(self) -> envs.Environment:
        """The registered env, built with ``env_kwargs``."""
        return envs.make(self.env_id, **envs.parse_keywords(self.env_kwargs))


#: Envs observed as grids (MinAtar's 10x10xC of 0/1): their config is an ``ImageConfig``.
IMAGE_ENVS = envs.MINATAR_IDS


@dataclasses.dataclass(frozen=True, kw_only=True)
class ImageConfig(Config, ImageObservations):
    """PQN on image observations (``IMAGE_ENVS``): ``conv.ConvTorso`` before the ``hidden``
    layers, LayerNorm over its flattened features. Observations are scaled to [0, 1] by the
    observation space's upper bound."""

    hidden: tuple[int, ...] = (128,)
    # (features, kernel, stride) per conv layer: the paper's MinAtar network, 16 3x3 filters
    conv_layers: tuple[int, ...] = (16, 3, 1)

    def __post_init__(self) -> None:
        super().__post_init__()
        shape = self.make_env().observation_space().shape
        if len(shape) != 3:
            raise ValueError(f"{self.env_id} observations are not images: shape {shape}")
        conv.check_conv_layers(self.conv_layers, min(shape[0], shape[1]))

    def conv_rows(self) -> tuple[int, ...]:
        """``(first, stop)``, the image rows the conv torso sees, or ``()`` for all."""
        return ()


#: Envs observed as stacked frames: their config is a ``PixelConfig`` (the Atari games: the
#: Nature DQN torso is ``--conv-layers 32,8,4,64,4,2,64,3,1 --hidden 512``).
PIXEL_ENVS = ("rl_jax/CartPolePixels-v1", *envs.ATARI_IDS)


@dataclasses.dataclass(frozen=True, kw_only=True)
class PixelConfig(ImageConfig):
    """PQN on frames (``PIXEL_ENVS``): the 2013 DQN paper's conv torso (DQN's and PPO's pixel
    torso here) on the frame rows the env draws on."""

    hidden: tuple[int, ...] = (256,)
    frame_size: int = 84  # frames are frame_size x frame_size grayscale pixels
    frame_stack: int = 4  # the last frame_stack frames are the observation's channels
    conv_layers: tuple[int, ...] = (16, 8, 4, 32, 4, 2)
    # the torso sees only the frame rows the env ever draws on (as DQN's crop_drawn_rows)
    crop_drawn_rows: bool = True

    def __post_init__(self) -> None:
        if self.frame_size < 1 or self.frame_stack < 1:
            raise ValueError("frame_size and frame_stack must be >= 1")
        super().__post_init__()
        first, stop = self.conv_rows() or (0, self.frame_size)
        conv.check_conv_layers(self.conv_layers, stop - first)

    def conv_rows(self) -> tuple[int, ...]:
        """``(first, stop)``, the frame rows the conv torso sees, or ``()`` for all."""
        env = self.make_env()
        if not self.crop_drawn_rows or not hasattr(env, "drawn_rows"):
            return ()
        first, stop = env.drawn_rows()
        return conv.covering_rows(self.conv_layers, first, stop, self.frame_size)

    def make_env(self) -> envs.Environment:
        """The registered env rendering ``frame_stack`` stacked frames of ``frame_size`` pixels."""
        return envs.make(
            self.env_id,
            frame_size=self.frame_size,
            frame_stack=self.frame_stack,
            **envs.parse_keywords(self.env_kwargs),
        )


@struct.dataclass
class Hyperparams(params.HyperparamsMethods):
    """What a sweep may vary without recompiling. Defaults: the paper's CartPole rates, with a
    constant rate, unscaled rewards and epsilon ending at 0.05; each env's recipe sets its own."""

    learning_rate: Scalar = 1e-4  # the optimizer's step size at the start
    lr_decay_steps: Scalar = 0.0  # env steps (one seed, all envs) for it to fall to 0 (0: constant)
    gamma: Scalar = 0.99  # discount
    q_lambda: Scalar = 0.95  # Q(lambda)'s lambda: 0 one-step targets, 1 Monte-Carlo returns
    epsilon_start: Scalar = 1.0  # chance of a random action at env step 0
    epsilon_end: Scalar = 0.05  # chance of a random action after epsilon_decay_steps
    epsilon_decay_steps: Scalar = 100_000.0  # env steps (one seed, all envs) of the linear decay
    max_grad_norm: Scalar = 10.0  # clip the gradient's global norm to this (0: no clipping)
    reward_scale: Scalar = 1.0  # rewards are multiplied by this before the targets


# ---- the Q(lambda) targets ------------------------------------------------------------------
def q_lambda_targets(
    r_t: jax.Array, discount_t: jax.Array, v_t: jax.Array, lambda_t: jax.Array
) -> jax.Array:
    """Q(lambda) returns of one rollout, ``[T, ...]`` leaves, computed backwards over ``t``:

        G_t = r_t + discount_t * ((1 - lambda_t) * v_t + lambda_t * G_{t+1})

    ``v_t`` is the bootstrap value of step ``t``'s next observation (``max_a Q(s_{t+1}, a)``),
    ``discount_t`` is ``gamma`` (0 after a termination) and ``lambda_t`` is ``lambda`` (0 where
    an episode ended, so that no return runs into the next episode). The rollout's last step
    bootstraps from its own ``v`` (its lambda taken as 0): ``G_{T-1} = r + discount * v``.
    ``lambda = 0`` gives one-step Q-learning targets; ``lambda = 1`` the discounted rewards to
    the episode's end, or to the rollout's end and then ``v``. No gradient flows through it."""

    def backward(
        next_return: jax.Array, step: tuple[jax.Array, ...]
    ) -> tuple[jax.Array, jax.Array]:
        r, discount, v, lam = step
        g = r + discount * ((1.0 - lam) * v + lam * next_return)
        return g, g

    lambda_t = lambda_t.at[-1].set(0.0)  # the rollout's last step: r + discount * v, exactly
    start = jnp.zeros_like(v_t[-1])
    _, returns = jax.lax.scan(backward, start, (r_t, discount_t, v_t, lambda_t), reverse=True)
    return jax.lax.stop_gradient(returns)


# ---- the network ----------------------------------------------------------------------------
class QNetwork(nn.Module):
    """Observations ``[..., *obs_shape]`` -> Q-values ``[..., num_actions]``: an optional conv
    torso (its flattened features layer-normalised), then Dense, LayerNorm, ReLU per hidden
    layer, then a linear head."""

    num_actions: int
    hidden: tuple[int, ...]
    layer_norm: bool = True
    conv_layers: tuple[int, ...] = ()
    conv_rows: tuple[int, ...] = ()
    obs_high: float = 255.0  # image observations' largest value: the torso sees obs / obs_high

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        if self.conv_layers:
            x = obs
            if self.obs_high != 255.0:  # the torso divides by 255 (uint8 frames)
                x = obs.astype(jnp.float32) * (255.0 / self.obs_high)
            x = conv.ConvTorso(self.conv_layers, initializer="orthogonal", rows=self.conv_rows)(x)
            if self.layer_norm:
                x = nn.LayerNorm()(x)
        else:
            x = obs.astype(jnp.float32)
        for width in self.hidden:
            x = nn.Dense(width, kernel_init=nn.initializers.he_normal())(x)
            if self.layer_norm:
                x = nn.LayerNorm()(x)
            x = nn.relu(x)
        return nn.Dense(self.num_actions)(x)


@functools.lru_cache(maxsize=64)
def make_network(config: Config) -> QNetwork:
    """The Q-network for ``config`` (cached: called at every trace)."""
    space = episodes.action_space(config)
    if not isinstance(space, envs.Discrete):
        raise TypeError(f"PQN needs discrete actions, not {space}")
    if not isinstance(config, ImageConfig):
        return QNetwork(space.n, config.hidden, config.layer_norm)
    obs_space = episodes.observation_space(config)
    high = float(np.max(obs_space.high)) if isinstance(obs_space, envs.Box) else 255.0
    return QNetwork(
        space.n,
        config.hidden,
        config.layer_norm,
        conv_layers=config.conv_layers,
        conv_rows=config.conv_rows(),
        obs_high=high,
    )


def q_values(params: optax.Params, obs: jax.Array, config: Config) -> jax.Array:
    """``Q(obs, .)``: ``[..., num_actions]``."""
    return cast(jax.Array, make_network(config).apply(params, obs))


# ---- state ----------------------------------------------------------------------------------
@struct.dataclass
class Agent:
    """The Q-network's parameters and the optimizer state."""

    params: optax.Params  # the Q-network's parameters
    opt_state: optax.OptState  # optax inject_hyperparams(radam or adam) state: the rate in use


@struct.dataclass
class TrainState:
    """One seed's training state: the agent, the train envs and their last observations."""

    agent: Agent
    env_state: StatisticsState  # [num_envs, ...] of the train env (episodes.make_train_env)
    obs: jax.Array  # [num_envs, *obs_shape], the observation the next action answers
    key: jax.Array
    clock: Clock
    train_return: jax.Array  # [] float32, mean return of the episodes ended in the last chunk
    action_mask: jax.Array | None = None  # [num_envs, A] bool, legal actions of obs (masked envs)


class Rollout(NamedTuple):
    """``num_steps`` steps of every env, leaves ``[T, N, ...]``."""

    obs: jax.Array  # the observations acted on
    action: jax.Array  # epsilon-greedy actions
    r_t: jax.Array  # rewards as the env gave them
    v_t: jax.Array  # max over (legal) actions of Q at the true next observation
    terminated: jax.Array  # bool
    truncated: jax.Array  # bool
    episode_return: jax.Array  # the return of an episode that ended at this step, else 0


class Batch(NamedTuple):
    """What a gradient step learns from, leaves ``[B, ...]``."""

    obs: jax.Array
    action: jax.Array
    target: jax.Array  # the Q(lambda) return


# ---- the loss and updates -------------------------------------------------------------------
def loss_fn(
    params: optax.Params, batch: Batch, config: Config
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """``(mean 0.5 (Q(s, a) - G)^2, metrics)`` of one minibatch."""
    q = q_values(params, batch.obs, config)
    q_taken = jnp.take_along_axis(q, batch.action[:, None].astype(jnp.int32), axis=-1)[:, 0]
    loss = 0.5 * jnp.mean(jnp.square(q_taken - batch.target))
    return loss, {"loss": loss, "q": jnp.mean(q_taken)}


def gradient_step(
    agent: Agent, batch: Batch, hparams: Hyperparams, config: Config, rate: jax.Array
) -> tuple[Agent, dict[str, jax.Array]]:
    """One optimizer step on a minibatch at ``rate``, the gradient clipped by its global norm."""
    grads, metrics = jax.grad(loss_fn, has_aux=True)(agent.params, batch, config)
    grads, metrics["grad_norm"] = clip_by_global_norm(grads, hparams.max_grad_norm)
    params, opt_state = injected_step(
        OPTIMIZERS[config.optimizer], grads, agent.opt_state, agent.params, learning_rate=rate
    )
    return Agent(params, opt_state), metrics


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


# ---- acting and rollouts --------------------------------------------------------------------
def act(agent: Agent, obs: jax.Array, config: Config, legal: jax.Array | None = None) -> jax.Array:
    """The greedy action (among the ``legal`` ones, where the env has a mask)."""
    q = q_values(agent.params, obs, config)
    if legal is None:
        return jnp.argmax(q, axis=-1).astype(jnp.int32)
    return masked_argmax(q, legal)


def epsilon_at(env_steps: jax.Array, hparams: Hyperparams) -> jax.Array:
    """The exploration rate after ``env_steps`` env steps of one seed."""
    return linear_schedule(
        hparams.epsilon_start, hparams.epsilon_end, env_steps, hparams.epsilon_decay_steps
    )


def collect(
    agent: Agent,
    env_state: StatisticsState,
    obs: jax.Array,
    key: jax.Array,
    epsilon: jax.Array,
    config: Config,
    legal: jax.Array | None = None,
) -> tuple[StatisticsState, jax.Array, jax.Array | None, Rollout]:
    """``(env_state, obs, legal, Rollout)`` after ``num_steps`` epsilon-greedy steps of every
    env. Each step also values its true next observation (``max_a Q``, over the legal actions
    of that observation where the env has a mask), which differs from the next step's
    observation where an episode ended (autoreset), so that truncations can bootstrap."""
    env = episodes.make_train_env(config)
    num_actions = make_network(config).num_actions

    Carry = tuple[StatisticsState, jax.Array, jax.Array | None]

    def step(carry: Carry, step_key: jax.Array) -> tuple[Carry, Rollout]:
        env_state, obs, legal = carry
        action_key, env_key = jax.random.split(step_key)
        q = q_values(agent.params, obs, config)
        everything = jnp.ones((config.num_envs, num_actions), jnp.bool_)
        action = masked_epsilon_greedy(
            action_key, q, everything if legal is None else legal, epsilon
        )
        keys = jax.random.split(env_key, config.num_envs)
        env_state, ts = jax.vmap(env.step)(keys, env_state, action)
        q_next = q_values(agent.params, ts.info["final_obs"], config)
        next_legal = None if legal is None else ts.info[ACTION_MASK]
        final_legal = everything if legal is None else ts.info[FINAL_ACTION_MASK]
        ended = jnp.logical_or(ts.terminated, ts.truncated)
        row = Rollout(
            obs=obs,
            action=action,
            r_t=ts.reward,
            v_t=masked_max(q_next, final_legal),
            terminated=ts.terminated,
            truncated=ts.truncated,
            episode_return=jnp.where(ended, ts.info["episode_return"], 0.0),
        )
        return (env_state, ts.obs, next_legal), row

    keys = jax.random.split(key, config.num_steps)
    (env_state, obs, legal), rollout = jax.lax.scan(step, (env_state, obs, legal), keys)
    return env_state, obs, legal, rollout


def rollout_targets(rollout: Rollout, hparams: Hyperparams) -> jax.Array:
    """The Q(lambda) returns ``[T, N]`` of a rollout: through truncations from the final
    observation's value, not through terminations, the lambda-mixture cut at every end."""
    ended = jnp.logical_or(rollout.terminated, rollout.truncated)
    discount_t = hparams.gamma * (1.0 - rollout.terminated.astype(jnp.float32))
    lambda_t = hparams.q_lambda * (1.0 - ended.astype(jnp.float32))
    lambda_t = jnp.broadcast_to(lambda_t, rollout.r_t.shape)
    return q_lambda_targets(hparams.reward_scale * rollout.r_t, discount_t, rollout.v_t, lambda_t)


IterationMetrics = tuple[dict[str, jax.Array], tuple[jax.Array, jax.Array]]


def train_iteration(
    state: TrainState, config: Config, hparams: Hyperparams
) -> tuple[TrainState, IterationMetrics]:
    """One epsilon-greedy rollout, its Q(lambda) targets and the epochs of minibatch
    updates; also the rollout's summed episode returns and ended-episode count."""
    key, collect_key, update_key = jax.random.split(state.key, 3)
    epsilon = epsilon_at(state.clock.env_steps, hparams)
    env_state, obs, legal, rollout = collect(
        state.agent, state.env_state, state.obs, collect_key, epsilon, config, state.action_mask
    )
    target = rollout_targets(rollout, hparams)
    flat = lambda x: x.reshape(config.batch_size, *x.shape[2:])  # noqa: E731
    batch = jax.tree.map(flat, Batch(rollout.obs, rollout.action, target))
    rate = linearly_decayed(hparams.learning_rate, state.clock.env_steps, hparams.lr_decay_steps)
    agent, metrics = update(state.agent, batch, update_key, hparams, config, rate)
    metrics = {**metrics, "learning_rate": rate, "epsilon": epsilon}
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
    network = make_network(config)  # a TypeError for continuous actions
    env_state, ts = jax.vmap(env.reset)(jax.random.split(env_key, config.num_envs))
    space = env.observation_space()
    params = network.init(agent_key, jnp.zeros(space.shape, space.dtype))
    optimizer = optax.inject_hyperparams(OPTIMIZERS[config.optimizer])(hparams.learning_rate)
    state = TrainState(
        agent=Agent(params, optimizer.init(params)),
        env_state=env_state,
        obs=ts.obs,
        key=key,
        clock=Clock(env_steps=jnp.int32(0), updates=jnp.int32(0), iterations=jnp.int32(0)),
        train_return=jnp.float32(jnp.nan),
    )
    if envs.has_action_mask(env):
        state = dataclasses.replace(state, action_mask=ts.info[ACTION_MASK])
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
# Hyperparams. Envs without a recipe of their own train on those defaults.

# Source: purejaxql's config/alg/pqn_cartpole.yaml (32 envs x 64 steps, 4 epochs x 16
# minibatches, 2 x 256 units, rate 1e-4 decayed over 5e5 steps, epsilon 1 to 0.2 over 20%).
CARTPOLE_CONFIG: dict[str, Setting] = {
    "num_envs": 32,
    "num_steps": 64,
    "num_epochs": 4,
    "num_minibatches": 16,
    "iterations_per_chunk": 12,  # evaluated every 24,576 env steps, about 5% of the budget
    "hidden": (256, 256),
}
CARTPOLE_HPARAMS: dict[str, Setting] = {
    "learning_rate": 1e-4,
    "lr_decay_steps": 500_000.0,
    "gamma": 0.99,
    "q_lambda": 0.95,
    "epsilon_start": 1.0,
    "epsilon_end": 0.2,
    "epsilon_decay_steps": 100_000.0,
    "max_grad_norm": 10.0,
    "reward_scale": 0.1,
}

# Source: purejaxql's config/alg/pqn_minatar.yaml and pqn_minatar.py's CNN (128 envs x 32
# steps, 2 epochs x 32 minibatches, 16 3x3 filters then 128 units, rate 5e-4 decayed over 1e7
# steps, epsilon 1 to 0.05 over 10%, lambda 0.65).
MINATAR_CONFIG: dict[str, Setting] = {
    "num_envs": 128,
    "num_steps": 32,
    "num_epochs": 2,
    "num_minibatches": 32,
    "iterations_per_chunk": 100,  # evaluated every 409,600 env steps, about 4% of the budget
    "hidden": (128,),
    "conv_layers": (16, 3, 1),
}
MINATAR_HPARAMS: dict[str, Setting] = {
    "learning_rate": 5e-4,
    "lr_decay_steps": 10_000_000.0,
    "gamma": 0.99,
    "q_lambda": 0.65,
    "epsilon_start": 1.0,
    "epsilon_end": 0.05,
    "epsilon_decay_steps": 1_000_000.0,
    "max_grad_norm": 10.0,
    "reward_scale": 1.0,
}

# Source: the CartPole recipe's loop and rates (pqn_cartpole.yaml) on DQN's pixel torso; the
# paper has no CartPole-from-frames config. Untuned.
PIXELS_CONFIG: dict[str, Setting] = {
    **CARTPOLE_CONFIG,
    "num_envs": 16,
    "iterations_per_chunk": 6,
    "hidden": (256,),
}

RECIPES = Recipes(
    Recipe(
        "default",
        "the paper's CartPole config: 32 envs x 64 steps, 4 epochs x 16 minibatches, 2 x 256",
        CARTPOLE_CONFIG,
        CARTPOLE_HPARAMS,
        envs=("rl_jax/CartPole-v1",),
        total_steps=500_000,
    ),
    Recipe(
        "default",
        "the CartPole recipe on frames: DQN's conv torso, 16 envs x 64 steps (untuned)",
        PIXELS_CONFIG,
        CARTPOLE_HPARAMS,
        envs=("rl_jax/CartPolePixels-v1",),
        total_steps=500_000,
    ),
    Recipe(
        "default",
        "the paper's MinAtar config: 128 envs x 32 steps, 2 epochs x 32 minibatches, conv 16",
        MINATAR_CONFIG,
        MINATAR_HPARAMS,
        envs=IMAGE_ENVS,
        total_steps=10_000_000,
    ),
)


# ---- the Algorithm object -------------------------------------------------------------------
class PQN(RecipeBook[Config]):
    """PQN as an ``rl_jax.training.algorithm.Algorithm``."""

    name = "pqn"
    config_type, hparams_type = Config, Hyperparams
    recipes = RECIPES
    ranges = {
        "q_lambda": validation.UNIT,
        "epsilon_decay_steps": validation.NON_NEGATIVE,
        "reward_scale": validation.POSITIVE,
    }

    def default_config(
        self, env_id: str, recipe: str | None = None, **overrides: Setting
    ) -> Config:
        """The recipe's ``Config``: an ``ImageConfig`` for ``IMAGE_ENVS``, a ``PixelConfig``
        for ``PIXEL_ENVS``."""
        values = {**self.recipe(env_id, recipe).config, **overrides}
        if env_id in PIXEL_ENVS:
            return PixelConfig(env_id=env_id, **values)  # type: ignore[arg-type]
        if env_id in IMAGE_ENVS:
            return ImageConfig(env_id=env_id, **values)  # type: ignore[arg-type]
        return Config(env_id=env_id, **values)  # type: ignore[arg-type]

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
        """``obs -> action`` of the greedy policy of one seed's state; for an env with an
        action mask, ``(obs, legal) -> action``, the greedy legal action."""
        return lambda obs, legal=None: act(state.agent, obs, config, legal)

    def make_env(self, config: Config) -> envs.Environment:
        """The env the policy acts in, for rendering."""
        return episodes.make_eval_env(config)


pqn = PQN()
default_config, default_hyperparams = pqn.default_config, pqn.default_hyperparams
