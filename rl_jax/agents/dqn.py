"""DQN (Mnih et al. 2015) and its usual extensions, each a setting, on the off-policy machinery.

A Q-network with one output per action learns from replay with a Huber loss against a target
network; the target network takes a step ``tau`` towards the online one every
``target_update_period`` updates (``tau = 1``: the paper's periodic hard copy; ``tau < 1`` with
period 1: Polyak averaging). Exploration is epsilon-greedy, epsilon falling linearly over env
steps. Settings: ``double`` (van Hasselt et al. 2016: the online network picks the bootstrap
action, the target network values it), ``dueling`` (Wang et al. 2016), ``n_step`` returns,
``prioritized`` replay (Schaul et al. 2016, proportional: ``rl_jax.training.prioritized``),
``norm="layer"`` (LayerNorm in the Q-network, as PQN's) and ``policy_checkpoints`` (TD7's: the
greedy policy evaluated, saved and loaded is a copy of the Q-network that passed an assessment
over training episodes, ``rl_jax.training.policy_checkpoints``; CartPole's recipe uses it).

Episode ends follow the env contract, as in TD3: an n-step window stops at the first step that
ended an episode and bootstraps from that step's true next observation unless the step
*terminated* (a time-limit truncation still bootstraps). Continuous envs run through
``envs.DiscretizeActions`` with ``action_bins`` values per dimension (3 bins: the rocket's thrust
in {-1, 0, +1}).

Here: its settings (``Config``, ``PixelConfig`` for envs seen as frames, ``Hyperparams``), its
network, update and acting, its recipes per env and the learner object. Beside it: its replay
(``dqn_parts``) and its pure maths (``q_learning``). Usage is TD3's::

    config = dqn.default_config("rl_jax/CartPole-v1", double=True, n_step=3)
    hparams = dqn.default_hyperparams("rl_jax/CartPole-v1")
    state = dqn.init(jax.random.key(0), config, hparams)
    state, metrics = jax.jit(dqn.train_chunk, static_argnums=1)(state, config, hparams)
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any, cast

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct
from jax.typing import ArrayLike

from rl_jax import envs
from rl_jax.agents import dqn_parts
from rl_jax.agents.common import injected_step, linearly_decayed, polyak_update
from rl_jax.agents.dqn_parts import Buffer
from rl_jax.agents.q_learning import (
    double_q_values,
    epsilon_greedy,
    greedy_values,
    linear_schedule,
    masked_argmax,
    masked_double_q_values,
    masked_epsilon_greedy,
    masked_max,
    n_step_target,
    q_learning_loss,
)
from rl_jax.training import (
    augment,
    conv,
    episodes,
    networks,
    offpolicy,
    params,
    policy_checkpoints,
    validation,
)
from rl_jax.training.episodes import ImageObservations
from rl_jax.training.offpolicy import Clock, OffPolicyConfig, TrainState
from rl_jax.training.policy_checkpoints import PolicyCheckpoint
from rl_jax.training.recipes import Recipe, Recipes, Setting
from rl_jax.training.replay import NStepBatch, Transition


# ---- settings -----------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True, kw_only=True)
class Config(OffPolicyConfig):
    """Static settings of DQN (the loop's are in ``OffPolicyConfig``)."""

    hidden: tuple[int, ...] = (120, 84)  # hidden ReLU layers of the Q-network
    double: bool = False  # Double DQN targets: the online net's argmax, valued by the target net
    dueling: bool = False  # dueling head: q = v + a - mean(a)
    n_step: int = 1  # rewards summed before bootstrapping (a window stops at an episode's end)
    prioritized: bool = False  # proportional prioritized replay with importance weights
    target_update_period: int = 500  # gradient updates between target steps of size tau
    action_bins: int = 3  # values per action dim when the env's actions are continuous
    network_init: networks.Initializer = "fan_in_uniform"  # see rl_jax.training.networks
    norm: networks.Norm = "none"  # "layer": LayerNorm before each hidden ReLU of the Q-network
    # TD7's policy checkpoints (rl_jax.training.policy_checkpoints): the training envs act
    # (epsilon-greedily) with a frozen copy of the Q-network for an assessment of
    # checkpoint_episodes episodes (1 before env step checkpoint_episodes_from); if none returned
    # less than the checkpoint's score, the copy becomes the checkpoint, whose greedy policy is
    # what evaluation, best/ and loaded policies use. Updates go on meanwhile.
    policy_checkpoints: bool = False
    checkpoint_episodes: int = 20  # policy_checkpoints: episodes per assessment (TD7: 20)
    checkpoint_episodes_from: int = 750_000  # policy_checkpoints: env step of the switch

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.norm not in ("none", "layer"):
            raise ValueError(f"norm must be 'none' or 'layer', got {self.norm!r}")
        if self.n_step < 1 or self.target_update_period < 1:
            raise ValueError("n_step and target_update_period must be >= 1")
        if self.checkpoint_episodes < 1 or self.checkpoint_episodes_from < 0:
            raise ValueError("checkpoint_episodes must be >= 1, checkpoint_episodes_from >= 0")
        if self.action_bins < 2:
            raise ValueError(f"action_bins must be >= 2, got {self.action_bins}")
        if self.network_init not in networks.INITS:
            raise ValueError(f"network_init must be one of {networks.INITS}")

    def make_env(self) -> envs.Environment:
        """The registered env; a continuous one with its actions discretised."""
        env = super().make_env()
        if isinstance(env.action_space(), envs.Box):
            env = envs.DiscretizeActions(env, self.action_bins)
        return env


#: Envs observed as stacked frames: their config is a ``PixelConfig`` (the Atari games: the
#: Nature DQN torso is ``--conv-layers 32,8,4,64,4,2,64,3,1 --hidden 512``).
PIXEL_ENVS = ("rl_jax/CartPolePixels-v1", *envs.ATARI_IDS)


@dataclasses.dataclass(frozen=True, kw_only=True)
class PixelConfig(Config, ImageObservations):
    """DQN on frames (``PIXEL_ENVS``): the frame geometry and a conv torso before ``hidden``.

    The replay keeps each frame once per step and rebuilds stacks when sampling
    (``rl_jax.training.frame_replay``). The default torso is the 2013 DQN paper's (16 8x8/4, 32
    4x4/2, then 256 units), not Nature DQN's (32 8x8/4, 64 4x4/2, 64 3x3/1, 512): its gradient
    step costs about a third as much on a CPU, and CartPole's frames are simple."""

    hidden: tuple[int, ...] = (256,)  # hidden ReLU layers after the conv torso
    frame_size: int = 84  # frames are frame_size x frame_size grayscale pixels
    frame_stack: int = 4  # the last frame_stack frames are the observation's channels
    conv_layers: tuple[int, ...] = (16, 8, 4, 32, 4, 2)  # (features, kernel, stride) per layer
    # Seeds as an unrolled loop in the one program (training.parallel.seed_loop), not a vmap:
    # XLA's CPU backend runs the conv torso's batched (vmapped) gradients slower than a loop of
    # unbatched ones.
    loop_seeds: bool = True
    # The torso sees only the rows the env ever draws on (its ``drawn_rows``; CartPole: 31 of 84,
    # grown to 36 that the conv stack reads whole). The other rows are white in every frame, so
    # the network loses nothing while its convolutions cost 36/84 as much. Off by default: runs
    # saved before it existed see the whole frame.
    crop_drawn_rows: bool = False
    # DrQ's random shifts (rl_jax.training.augment): every sampled stack, obs and next_obs
    # apart, is moved by up to augment_shift pixels in each axis (edges repeated) before the
    # Q-networks see it, in the loss only; acting and evaluation see the frames as they are.
    # DrQ used 4 at 84x84. 0: off (the update is then the same program as before it existed).
    # On CartPole's frames 4 stopped learning altogether.
    augment_shift: int = 0

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.frame_size < 1 or self.frame_stack < 1:
            raise ValueError("frame_size and frame_stack must be >= 1")
        if not 0 <= self.augment_shift < self.frame_size:
            raise ValueError(
                f"augment_shift must be in 0..{self.frame_size - 1}, got {self.augment_shift}"
            )
        conv.check_conv_layers(self.conv_layers, self.frame_size)
        given = {"frame_size", "frame_stack"} & set(envs.parse_keywords(self.env_kwargs))
        if given:
            name = sorted(given)[0]
            raise ValueError(
                f"{name} is a config field here: --{name.replace('_', '-')}, not --env-kwargs"
            )
        first, stop = self.conv_rows() or (0, self.frame_size)
        conv.check_conv_layers(self.conv_layers, stop - first)

    def make_env(self) -> envs.Environment:
        """The registered env rendering ``frame_stack`` stacked frames of ``frame_size`` pixels."""
        return envs.make(
            self.env_id,
            frame_size=self.frame_size,
            frame_stack=self.frame_stack,
            **envs.parse_keywords(self.env_kwargs),
        )

    def conv_rows(self) -> tuple[int, ...]:
        """``(first, stop)``, the frame rows the conv torso sees, or ``()`` for all."""
        env = self.make_env()
        if not self.crop_drawn_rows or not hasattr(env, "drawn_rows"):
            return ()
        return conv.covering_rows(self.conv_layers, *env.drawn_rows(), self.frame_size)


#: Envs observed as images that are not frames (MinAtar's 10x10xC grids of 0/1): their config is
#: an ``ImageConfig``.
IMAGE_ENVS = envs.MINATAR_IDS


@dataclasses.dataclass(frozen=True, kw_only=True)
class ImageConfig(Config, ImageObservations):
    """DQN on image observations (``IMAGE_ENVS``): a conv torso before ``hidden``, by default the
    MinAtar paper's network (16 3x3 filters of stride 1, then 128 units). The replay keeps
    whole observations; the torso scales them by the observation space's upper bound."""

    hidden: tuple[int, ...] = (128,)  # hidden ReLU layers after the conv torso
    conv_layers: tuple[int, ...] = (16, 3, 1)  # (features, kernel, stride) per layer

    def __post_init__(self) -> None:
        super().__post_init__()
        shape = self.make_env().observation_space().shape
        if len(shape) != 3:
            raise ValueError(f"{self.env_id} observations are not images: shape {shape}")
        conv.check_conv_layers(self.conv_layers, min(shape[0], shape[1]))

    def conv_rows(self) -> tuple[int, ...]:
        """``()``: the torso sees the whole image."""
        return ()


@struct.dataclass
class Hyperparams(params.HyperparamsMethods):
    """What a sweep may vary without recompiling. Defaults: CleanRL's classic-control DQN."""

    learning_rate: ArrayLike = 2.5e-4  # Adam step size
    lr_decay_steps: ArrayLike = 0.0  # env steps (all envs) for the rate to fall to 0 (0: constant)
    gamma: ArrayLike = 0.99  # discount
    tau: ArrayLike = 1.0  # target step every target_update_period updates (1: hard copy)
    epsilon_start: ArrayLike = 1.0  # exploration rate at env step 0
    epsilon_end: ArrayLike = 0.05  # exploration rate after epsilon_decay_steps
    epsilon_decay_steps: ArrayLike = 250_000.0  # env steps (all envs) of the linear epsilon decay
    huber_delta: ArrayLike = 1.0  # TD errors beyond this are penalised linearly, not squared
    max_grad_norm: ArrayLike = 10.0  # gradients are clipped to this global norm
    priority_alpha: ArrayLike = 0.6  # prioritized: P(i) proportional to priority_i^alpha
    priority_beta_start: ArrayLike = 0.4  # prioritized: importance-weight exponent at the start
    priority_beta_steps: ArrayLike = 500_000.0  # prioritized: env steps for beta to rise to 1
    priority_eps: ArrayLike = 1e-6  # prioritized: priority = |TD error| + eps
    # policy_checkpoints: the checkpoint's score is multiplied by this when assessments lengthen
    # to checkpoint_episodes (TD7: 0.9)
    checkpoint_reset_weight: ArrayLike = 0.9


# ---- state and network --------------------------------------------------------------------------
@struct.dataclass
class Agent:
    """The online and target Q-networks, the optimizer state and, with ``policy_checkpoints``,
    the checkpoint."""

    online: optax.Params  # Q-network parameters
    target: optax.Params  # target Q-network parameters
    opt_state: optax.InjectStatefulHyperparamsState  # holds the learning rate and clip norm
    # policy_checkpoints: the checkpoint of Q-network parameters (None without: the state and
    # checkpoints of runs without it stay as they were)
    checkpoint: PolicyCheckpoint | None = None


@functools.lru_cache(maxsize=64)
def make_network(config: Config) -> networks.QNetwork:
    """The Q-network for ``config`` (cached: called at every trace)."""
    space = episodes.action_space(config)
    if not isinstance(space, envs.Discrete):
        raise TypeError(f"DQN needs a discrete action space, got {space}")
    layers = networks.Layers(
        hidden=config.hidden, initializer=config.network_init, norm=config.norm
    )
    return networks.QNetwork(
        layers=layers, num_actions=space.n, dueling=config.dueling, **conv_settings(config)
    )


def conv_settings(config: Config) -> dict[str, Any]:
    """The ``networks.QNetwork`` fields of a config's conv torso (none for vector obs): layers,
    rows and, for an ``ImageConfig``, the observations' largest value."""
    if isinstance(config, PixelConfig):
        return {"conv_layers": config.conv_layers, "conv_rows": config.conv_rows()}
    if not isinstance(config, ImageConfig):
        return {}
    space = episodes.observation_space(config)
    high = float(np.max(space.high)) if isinstance(space, envs.Box) else 255.0
    return {"conv_layers": config.conv_layers, "obs_high": high}


# ---- the replay (dqn_parts) ---------------------------------------------------------------------
def replay_for(config: Config) -> dqn_parts.Replay:
    """The one place where the config picks DQN's replay: ``Config.prioritized`` rows, frames
    kept apart for a ``PixelConfig``."""
    frames = isinstance(config, PixelConfig)
    return dqn_parts.make_replay(config, config.n_step, config.prioritized, frames)


def init_buffer(example: Transition, config: Config) -> Buffer:
    """``replay_for(config).init``, as the loop calls it."""
    return replay_for(config).init(example)


def add_to_buffer(
    buffer: Buffer, transitions: Transition, config: Config, hparams: Hyperparams
) -> Buffer:
    """``replay_for(config).add``, as the loop calls it."""
    return replay_for(config).add(buffer, transitions, hparams)


# ---- losses on networks, one update ------------------------------------------------------------
def loss_fn(
    online: optax.Params,
    target: optax.Params,
    batch: NStepBatch,
    weights: jax.Array,
    hparams: Hyperparams,
    config: Config,
) -> tuple[jax.Array, tuple[jax.Array, jax.Array]]:
    """``(loss, (td_error [B], q_taken mean))``; the target net enters only through the
    stopped-gradient target."""
    net = make_network(config)
    q_tm1 = net.apply(online, batch.obs)
    q_t = cast(jax.Array, net.apply(target, batch.next_obs))
    legal_t = batch.next_legal  # for an env with an action mask: bootstrap over legal actions
    if config.double and legal_t is not None:
        q_t_online = cast(jax.Array, net.apply(online, batch.next_obs))
        v_t = masked_double_q_values(q_t, q_t_online, legal_t)
    elif config.double:
        v_t = double_q_values(q_t, net.apply(online, batch.next_obs))
    elif legal_t is not None:
        v_t = masked_max(q_t, legal_t)
    else:
        v_t = greedy_values(q_t)
    target_tm1 = n_step_target(batch.r_t, batch.discount_t, v_t)
    loss, td_error = q_learning_loss(q_tm1, batch.action, target_tm1, weights, hparams.huber_delta)
    return loss, (td_error, jnp.mean(target_tm1 - td_error))  # the mean q of the taken actions


def _optimizer(learning_rate: ArrayLike, max_grad_norm: ArrayLike) -> optax.GradientTransformation:
    return optax.chain(optax.clip_by_global_norm(max_grad_norm), optax.adam(learning_rate))


def learning_rate_at(env_steps: jax.Array, hparams: Hyperparams) -> jax.Array:
    """The Adam rate after ``env_steps``: linear decay to 0 over ``lr_decay_steps`` (if > 0).
    DQN's greedy policy on CartPole otherwise keeps collapsing and recovering long after it first
    scores 500."""
    return linearly_decayed(hparams.learning_rate, env_steps, hparams.lr_decay_steps)


def _gradient_step(
    agent: Agent, grads: optax.Updates, hparams: Hyperparams, env_steps: jax.Array
) -> Agent:
    online, opt_state = injected_step(
        _optimizer,
        grads,
        agent.opt_state,
        agent.online,
        learning_rate=learning_rate_at(env_steps, hparams),
        max_grad_norm=hparams.max_grad_norm,
    )
    return agent.replace(online=online, opt_state=opt_state)


def shifted_batch(batch: NStepBatch, key: jax.Array, shift: int) -> NStepBatch:
    """DrQ's random shifts (``PixelConfig.augment_shift``): obs and next_obs apart."""
    obs_key, next_key = jax.random.split(jax.random.fold_in(key, 1))
    return batch._replace(
        obs=augment.random_shift(obs_key, batch.obs, shift),
        next_obs=augment.random_shift(next_key, batch.next_obs, shift),
    )


def update(
    agent: Agent,
    buffer: Buffer,
    key: jax.Array,
    config: Config,
    hparams: Hyperparams,
    update_index: jax.Array,
) -> tuple[Agent, Buffer, dict[str, jax.Array]]:
    """One gradient update, then (when due) a target step and new priorities."""
    replay = replay_for(config)
    batch, weights, indices = replay.sample(buffer, key, hparams, update_index)
    if isinstance(config, PixelConfig) and config.augment_shift:
        batch = shifted_batch(batch, key, config.augment_shift)
    (loss, (td_error, q)), grads = jax.value_and_grad(loss_fn, has_aux=True)(
        agent.online, agent.target, batch, weights, hparams, config
    )
    env_steps = offpolicy.env_steps_at_update(update_index, config)
    agent = _gradient_step(agent, grads, hparams, env_steps)
    due = (update_index + 1) % config.target_update_period == 0
    target = jax.lax.cond(
        due, lambda: polyak_update(agent.target, agent.online, hparams.tau), lambda: agent.target
    )
    agent = agent.replace(target=target)
    buffer = replay.write_priorities(buffer, indices, td_error, hparams)
    epsilon = epsilon_at(env_steps, hparams)
    return agent, buffer, {"loss": loss, "q": q, "epsilon": epsilon}


# ---- acting -------------------------------------------------------------------------------------
def epsilon_at(env_steps: jax.Array, hparams: Hyperparams) -> jax.Array:
    """The exploration rate after ``env_steps``: linear from ``epsilon_start`` to
    ``epsilon_end`` over ``epsilon_decay_steps``, then constant."""
    return linear_schedule(
        hparams.epsilon_start, hparams.epsilon_end, env_steps, hparams.epsilon_decay_steps
    )


def greedy(
    params: optax.Params, obs: jax.Array, config: Config, legal: jax.Array | None = None
) -> jax.Array:
    """Greedy actions ``[N]`` int32 of the Q-network ``params`` (among the ``legal`` ones, bool
    ``[N, A]``, for an env with an action mask)."""
    return greedy_actions(make_network(config), params, obs, legal)


def greedy_actions(
    net: networks.QNetwork, params: optax.Params, obs: jax.Array, legal: jax.Array | None = None
) -> jax.Array:
    """Greedy actions ``[N]`` int32 of ``net`` at ``params`` (legal ones, given ``legal``)."""
    if legal is not None:
        return masked_argmax(cast(jax.Array, net.apply(params, obs)), legal)
    return jnp.argmax(net.apply(params, obs), axis=-1).astype(jnp.int32)


def act(agent: Agent, obs: jax.Array, config: Config, legal: jax.Array | None = None) -> jax.Array:
    """Greedy actions ``[N]`` int32: of the online network, or the checkpoint's (legal ones,
    given the env's mask ``legal``)."""
    return greedy(policy_params(agent, config), obs, config, legal)


def policy_params(agent: Agent, config: Config) -> optax.Params:
    """The Q-network whose greedy policy is evaluated, saved as best/ and loaded."""
    return agent.checkpoint.best if config.policy_checkpoints else agent.online


def explore(
    agent: Agent,
    obs: jax.Array,
    noise: jax.Array,
    key: jax.Array,
    config: Config,
    hparams: Hyperparams,
    clock: Clock,
    legal: jax.Array | None = None,
) -> tuple[jax.Array, jax.Array]:
    """``(actions, noise)``. Epsilon-greedy: a uniform action with probability epsilon(env steps),
    else greedy (with ``policy_checkpoints``, the assessed copy's); both among the ``legal``
    actions (bool ``[N, A]``) for an env with an action mask. Independent from step to step,
    so the carried ``noise`` state is passed through."""
    net = make_network(config)
    acting = agent.checkpoint.assessed if config.policy_checkpoints else agent.online
    if legal is not None:
        epsilon = epsilon_at(clock.env_steps, hparams)
        q = cast(jax.Array, net.apply(acting, obs))
        return masked_epsilon_greedy(key, q, legal, epsilon), noise
    exploit = greedy_actions(net, acting, obs)
    epsilon = epsilon_at(clock.env_steps, hparams)
    return epsilon_greedy(key, exploit, net.num_actions, epsilon), noise


def observe(
    agent: Agent,
    transitions: Transition,
    episode_return: jax.Array,
    done: jax.Array,
    clock: Clock,
    config: Config,
    hparams: Hyperparams,
) -> Agent:
    """Every env step: policy checkpoints count the episodes that ended."""
    return policy_checkpoints.observe_online(
        agent, episode_return, done, clock, config, hparams.checkpoint_reset_weight
    )


# ---- init and the loop's learner ----------------------------------------------------------------
def init_agent(
    key: jax.Array,
    config: Config,
    hparams: Hyperparams,
    obs_space: envs.Space,
    action_space: envs.Space,
) -> Agent:
    """A fresh agent: the target network a copy of the online one (and a checkpoint of
    it with ``policy_checkpoints``)."""
    online = make_network(config).init(key, jnp.zeros(obs_space.shape, jnp.float32))
    optimizer = optax.inject_hyperparams(_optimizer)(hparams.learning_rate, hparams.max_grad_norm)
    opt_state = optimizer.init(online)
    agent = Agent(online=online, target=online, opt_state=opt_state)
    if config.policy_checkpoints:
        checkpoint = policy_checkpoints.init(online, config.num_envs, config.learning_starts)
        agent = agent.replace(checkpoint=checkpoint)
    return agent


LEARNER = offpolicy.Learner(
    init_agent,
    explore,
    act,
    update,
    ("loss", "q", "epsilon"),
    init_buffer,
    add_to_buffer,
    observe,
)


# ---- recipes ------------------------------------------------------------------------------------
# Each env's default on top of the Config and Hyperparams defaults (CleanRL's classic-control
# DQN), each with the reason it was chosen and a link to the runs that chose it.

# The classic-control base: wider layers, a faster rate and a short epsilon decay (as in
# rl-baselines3-zoo's tuned DQN), with 4 envs and one update per 2 env steps.
_CLASSIC: dict[str, Setting] = {
    "num_envs": 4,
    "updates_per_iteration": 2,
    "iterations_per_chunk": 1000,
    "learning_starts": 1000,
    "buffer_size": 100_000,
    "batch_size": 64,
    "hidden": (256, 256),
    "target_update_period": 100,
}
# CartPole: the policy a run ends with is TD7's checkpoint, since the greedy policy alone keeps
# collapsing and recovering after it first scores 500 (RESULTS.md#dqn-on-cartpole).
_CARTPOLE: dict[str, Setting] = {
    **_CLASSIC,
    "hidden": (64, 64),  # enough here, at a fraction of 256x256's cost
    "n_step": 3,
    "policy_checkpoints": True,
    "checkpoint_episodes": 20,  # TD7's; fewer let checkpoints short of 500 through
    "checkpoint_episodes_from": 20_000,
}
_CONFIGS: dict[str, dict[str, Setting]] = {
    "rl_jax/CartPole-v1": _CARTPOLE,
    # Pixels: the settings that got the conv torso learning (RESULTS.md#dqn-from-pixels).
    "rl_jax/CartPolePixels-v1": {
        **_CLASSIC,
        "hidden": (256,),
        "buffer_size": 50_000,  # frame pairs: about 0.7 GB per seed
        "batch_size": 32,
        "updates_per_iteration": 1,  # one update per 4 env steps
        "double": True,
        "n_step": 3,
        "target_update_period": 500,
        "crop_drawn_rows": True,  # the other rows are always white: the same net, cheaper
        "norm": "layer",  # learns faster than without
    },
    "rl_jax/InvertedPendulum-v5": _CLASSIC,
    "rl_jax/Rocket-v0": {**_CLASSIC, "action_bins": 3},
    # The settle variant: finer thrust and LayerNorm bring every seed to rest
    # (RESULTS.md#the-rocket).
    "rl_jax/RocketSettle-v0": {**_CLASSIC, "action_bins": 5, "norm": "layer"},
}
_FAST_DECAY = {"learning_rate": 1e-3, "epsilon_decay_steps": 8000.0, "epsilon_end": 0.04}
_HPARAMS: dict[str, dict[str, float]] = {
    # A constant rate (the checkpoint keeps what was learned); epsilon 0.01 after 8k steps, so
    # that the training episodes that assess a copy are nearly its greedy policy's.
    "rl_jax/CartPole-v1": {**_FAST_DECAY, "learning_rate": 3e-3, "epsilon_end": 0.01},
    # The rate falls to 0 over the script's 200k steps, so that the policy the run ends with is a
    # settled one: at a constant rate it kept collapsing and recovering.
    "rl_jax/CartPolePixels-v1": {**_FAST_DECAY, "learning_rate": 5e-4, "lr_decay_steps": 200_000.0},
    "rl_jax/InvertedPendulum-v5": _FAST_DECAY,
    "rl_jax/Rocket-v0": {"learning_rate": 1e-3, "epsilon_decay_steps": 50_000.0},
    # gamma 0.995 as TD3's rocket recipe: at 0.99 creeping in scores about as well as arriving.
    "rl_jax/RocketSettle-v0": {
        "learning_rate": 1e-3,
        "epsilon_decay_steps": 50_000.0,
        "gamma": 0.995,
    },
}

# MinAtar: the MinAtar paper's DQN (Young & Tian 2019, its repository's examples/dqn.py): the
# 16x3x3 conv + 128 network, batch 32, a 100k replay filled with 5k random steps first, one update
# per env step, a hard target copy every 1,000 updates, gamma 0.99, epsilon 1 to 0.1 over the
# first 100k steps, step size 2.5e-4, on MinAtar's sticky actions (0.1; gymnax has none, the env's
# ``sticky_actions`` keyword adds them). The paper's RMSProp (alpha 0.95, centred) is Adam here, as
# in all our DQN recipes. 4 envs with 4 updates per iteration keep one update per env step.
MINATAR_CONFIG: dict[str, Setting] = {
    "env_kwargs": "sticky_actions=0.1",
    "num_envs": 4,
    "updates_per_iteration": 4,
    "iterations_per_chunk": 12_500,  # evaluated every 50k env steps, 1% of the paper's budget
    "learning_starts": 5000,
    "buffer_size": 100_000,
    "batch_size": 32,
    "hidden": (128,),
    "conv_layers": (16, 3, 1),
    "target_update_period": 1000,
}
MINATAR_HPARAMS: dict[str, Setting] = {
    "learning_rate": 2.5e-4,
    "gamma": 0.99,
    "epsilon_start": 1.0,
    "epsilon_end": 0.1,
    "epsilon_decay_steps": 100_000.0,
}

# Atari: Nature DQN (Mnih et al. 2015): its network (32 8x8/4, 64 4x4/2, 64 3x3/1, 512 units), a
# replay of 1M steps filled with 50k random steps first (13 GB per seed, as much again while a
# checkpoint is written; --buffer-size scales it down), one update per 4 env steps, batch 32, a
# hard target copy every 10,000 updates, gamma 0.99, epsilon 1 to 0.1 over the first 1M steps,
# step size 2.5e-4 (Adam here, RMSProp there), a lost life ending the episode, rewards clipped to
# their sign, up to 30 no-op starts and no sticky actions. Not yet run to a result here.
NATURE_CONFIG: dict[str, Setting] = {
    "env_kwargs": "episodic_life=True, clip_rewards=True, repeat_action_probability=0.0",
    "num_envs": 4,
    "updates_per_iteration": 1,
    "iterations_per_chunk": 62_500,  # evaluated every 250k env steps
    "learning_starts": 50_000,
    "buffer_size": 1_000_000,
    "batch_size": 32,
    "hidden": (512,),
    "conv_layers": (32, 8, 4, 64, 4, 2, 64, 3, 1),
    "target_update_period": 10_000,
}
NATURE_HPARAMS: dict[str, Setting] = {
    "learning_rate": 2.5e-4,
    "gamma": 0.99,
    "epsilon_start": 1.0,
    "epsilon_end": 0.1,
    "epsilon_decay_steps": 1_000_000.0,
}

_ABOUT = {
    "rl_jax/CartPole-v1": "64x64, 3-step returns, rate 3e-3, TD7's policy checkpoints",
    "rl_jax/CartPolePixels-v1": "conv torso, Double DQN, 3-step returns, LayerNorm, rate to 0",
    "rl_jax/InvertedPendulum-v5": "the classic-control base: 256x256, 4 envs, rate 1e-3",
    "rl_jax/Rocket-v0": "the classic-control base, thrust {-1, 0, +1}",
    "rl_jax/RocketSettle-v0": "thrust {-1, -0.5, 0, 0.5, 1}, LayerNorm, gamma 0.995",
}
# (env steps/s per seed, seeds) for run plans' estimates, measured as
# docs/learners/dqn.md#how-the-recipes-were-chosen says
_THROUGHPUT = {"rl_jax/CartPolePixels-v1": (117.0, 3)}
RECIPES = Recipes(
    *(
        Recipe(
            "default",
            about,
            _CONFIGS[env_id],
            _HPARAMS.get(env_id, {}),
            envs=(env_id,),
            throughput=_THROUGHPUT.get(env_id),
        )
        for env_id, about in _ABOUT.items()
    ),
    Recipe(
        "default",
        "the MinAtar paper's DQN: conv 16 3x3 + 128, batch 32, 100k replay, sticky actions 0.1",
        MINATAR_CONFIG,
        MINATAR_HPARAMS,
        envs=IMAGE_ENVS,
        total_steps=5_000_000,
    ),
    Recipe(
        "nature",
        "Nature DQN: its conv torso + 512, 1M replay, lives and reward signs (not yet run here)",
        NATURE_CONFIG,
        NATURE_HPARAMS,
        envs=envs.ATARI_IDS,
        total_steps=10_000_000,
    ),
)


# ---- the Algorithm object -----------------------------------------------------------------------
class DQN(offpolicy.OffPolicyAlgorithm[Config]):
    """DQN as an ``rl_jax.training.algorithm.Algorithm``."""

    name = "dqn"
    config_type, hparams_type = Config, Hyperparams
    recipes = RECIPES
    learner = LEARNER
    # Gradients are always clipped here: a norm of 0 would zero them (REINFORCE's 0 means off).
    ranges = {"max_grad_norm": validation.POSITIVE}

    def default_config(self, env_id: str, recipe: str | None = None, **overrides: Any) -> Config:
        """The recipe's ``Config``; a ``PixelConfig`` for the envs of ``PIXEL_ENVS``, an
        ``ImageConfig`` for those of ``IMAGE_ENVS``."""
        if env_id not in PIXEL_ENVS + IMAGE_ENVS:
            return super().default_config(env_id, recipe, **overrides)
        values = {**self.recipe(env_id, recipe).config, **overrides}
        if env_id in IMAGE_ENVS:
            return ImageConfig(env_id=env_id, **values)
        return PixelConfig(env_id=env_id, **values)

    def policy(self, state: TrainState, config: Config) -> Callable[..., jax.Array]:
        """``obs -> action index`` of the greedy policy of one seed's state (with
        ``policy_checkpoints``, the checkpoint's); for an env with an action mask
        ``(obs, legal) -> action index``, the best legal action."""
        params = policy_params(state.agent, config)
        return lambda obs, legal=None: greedy(params, obs, config, legal)

    def make_env(self, config: Config) -> envs.Environment:
        """The env the policy acts in (discretised actions), for rendering."""
        return episodes.make_eval_env(config)

    def loop_seeds(self, config: Config) -> bool:
        """Seeds as an unrolled loop where a ``PixelConfig`` asks for it (conv nets on CPU)."""
        return isinstance(config, PixelConfig) and config.loop_seeds


dqn = DQN()
default_config, default_hyperparams = dqn.default_config, dqn.default_hyperparams
init, train_chunk = dqn.init, dqn.train_chunk
