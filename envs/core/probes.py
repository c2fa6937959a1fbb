"""Probe environments: tiny MDPs whose value function and best action are known exactly.

They isolate one piece of a learner at a time (the usual debugging ladder for RL):

* ``ConstantReward`` — one step, reward 1: the value net must learn Q = 1 (fits a constant).
* ``ActionReward`` — one step, reward ``1 - (a - 0.5)^2``: Q depends only on the action; the
  policy must find a = 0.5 (the actor's gradient through the critic).
* ``TwoStep`` — obs 0, then obs 1, reward 1 at the end: Q(obs 0) = gamma, Q(obs 1) = 1
  (discounting and bootstrapping through a non-terminal step).
* ``Truncation`` — obs in {0, 1}, reward = obs, obs flips every step, and every episode is *cut by
  the time limit* after one step, never terminated. Bootstrapping through truncation from the true
  final observation gives Q(0) = gamma / (1 - gamma^2), Q(1) = 1 / (1 - gamma^2); treating the cut
  as terminal gives 0 and 1; bootstrapping from the next episode's first obs (a lost final obs)
  gives gamma / (2 (1 - gamma)) and 1 + that. ``Termination`` is the same MDP ending in a true
  terminal state: Q(0) = 0, Q(1) = 1.

Every probe takes ``num_actions``: ``None`` gives a continuous ``Box(-1, 1, (1,))`` action, an int
``n`` gives ``Discrete(n)`` whose index ``i`` stands for the i-th of ``n`` evenly spaced values in
[-1, 1] (so the reward functions, and the known answers, are the same for DQN-style learners).
Observations are ``(1,)`` float32. Importing this module registers the ``rl_jax/Probe*`` ids;
``rl_jax/Probe*Discrete-v0`` are the discrete-action versions (``DISCRETE_ACTIONS`` = 5 actions:
index 3 stands for 0.5, the best action of ``ActionReward``).

``RememberFirst`` (``rl_jax/ProbeRememberFirst-v0``, ``...Discrete-v0`` with two actions) probes
memory: the reward depends on the first observation only, which a feed-forward policy no longer
sees when it is paid.

``FatalIllegalActions`` (``rl_jax/ProbeFatalIllegalActions-v0``) probes the legal-action mask
(``info["action_mask"]``): an illegal action terminates with a large negative reward.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from rl_jax.envs.core.core import Array, Environment, EnvParams, EnvState, PRNGKey, float32_field
from rl_jax.envs.core.preprocessing import ACTION_MASK
from rl_jax.envs.core.registry import register
from rl_jax.envs.core.spaces import Box, Discrete, Space


@struct.dataclass
class ProbeState(EnvState):
    """A probe's state: its one-dimensional observation value."""

    position: Array  # [] float32, the current observation value


@struct.dataclass
class ProbeParams(EnvParams):
    """Probes have no dynamic parameters."""

    pass


class Probe(Environment[ProbeState, ProbeParams]):
    """Shared plumbing: a scalar position observed as ``(1,)``, continuous or discrete actions."""

    max_episode_steps = 1

    def __init__(self, num_actions: int | None = None):
        if num_actions is not None and num_actions < 2:
            raise ValueError(f"num_actions must be None (continuous) or >= 2, got {num_actions}")
        self.num_actions = num_actions

    @property
    def default_params(self) -> ProbeParams:
        """The empty params of every probe."""
        return ProbeParams()

    def observation_space(self, params: ProbeParams | None = None) -> Space:
        """One observation value in [-1, 1]."""
        return Box(-1.0, 1.0, (1,))

    def action_space(self, params: ProbeParams | None = None) -> Space:
        """One action in [-1, 1], or ``Discrete(num_actions)`` for a discrete probe."""
        if self.num_actions is None:
            return Box(-1.0, 1.0, (1,))
        return Discrete(self.num_actions)

    def action_value(self, action: Array) -> Array:
        """The scalar in [-1, 1] an action stands for (an index maps onto an even grid)."""
        if self.num_actions is None:
            return jnp.clip(jnp.reshape(action, ()), -1.0, 1.0)
        grid = jnp.asarray(np.linspace(-1.0, 1.0, self.num_actions, dtype=np.float32))
        return grid[jnp.asarray(action, jnp.int32)]

    def start_position(self, key: Array) -> Array:
        """The first observation value of an episode (0 unless a probe overrides it)."""
        return jnp.zeros((), jnp.float32)

    def reset_env(self, key: PRNGKey, params: ProbeParams):
        """Start at ``start_position``; the observation is that value."""
        position = self.start_position(key)
        return ProbeState(time=jnp.int32(0), position=position), position[None]

    def state_from_vector(self, vector: Array, params: ProbeParams | None = None):
        """Start at the one observation value given in ``vector``."""
        position = jnp.asarray(vector, jnp.float32).reshape(())
        return ProbeState(time=jnp.int32(0), position=position), position[None]

    def _next(
        self,
        state: ProbeState,
        position: float | Array,
        reward: float | Array,
        terminated: bool | Array,
    ):
        next_state = ProbeState(time=state.time + 1, position=jnp.asarray(position, jnp.float32))
        terminated = jnp.asarray(terminated, jnp.bool_)
        return next_state, next_state.position[None], jnp.asarray(reward, jnp.float32), terminated


class ConstantReward(Probe):
    """One step, reward 1, terminal. Q(s, a) = 1 for every action."""

    def step_env(self, key: PRNGKey, state: ProbeState, action: Array, params: ProbeParams):
        """Reward 1, then the episode terminates."""
        return (*self._next(state, 0.0, 1.0, True), {})


class ActionReward(Probe):
    """One step, reward ``1 - (a - 0.5)^2``, terminal. Best action 0.5 with Q = 1."""

    best_action = 0.5

    def step_env(self, key: PRNGKey, state: ProbeState, action: Array, params: ProbeParams):
        """Reward ``1 - (action - best_action)^2``, then the episode terminates."""
        reward = 1.0 - (self.action_value(action) - self.best_action) ** 2
        return (*self._next(state, 0.0, reward, True), {})


class TwoStep(Probe):
    """Obs 0 (reward 0) -> obs 1 (reward 1, terminal). Q(0, a) = gamma, Q(1, a) = 1."""

    max_episode_steps = 2

    def step_env(self, key: PRNGKey, state: ProbeState, action: Array, params: ProbeParams):
        """Reward 0 on the first step and 1 on the second, which terminates."""
        at_end = state.position >= 0.5
        return (*self._next(state, 1.0, jnp.where(at_end, 1.0, 0.0), at_end), {})


class Truncation(Probe):
    """Obs in {0, 1} uniformly at reset; reward = obs; obs flips; the time limit cuts every episode
    after one step. Values with correct bootstrapping: Q(0) = g / (1 - g^2), Q(1) = 1 / (1 - g^2).
    """

    terminal = False

    def start_position(self, key: Array):
        """0 or 1 with equal chance."""
        return jax.random.bernoulli(key).astype(jnp.float32)

    def step_env(self, key: PRNGKey, state: ProbeState, action: Array, params: ProbeParams):
        """Flip the position (0 <-> 1) and pay the old one; the episode is terminal only when
        ``terminal`` is set (``Termination``), otherwise the time limit truncates it.
        """
        return (*self._next(state, 1.0 - state.position, state.position, self.terminal), {})

    @staticmethod
    def true_q(position: float, gamma: float, terminal: bool = False) -> float:
        """The exact Q-value at ``position`` under discount ``gamma``: bootstrapped through the
        truncation, or the reward alone when the step is ``terminal``. Tests compare a critic
        with it.
        """
        if terminal:
            return float(position)
        return (gamma ** (1.0 - position)) / (1.0 - gamma**2)


class Termination(Truncation):
    """The ``Truncation`` MDP, but each step ends in a true terminal state: Q(0) = 0, Q(1) = 1."""

    terminal = True


@struct.dataclass
class RememberFirstState(ProbeState):
    """``RememberFirst``'s state: the position and the first observation's sign."""

    first: Array  # [] float32, -1 or 1


class RememberFirst(Probe):
    """A memory probe: the first observation is -1 or 1 (equal chance), every later one 0; the
    last of ``length`` steps pays ``first * a`` and terminates, the others pay 0. A policy that
    remembers the first observation earns 1 (action ``first``); a feed-forward one sees 0 on the
    step that pays and earns 0 at best."""

    length = 3
    max_episode_steps = 3

    def reset_env(self, key: PRNGKey, params: ProbeParams):
        """Observe the first sign; the episode's later observations are 0."""
        first = jnp.where(jax.random.bernoulli(key), 1.0, -1.0).astype(jnp.float32)
        state = RememberFirstState(time=jnp.int32(0), position=first, first=first)
        return state, first[None]

    def state_from_vector(self, vector: Array, params: ProbeParams | None = None):
        """Start at the first sign given in ``vector``."""
        first = jnp.sign(jnp.asarray(vector, jnp.float32).reshape(()))
        state = RememberFirstState(time=jnp.int32(0), position=first, first=first)
        return state, first[None]

    def step_env(self, key: PRNGKey, state: ProbeState, action: Array, params: ProbeParams):
        """Pay ``first * a`` on the last step, which terminates; 0 and observation 0 before."""
        assert isinstance(state, RememberFirstState)  # reset_env and state_from_vector make one
        last = state.time + 1 >= self.length
        reward = jnp.where(last, state.first * self.action_value(action), 0.0)
        next_state = RememberFirstState(
            time=state.time + 1, position=jnp.zeros((), jnp.float32), first=state.first
        )
        zero = jnp.zeros((1,), jnp.float32)
        return next_state, zero, reward.astype(jnp.float32), last, {}


@struct.dataclass
class IllegalActionsState(EnvState):
    """``FatalIllegalActions``'s state: which actions are legal now."""

    legal: Array  # [num_actions] bool, at least one True


@struct.dataclass
class IllegalActionsParams(EnvParams):
    """The reward of an illegal action, which also ends the episode."""

    illegal_reward: Array = float32_field(-10.0)


class FatalIllegalActions(Environment[IllegalActionsState, IllegalActionsParams]):
    """An env with a legal-action mask whose illegal actions are fatal: taking one pays
    ``illegal_reward`` (-10) and terminates.

    Each state's legal actions are a uniform draw among the non-empty subsets of the
    ``num_actions`` (4) actions, reported as ``info["action_mask"]`` (reset's included) and as
    the observation (the mask as 0/1 floats). A legal action ``a`` pays ``(a + 1) / n`` and
    moves to a fresh draw; episodes are cut after 10 steps. The best policy takes the highest
    legal action: it never dies, and its values are ``true_q``. A learner that ignores the mask
    must learn the same from the observation, dying on the way.
    """

    max_episode_steps = 10

    def __init__(self, num_actions: int = 4):
        if not 2 <= num_actions <= 16:
            raise ValueError(f"num_actions must be in [2, 16], got {num_actions}")
        self.num_actions = num_actions

    @property
    def default_params(self) -> IllegalActionsParams:
        """An illegal action pays -10."""
        return IllegalActionsParams()

    def observation_space(self, params: IllegalActionsParams | None = None) -> Space:
        """The legal-action mask as 0/1 floats."""
        shape = (self.num_actions,)
        return Box(np.zeros(shape, np.float32), np.ones(shape, np.float32), shape)

    def action_space(self, params: IllegalActionsParams | None = None) -> Space:
        """``Discrete(num_actions)``."""
        return Discrete(self.num_actions)

    def empty_info(self) -> dict[str, Array]:
        """``action_mask``: all True."""
        return {ACTION_MASK: jnp.ones((self.num_actions,), jnp.bool_)}

    def draw_legal(self, key: Array) -> Array:
        """A uniform non-empty subset of the actions, as a bool ``[num_actions]`` mask."""
        subset = jax.random.randint(key, (), 1, 2**self.num_actions)
        return (subset >> jnp.arange(self.num_actions)) & 1 == 1

    def _at(self, legal: Array, time: Array) -> tuple[IllegalActionsState, Array]:
        return IllegalActionsState(time=time, legal=legal), legal.astype(jnp.float32)

    def reset_env(self, key: PRNGKey, params: IllegalActionsParams):
        """A fresh draw of legal actions; the observation is the mask."""
        return self._at(self.draw_legal(key), jnp.int32(0))

    def state_from_vector(self, vector: Array, params: IllegalActionsParams | None = None):
        """Start with the legal actions given as a 0/1 vector (not all 0)."""
        return self._at(jnp.asarray(vector).reshape(self.num_actions) > 0.5, jnp.int32(0))

    def first_info(self, state: IllegalActionsState):
        """The first timestep's ``info`` holds the episode's first legal actions."""
        return {ACTION_MASK: state.legal}

    def step_env(
        self, key: PRNGKey, state: IllegalActionsState, action: Array, params: IllegalActionsParams
    ):
        """Pay ``(a + 1) / n`` for a legal ``a`` and draw the next legal actions; an illegal
        action pays ``illegal_reward`` and terminates."""
        action = jnp.asarray(action, jnp.int32)
        legal = state.legal[action]
        reward = jnp.where(legal, (action + 1) / self.num_actions, params.illegal_reward)
        next_state, obs = self._at(self.draw_legal(key), state.time + 1)
        return next_state, obs, reward, ~legal, {ACTION_MASK: next_state.legal}

    def best_reward(self) -> float:
        """The mean reward of the best policy, ``E[(max legal a + 1) / n]``: of the
        ``2^n - 1`` subsets, ``2^a`` have ``a`` as their highest action."""
        n = self.num_actions
        return sum((a + 1) / n * 2**a for a in range(n)) / (2**n - 1)

    def true_q(self, legal: np.ndarray, gamma: float, illegal_reward: float = -10.0) -> np.ndarray:
        """The exact Q-values ``[num_actions]`` in a state with ``legal`` actions: a legal ``a``
        is worth ``(a + 1) / n`` plus ``gamma`` times the best policy's value, bootstrapped
        through the time limit (``best_reward / (1 - gamma)``); an illegal one its reward."""
        value = self.best_reward() / (1.0 - gamma)
        rewards = (np.arange(self.num_actions) + 1) / self.num_actions
        return np.where(np.asarray(legal, bool), rewards + gamma * value, illegal_reward)


DISCRETE_ACTIONS = 5


class _Discrete(Probe):
    """Mixed in first: the probe with ``DISCRETE_ACTIONS`` discrete actions by default."""

    def __init__(self, num_actions: int | None = DISCRETE_ACTIONS):
        super().__init__(num_actions)


class DiscreteConstantReward(_Discrete, ConstantReward):
    """``ConstantReward`` with discrete actions."""


class DiscreteActionReward(_Discrete, ActionReward):
    """``ActionReward`` with discrete actions: Q(0, i) = 1 - (linspace(-1, 1, 5)[i] - 0.5)^2."""


class DiscreteTwoStep(_Discrete, TwoStep):
    """``TwoStep`` with discrete actions."""


class DiscreteTruncation(_Discrete, Truncation):
    """``Truncation`` with discrete actions."""


class DiscreteTermination(_Discrete, Termination):
    """``Termination`` with discrete actions."""


class DiscreteRememberFirst(RememberFirst):
    """``RememberFirst`` with two discrete actions, standing for -1 and 1."""

    def __init__(self, num_actions: int | None = 2):
        super().__init__(num_actions)


PROBE_IDS = {
    "rl_jax/ProbeConstantReward-v0": "rl_jax.envs.core.probes:ConstantReward",
    "rl_jax/ProbeActionReward-v0": "rl_jax.envs.core.probes:ActionReward",
    "rl_jax/ProbeTwoStep-v0": "rl_jax.envs.core.probes:TwoStep",
    "rl_jax/ProbeTruncation-v0": "rl_jax.envs.core.probes:Truncation",
    "rl_jax/ProbeTermination-v0": "rl_jax.envs.core.probes:Termination",
    "rl_jax/ProbeConstantRewardDiscrete-v0": "rl_jax.envs.core.probes:DiscreteConstantReward",
    "rl_jax/ProbeActionRewardDiscrete-v0": "rl_jax.envs.core.probes:DiscreteActionReward",
    "rl_jax/ProbeTwoStepDiscrete-v0": "rl_jax.envs.core.probes:DiscreteTwoStep",
    "rl_jax/ProbeTruncationDiscrete-v0": "rl_jax.envs.core.probes:DiscreteTruncation",
    "rl_jax/ProbeTerminationDiscrete-v0": "rl_jax.envs.core.probes:DiscreteTermination",
    "rl_jax/ProbeFatalIllegalActions-v0": "rl_jax.envs.core.probes:FatalIllegalActions",
    "rl_jax/ProbeRememberFirst-v0": "rl_jax.envs.core.probes:RememberFirst",
    "rl_jax/ProbeRememberFirstDiscrete-v0": "rl_jax.envs.core.probes:DiscreteRememberFirst",
}
for _env_id, _entry_point in PROBE_IDS.items():
    register(_env_id, _entry_point)
