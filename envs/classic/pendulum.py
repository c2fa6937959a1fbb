"""Torque-limited pendulum swing-up (``rl_jax/Pendulum-v1``) with gymnasium 1.4.0
``Pendulum-v1``'s dynamics, reward, truncation (200 steps, never terminates) and reset
distribution, in float32.

``theta = 0`` is upright. Each step the torque is clipped to ``max_torque``, the cost
``normalize(theta)^2 + 0.1 theta_dot^2 + 0.001 u^2`` of the *current* state is paid, then
``theta_dot`` takes a semi-implicit Euler step (clipped to ``max_speed``) and ``theta`` follows it.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from rl_jax.envs.classic.drawing import Canvas
from rl_jax.envs.core.core import Array, Environment, EnvParams, EnvState, PRNGKey, float32_field
from rl_jax.envs.core.spaces import Box


@struct.dataclass
class PendulumState(EnvState):
    """The pendulum's angle and angular velocity, plus the last torque for drawing."""

    theta: Array  # [] float32, angle from upright, not wrapped (as gymnasium's)
    theta_dot: Array  # [] float32
    last_torque: Array  # [] float32, the clipped torque of the last step (for rendering)


@struct.dataclass
class PendulumParams(EnvParams):
    """gymnasium's Pendulum constants and reset ranges, as vmappable float32 fields."""

    max_speed: Array = float32_field(8.0)
    max_torque: Array = float32_field(2.0)
    dt: Array = float32_field(0.05)
    g: Array = float32_field(10.0)
    m: Array = float32_field(1.0)
    l: Array = float32_field(1.0)  # noqa: E741 - gymnasium's name for the length
    x_init: Array = float32_field(math.pi)  # reset: theta uniform in [-x_init, x_init]
    y_init: Array = float32_field(1.0)  # reset: theta_dot uniform in [-y_init, y_init]


def angle_normalize(theta: Array) -> Array:
    """Wrap an angle into [-pi, pi)."""
    return ((theta + jnp.pi) % (2 * jnp.pi)) - jnp.pi


class Pendulum(Environment[PendulumState, PendulumParams]):
    """Action ``Box(-2, 2, (1,))`` torque; obs ``(cos theta, sin theta, theta_dot)``."""

    max_episode_steps = 200
    render_fps = 30
    #: gymnasium ``reset(options=...)`` keys -> params fields they set for that reset
    reset_option_params = {"x_init": "x_init", "y_init": "y_init"}

    @property
    def default_params(self) -> PendulumParams:
        """gymnasium's Pendulum-v1 constants."""
        return PendulumParams()

    def reset_env(self, key: PRNGKey, params: PendulumParams) -> tuple[PendulumState, Array]:
        """Angle uniform in ``[-x_init, x_init]`` and velocity in ``[-y_init, y_init]``."""
        high = jnp.stack([params.x_init, params.y_init]).astype(jnp.float32)
        values = jax.random.uniform(key, (2,), jnp.float32, -high, high)
        return self._state_and_obs(values[0], values[1], jnp.zeros((), jnp.float32))

    def state_from_vector(
        self, vector: Array, params: PendulumParams | None = None
    ) -> tuple[PendulumState, Array]:
        """``vector = [theta, theta_dot]``, as gymnasium's ``env.unwrapped.state``."""
        values = jnp.asarray(vector, jnp.float32).reshape(2)
        return self._state_and_obs(values[0], values[1], jnp.zeros((), jnp.float32))

    def state_to_vector(self, state: PendulumState) -> Array:
        """The inverse of ``state_from_vector``: ``[theta, theta_dot]``."""
        return jnp.stack([state.theta, state.theta_dot])

    def _state_and_obs(
        self, theta: Array, theta_dot: Array, torque: Array, time: Array | None = None
    ) -> tuple[PendulumState, Array]:
        time = jnp.int32(0) if time is None else time
        state = PendulumState(time=time, theta=theta, theta_dot=theta_dot, last_torque=torque)
        return state, jnp.stack([jnp.cos(theta), jnp.sin(theta), theta_dot])

    def step_env(self, key: PRNGKey, state: PendulumState, action: Array, params: PendulumParams):
        """Apply the clipped torque for ``dt`` seconds, as gymnasium's Pendulum-v1 does.

        The reward is minus the cost ``angle^2 + 0.1 velocity^2 + 0.001 torque^2`` of the state
        before the step (angle normalised to [-pi, pi]); the pendulum never terminates.
        """
        torque = jnp.clip(jnp.asarray(action, jnp.float32), -params.max_torque, params.max_torque)
        torque = jnp.reshape(torque, (-1,))[0]
        theta, theta_dot = state.theta, state.theta_dot
        costs = angle_normalize(theta) ** 2 + 0.1 * theta_dot**2 + 0.001 * torque**2
        gravity_term = 3 * params.g / (2 * params.l) * jnp.sin(theta)
        torque_term = 3.0 / (params.m * params.l**2) * torque
        new_theta_dot = theta_dot + (gravity_term + torque_term) * params.dt
        new_theta_dot = jnp.clip(new_theta_dot, -params.max_speed, params.max_speed)
        new_theta = theta + new_theta_dot * params.dt
        new_state, obs = self._state_and_obs(new_theta, new_theta_dot, torque, state.time + 1)
        return new_state, obs, -costs, jnp.zeros((), jnp.bool_), {}

    def observation_space(self, params: PendulumParams | None = None) -> Box:
        """``(cos theta, sin theta, theta_dot)``, the velocity bounded by ``max_speed``."""
        params = self.default_params if params is None else params
        high = np.array([1.0, 1.0, params.max_speed], np.float32)
        return Box(-high, high, (3,))

    def action_space(self, params: PendulumParams | None = None) -> Box:
        """One torque in ``[-max_torque, max_torque]``."""
        params = self.default_params if params is None else params
        return Box(-params.max_torque, params.max_torque, (1,))

    def render(self, state: PendulumState, params: PendulumParams | None = None) -> np.ndarray:
        """A 500x500 RGB frame as gymnasium's: red rod from the pivot, torque bar underneath."""
        params = self.default_params if params is None else params
        return draw_pendulum(float(state.theta), float(state.last_torque), float(params.max_torque))


def draw_pendulum(theta: float, torque: float, max_torque: float = 2.0) -> np.ndarray:
    """A 500x500 RGB frame of the pendulum at ``theta``, with a bar showing the applied
    ``torque``.
    """
    size = 500
    canvas = Canvas(size, size)
    center = (size / 2, size / 2)
    rod_length = size / 2.2 * 0.8  # gymnasium: 1 unit of length spans size / 2.2 pixels
    # theta = 0 points up and positive theta turns counter-clockwise, as in gymnasium's frames.
    tip = (center[0] - rod_length * math.sin(theta), center[1] - rod_length * math.cos(theta))
    canvas.line(center, tip, size / 2.2 * 0.2, (204, 77, 77))
    canvas.circle(center, size / 2.2 * 0.05, (0, 0, 0))
    # Torque: a bar pointing the way it pushes the tip of an upright pole.
    bar = torque / max(max_torque, 1e-6) * size * 0.3
    canvas.line((size / 2, size - 30), (size / 2 - bar, size - 30), 8, (60, 60, 60))
    return canvas.image()
