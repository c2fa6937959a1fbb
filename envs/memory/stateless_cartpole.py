"""POPGym's StatelessCartPole at difficulty Easy (``rl_jax/StatelessCartPoleEasy-v0``; popgym
1.0.7 names the class ``PositionOnlyCartPoleEasy``), in JAX.

gymnasium's CartPole-v1 dynamics, termination and start distribution (``envs.classic.cartpole``),
seen as popgym shows it: the cart position and pole angle only, in a box of twice the termination
thresholds. Every step pays ``1 / 200`` (popgym's transform of CartPole's +1, the terminating step
included), so a balanced episode returns 1; the episode is truncated after 200 steps. (popgym
pays -1 instead for a step taken after the episode terminated, which the reset-after-done
contract never asks of an env.)
"""

from __future__ import annotations

import numpy as np

from rl_jax.envs.classic.cartpole import CartPole, CartPoleParams, CartPoleState
from rl_jax.envs.core.core import Array, PRNGKey
from rl_jax.envs.core.spaces import Box

POSITIONS = np.array([0, 2])  # x and theta of CartPole's (x, x_dot, theta, theta_dot)
EPISODE_LENGTH = 200  # popgym's max_episode_length at Easy (400 at Medium, 600 at Hard)


class StatelessCartPole(CartPole):
    """Action ``Discrete(2)`` (0 pushes left, 1 right); obs ``(x, theta)``; reward 1/200 a step."""

    max_episode_steps = EPISODE_LENGTH

    def __init__(self) -> None:
        super().__init__()

    def _state_and_obs(self, values: Array) -> tuple[CartPoleState, Array]:
        state, obs = super()._state_and_obs(values)
        return state, obs[POSITIONS]

    def step_env(self, key: PRNGKey, state: CartPoleState, action: Array, params: CartPoleParams):
        """CartPole's step, observing ``(x, theta)`` and paying ``1 / 200``."""
        state, obs, reward, terminated, info = super().step_env(key, state, action, params)
        return state, obs[POSITIONS], reward / EPISODE_LENGTH, terminated, info

    def observation_space(self, params: CartPoleParams | None = None) -> Box:
        """popgym's box: twice the termination thresholds of position and angle."""
        space = super().observation_space(params)
        return Box(space.low[POSITIONS], space.high[POSITIONS], (len(POSITIONS),))
