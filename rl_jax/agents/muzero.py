"""MuZero (Schrittwieser et al. 2020) with Gumbel root search (Danihelka et al. 2022, "Policy
improvement by planning with Gumbel"), on single-agent envs with discrete actions.

Three small networks make a learned model: the representation ``h(obs) -> latent``, the
dynamics ``g(latent, action) -> (latent, reward)`` and the prediction ``f(latent) -> (policy,
value)``; rewards and values are categorical on an integer support after the rescaling ``h``
(``muzero_parts``). The search is mctx's ``gumbel_muzero_policy`` over that model.

One *iteration*: ``num_envs`` vmapped envs (autoreset) each take ``num_steps`` steps, every
action the (Gumbel) search's with ``num_simulations`` simulations; the steps go into a ring of
each env's trajectory with the search's improved policy and root value. Then
``updates_per_iteration`` AdamW steps, each on ``batch_size`` windows of ``unroll_steps + td_steps
+ 1`` consecutive steps drawn uniformly (or, with ``prioritized``, by the value error at their
start): from the window's first observation the model unrolls
``unroll_steps`` of the stored actions, trained towards the improved policies, the rewards and
``td_steps``-step value targets that bootstrap from the target network's value (an EMA of the
network, step ``tau``) of the stored next observations (``muzero_parts.unroll_loss``).

A *chunk* is ``iterations_per_chunk`` iterations, then one evaluation of the deterministic
search (no Gumbel noise): ``num_envs * num_steps * iterations_per_chunk`` env steps.

With ``model = "simulator"`` the model is the env itself (``muzero_simulator``): AlphaZero on a
single-agent env. The search starts from each env's state and steps the true env; the network is
only the prediction ``f(obs) -> (policy, value)``, trained at the window's first step (K = 0, no
reward loss) towards the same targets. Acting and the learner's evaluation search from env
states; ``policy`` (``load_policy``, GIFs, ``rl-jax evaluate``) sees only an observation, so there
it is the prediction network's greedy action, without a search.

On image envs (MinAtar's grids, ``IMAGE_ENVS``) the config is an ``ImageConfig``: the
representation network reads the observation through a conv torso first.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import NamedTuple, NoReturn, cast

import flax.linen as nn
import jax
import jax.numpy as jnp
import mctx
import optax
from flax import struct

from rl_jax import envs
from rl_jax.agents import muzero_parts as parts
from rl_jax.agents import muzero_simulator as simulator
from rl_jax.agents.common import (
    clip_by_global_norm,
    injected_step,
    linearly_decayed,
    polyak_update,
)
from rl_jax.envs.core.wrappers import StatisticsState
from rl_jax.training import conv, episodes, networks, params, validation
from rl_jax.training.algorithm import ChunkMetrics, Clock, RecipeBook
from rl_jax.training.episodes import ImageObservations
from rl_jax.training.networks import Params
from rl_jax.training.params import Scalar
from rl_jax.training.recipes import Recipe, Recipes, Setting

BOOTSTRAPS = ("target", "search")
MODELS = ("learned", "simulator")


# ---- settings -------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True, kw_only=True)
class Config:
    """Static settings (changing one recompiles)."""

    env_id: str
    num_envs: int = 16  # envs stepped together (vmapped), each with its own episode
    num_steps: int = 4  # steps of every env per iteration, before its updates
    iterations_per_chunk: int = 100  # iterations per compiled call; eval after each call
    num_simulations: int = 16  # simulations of the search at every step
    max_considered_actions: int = 16  # root actions Gumbel sampling considers
    unroll_steps: int = 5  # K: steps the model is unrolled in training
    td_steps: int = 10  # n: rewards summed before a value target bootstraps
    # where value targets bootstrap: "target", the target network's value of the stored next
    # observation; "search", the root value the search had there when acting
    bootstrap: str = "target"
    buffer_size: int = 100_000  # steps the replay keeps, all envs (each env num_envs-th of it)
    # draw windows by priority (priority_exponent, importance_exponent) rather than uniformly
    prioritized: bool = False
    batch_size: int = 256  # windows per gradient update
    updates_per_iteration: int = 8  # gradient updates after each iteration's steps
    warm_up: int = 1_000  # env steps per seed before the first update
    latent_size: int = 64  # the hidden state's width
    hidden: tuple[int, ...] = (64,)  # hidden layers of each of the three networks
    value_support: int = 20  # values are categorical on the integers -S .. S after h
    reward_support: int = 5  # rewards are categorical on -S .. S after h
    num_eval_envs: int = 10  # episodes of the deterministic search per evaluation
    # the search's model: "learned", MuZero's networks; "simulator", the true env stepped from
    # the env states (AlphaZero on a single-agent env: K = 0, no reward or dynamics to learn)
    model: str = "learned"

    def __post_init__(self) -> None:
        for name in (
            "num_envs",
            "num_steps",
            "iterations_per_chunk",
            "num_simulations",
            "max_considered_actions",
            "unroll_steps",
            "td_steps",
            "batch_size",
            "updates_per_iteration",
            "latent_size",
            "value_support",
            "reward_support",
            "num_eval_envs",
        ):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.bootstrap not in BOOTSTRAPS:
            raise ValueError(f"bootstrap must be one of {BOOTSTRAPS}, got {self.bootstrap!r}")
        if self.model not in MODELS:
            raise ValueError(f"model must be one of {MODELS}, got {self.model!r}")
        if self.replay_rows < self.num_steps:
            raise ValueError(
                f"buffer_size ({self.buffer_size}) must hold one iteration's num_steps "
                f"({self.num_steps}) in each of the {self.num_envs} envs"
            )
        if self.replay_rows <= self.window:
            unrolled = "unroll_steps" if self.model == "learned" else "0 (the simulator)"
            raise ValueError(
                f"buffer_size ({self.buffer_size}) must hold more than one window of "
                f"{unrolled} + td_steps + 1 = {self.window} steps in each of the "
                f"{self.num_envs} envs"
            )

    @property
    def unrolled(self) -> int:
        """Steps the model is unrolled in training: ``unroll_steps``, 0 with the simulator."""
        return 0 if self.model == "simulator" else self.unroll_steps

    @property
    def window(self) -> int:
        """Consecutive steps one training sample reads: ``unrolled + td_steps + 1``."""
        return self.unrolled + self.td_steps + 1

    @property
    def replay_rows(self) -> int:
        """Steps of each env's trajectory the replay keeps."""
        return self.buffer_size // self.num_envs

    def make_env(self) -> envs.Environment:
        """The registered env."""
        return envs.make(self.env_id)


#: Envs observed as images: their config is an ``ImageConfig``.
IMAGE_ENVS = envs.MINATAR_IDS


@dataclasses.dataclass(frozen=True, kw_only=True)
class ImageConfig(Config, ImageObservations):
    """MuZero on image observations (``IMAGE_ENVS``): the representation network reads the
    ``[H, W, C]`` observation through ``conv.ConvTorso`` before its ``hidden`` layers; the
    dynamics and prediction networks stay MLPs on the hidden state."""

    # (features, kernel, stride) per conv layer: the MinAtar paper's network, 16 3x3 filters
    conv_layers: tuple[int, ...] = (16, 3, 1)

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.model == "simulator":
            raise ValueError(
                "model 'simulator' reads flat observations; image envs train the learned model"
            )
        shape = self.make_env().observation_space().shape
        if len(shape) != 3:
            raise ValueError(f"{self.env_id} observations are not images: shape {shape}")
        conv.check_conv_layers(self.conv_layers, min(shape[0], shape[1]))


@struct.dataclass
class Hyperparams(params.HyperparamsMethods):
    """What a sweep may vary without recompiling."""

    learning_rate: Scalar = 1e-3  # AdamW's step size at the start
    lr_decay_steps: Scalar = 0.0  # env steps (one seed) over which it falls to 0 (0: constant)
    weight_decay: Scalar = 1e-4  # AdamW's decoupled weight decay
    max_grad_norm: Scalar = 5.0  # clip the gradient's global norm to this (0: no clipping)
    gamma: Scalar = 0.997  # discount, of the targets and inside the search
    value_coef: Scalar = 0.25  # weight of the value loss beside the policy and reward losses
    tau: Scalar = 0.01  # step of the target network towards the network, per update
    # prioritized: a window is drawn with chance priority^alpha, its priority the value error
    # at its start when last drawn (new steps: the largest so far)
    priority_exponent: Scalar = 0.6
    importance_exponent: Scalar = 0.4  # prioritized: importance weights (count P)^-beta


# ---- the networks ---------------------------------------------------------------------------
class MuZeroNet(nn.Module):
    """The representation, dynamics and prediction MLPs; hidden states are min-max scaled to
    [0, 1] (``muzero_parts.scale_latent``), on the scale of the one-hot action beside them.
    With ``conv_layers`` the representation reads image observations through a conv torso
    (``conv.ConvTorso``; pixels divided by ``obs_high``) first."""

    num_actions: int
    latent_size: int
    hidden: tuple[int, ...]
    value_bins: int
    reward_bins: int
    conv_layers: tuple[int, ...] = ()
    obs_high: float = 1.0  # image observations' largest value (MinAtar's grids: 1)

    def setup(self) -> None:
        layers = networks.Layers(hidden=self.hidden)
        self.torso = conv.ConvTorso(self.conv_layers, high=self.obs_high)
        self.representation = networks.MLP(layers, self.latent_size)
        self.dynamics = networks.MLP(layers, self.latent_size + self.reward_bins)
        self.prediction = networks.MLP(layers, self.num_actions + self.value_bins)

    def predict(self, latent: jax.Array) -> tuple[jax.Array, jax.Array]:
        """``(policy logits [B, A], value logits [B, V])`` of hidden states ``[B, L]``."""
        out = self.prediction(latent)
        return out[..., : self.num_actions], out[..., self.num_actions :]

    def initial(self, obs: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
        """``(latent, policy logits, value logits)`` of observations ``[B, ...]``."""
        features = self.torso(obs) if self.conv_layers else obs.reshape(obs.shape[0], -1)
        latent = parts.scale_latent(self.representation(features))
        return (latent, *self.predict(latent))

    def recurrent(
        self, latent: jax.Array, action: jax.Array
    ) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
        """``(next latent, reward logits, policy logits, value logits)`` after ``action [B]``."""
        inputs = jnp.concatenate([latent, jax.nn.one_hot(action, self.num_actions)], axis=-1)
        out = self.dynamics(inputs)
        next_latent = parts.scale_latent(out[..., : self.latent_size])
        return (next_latent, out[..., self.latent_size :], *self.predict(next_latent))

    def __call__(self, obs: jax.Array, action: jax.Array) -> tuple[jax.Array, ...]:
        """Every network once (what ``init`` traces)."""
        latent, *_ = self.initial(obs)
        return self.recurrent(latent, action)


@functools.lru_cache(maxsize=64)
def make_network(config: Config) -> MuZeroNet | simulator.PredictionNet:
    """The networks for ``config`` (cached: called at every trace): the prediction network
    alone with the simulator as the model."""
    space = episodes.action_space(config)
    if not isinstance(space, envs.Discrete):
        raise TypeError(f"MuZero needs discrete actions; {config.env_id} has {space}")
    if config.model == "simulator":
        return simulator.PredictionNet(space.n, config.hidden, 2 * config.value_support + 1)
    conv_layers: tuple[int, ...] = ()
    obs_high = 1.0
    if isinstance(config, ImageConfig):
        obs_space = episodes.observation_space(config)
        assert isinstance(obs_space, envs.Box)  # images: ImageConfig checked their shape
        conv_layers, obs_high = config.conv_layers, float(obs_space.high.max())
    return MuZeroNet(
        num_actions=space.n,
        latent_size=config.latent_size,
        hidden=config.hidden,
        value_bins=2 * config.value_support + 1,
        reward_bins=2 * config.reward_support + 1,
        conv_layers=conv_layers,
        obs_high=obs_high,
    )


def model_fns(net_params: Params, config: Config) -> tuple[parts.InitialFn, parts.RecurrentFn]:
    """The network's ``(initial, recurrent)`` functions with ``net_params`` bound. With the
    simulator, ``initial`` is the prediction network's (the observation is its hidden state)
    and there is no ``recurrent`` to call (K = 0)."""
    network = make_network(config)
    if isinstance(network, simulator.PredictionNet):

        def predict_initial(obs: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
            return network.apply(net_params, obs, method=simulator.PredictionNet.initial)  # type: ignore[return-value]

        def no_recurrent(latent: jax.Array, action: jax.Array) -> NoReturn:
            raise ValueError("the simulator is the model: there is no learned dynamics")

        return predict_initial, no_recurrent

    def initial(obs: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
        return network.apply(net_params, obs, method=MuZeroNet.initial)  # type: ignore[return-value]

    def recurrent(
        latent: jax.Array, action: jax.Array
    ) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
        return network.apply(net_params, latent, action, method=MuZeroNet.recurrent)  # type: ignore[return-value]

    return initial, recurrent


# ---- the state ------------------------------------------------------------------------------
@struct.dataclass
class Agent:
    """What the policy reads, the target network and the optimizer."""

    params: Params
    target_params: Params  # an EMA of params: the value targets bootstrap from it
    opt_state: optax.OptState
    gamma: jax.Array  # [] the search's discount (the hyperparameter's, kept for the policy)


class Replay(NamedTuple):
    """Each env's last ``replay_rows`` steps, a time-major ring ``[L, N, ...]``."""

    obs: jax.Array  # the observation acted on
    action: jax.Array  # int32
    reward: jax.Array
    terminated: jax.Array  # bool
    truncated: jax.Array  # bool
    next_obs: jax.Array  # the true next observation (the one that ended an episode, there)
    policy: jax.Array  # [L, N, A] the search's improved policy
    root_value: jax.Array  # the search's value of obs
    priority: jax.Array  # the value error of a window starting here, when it was last drawn
    written: jax.Array  # [] int32, steps written per env so far


@struct.dataclass
class TrainState:
    """One seed's training state."""

    agent: Agent
    replay: Replay
    env_state: StatisticsState  # [num_envs, ...] of the train env (episodes.make_train_env)
    obs: jax.Array  # [num_envs, *obs_shape], the observation the next action answers
    key: jax.Array
    clock: Clock
    train_return: jax.Array  # [] float32, mean return of the episodes ended in the last chunk


# ---- the search -----------------------------------------------------------------------------
def search(
    agent: Agent, obs: jax.Array, key: jax.Array, config: Config, gumbel_scale: float = 1.0
) -> mctx.PolicyOutput:
    """Gumbel MuZero's search over the learned model from observations ``[B, ...]``;
    ``gumbel_scale`` 0 makes it deterministic."""
    initial, recurrent = model_fns(agent.params, config)
    latent, logits, value_logits = initial(obs)
    value = parts.logits_to_scalar(value_logits, config.value_support)
    root = mctx.RootFnOutput(prior_logits=logits, value=value, embedding=latent)

    def recurrent_fn(
        net_params: Params, key: jax.Array, action: jax.Array, latent: jax.Array
    ) -> tuple[mctx.RecurrentFnOutput, jax.Array]:
        del net_params, key  # bound above; the model is deterministic
        latent, reward_logits, logits, value_logits = recurrent(latent, action)
        reward = parts.logits_to_scalar(reward_logits, config.reward_support)
        output = mctx.RecurrentFnOutput(
            reward=reward,
            discount=jnp.broadcast_to(agent.gamma, reward.shape),
            prior_logits=logits,
            value=parts.logits_to_scalar(value_logits, config.value_support),
        )
        return output, latent

    return mctx.gumbel_muzero_policy(
        agent.params,
        key,
        root,
        recurrent_fn,
        config.num_simulations,
        max_num_considered_actions=min(config.max_considered_actions, logits.shape[-1]),
        gumbel_scale=gumbel_scale,
    )


def simulator_search(
    agent: Agent,
    env_state: envs.EnvState,
    obs: jax.Array,
    key: jax.Array,
    config: Config,
    gumbel_scale: float = 1.0,
) -> mctx.PolicyOutput:
    """The search with the simulator as the model (``muzero_simulator.search``) from the eval
    env's states ``env_state [B, ...]``, observed as ``obs``."""
    network = make_network(config)

    def predict(obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        return network.apply(agent.params, obs, method=simulator.PredictionNet.predict)  # type: ignore[return-value]

    settings = (config.num_simulations, config.max_considered_actions, config.value_support)
    env = episodes.make_eval_env(config)
    return simulator.search(predict, env, env_state, obs, key, agent.gamma, settings, gumbel_scale)


def act(agent: Agent, obs: jax.Array, config: Config) -> jax.Array:
    """The deterministic policy of observations ``[B, ...]``: the search's action without
    Gumbel noise (the key is then unused)."""
    return search(agent, obs, jax.random.key(0), config, gumbel_scale=0.0).action


# ---- acting and the replay ------------------------------------------------------------------
class Steps(NamedTuple):
    """``num_steps`` steps of every env, ``[T, N, ...]``: the replay's rows, and the returns."""

    rows: Replay  # its ``written`` is 0
    episode_return: jax.Array  # the return of an episode that ended at this step, else 0


def collect(state: TrainState, key: jax.Array, config: Config) -> tuple[TrainState, Steps]:
    """``num_steps`` steps of every env, each action the Gumbel search's."""
    env = episodes.make_train_env(config)

    def step(
        carry: tuple[StatisticsState, jax.Array], key: jax.Array
    ) -> tuple[tuple[StatisticsState, jax.Array], Steps]:
        env_state, obs = carry
        search_key, env_key = jax.random.split(key)
        if config.model == "simulator":  # the train env's state under its wrappers: the eval env's
            inner = env_state.env_state
            output = simulator_search(state.agent, inner, obs, search_key, config)
        else:
            output = search(state.agent, obs, search_key, config)
        keys = jax.random.split(env_key, config.num_envs)
        env_state, ts = jax.vmap(env.step)(keys, env_state, output.action)
        ended = jnp.logical_or(ts.terminated, ts.truncated)
        row = Replay(
            obs=obs,
            action=output.action.astype(jnp.int32),
            reward=ts.reward.astype(jnp.float32),
            terminated=ts.terminated,
            truncated=ts.truncated,
            next_obs=ts.info["final_obs"],
            policy=output.action_weights,
            root_value=output.search_tree.summary().value,
            priority=jnp.zeros(config.num_envs, jnp.float32),
            written=jnp.int32(0),
        )
        return (env_state, ts.obs), Steps(row, jnp.where(ended, ts.info["episode_return"], 0.0))

    keys = jax.random.split(key, config.num_steps)
    (env_state, obs), steps = jax.lax.scan(step, (state.env_state, state.obs), keys)
    return dataclasses.replace(state, env_state=env_state, obs=obs), steps


def replay_init(config: Config, obs: jax.Array, num_actions: int) -> Replay:
    """An empty replay, shaped by one observation."""
    rows, n = config.replay_rows, config.num_envs
    return Replay(
        obs=jnp.zeros((rows, n, *obs.shape), obs.dtype),
        action=jnp.zeros((rows, n), jnp.int32),
        reward=jnp.zeros((rows, n), jnp.float32),
        terminated=jnp.zeros((rows, n), jnp.bool_),
        truncated=jnp.zeros((rows, n), jnp.bool_),
        next_obs=jnp.zeros((rows, n, *obs.shape), obs.dtype),
        policy=jnp.zeros((rows, n, num_actions), jnp.float32),
        root_value=jnp.zeros((rows, n), jnp.float32),
        priority=jnp.zeros((rows, n), jnp.float32),
        written=jnp.int32(0),
    )


def replay_add(replay: Replay, rows: Replay) -> Replay:
    """The replay with ``rows`` (``[T, N, ...]``) written over its oldest steps, each with the
    largest priority so far (at least 1): a new window is drawn soon."""
    length, capacity = rows.action.shape[0], replay.action.shape[0]
    index = (replay.written + jnp.arange(length)) % capacity
    fields = [old.at[index].set(new) for old, new in zip(replay[:-2], rows[:-2], strict=True)]
    highest = jnp.maximum(jnp.max(replay.priority), 1.0)
    priority = replay.priority.at[index].set(highest)
    return Replay._make([*fields, priority, replay.written + length])


class Drawn(NamedTuple):
    """Where a batch of windows starts, ``[B]`` each, and their importance weights."""

    row: jax.Array  # the ring row of the first step
    env: jax.Array
    weight: jax.Array


def sample_windows(
    replay: Replay, key: jax.Array, config: Config, hparams: Hyperparams
) -> tuple[Replay, Drawn]:
    """``batch_size`` windows of ``window`` consecutive steps of one env each, ``[W, B, ...]``,
    their first step drawn among those whose window has been written: uniformly, or with
    ``prioritized`` by priority (``draw_by_priority``)."""
    capacity = replay.action.shape[0]
    if config.prioritized:
        drawn = draw_by_priority(replay, key, config, hparams)
    else:
        oldest = jnp.maximum(replay.written - capacity, 0)
        newest = jnp.maximum(replay.written - config.window, oldest)
        start_key, env_key = jax.random.split(key)
        start = jax.random.randint(start_key, (config.batch_size,), oldest, newest + 1)
        env = jax.random.randint(env_key, (config.batch_size,), 0, config.num_envs)
        drawn = Drawn(start % capacity, env, jnp.ones(config.batch_size))
    steps = (drawn.row[None] + jnp.arange(config.window)[:, None]) % capacity  # [W, B]
    fields = [field[steps, drawn.env[None]] for field in replay[:-1]]
    return Replay._make([*fields, replay.written]), drawn


def draw_by_priority(replay: Replay, key: jax.Array, config: Config, hparams: Hyperparams) -> Drawn:
    """Window starts drawn with chance ``priority^alpha`` among those whose window has been
    written (``muzero_parts.start_probabilities``), and their importance weights."""
    capacity = replay.action.shape[0]
    time = parts.ring_times(replay.written, capacity)
    valid = (time >= 0) & (time <= replay.written - config.window)
    valid = jnp.broadcast_to(valid[:, None], replay.priority.shape)
    probability, count = parts.start_probabilities(
        replay.priority, valid, hparams.priority_exponent
    )
    drawn = jax.random.choice(key, probability.shape[0], (config.batch_size,), p=probability)
    row, env = drawn // config.num_envs, drawn % config.num_envs
    weight = parts.importance_weights(probability[drawn], count, hparams.importance_exponent)
    return Drawn(row, env, weight)


# ---- training -------------------------------------------------------------------------------
def targets(
    agent: Agent, windows: Replay, hparams: Hyperparams, config: Config
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``(policy [K + 1, B, A], value [K + 1, B], reward [K, B])`` targets of windows."""
    k, n = config.unrolled, config.td_steps
    steps = k + n  # the steps whose value of the next observation the targets read
    initial, _ = model_fns(agent.target_params, config)
    next_obs = windows.next_obs[:steps]
    _, _, value_logits = initial(next_obs.reshape(-1, *next_obs.shape[2:]))
    v_next = parts.logits_to_scalar(value_logits, config.value_support).reshape(next_obs.shape[:2])
    if config.bootstrap == "search":  # the root value of the next step, unless one ended here
        ended = jnp.logical_or(windows.terminated, windows.truncated)[:steps]
        v_next = jnp.where(ended, v_next, windows.root_value[1 : steps + 1])
    values = parts.value_targets(
        windows.reward[:steps],
        windows.terminated[:steps],
        windows.truncated[:steps],
        v_next,
        hparams.gamma,
        n,
    )
    return windows.policy[: k + 1], values[: k + 1], windows.reward[:k]


def loss_fn(
    net_params: Params,
    windows: Replay,
    targets: tuple[jax.Array, jax.Array, jax.Array],
    hparams: Hyperparams,
    config: Config,
    weight: jax.Array | None = None,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """``(loss, metrics)`` of a batch of windows: ``muzero_parts.unroll_loss`` (K = 0 with the
    simulator: the policy and value losses at the window's first step)."""
    k = config.unrolled
    initial, recurrent = model_fns(net_params, config)
    policy, value, reward = targets
    return parts.unroll_loss(
        initial,
        recurrent,
        windows.obs[0],
        windows.action[:k],
        policy,
        value,
        reward,
        parts.unroll_masks(windows.terminated[:k], windows.truncated[:k]),
        (config.value_support, config.reward_support),
        hparams.value_coef,
        weight,
    )


def _adamw(learning_rate: Scalar, weight_decay: Scalar) -> optax.GradientTransformation:
    return optax.adamw(learning_rate, weight_decay=weight_decay)


def update(
    agent: Agent,
    replay: Replay,
    key: jax.Array,
    hparams: Hyperparams,
    config: Config,
    rate: jax.Array,
) -> tuple[Agent, Replay, dict[str, jax.Array]]:
    """One AdamW step at ``rate`` on ``batch_size`` windows, the target network's EMA step,
    and with ``prioritized`` the drawn windows' new priorities: the network's value error at
    their first step."""
    windows, drawn = sample_windows(replay, key, config, hparams)
    batch_targets = targets(agent, windows, hparams, config)
    if config.prioritized:
        initial, _ = model_fns(agent.params, config)
        value = parts.logits_to_scalar(initial(windows.obs[0])[2], config.value_support)
        error = jax.lax.stop_gradient(jnp.abs(value - batch_targets[1][0]))
        priority = replay.priority.at[drawn.row, drawn.env].set(error + 1e-3)
        replay = replay._replace(priority=priority)
    grads, metrics = jax.grad(loss_fn, has_aux=True)(
        agent.params, windows, batch_targets, hparams, config, drawn.weight
    )
    grads, metrics["grad_norm"] = clip_by_global_norm(grads, hparams.max_grad_norm)
    net_params, opt_state = injected_step(
        _adamw,
        grads,
        agent.opt_state,
        agent.params,
        learning_rate=rate,
        weight_decay=hparams.weight_decay,
    )
    target = polyak_update(agent.target_params, net_params, hparams.tau)
    agent = Agent(net_params, target, opt_state, agent.gamma)
    return agent, replay, metrics


IterationMetrics = tuple[dict[str, jax.Array], tuple[jax.Array, jax.Array]]


def train_iteration(
    state: TrainState, config: Config, hparams: Hyperparams
) -> tuple[TrainState, IterationMetrics]:
    """``num_steps`` searched steps of every env into the replay, then the updates (once
    ``warm_up`` env steps are in)."""
    key, collect_key, update_key = jax.random.split(state.key, 3)
    state, steps = collect(state, collect_key, config)
    replay = replay_add(state.replay, steps.rows)
    rate = linearly_decayed(hparams.learning_rate, state.clock.env_steps, hparams.lr_decay_steps)

    Carry = tuple[Agent, jax.Array]

    def one_update(carry: Carry, key: jax.Array) -> tuple[Carry, dict[str, jax.Array]]:
        agent, priority = carry
        current = replay._replace(priority=priority)
        agent, current, metrics = update(agent, current, key, hparams, config, rate)
        return (agent, current.priority), metrics

    update_keys = jax.random.split(update_key, config.updates_per_iteration)
    (agent, priority), metrics = jax.lax.scan(
        one_update, (state.agent, replay.priority), update_keys
    )
    env_steps = state.clock.env_steps + config.num_envs * config.num_steps
    ready = env_steps >= max(config.warm_up, config.num_envs * config.window)
    agent = jax.tree.map(lambda new, old: jnp.where(ready, new, old), agent, state.agent)
    replay = replay._replace(priority=jnp.where(ready, priority, replay.priority))
    clock = Clock(
        env_steps=env_steps,
        updates=state.clock.updates + jnp.where(ready, config.updates_per_iteration, 0),
        iterations=state.clock.iterations + 1,
    )
    state = dataclasses.replace(state, agent=agent, replay=replay, key=key, clock=clock)
    ended = jnp.logical_or(steps.rows.terminated, steps.rows.truncated)
    metrics = {
        **jax.tree.map(jnp.mean, metrics),
        "learning_rate": rate,
        "root_value": jnp.mean(steps.rows.root_value),
    }
    return state, (metrics, (jnp.sum(steps.episode_return), jnp.sum(ended)))


def init(key: jax.Array, config: Config, hparams: Hyperparams) -> TrainState:
    """A fresh state for one seed and one hyperparameter set."""
    env = episodes.make_train_env(config)
    network = make_network(config)
    net_key, env_key, key = jax.random.split(key, 3)
    env_state, ts = jax.vmap(env.reset)(jax.random.split(env_key, config.num_envs))
    net_params = network.init(net_key, ts.obs[:1], jnp.zeros((1,), jnp.int32))
    optimizer = optax.inject_hyperparams(_adamw)(hparams.learning_rate, hparams.weight_decay)
    gamma = jnp.asarray(hparams.gamma, jnp.float32)
    zero = jnp.int32(0)
    return TrainState(
        agent=Agent(net_params, net_params, optimizer.init(net_params), gamma),
        replay=replay_init(config, ts.obs[0], network.num_actions),
        env_state=env_state,
        obs=ts.obs,
        key=key,
        clock=Clock(env_steps=zero, updates=zero, iterations=zero),
        train_return=jnp.float32(jnp.nan),
    )


def train_chunk(
    state: TrainState, config: Config, hparams: Hyperparams
) -> tuple[TrainState, ChunkMetrics]:
    """``iterations_per_chunk`` iterations, then one evaluation. Pure; jit outside."""
    return episodes.iterate_and_evaluate(
        state,
        lambda s: train_iteration(s, config, hparams),
        config.iterations_per_chunk,
        lambda s, key: evaluate(s.agent, config, key),
    )


def evaluate(agent: Agent, config: Config, key: jax.Array) -> jax.Array:
    """Mean return of ``num_eval_envs`` episodes of the deterministic search (no Gumbel noise);
    with the simulator it searches from the eval envs' states (the search's key fixed)."""
    if config.model == "learned":
        return episodes.evaluate(act, agent, config, key)

    def search_act(env_state: envs.EnvState, obs: jax.Array) -> jax.Array:
        return simulator_search(agent, env_state, obs, jax.random.key(0), config, 0.0).action

    env = episodes.make_eval_env(config)
    return jnp.mean(simulator.episode_returns(search_act, env, key, config.num_eval_envs))


def greedy_act(agent: Agent, obs: jax.Array, config: Config) -> jax.Array:
    """The prediction network's greedy action of observations ``[B, ...]`` (no search): the
    simulator model's policy where only an observation is at hand."""
    initial, _ = model_fns(agent.params, config)
    return jnp.argmax(initial(obs)[1], axis=-1)


# ---- recipes --------------------------------------------------------------------------------
CARTPOLE_CONFIG: dict[str, Setting] = {
    "num_envs": 16,
    "num_steps": 4,
    "num_simulations": 16,
    "unroll_steps": 5,
    "td_steps": 10,
    "batch_size": 256,
    "updates_per_iteration": 8,
    "hidden": (128,),
    "latent_size": 128,
    "value_support": 20,  # h(1 / (1 - 0.997)) = 17.6
    "reward_support": 5,
    "prioritized": True,  # windows drawn by value error: the rare late failures get replayed
}
CARTPOLE_HPARAMS: dict[str, Setting] = {
    "learning_rate": 1e-3,
    "lr_decay_steps": 100_000.0,  # to 0 over the budget: the policy it reached stays
    "gamma": 0.997,  # a ~300-step horizon: failures far ahead (a drift out of bounds) count
    "value_coef": 1.0,
}

# AlphaZero on CartPole: the recipe above with the simulator as the search's model, untuned.
# Its loop, search, prediction network, n-step targets and rates are the learned model's;
# unroll_steps, latent_size and reward_support are unused there (K = 0, no dynamics or reward).
# Its windows stay uniform, as its recorded row ran.
CARTPOLE_SIMULATOR_CONFIG: dict[str, Setting] = {
    **CARTPOLE_CONFIG,
    "prioritized": False,
    "model": "simulator",
}

RECIPES = Recipes(
    Recipe(
        "default",
        "16 envs x 4 steps, 16 simulations, 128-unit nets, K=5, n=10, gamma 0.997, 8 x 256, PER",
        CARTPOLE_CONFIG,
        CARTPOLE_HPARAMS,
        envs=("rl_jax/CartPole-v1",),
        total_steps=100_000,
    ),
    Recipe(
        "simulator",
        "AlphaZero: the default recipe with the simulator as the model (untuned), K=0",
        CARTPOLE_SIMULATOR_CONFIG,
        CARTPOLE_HPARAMS,
        envs=("rl_jax/CartPole-v1",),
        total_steps=100_000,
    ),
)


# ---- the Algorithm object -------------------------------------------------------------------
class MuZero(RecipeBook):
    """MuZero as an ``rl_jax.training.algorithm.Algorithm``."""

    name = "muzero"
    config_type, hparams_type = Config, Hyperparams
    recipes = RECIPES
    policy_fields = ("agent",)
    ranges = {
        "value_coef": validation.NON_NEGATIVE,
        "weight_decay": validation.NON_NEGATIVE,
    }

    def default_config(
        self, env_id: str, recipe: str | None = None, **overrides: Setting
    ) -> Config:
        """The recipe's ``Config``; an ``ImageConfig`` for the envs of ``IMAGE_ENVS``."""
        if env_id not in IMAGE_ENVS:
            return super().default_config(env_id, recipe, **overrides)
        # built from named settings as the base class builds a Config (checked when built)
        image_config: type = ImageConfig
        values = {**self.recipe(env_id, recipe).config, **overrides}
        return cast(Config, image_config(env_id=env_id, **values))

    def init(self, key: jax.Array, config: Config, hparams: Hyperparams) -> TrainState:
        """A fresh state for one seed and one hyperparameter set."""
        return init(key, config, hparams)

    def train_chunk(
        self, state: TrainState, config: Config, hparams: Hyperparams
    ) -> tuple[TrainState, ChunkMetrics]:
        """``iterations_per_chunk`` iterations, then one evaluation."""
        return train_chunk(state, config, hparams)

    def env_steps_per_chunk(self, config: Config) -> int:
        """Env steps per seed in one chunk: ``num_envs * num_steps * iterations_per_chunk``."""
        return config.num_envs * config.num_steps * config.iterations_per_chunk

    def warm_up_steps(self, config: Config) -> int:
        """Env steps per seed before the first update."""
        return max(config.warm_up, config.num_envs * config.window)

    def replay_capacity(self, config: Config) -> int:
        """Steps the replay holds: ``replay_rows * num_envs``."""
        return config.replay_rows * config.num_envs

    def policy(self, state: TrainState, config: Config) -> Callable[..., jax.Array]:
        """``obs -> action``: the deterministic search's action from one observation; with the
        simulator as the model (which needs the env's state, not at hand here) the prediction
        network's greedy action."""
        choose = greedy_act if config.model == "simulator" else act
        return lambda obs, legal=None: choose(state.agent, obs[None], config)[0]

    def make_env(self, config: Config) -> envs.Environment:
        """The env the policy acts in, for rendering."""
        return episodes.make_eval_env(config)


muzero = MuZero()
default_config, default_hyperparams = muzero.default_config, muzero.default_hyperparams
