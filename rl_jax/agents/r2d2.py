"""R2D2 (Kapturowski et al. 2019): a recurrent DQN that learns from replayed sequences, for envs
that show only part of their state (``rl_jax/CartPoleNoVel-v1``).

The Q-network: observation -> ``hidden`` ReLU layers -> an LSTM (flax's ``OptimizedLSTMCell``,
its carry the policy's state) -> a linear (or ``dueling``) head of one value per action. Every
env carries its own state, zero at each episode start; acting is epsilon-greedy on the online
network, epsilon falling linearly over env steps as DQN's.

It runs on the shared off-policy loop (``rl_jax.training.offpolicy``) as a recurrent learner:
the loop carries each env's state, resets it at episode starts and stores it with every step.
The replay (``r2d2_parts``) writes, every ``seq_period`` steps, each env's last ``seq_len`` steps
as a sequence with the state the policy had before its first step (stored state). One update
samples ``batch_size`` sequences (uniform, or ``prioritized``: priority ``eta max|delta| + (1 -
eta) mean|delta|`` over the sequence, with importance weights), and unrolls the online and the
target network from the stored state, resetting it where an episode starts inside the sequence:

- the first ``burn_in`` steps only refresh the state (no gradient, no loss);
- on the rest, the loss is ``0.5 (y - q(a))^2`` with the n-step double-Q target
  ``y = h(r_t + ... + gamma^k h^-1(q_target(s', argmax q_online(s'))))`` and ``h`` the invertible
  value rescaling. A window stops at the first step that ended an episode and bootstraps from that
  step's true next observation, read with the state reached on it, unless it terminated; it also
  stops at the sequence's last step.

The target network takes a step ``tau`` towards the online one every ``target_update_period``
updates. With ``policy_checkpoints`` (TD7's, as DQN's: ``rl_jax.training.policy_checkpoints``)
the training envs act with a frozen copy of the network that is assessed over training episodes,
each begun from the zero state under the copy, and evaluation, ``best/`` and loaded policies use
the checkpoint: the last copy whose assessment had no episode below the checkpoint's score.
Pixel envs and legal-action masks are not supported (refused).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any, cast

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
from flax import struct
from jax.typing import ArrayLike

from rl_jax import envs
from rl_jax.agents import r2d2_parts
from rl_jax.agents.common import clipped_adam, injected_step, linearly_decayed, polyak_update
from rl_jax.agents.q_learning import epsilon_greedy, linear_schedule
from rl_jax.agents.r2d2_parts import Sequence, SequenceReplay
from rl_jax.training import episodes, networks, offpolicy, params, policy_checkpoints, validation
from rl_jax.training.offpolicy import Clock, OffPolicyConfig, TrainState
from rl_jax.training.policy_checkpoints import PolicyCheckpoint
from rl_jax.training.recipes import Recipe, Recipes, Setting
from rl_jax.training.replay import Transition

__all__ = ["Config", "Hyperparams", "r2d2"]

#: The LSTM's carry ``(c, h)`` for one env; with leading axes, many.
Carry = tuple[jax.Array, jax.Array]


# ---- settings -----------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True, kw_only=True)
class Config(OffPolicyConfig):
    """Static settings of R2D2 (the loop's are in ``OffPolicyConfig``; ``batch_size`` counts
    sequences, ``buffer_size`` env steps: the replay keeps ``buffer_size / seq_period``
    sequences)."""

    hidden: tuple[int, ...] = (64,)  # ReLU layers between the observation and the LSTM
    cell_size: int = 64  # features of the LSTM's state
    dueling: bool = True  # dueling head: q = v + a - mean(a) (the paper's)
    seq_len: int = 20  # steps per replayed sequence, burn-in included (paper: 80 + 40)
    seq_period: int = 10  # steps between sequence starts: overlap seq_len - seq_period
    burn_in: int = 5  # first steps of a sequence that only refresh the state (paper: 40)
    n_step: int = 3  # rewards summed before bootstrapping (paper: 5)
    prioritized: bool = False  # prioritised sequences, with importance weights
    target_update_period: int = 100  # gradient updates between target steps of size tau
    # TD7's policy checkpoints, as DQN's (the module docstring)
    policy_checkpoints: bool = False
    checkpoint_episodes: int = 20  # policy_checkpoints: episodes per assessment (TD7: 20)
    checkpoint_episodes_from: int = 750_000  # policy_checkpoints: env step of the switch

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.cell_size < 1 or self.n_step < 1 or self.target_update_period < 1:
            raise ValueError("cell_size, n_step and target_update_period must be >= 1")
        if self.checkpoint_episodes < 1 or self.checkpoint_episodes_from < 0:
            raise ValueError("checkpoint_episodes must be >= 1, checkpoint_episodes_from >= 0")
        if not 0 <= self.burn_in < self.seq_len:
            raise ValueError(f"burn_in must be in 0..seq_len - 1, got {self.burn_in}")
        if not 1 <= self.seq_period <= self.seq_len:
            raise ValueError(f"seq_period must be in 1..seq_len, got {self.seq_period}")
        if self.learning_starts < self.seq_len * self.num_envs:
            raise ValueError(
                f"learning_starts must be >= seq_len x num_envs ({self.seq_len * self.num_envs})"
                " env steps: updates need a first sequence in the replay"
            )


@struct.dataclass
class Hyperparams(params.HyperparamsMethods):
    """What a sweep may vary without recompiling."""

    learning_rate: ArrayLike = 1e-3  # Adam step size (paper: 1e-4)
    lr_decay_steps: ArrayLike = 0.0  # env steps (all envs) for the rate to fall to 0 (0: constant)
    adam_eps: ArrayLike = 1e-3  # Adam's epsilon (the paper's)
    gamma: ArrayLike = 0.99  # discount (paper: 0.997)
    tau: ArrayLike = 1.0  # target step every target_update_period updates (1: hard copy)
    epsilon_start: ArrayLike = 1.0  # exploration rate at env step 0
    epsilon_end: ArrayLike = 0.01  # exploration rate after epsilon_decay_steps
    epsilon_decay_steps: ArrayLike = 20_000.0  # env steps (all envs) of the linear decay
    max_grad_norm: ArrayLike = 10.0  # gradients are clipped to this global norm
    rescale_eps: ArrayLike = 1e-3  # eps of the value rescaling h (the paper's)
    priority_eta: ArrayLike = 0.9  # prioritized: weight of the max |TD error| (the paper's)
    priority_alpha: ArrayLike = 0.9  # prioritized: P(i) proportional to p_i^alpha (paper's)
    priority_beta: ArrayLike = 0.6  # prioritized: importance-weight exponent (the paper's)
    priority_eps: ArrayLike = 1e-6  # prioritized: added to every priority
    # policy_checkpoints: the checkpoint's score is multiplied by this when assessments lengthen
    # to checkpoint_episodes (TD7: 0.9)
    checkpoint_reset_weight: ArrayLike = 0.9


# ---- the network --------------------------------------------------------------------------------
class RecurrentQNetwork(nn.Module):
    """``(carry, obs [..., obs_dim]) -> (carry, q [..., num_actions])`` for one step: ``hidden``
    ReLU layers (``embed``), an LSTM (``recur``), then a linear or dueling head (``head``). The
    three are methods of their own so that an unroll scans only the recurrence and runs the
    layers before and after it as batched calls over all steps."""

    layers: networks.Layers
    cell_size: int
    num_actions: int
    dueling: bool = True

    def setup(self) -> None:
        self.torso = networks.Torso(self.layers)
        self.cell = nn.OptimizedLSTMCell(self.cell_size)
        dense = lambda outputs: networks.dense(  # noqa: E731
            outputs, self.cell_size, self.layers.initializer, 1.0, jnp.float32
        )
        self.advantage = dense(self.num_actions)
        self.value = dense(1) if self.dueling else None

    def embed(self, obs: jax.Array) -> jax.Array:
        """The hidden layers: ``[..., obs_dim] -> [..., features]``."""
        return self.torso(obs)

    def recur(self, carry: Carry, x: jax.Array) -> tuple[Carry, jax.Array]:
        """One step of the LSTM: ``(carry, features) -> (carry, output)``."""
        return self.cell(carry, x)

    def head(self, x: jax.Array) -> jax.Array:
        """The action values of the LSTM's outputs: ``[..., cell_size] -> [..., A]``."""
        advantage = self.advantage(x)
        if self.value is None:
            return advantage
        return self.value(x) + advantage - jnp.mean(advantage, axis=-1, keepdims=True)

    def __call__(self, carry: Carry, obs: jax.Array) -> tuple[Carry, jax.Array]:
        carry, x = self.recur(carry, self.embed(obs))
        return carry, self.head(x)


@functools.lru_cache(maxsize=64)
def make_network(config: Config) -> RecurrentQNetwork:
    """The Q-network for ``config`` (cached: called at every trace)."""
    space = episodes.action_space(config)
    if not isinstance(space, envs.Discrete):
        raise TypeError(f"R2D2 needs a discrete action space, got {space}")
    layers = networks.Layers(hidden=config.hidden)
    return RecurrentQNetwork(layers, config.cell_size, space.n, config.dueling)


def initial_carry(config: Config) -> Carry:
    """One env's state at an episode start: zeros."""
    zeros = jnp.zeros((config.cell_size,), jnp.float32)
    return zeros, zeros


def apply(params: optax.Params, carry: Carry, obs: jax.Array, config: Config):
    """One step of the network on a batch: ``(carry [B, ...], q [B, A])``."""
    return cast(tuple[Carry, jax.Array], make_network(config).apply(params, carry, obs))


def _recurrence(
    params: optax.Params, carry: Carry, x: jax.Array, starts: jax.Array, config: Config
) -> tuple[Carry, tuple[jax.Array, Carry]]:
    """The LSTM over features ``x [T, B, ...]`` from ``carry [B, ...]``, reset to zero before
    every step where ``starts [T, B]``: ``(last carry, (outputs, carry reached on each step))``."""
    net = make_network(config)

    def step(carry: Carry, inputs: tuple[jax.Array, jax.Array]):
        x, start = inputs
        carry = episodes.reset_policy_state(start, carry, initial_carry(config))
        carry, out = cast(tuple[Carry, jax.Array], net.apply(params, carry, x, method=net.recur))
        return carry, (out, carry)

    return jax.lax.scan(step, carry, (x, starts))


def advance(
    params: optax.Params, carry: Carry, obs: jax.Array, starts: jax.Array, config: Config
) -> Carry:
    """The state after the steps ``obs [T, B, ...]`` from ``carry [B, ...]``, reset to zero
    before every step where ``starts [T, B]``: the burn-in (the caller stops its gradient)."""
    net = make_network(config)
    x = cast(jax.Array, net.apply(params, obs, method=net.embed))
    return _recurrence(params, carry, x, starts, config)[0]


def unroll(
    params: optax.Params,
    carry: Carry,
    steps: Transition,
    starts: jax.Array,
    config: Config,
) -> tuple[jax.Array, jax.Array]:
    """``(q, q_next)`` ``[T, B, A]`` over the steps (leaves ``[T, B, ...]``) from ``carry``:
    ``q`` of each step's observation, ``q_next`` of its true next observation read with the
    state reached on the step (before any reset), so that a truncation bootstraps as the episode
    would have gone on. Only the recurrence is a scan."""
    net = make_network(config)
    x = cast(jax.Array, net.apply(params, steps.obs, method=net.embed))
    _, (out, reached) = _recurrence(params, carry, x, starts, config)
    q = net.apply(params, out, method=net.head)
    return cast(jax.Array, q), apply(params, reached, steps.next_obs, config)[1]


# ---- state and replay ---------------------------------------------------------------------------
@struct.dataclass
class Agent:
    """The online and target Q-networks, the optimizer state and, with ``policy_checkpoints``,
    the checkpoint."""

    online: optax.Params
    target: optax.Params
    opt_state: optax.InjectStatefulHyperparamsState  # holds the learning rate
    # policy_checkpoints: the checkpoint of Q-network parameters (None without: the state and
    # checkpoints of runs without it stay as they were)
    checkpoint: PolicyCheckpoint | None = None


def init_buffer(example: Transition, config: Config) -> SequenceReplay:
    """An empty sequence replay; each step keeps the state its action was chosen with."""
    example = example._replace(policy_state=initial_carry(config))
    size = r2d2_parts.capacity(config.buffer_size, config.seq_period)
    return r2d2_parts.init(
        example, config.num_envs, config.seq_len, config.seq_period, size, config.prioritized
    )


def add_to_buffer(
    buffer: SequenceReplay, transitions: Transition, config: Config, hparams: Hyperparams
) -> SequenceReplay:
    """One step of every env into the sequence replay."""
    return r2d2_parts.add(buffer, transitions, hparams.priority_alpha)


# ---- learning -----------------------------------------------------------------------------------
def loss_fn(
    online: optax.Params,
    target: optax.Params,
    batch: Sequence,
    weights: jax.Array,
    hparams: Hyperparams,
    config: Config,
) -> tuple[jax.Array, tuple[jax.Array, jax.Array]]:
    """``(loss, (td_error [T - burn_in, B], mean q of the taken actions))`` of sequences
    ``[B, L, ...]`` from their stored states."""
    steps = jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), batch.steps)
    starts = r2d2_parts.episode_starts(steps.terminated, steps.truncated)
    warm, learn = config.burn_in, slice(config.burn_in, None)
    carry = cast(Carry, batch.start_state)
    online_carry = advance(online, carry, steps.obs[:warm], starts[:warm], config)
    target_carry = advance(target, carry, steps.obs[:warm], starts[:warm], config)
    online_carry, target_carry = jax.lax.stop_gradient((online_carry, target_carry))
    steps = jax.tree.map(lambda x: x[learn], steps)
    q, q_next_online = unroll(online, online_carry, steps, starts[learn], config)
    _, q_next_target = unroll(target, target_carry, steps, starts[learn], config)
    best = jnp.argmax(q_next_online, axis=-1)
    v_t = jnp.take_along_axis(q_next_target, best[..., None], axis=-1)[..., 0]
    ended = jnp.logical_or(steps.terminated, steps.truncated)
    discount_t = hparams.gamma * (1.0 - steps.terminated.astype(jnp.float32))
    y = r2d2_parts.rescaled_n_step_targets(
        steps.reward, discount_t, v_t, ended, config.n_step, hparams.rescale_eps
    )
    action = steps.action.astype(jnp.int32)
    q_taken = jnp.take_along_axis(q, action[..., None], axis=-1)[..., 0]
    td_error = y - q_taken
    loss = jnp.mean(weights * jnp.mean(0.5 * td_error**2, axis=0))
    return loss, (td_error, jnp.mean(q_taken))


def update(
    agent: Agent,
    buffer: SequenceReplay,
    key: jax.Array,
    config: Config,
    hparams: Hyperparams,
    update_index: jax.Array,
) -> tuple[Agent, SequenceReplay, dict[str, jax.Array]]:
    """One gradient update on sampled sequences, then (when due) a target step and the
    sequences' new priorities."""
    batch, weights, indices = r2d2_parts.sample(
        buffer, key, config.batch_size, hparams.priority_beta
    )
    (loss, (td_error, q)), grads = jax.value_and_grad(loss_fn, has_aux=True)(
        agent.online, agent.target, batch, weights, hparams, config
    )
    env_steps = offpolicy.env_steps_at_update(update_index, config)
    online, opt_state = injected_step(
        clipped_adam,
        grads,
        agent.opt_state,
        agent.online,
        learning_rate=linearly_decayed(hparams.learning_rate, env_steps, hparams.lr_decay_steps),
        max_grad_norm=hparams.max_grad_norm,
        adam_eps=hparams.adam_eps,
    )
    due = (update_index + 1) % config.target_update_period == 0
    target = jax.lax.cond(
        due, lambda: polyak_update(agent.target, online, hparams.tau), lambda: agent.target
    )
    priorities = r2d2_parts.sequence_priorities(td_error, hparams.priority_eta)
    buffer = r2d2_parts.write_priorities(
        buffer, indices, priorities + hparams.priority_eps, hparams.priority_alpha
    )
    agent = dataclasses.replace(agent, online=online, target=target, opt_state=opt_state)
    return agent, buffer, {"loss": loss, "q": q, "epsilon": epsilon_at(env_steps, hparams)}


# ---- acting -------------------------------------------------------------------------------------
def epsilon_at(env_steps: jax.Array, hparams: Hyperparams) -> jax.Array:
    """The exploration rate after ``env_steps``: linear from ``epsilon_start`` to
    ``epsilon_end`` over ``epsilon_decay_steps``, then constant."""
    return linear_schedule(
        hparams.epsilon_start, hparams.epsilon_end, env_steps, hparams.epsilon_decay_steps
    )


def greedy(
    params: optax.Params, carry: Carry, obs: jax.Array, config: Config
) -> tuple[jax.Array, Carry]:
    """Greedy actions ``[N]`` int32 of the network at ``params``, and the next states."""
    carry, q = apply(params, carry, obs, config)
    return jnp.argmax(q, axis=-1).astype(jnp.int32), carry


def policy_params(agent: Agent, config: Config) -> optax.Params:
    """The network whose greedy policy is evaluated, saved as best/ and loaded: the online one,
    or with ``policy_checkpoints`` the checkpoint's."""
    if config.policy_checkpoints:
        return cast(PolicyCheckpoint, agent.checkpoint).best
    return agent.online


def act(agent: Agent, carry: Carry, obs: jax.Array, config: Config) -> tuple[jax.Array, Carry]:
    """Greedy actions ``[N]`` int32 of ``policy_params``' network, and the next states."""
    return greedy(policy_params(agent, config), carry, obs, config)


def explore(
    agent: Agent,
    obs: jax.Array,
    carry: Carry,
    key: jax.Array,
    config: Config,
    hparams: Hyperparams,
    clock: Clock,
) -> tuple[jax.Array, Carry]:
    """``(actions, next states)``: epsilon-greedy on the online network (with
    ``policy_checkpoints``, the assessed copy's); the loop's exploration state is the LSTM's
    (``Learner.policy_state``)."""
    acting = agent.online
    if config.policy_checkpoints:
        acting = cast(PolicyCheckpoint, agent.checkpoint).assessed
    exploit, carry = greedy(acting, carry, obs, config)
    num_actions = make_network(config).num_actions
    return epsilon_greedy(key, exploit, num_actions, epsilon_at(clock.env_steps, hparams)), carry


def observe(
    agent: Agent,
    transitions: Transition,
    episode_return: jax.Array,
    done: jax.Array,
    clock: Clock,
    config: Config,
    hparams: Hyperparams,
) -> Agent:
    """Every env step: policy checkpoints count the episodes that ended (each env's next episode
    starts from the zero state, so an episode begun under the assessed copy is wholly its)."""
    return policy_checkpoints.observe_online(
        agent, episode_return, done, clock, config, hparams.checkpoint_reset_weight
    )


def init_agent(
    key: jax.Array,
    config: Config,
    hparams: Hyperparams,
    obs_space: envs.Space,
    action_space: envs.Space,
) -> Agent:
    """A fresh agent: the target network a copy of the online one (and a checkpoint of it with
    ``policy_checkpoints``)."""
    if envs.has_action_mask(episodes.make_eval_env(config)):
        raise ValueError(f"r2d2 does not read action masks, which {config.env_id} has")
    obs = jnp.zeros(obs_space.shape, jnp.float32)
    online = make_network(config).init(key, initial_carry(config), obs)
    optimizer = optax.inject_hyperparams(clipped_adam)(
        hparams.learning_rate, hparams.max_grad_norm, hparams.adam_eps
    )
    agent = Agent(online=online, target=online, opt_state=optimizer.init(online))
    if config.policy_checkpoints:
        checkpoint = policy_checkpoints.init(online, config.num_envs, config.learning_starts)
        agent = dataclasses.replace(agent, checkpoint=checkpoint)
    return agent


LEARNER = offpolicy.Learner(
    init_agent,
    explore,
    cast(Any, act),
    update,
    ("loss", "q", "epsilon"),
    init_buffer,
    add_to_buffer,
    observe,
    policy_state=initial_carry,
)


# ---- recipes ------------------------------------------------------------------------------------
# CartPole: the policy a run ends with is TD7's checkpoint, as DQN's CartPole recipe does: the
# greedy policy alone dips below 500 again after first reaching it (RESULTS.md).
_CARTPOLE: dict[str, Setting] = {
    "num_envs": 4,
    "updates_per_iteration": 1,
    "iterations_per_chunk": 2500,
    "learning_starts": 2000,
    "buffer_size": 100_000,
    "batch_size": 32,
    "n_step": 5,  # the paper's
    "policy_checkpoints": True,
    "checkpoint_episodes_from": 20_000,
}
RECIPES = Recipes(
    Recipe(
        "default",
        "LSTM 64 on a 64-unit layer, sequences of 20 (burn-in 5, overlap 10), 5-step targets, "
        "rate 1e-3 to 0 over 200k steps, TD7's policy checkpoints from 20k",
        _CARTPOLE,
        {"lr_decay_steps": 200_000.0},
        envs=("rl_jax/CartPoleNoVel-v1", "rl_jax/CartPole-v1"),
        total_steps=200_000,
    ),
)


# ---- the Algorithm object -----------------------------------------------------------------------
class R2D2(offpolicy.OffPolicyAlgorithm[Config]):
    """R2D2 as an ``rl_jax.training.algorithm.Algorithm`` with a recurrent policy."""

    name = "r2d2"
    config_type, hparams_type = Config, Hyperparams
    recipes = RECIPES
    learner = LEARNER
    ranges = {
        "max_grad_norm": validation.POSITIVE,
        "rescale_eps": validation.POSITIVE,
        "adam_eps": validation.POSITIVE,
        "priority_eta": validation.UNIT,
    }

    def initial_policy_state(self, config: Config) -> Carry:
        """The LSTM's zero state: the policy is recurrent."""
        return initial_carry(config)

    def policy(  # type: ignore[override]
        self, state: TrainState, config: Config
    ) -> Callable[[Carry, jax.Array], tuple[jax.Array, Carry]]:
        """``(carry, obs) -> (action index, carry)`` of the greedy policy, for one env."""
        return episodes.one_env_recurrent_policy(act, state.agent, config)  # type: ignore[return-value]

    def make_env(self, config: Config) -> envs.Environment:
        """The env as the policy sees it (``episodes.make_eval_env``)."""
        return episodes.make_eval_env(config)


r2d2 = R2D2()
default_config, default_hyperparams = r2d2.default_config, r2d2.default_hyperparams
init, train_chunk = r2d2.init, r2d2.train_chunk
