"""Recurrent PPO: PPO (``rl_jax.agents.ppo``) whose actor and critic read a recurrent core, an
LSTM or a GRU (flax's ``OptimizedLSTMCell`` / ``GRUCell``), for envs that show only part of
their state (``rl_jax/CartPoleNoVel-v1``, the POPGym memory tasks, the position-only MuJoCo
tasks such as ``rl_jax/Hopper-P-v5``).

The network: observation -> ``hidden`` layers -> the cell (its carry the policy's state) -> a
linear policy head and a linear value head, both on the cell's output, each after its own
``head_hidden`` layers; with ``critic_cell`` the value reads a second cell. Every env carries its
own state, zero at each episode start.

One *iteration*: ``num_envs`` envs (autoreset) each take ``num_steps`` steps with the current
stochastic policy, keeping the state the cell had before every step (after the reset where an
episode started) and whether the step's observation starts an episode. Advantages are PPO's
GAE(lambda) over the whole rollout (``ppo_parts``; truncations bootstrap from the value of the
true final observation, read with the state the cell reached on the step that ended there). The
rollout is then cut into sequences of ``seq_len`` steps of one env, each with the state it started
from; ``num_epochs`` passes each shuffle the ``num_envs * num_steps / seq_len`` sequences into
``num_minibatches`` minibatches of whole sequences. The loss (PPO's clipped surrogate, value
loss and entropy bonus) unrolls the cell over every sequence from its stored state: truncated
backpropagation through time, no gradient into the stored state, the state reset to zero where
an episode starts inside a sequence, exactly as while acting.

A module of its own rather than a PPO option: the recurrent state runs through every function
of PPO (the rollout carries it, the batch is made of sequences rather than steps, the loss
unrolls a scan, the deterministic policy returns a state) and would add a branch to each;
``ppo.py`` stays the readable feed-forward reference. What the two share is imported: the
losses, GAE and the action distributions (``ppo_parts``, ``policy_gradient``) and the optimizer
step (``common``).

Options: observations standardised by running statistics (``normalize_obs``: acting and
learning on one batch use the statistics from before it, as in PPO), and rewards divided by a
running std of discounted returns (``normalize_rewards``, PPO's and VecNormalize's). Not
supported: legal-action masks (refused), frames.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Literal, NamedTuple, TypeVar, cast

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
from flax import struct

from rl_jax import envs
from rl_jax.agents import ppo_parts
from rl_jax.agents.common import clip_by_global_norm, injected_step, linearly_decayed
from rl_jax.agents.policy_gradient import entropy, log_prob
from rl_jax.agents.ppo_parts import deterministic_action, sample_action, to_env_action
from rl_jax.envs.core.wrappers import StatisticsState
from rl_jax.training import episodes, networks, normalization, params, validation
from rl_jax.training.algorithm import ChunkMetrics, Clock, RecipeBook
from rl_jax.training.networks import Params
from rl_jax.training.normalization import RunningStats
from rl_jax.training.params import Scalar
from rl_jax.training.recipes import Recipe, Recipes, Setting

__all__ = ["Config", "Hyperparams", "recurrent_ppo"]

CELLS = ("lstm", "gru")
#: A cell's carry for one env: an LSTM's ``(c, h)``, a GRU's ``h``; with leading axes, many.
CellCarry = tuple[jax.Array, jax.Array] | jax.Array
#: The network's carry: its cell's, or with ``critic_cell`` the pair (the actor's, the critic's).
Carry = CellCarry | tuple[CellCarry, CellCarry]


@dataclasses.dataclass(frozen=True, kw_only=True)
class Config:
    """Static settings (changing one recompiles)."""

    env_id: str
    num_envs: int = 8  # envs stepped together (vmapped), each with its own episode and state
    num_steps: int = 32  # steps of every env per rollout: a batch is num_envs * num_steps
    seq_len: int = 32  # steps per training sequence (BPTT length); must divide num_steps
    num_epochs: int = 4  # passes over each batch
    num_minibatches: int = 1  # minibatches of whole sequences per pass (must split them evenly)
    iterations_per_chunk: int = 1  # rollouts and updates per compiled call; eval after each call
    num_eval_envs: int = 10  # episodes of the deterministic policy per evaluation
    cell: Literal["lstm", "gru"] = "lstm"  # the recurrent cell: "lstm" or "gru"
    cell_size: int = 64  # features of the cell's state
    hidden: tuple[int, ...] = ()  # layers between the observation and the cell
    head_hidden: tuple[int, ...] = ()  # layers after the cell, the policy's and the value's own
    critic_cell: bool = False  # the value has a cell of its own (sb3-contrib's enable_critic_lstm)
    activation: networks.Activation = "tanh"  # of those layers: see networks.ACTIVATIONS
    initial_std: float = 1.0  # Gaussian policy: the state-independent std before training
    normalize_obs: bool = False  # standardise observations by running mean and variance
    normalize_rewards: bool = False  # divide rewards by a running std of discounted returns
    normalize_advantages: bool = True  # standardise the advantages of each minibatch
    # the env's constructor keywords, "name=value, name=value": envs.make(env_id, **them)
    env_kwargs: str = ""

    def __post_init__(self) -> None:
        envs.parse_keywords(self.env_kwargs)  # a ValueError names what is wrong
        counts = ("num_envs", "num_steps", "seq_len", "num_epochs", "num_minibatches")
        for name in (*counts, "iterations_per_chunk", "num_eval_envs", "cell_size"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.num_steps % self.seq_len:
            raise ValueError(f"seq_len ({self.seq_len}) must divide num_steps ({self.num_steps})")
        if self.num_sequences % self.num_minibatches:
            raise ValueError(
                f"num_minibatches ({self.num_minibatches}) must divide the "
                f"{self.num_sequences} sequences of num_envs x num_steps / seq_len"
            )
        if self.cell not in CELLS:
            raise ValueError(f"cell must be one of {list(CELLS)}, got {self.cell!r}")
        if self.activation not in networks.ACTIVATIONS:
            raise ValueError(f"activation must be one of {list(networks.ACTIVATIONS)}")
        if self.initial_std <= 0.0:
            raise ValueError(f"initial_std must be > 0, got {self.initial_std}")

    @property
    def batch_size(self) -> int:
        """Env steps per rollout: ``num_envs * num_steps``."""
        return self.num_envs * self.num_steps

    @property
    def num_sequences(self) -> int:
        """Training sequences per rollout: ``batch_size / seq_len``."""
        return self.batch_size // self.seq_len

    def make_env(self) -> envs.Environment:
        """The registered env with ``env_kwargs``."""
        return envs.make(self.env_id, **envs.parse_keywords(self.env_kwargs))


@struct.dataclass
class Hyperparams(params.HyperparamsMethods):
    """What a sweep may vary without recompiling."""

    learning_rate: Scalar = 3e-4  # Adam step size at the start
    lr_decay_steps: Scalar = 0.0  # env steps over which the rate falls to 0 (0: constant)
    gamma: Scalar = 0.99  # discount
    gae_lambda: Scalar = 0.95  # GAE's lambda: 0 one-step TD errors, 1 Monte-Carlo returns
    clip_eps: Scalar = 0.2  # the surrogate's ratio is clipped to [1 - clip_eps, 1 + clip_eps]
    clip_decay_steps: Scalar = 0.0  # env steps over which clip_eps falls to 0 (0: constant)
    vf_coef: Scalar = 0.5  # weight of the value loss
    ent_coef: Scalar = 0.0  # weight of the policy's mean entropy, subtracted from the loss
    max_grad_norm: Scalar = 0.5  # clip the gradient's global norm to this (0: no clipping)
    adam_eps: Scalar = 1e-5  # Adam's epsilon
    reward_clip: Scalar = 10.0  # normalize_rewards: scaled rewards are clipped to +-this (0: not)


# rl-baselines3-zoo's ppo_lstm settings for CartPoleNoVel-v1, in this learner's terms: 8 envs x 32
# steps, 20 epochs over the 256 steps in one minibatch, a 64-unit LSTM, gamma 0.98, lambda 0.8,
# no entropy bonus, observations standardised (the zoo's VecNormalize; without, the pole's angle
# is too small a signal to learn from in 100k steps), and the rate 1e-3 and the clip range 0.2
# both falling to 0 over the 100k steps. One evaluation every 40 rollouts (docs/learners).
CARTPOLE_NOVEL_CONFIG: dict[str, Setting] = {
    "num_envs": 8,
    "num_steps": 32,
    "seq_len": 32,
    "num_epochs": 20,
    "num_minibatches": 1,
    "iterations_per_chunk": 40,
    "cell": "lstm",
    "cell_size": 64,
    "normalize_obs": True,
}
CARTPOLE_NOVEL_HPARAMS: dict[str, Setting] = {
    "learning_rate": 1e-3,
    "lr_decay_steps": 100_000.0,
    "clip_decay_steps": 100_000.0,
    "gamma": 0.98,
    "gae_lambda": 0.8,
    "ent_coef": 0.0,
}

# The CartPoleNoVel recipe above with a GRU of 64 for the LSTM, rewards scaled by a running std of
# the discounted returns (as the zoo's VecNormalize does), gamma 0.99 and 16 envs (updates of 16
# sequences, half as many of them): chosen over 30 seeds among one-setting changes of the recipe
# (RESULTS.md); sb3-contrib has no GRU, so the speed comparison stays on the LSTM recipe.
CARTPOLE_NOVEL_GRU_CONFIG: dict[str, Setting] = {
    **CARTPOLE_NOVEL_CONFIG,
    "num_envs": 16,
    "cell": "gru",
    "normalize_rewards": True,
}
CARTPOLE_NOVEL_GRU_HPARAMS: dict[str, Setting] = {**CARTPOLE_NOVEL_HPARAMS, "gamma": 0.99}

# rl-baselines3-zoo's ppo_lstm settings for PendulumNoVel-v1 (hyperparams/ppo_lstm.yml): 4 envs x
# 1024 steps, 10 epochs in minibatches of 128 steps (sb3-contrib's default batch_size: here 32
# sequences of 128 steps, one per minibatch), gamma 0.9, lambda 0.95, no entropy bonus, the rate
# 1e-3 (here falling to 0) and the clip range 0.2, no VecNormalize; an LSTM of 64 as in the
# CartPoleNoVel recipe (sb3-contrib's default of 256 takes 4 times as long on a CPU);
# MlpLstmPolicy's defaults for the rest: the critic's own LSTM and 64 x 64 tanh layers for each
# head after it. No field for the zoo's gSDE (use_sde, sde_sample_freq 4): the policy's noise is
# a state-independent Gaussian.
PENDULUM_NOVEL_CONFIG: dict[str, Setting] = {
    "num_envs": 4,
    "num_steps": 1024,
    "seq_len": 128,
    "num_epochs": 10,
    "num_minibatches": 32,
    "iterations_per_chunk": 5,  # 20,480 env steps per evaluation: 5 of them in 102,400 steps
    "cell": "lstm",
    "cell_size": 64,
    "critic_cell": True,
    "head_hidden": (64, 64),
}
PENDULUM_NOVEL_HPARAMS: dict[str, Setting] = {
    "learning_rate": 1e-3,
    "lr_decay_steps": 100_000.0,  # falls to 0 over the budget (the zoo's is constant): RESULTS.md
    "gamma": 0.9,
    "gae_lambda": 0.95,
    "clip_eps": 0.2,
    "ent_coef": 0.0,
}

#: POPGym's memory tasks at Easy that the recipe below is written for.
POPGYM_EASY = (
    "rl_jax/RepeatPreviousEasy-v0",
    "rl_jax/RepeatFirstEasy-v0",
    "rl_jax/CountRecallEasy-v0",
    "rl_jax/AutoencodeEasy-v0",
    "rl_jax/StatelessCartPoleEasy-v0",
)
# POPGym's PPO with a GRU (popgym/baselines/ppo.py, on RLlib's PPO) in this learner's terms:
# its GRU of 256 after a 128-unit layer, gamma 0.99, value-loss weight 1.0, no entropy bonus, and
# RLlib's PPO defaults (lambda 1.0, clip 0.3, no gradient clipping). Scaled to a 2-core CPU:
# 32 envs x 128 steps (theirs 64 x 1024), 4 epochs of 4 minibatches of 8 sequences of 128 steps
# (theirs 30 of 8 x 8,192 steps, sequences up to 1,024) and the rate 5e-4 (theirs 5e-5, for
# batches 16 times as large), the heads' 2 x 128 layers each (ReLU for their LeakyReLU). Not
# here: RLlib's KL penalty and value clipping, and popgym's previous-action observation wrapper.
POPGYM_CONFIG: dict[str, Setting] = {
    "num_envs": 32,
    "num_steps": 128,
    "seq_len": 128,
    "num_epochs": 4,
    "num_minibatches": 4,
    "iterations_per_chunk": 10,  # 40,960 env steps per evaluation
    "cell": "gru",
    "cell_size": 256,
    "hidden": (128,),
    "head_hidden": (128, 128),
    "activation": "relu",
}
POPGYM_HPARAMS: dict[str, Setting] = {
    "learning_rate": 5e-4,
    "gamma": 0.99,
    "gae_lambda": 1.0,
    "clip_eps": 0.3,
    "vf_coef": 1.0,
    "ent_coef": 0.0,
    "max_grad_norm": 0.0,
}

#: The position-only MuJoCo tasks (envs/memory/masked.py, Ni et al. 2022's "-P" variants).
MUJOCO_POSITIONS = (
    "rl_jax/Hopper-P-v5",
    "rl_jax/Walker2d-P-v5",
    "rl_jax/HalfCheetah-P-v5",
    "rl_jax/Ant-P-v5",
)
# PPO's vectorised MuJoCo recipe (ppo.MUJOCO_CONFIG, ppo.CLEANRL_HPARAMS) with an LSTM of 128,
# untuned: 64 envs x 32 steps (a sequence is an env's whole rollout, seq_len = num_steps), 10
# epochs x 32 minibatches (2 sequences, 64 steps each, PPO's minibatch size), the rate 3e-4 to 0
# over 1M steps, gamma 0.99, lambda 0.95, clip 0.2, value weight 0.5, no entropy bonus, gradient
# norm 0.5, Adam eps 1e-5, observations standardised, rewards scaled by the running std of the
# discounted returns and clipped to +-10, advantages per minibatch. PPO's 64 x 64 tanh layers,
# the actor's and the critic's own, are here each head's own 64 x 64 after the shared cell. No
# counterpart here for PPO's clipped value loss (clip_value_loss, value_clip_eps 0.2): the value
# learns the scaled returns with the plain squared loss.
MUJOCO_POSITIONS_CONFIG: dict[str, Setting] = {
    "num_envs": 64,
    "num_steps": 32,
    "seq_len": 32,
    "num_epochs": 10,
    "num_minibatches": 32,
    "iterations_per_chunk": 10,  # evaluated every 20,480 env steps, as PPO's recipe
    "cell": "lstm",
    "cell_size": 128,
    "hidden": (),
    "head_hidden": (64, 64),
    "critic_cell": False,
    "activation": "tanh",
    "initial_std": 1.0,
    "normalize_obs": True,
    "normalize_rewards": True,
    "normalize_advantages": True,
}
MUJOCO_POSITIONS_HPARAMS: dict[str, Setting] = {
    "learning_rate": 3e-4,
    "lr_decay_steps": 1_000_000.0,
    "gamma": 0.99,
    "gae_lambda": 0.95,
    "clip_eps": 0.2,
    "vf_coef": 0.5,
    "ent_coef": 0.0,
    "max_grad_norm": 0.5,
    "adam_eps": 1e-5,
}

RECIPES = Recipes(
    Recipe(
        "default",
        "RL Zoo's ppo_lstm: 8 envs x 32 steps, 20 epochs, LSTM 64, normalised obs, lr 1e-3 and "
        "clip 0.2 to 0",
        CARTPOLE_NOVEL_CONFIG,
        CARTPOLE_NOVEL_HPARAMS,
        envs=("rl_jax/CartPoleNoVel-v1",),
        total_steps=100_000,
    ),
    Recipe(
        "gru",
        "the default recipe with a GRU of 64, 16 envs, rewards scaled by a running std, gamma 0.99",
        CARTPOLE_NOVEL_GRU_CONFIG,
        CARTPOLE_NOVEL_GRU_HPARAMS,
        envs=("rl_jax/CartPoleNoVel-v1",),
        total_steps=100_000,
    ),
    Recipe(
        "default",
        "RL Zoo's ppo_lstm: 4 envs x 1024 steps, 10 epochs x 32 minibatches, LSTM 64 and the "
        "critic's own, gamma 0.9, lr 1e-3 to 0 (no gSDE)",
        PENDULUM_NOVEL_CONFIG,
        PENDULUM_NOVEL_HPARAMS,
        envs=("rl_jax/PendulumNoVel-v1",),
        total_steps=100_000,
    ),
    Recipe(
        "default",
        "POPGym's PPO + GRU 256 scaled to a CPU: 32 envs x 128 steps, 4 epochs x 4, lr 5e-4",
        POPGYM_CONFIG,
        POPGYM_HPARAMS,
        envs=POPGYM_EASY,
        total_steps=1_024_000,
    ),
    Recipe(
        "default",
        "PPO's vectorised MuJoCo recipe with an LSTM 128 (untuned): 64 envs x 32 steps, 10 "
        "epochs x 32, normalised obs and rewards",
        MUJOCO_POSITIONS_CONFIG,
        MUJOCO_POSITIONS_HPARAMS,
        envs=MUJOCO_POSITIONS,
        total_steps=1_000_000,
    ),
)


# ---- the network -------------------------------------------------------------------------------
def _layer(features: int, gain: float) -> nn.Dense:
    init = nn.initializers.orthogonal(gain)
    return nn.Dense(features, kernel_init=init, bias_init=nn.initializers.zeros)


class RecurrentActorCritic(nn.Module):
    """``(carry, obs) -> (carry, {"logits" | "mean", "std"; "value"})`` for one step. ``layers``:
    the hidden layers before the cell (``ppo_parts.check_orthogonal_layers``); ``head_hidden``:
    the policy's and the value's own layers after it; ``critic_cell``: the value reads a second
    cell of its own, and the carry is the pair ``(actor's, critic's)``."""

    cell: Literal["lstm", "gru"]
    cell_size: int
    layers: networks.Layers = networks.Layers((), activation="tanh", initializer="orthogonal")
    head_hidden: tuple[int, ...] = ()
    critic_cell: bool = False
    action_dim: int = 1
    num_actions: int | None = None  # set: categorical
    initial_std: float = 1.0

    def _cell(
        self, carry: CellCarry, x: jax.Array, name: str | None
    ) -> tuple[CellCarry, jax.Array]:
        if self.cell == "lstm":
            lstm_carry = cast(tuple[jax.Array, jax.Array], carry)
            return cast(
                tuple[CellCarry, jax.Array],
                nn.OptimizedLSTMCell(self.cell_size, name=name)(lstm_carry, x),
            )
        return cast(tuple[CellCarry, jax.Array], nn.GRUCell(self.cell_size, name=name)(carry, x))

    def _head(self, x: jax.Array) -> jax.Array:
        function = networks.ACTIVATIONS[self.layers.activation][0]
        for width in self.head_hidden:
            x = function(_layer(width, 2.0**0.5)(x))
        return x

    @nn.compact
    def __call__(self, carry: Carry, obs: jax.Array) -> tuple[Carry, dict[str, jax.Array]]:
        ppo_parts.check_orthogonal_layers(self.layers, "RecurrentActorCritic")
        function = networks.ACTIVATIONS[self.layers.activation][0]
        x = obs
        for width in self.layers.hidden:
            x = function(_layer(width, 2.0**0.5)(x))
        if self.critic_cell:
            actor_carry, critic_carry = cast(tuple[CellCarry, CellCarry], carry)
            actor_carry, x_pi = self._cell(actor_carry, x, "actor_cell")
            critic_carry, x_v = self._cell(critic_carry, x, "critic_cell")
            carry = (actor_carry, critic_carry)
        else:
            carry, x_pi = self._cell(cast(CellCarry, carry), x, None)
            x_v = x_pi
        x_pi, x_v = self._head(x_pi), self._head(x_v)
        out = {"value": _layer(1, 1.0)(x_v)[..., 0]}
        if self.num_actions is not None:
            return carry, {**out, "logits": _layer(self.num_actions, 0.01)(x_pi)}
        mean = _layer(self.action_dim, 0.01)(x_pi)
        start = jnp.log(jnp.float32(self.initial_std))
        log_std = self.param("log_std", lambda _, shape: jnp.full(shape, start), (self.action_dim,))
        return carry, {**out, "mean": mean, "std": jnp.broadcast_to(jnp.exp(log_std), mean.shape)}


@functools.lru_cache(maxsize=64)
def make_network(config: Config) -> RecurrentActorCritic:
    """The network for ``config`` (cached: called at every trace)."""
    space = episodes.action_space(config)
    discrete = isinstance(space, envs.Discrete)
    layers = networks.Layers(
        hidden=config.hidden, activation=config.activation, initializer="orthogonal"
    )
    return RecurrentActorCritic(
        cell=config.cell,
        cell_size=config.cell_size,
        layers=layers,
        head_hidden=config.head_hidden,
        critic_cell=config.critic_cell,
        action_dim=1 if discrete else space.shape[0],
        num_actions=space.n if isinstance(space, envs.Discrete) else None,
        initial_std=config.initial_std,
    )


def initial_carry(config: Config) -> Carry:
    """One env's state at an episode start: zeros."""
    zeros = jnp.zeros((config.cell_size,), jnp.float32)
    one: CellCarry = (zeros, zeros) if config.cell == "lstm" else zeros
    return (one, one) if config.critic_cell else one


def apply(
    params: Params,
    carry: Carry,
    obs: jax.Array,
    config: Config,
    obs_stats: RunningStats | None = None,
) -> tuple[Carry, dict[str, jax.Array]]:
    """One step of the network on a batch: ``carry [B, ...], obs [B, ...]``, the observations
    standardised by ``obs_stats`` (None: as they are)."""
    net = make_network(config)
    obs = normalization.normalize(obs_stats, obs)
    return cast(tuple[Carry, dict[str, jax.Array]], net.apply(params, carry, obs))


def unroll(
    params: Params,
    carry: Carry,
    obs: jax.Array,
    starts: jax.Array,
    config: Config,
    obs_stats: RunningStats | None = None,
) -> dict[str, jax.Array]:
    """The network over sequences, time first: ``obs [L, B, ...]`` from ``carry [B, ...]``, the
    state reset to zero before every step where ``starts [L, B]`` (an episode begins there);
    outputs ``[L, B, ...]``."""
    initial = initial_carry(config)

    def step(carry: Carry, inputs: tuple[jax.Array, jax.Array]):
        obs, start = inputs
        carry = cast(Carry, episodes.reset_policy_state(start, carry, initial))
        return apply(params, carry, obs, config, obs_stats)

    return jax.lax.scan(step, carry, (obs, starts))[1]


# ---- state ----------------------------------------------------------------------------------
@struct.dataclass
class Agent:
    """What learns: the network's parameters and Adam's state."""

    params: Params
    opt_state: optax.OptState  # optax inject_hyperparams(adam) state: holds the rate in use
    obs_stats: RunningStats | None = None  # with normalize_obs, else None


@struct.dataclass
class TrainState:
    """Everything of one seed's run."""

    agent: Agent
    env_state: StatisticsState  # [num_envs, ...] of the train env
    obs: jax.Array  # [num_envs, *obs_shape], the observation the next action answers
    carry: Carry  # [num_envs, cell_size] each env's state before acting on obs
    start: jax.Array  # [num_envs] bool, obs begins an episode
    key: jax.Array
    clock: Clock
    train_return: jax.Array  # [] float32, mean return of the episodes ended in the last chunk
    return_stats: RunningStats | None = (
        None  # normalize_rewards: RunningStats of discounted returns, [1]
    )
    discounted_return: jax.Array | None = (
        None  # normalize_rewards: [num_envs], each env's running return
    )


class Rollout(NamedTuple):
    """``num_steps`` steps of every env, leaves ``[T, N, ...]``."""

    obs: jax.Array
    carry: Carry  # the state the cell had before acting on obs
    start: jax.Array  # bool, obs begins an episode (the state above is then the initial one)
    action: jax.Array
    log_mu: jax.Array
    v_tm1: jax.Array
    v_t: jax.Array  # values of the true next observations
    r_t: jax.Array
    terminated: jax.Array
    truncated: jax.Array
    episode_return: jax.Array


class Sequences(NamedTuple):
    """What a gradient step learns from: whole sequences, leaves ``[S, L, ...]``."""

    obs: jax.Array
    start: jax.Array
    action: jax.Array
    log_mu: jax.Array
    advantage: jax.Array
    target: jax.Array


# ---- acting ---------------------------------------------------------------------------------
def act(agent: Agent, carry: Carry, obs: jax.Array, config: Config) -> tuple[jax.Array, Carry]:
    """The deterministic policy on a batch: ``(actions, next carry)``."""
    carry, policy = apply(agent.params, carry, obs, config, agent.obs_stats)
    space = episodes.action_space(config)
    return deterministic_action(policy, space), carry


def collect(state: TrainState, key: jax.Array, config: Config) -> tuple[TrainState, Rollout]:
    """``num_steps`` steps of every env; the state restarts where an episode ended."""
    env = episodes.make_train_env(config)
    space = env.action_space()
    initial = initial_carry(config)
    agent = state.agent

    def step(
        carry_in: tuple[StatisticsState, jax.Array, Carry, jax.Array], step_key: jax.Array
    ) -> tuple[tuple[StatisticsState, jax.Array, Carry, jax.Array], Rollout]:
        env_state, obs, carry, start = carry_in
        action_key, env_key = jax.random.split(step_key)
        next_carry, policy = apply(agent.params, carry, obs, config, agent.obs_stats)
        action = sample_action(policy, action_key)
        keys = jax.random.split(env_key, config.num_envs)
        env_state, ts = jax.vmap(env.step)(keys, env_state, to_env_action(action, space))
        _, final = apply(agent.params, next_carry, ts.info["final_obs"], config, agent.obs_stats)
        ended = jnp.logical_or(ts.terminated, ts.truncated)
        row = Rollout(
            obs=obs,
            carry=carry,
            start=start,
            action=action,
            log_mu=log_prob(policy, action),
            v_tm1=policy["value"],
            v_t=final["value"],
            r_t=ts.reward,
            terminated=ts.terminated,
            truncated=ts.truncated,
            episode_return=jnp.where(ended, ts.info["episode_return"], 0.0),
        )
        next_carry = episodes.reset_policy_state(ended, next_carry, initial)
        return (env_state, ts.obs, next_carry, ended), row

    keys = jax.random.split(key, config.num_steps)
    first = (state.env_state, state.obs, state.carry, state.start)
    (env_state, obs, carry, start), rollout = jax.lax.scan(step, first, keys)
    state = dataclasses.replace(state, env_state=env_state, obs=obs, carry=carry, start=start)
    return state, rollout


#: A pytree of arrays, kept in its own structure by ``to_sequences``.
R = TypeVar("R")


def to_sequences(tree: R, config: Config) -> R:
    """Leaves ``[T, N, ...]`` -> ``[N * T / L, L, ...]``: each env's rollout cut into sequences
    of ``L = seq_len`` steps."""
    length = config.seq_len

    def cut(x: jax.Array) -> jax.Array:
        x = jnp.swapaxes(x, 0, 1)  # [N, T, ...]
        return x.reshape(config.num_sequences, length, *x.shape[2:])

    return jax.tree.map(cut, tree)


# ---- learning -------------------------------------------------------------------------------
def loss_fn(
    params: Params,
    batch: Sequences,
    carry: Carry,
    hparams: Hyperparams,
    config: Config,
    obs_stats: RunningStats | None = None,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """``(loss, metrics)`` of a minibatch of sequences ``[B, L, ...]`` from their initial
    states ``carry [B, ...]`` (constants: truncated backpropagation through time)."""
    time_first = jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), batch)
    carry = jax.lax.stop_gradient(carry)
    policy = unroll(params, carry, time_first.obs, time_first.start, config, obs_stats)
    log_pi = log_prob(policy, time_first.action)
    advantage = time_first.advantage
    if config.normalize_advantages:
        advantage = ppo_parts.normalize_advantages(advantage)
    policy_loss = ppo_parts.clipped_surrogate_loss(
        log_pi, time_first.log_mu, advantage, hparams.clip_eps
    )
    value_loss = ppo_parts.value_loss(policy["value"], time_first.target)
    mean_entropy = jnp.mean(entropy(policy))
    total = policy_loss + hparams.vf_coef * value_loss - hparams.ent_coef * mean_entropy
    metrics = {"policy_loss": policy_loss, "value_loss": value_loss, "entropy": mean_entropy}
    return total, {
        **metrics,
        **ppo_parts.policy_statistics(log_pi, time_first.log_mu, hparams.clip_eps),
    }


def gradient_step(
    agent: Agent,
    batch: Sequences,
    carry: Carry,
    hparams: Hyperparams,
    config: Config,
    rate: jax.Array,
) -> tuple[Agent, dict[str, jax.Array]]:
    """One Adam step on a minibatch of sequences, the gradient clipped by its global norm."""
    grads, metrics = jax.grad(loss_fn, has_aux=True)(
        agent.params, batch, carry, hparams, config, agent.obs_stats
    )
    grads, metrics["grad_norm"] = clip_by_global_norm(grads, hparams.max_grad_norm)
    params, opt_state = injected_step(
        optax.adam, grads, agent.opt_state, agent.params, learning_rate=rate, eps=hparams.adam_eps
    )
    return dataclasses.replace(agent, params=params, opt_state=opt_state), metrics


def update(
    agent: Agent,
    batch: Sequences,
    carry: Carry,
    key: jax.Array,
    hparams: Hyperparams,
    config: Config,
    rate: jax.Array,
) -> tuple[Agent, dict[str, jax.Array]]:
    """``num_epochs`` passes over the sequences, each shuffled into ``num_minibatches``
    minibatches of whole sequences; metrics are the means over all steps."""
    count = config.num_minibatches

    def epoch(agent: Agent, epoch_key: jax.Array):
        order = jax.random.permutation(epoch_key, config.num_sequences)
        split = jax.tree.map(lambda x: x[order].reshape(count, -1, *x.shape[1:]), (batch, carry))
        return jax.lax.scan(
            lambda a, bc: gradient_step(a, bc[0], bc[1], hparams, config, rate), agent, split
        )

    agent, metrics = jax.lax.scan(epoch, agent, jax.random.split(key, config.num_epochs))
    return agent, jax.tree.map(jnp.mean, metrics)


def train_iteration(state: TrainState, config: Config, hparams: Hyperparams):
    """One rollout, its advantages, and the updates on its sequences."""
    key, collect_key, update_key = jax.random.split(state.key, 3)
    state, rollout = collect(state, collect_key, config)
    ended_t = jnp.logical_or(rollout.terminated, rollout.truncated)
    advantage, target, state = ppo_parts.lambda_targets(
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
    steps = Sequences(rollout.obs, rollout.start, rollout.action, rollout.log_mu, advantage, target)
    batch = to_sequences(steps, config)
    # each sequence's initial state: the stored state at its first step
    initial_states = jax.tree.map(lambda x: x[:, 0], to_sequences(rollout.carry, config))
    rate = linearly_decayed(hparams.learning_rate, state.clock.env_steps, hparams.lr_decay_steps)
    clip = linearly_decayed(hparams.clip_eps, state.clock.env_steps, hparams.clip_decay_steps)
    hparams = dataclasses.replace(hparams, clip_eps=clip)
    agent, metrics = update(state.agent, batch, initial_states, update_key, hparams, config, rate)
    if agent.obs_stats is not None:  # acting and learning on this batch used the stats before it
        mask = jnp.ones(rollout.r_t.shape, jnp.float32)
        stats = normalization.update(agent.obs_stats, rollout.obs, mask)
        agent = dataclasses.replace(agent, obs_stats=stats)
    clock = Clock(
        env_steps=state.clock.env_steps + config.batch_size,
        updates=state.clock.updates + config.num_epochs * config.num_minibatches,
        iterations=state.clock.iterations + 1,
    )
    state = dataclasses.replace(state, agent=agent, key=key, clock=clock)
    metrics = {**metrics, "learning_rate": rate}
    return state, (metrics, (jnp.sum(rollout.episode_return), jnp.sum(ended_t)))


def init(key: jax.Array, config: Config, hparams: Hyperparams) -> TrainState:
    """A fresh state for one seed and one hyperparameter set."""
    env = episodes.make_train_env(config)
    if envs.has_action_mask(env):
        raise ValueError(f"recurrent_ppo does not read action masks, which {config.env_id} has")
    agent_key, env_key, key = jax.random.split(key, 3)
    env_state, ts = jax.vmap(env.reset)(jax.random.split(env_key, config.num_envs))
    carry = cast(Carry, episodes.batched_policy_state(initial_carry(config), config.num_envs))
    params = make_network(config).init(agent_key, carry, ts.obs)
    optimizer = optax.inject_hyperparams(optax.adam)(hparams.learning_rate, eps=hparams.adam_eps)
    obs_size = env.observation_space().shape[0]
    obs_stats = normalization.init(obs_size) if config.normalize_obs else None
    state = TrainState(
        agent=Agent(params, optimizer.init(params), obs_stats),
        env_state=env_state,
        obs=ts.obs,
        carry=carry,
        start=jnp.ones(config.num_envs, jnp.bool_),
        key=key,
        clock=Clock(env_steps=jnp.int32(0), updates=jnp.int32(0), iterations=jnp.int32(0)),
        train_return=jnp.float32(jnp.nan),
    )
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
        lambda s, key: episodes.evaluate_recurrent(
            act, initial_carry(config), s.agent, config, key
        ),
    )


# ---- the Algorithm object -------------------------------------------------------------------
class RecurrentPPO(RecipeBook):
    """Recurrent PPO as an ``rl_jax.training.algorithm.Algorithm`` with a recurrent policy."""

    name = "recurrent_ppo"
    config_type, hparams_type = Config, Hyperparams
    recipes = RECIPES
    ranges = {
        "gae_lambda": validation.UNIT,
        "clip_eps": validation.POSITIVE,
        "adam_eps": validation.POSITIVE,
    }

    def init(self, key: jax.Array, config: Config, hparams: Hyperparams) -> TrainState:
        """``init``."""
        return init(key, config, hparams)

    def train_chunk(
        self, state: TrainState, config: Config, hparams: Hyperparams
    ) -> tuple[TrainState, ChunkMetrics]:
        """``train_chunk``."""
        return train_chunk(state, config, hparams)

    def env_steps_per_chunk(self, config: Config) -> int:
        """``batch_size * iterations_per_chunk``."""
        return config.batch_size * config.iterations_per_chunk

    def initial_policy_state(self, config: Config) -> Carry:
        """The cell's zero state: the policy is recurrent."""
        return initial_carry(config)

    def policy(
        self, state: TrainState, config: Config
    ) -> Callable[[Carry, jax.Array], tuple[jax.Array, Carry]]:
        """``(carry, obs) -> (action, carry)`` of the deterministic policy, for one env."""
        return episodes.one_env_recurrent_policy(act, state.agent, config)  # type: ignore[return-value]

    def make_env(self, config: Config) -> envs.Environment:
        """The env as the policy sees it (``episodes.make_eval_env``)."""
        return episodes.make_eval_env(config)


recurrent_ppo = RecurrentPPO()
default_config, default_hyperparams = (
    recurrent_ppo.default_config,
    recurrent_ppo.default_hyperparams,
)
