"""Cart-pole (``rl_jax/CartPole-v1``) with gymnasium 1.4.0 ``CartPole-v1``'s dynamics, reward,
termination, truncation (500 steps) and reset distribution, in float32.

The system is Barto, Sutton & Anderson's (1983) cart-pole, integrated with explicit Euler at
``tau = 0.02`` s (or semi-implicit Euler with ``kinematics_integrator="semi-implicit"``).
Reward is +1 on every step including the terminating one (or 0 / -1 with
``sutton_barto_reward=True``). Physical constants, thresholds and the reset bounds are params
fields, so they can be varied per env under vmap.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from rl_jax.envs.classic.drawing import Canvas
from rl_jax.envs.core.core import Array, Environment, EnvParams, EnvState, PRNGKey, float32_field
from rl_jax.envs.core.spaces import Box, Discrete


@struct.dataclass
class CartPoleState(EnvState):
    """The cart-pole's four state variables, as gymnasium's ``env.unwrapped.state``."""

    x: Array  # [] float32, cart position
    x_dot: Array  # [] float32, cart velocity
    theta: Array  # [] float32, pole angle from upright (positive leans right)
    theta_dot: Array  # [] float32


@struct.dataclass
class CartPoleParams(EnvParams):
    """gymnasium's CartPole constants, as vmappable float32 fields."""

    gravity: Array = float32_field(9.8)
    masscart: Array = float32_field(1.0)
    masspole: Array = float32_field(0.1)
    length: Array = float32_field(0.5)  # half the pole's length
    force_mag: Array = float32_field(10.0)
    tau: Array = float32_field(0.02)  # seconds per step
    theta_threshold_radians: Array = float32_field(12 * 2 * math.pi / 360)
    x_threshold: Array = float32_field(2.4)
    reset_low: Array = float32_field(-0.05)  # every state variable starts uniform in [low, high]
    reset_high: Array = float32_field(0.05)


class CartPole(Environment[CartPoleState, CartPoleParams]):
    """Action ``Discrete(2)``: 0 pushes left, 1 right. Obs ``(x, x_dot, theta, theta_dot)``."""

    max_episode_steps = 500
    render_fps = 50
    #: gymnasium ``reset(options=...)`` keys -> params fields they set for that reset
    reset_option_params = {"low": "reset_low", "high": "reset_high"}

    def __init__(self, sutton_barto_reward: bool = False, kinematics_integrator: str = "euler"):
        if kinematics_integrator not in ("euler", "semi-implicit"):
            choice = repr(kinematics_integrator)
            raise ValueError(f"kinematics_integrator: 'euler' or 'semi-implicit', not {choice}")
        self.sutton_barto_reward = sutton_barto_reward
        self.kinematics_integrator = kinematics_integrator

    @property
    def default_params(self) -> CartPoleParams:
        """gymnasium's CartPole-v1 constants."""
        return CartPoleParams()

    def reset_env(self, key: PRNGKey, params: CartPoleParams) -> tuple[CartPoleState, Array]:
        """Every state variable uniform in ``[reset_low, reset_high]``; the observation is the
        state.
        """
        values = jax.random.uniform(key, (4,), jnp.float32, params.reset_low, params.reset_high)
        return self._state_and_obs(values)

    def state_from_vector(
        self, vector: Array, params: CartPoleParams | None = None
    ) -> tuple[CartPoleState, Array]:
        """``vector = [x, x_dot, theta, theta_dot]``, as gymnasium's ``env.unwrapped.state``."""
        return self._state_and_obs(jnp.asarray(vector, jnp.float32).reshape(4))

    def state_to_vector(self, state: CartPoleState) -> Array:
        """The inverse of ``state_from_vector``: ``[x, x_dot, theta, theta_dot]``."""
        return jnp.stack([state.x, state.x_dot, state.theta, state.theta_dot])

    def _state_and_obs(self, values: Array) -> tuple[CartPoleState, Array]:
        state = CartPoleState(jnp.int32(0), values[0], values[1], values[2], values[3])
        return state, values

    def step_env(self, key: PRNGKey, state: CartPoleState, action: Array, params: CartPoleParams):
        """Push the cart left (action 0) or right (1) with ``force_mag`` for ``tau`` seconds.

        Integrates gymnasium's equations of motion (Euler or semi-implicit Euler), pays 1 per step
        (the terminal step included, as gymnasium does) and terminates when the cart leaves
        ``x_threshold`` or the pole tips past ``theta_threshold_radians``.
        """
        force = jnp.where(jnp.reshape(action, ()) == 1, params.force_mag, -params.force_mag)
        x_dot, theta_dot = state.x_dot, state.theta_dot
        x_acc, theta_acc = _accelerations(state.theta, theta_dot, force, params)
        tau = params.tau
        if self.kinematics_integrator == "euler":
            x, theta = state.x + tau * x_dot, state.theta + tau * theta_dot
            x_dot, theta_dot = x_dot + tau * x_acc, theta_dot + tau * theta_acc
        else:
            x_dot, theta_dot = x_dot + tau * x_acc, theta_dot + tau * theta_acc
            x, theta = state.x + tau * x_dot, state.theta + tau * theta_dot
        terminated = (
            (x < -params.x_threshold)
            | (x > params.x_threshold)
            | (theta < -params.theta_threshold_radians)
            | (theta > params.theta_threshold_radians)
        )
        if self.sutton_barto_reward:
            reward = jnp.where(terminated, -1.0, 0.0)
        else:
            reward = jnp.ones((), jnp.float32)
        new_state = CartPoleState(state.time + 1, x, x_dot, theta, theta_dot)
        return new_state, jnp.stack([x, x_dot, theta, theta_dot]), reward, terminated, {}

    def observation_space(self, params: CartPoleParams | None = None) -> Box:
        """gymnasium's observation box: twice the termination thresholds for position and angle,
        velocities unbounded.
        """
        params = self.default_params if params is None else params
        high = np.array(
            [2 * params.x_threshold, np.inf, 2 * params.theta_threshold_radians, np.inf], np.float32
        )
        return Box(-high, high, (4,))

    def action_space(self, params: CartPoleParams | None = None) -> Discrete:
        """Two actions: 0 pushes left, 1 pushes right."""
        return Discrete(2)

    def render(self, state: CartPoleState, params: CartPoleParams | None = None) -> np.ndarray:
        """A 600x400 RGB frame laid out as gymnasium's: cart on a track, pole from the axle."""
        params = self.default_params if params is None else params
        return draw_cartpole(float(state.x), float(state.theta), params)


def _accelerations(
    theta: Array, theta_dot: Array, force: Array, params: CartPoleParams
) -> tuple[Array, Array]:
    """Frictionless cart-pole accelerations, grouped as in Barto, Sutton & Anderson's pole.c."""
    total_mass = params.masspole + params.masscart
    polemass_length = params.masspole * params.length
    cos_theta, sin_theta = jnp.cos(theta), jnp.sin(theta)
    temp = (force + polemass_length * theta_dot**2 * sin_theta) / total_mass
    theta_acc = (params.gravity * sin_theta - cos_theta * temp) / (
        params.length * (4.0 / 3.0 - params.masspole * cos_theta**2 / total_mass)
    )
    x_acc = temp - polemass_length * theta_acc * cos_theta / total_mass
    return x_acc, theta_acc


def draw_cartpole(x: float, theta: float, params: CartPoleParams) -> np.ndarray:
    """A 600x400 RGB frame of the cart at ``x`` with the pole at angle ``theta``, laid out as
    gymnasium's renderer draws it.
    """
    width, height = 600, 400
    scale = width / (2 * float(params.x_threshold))
    canvas = Canvas(width, height)
    cart_x = x * scale + width / 2.0
    cart_top = height - 100.0  # gymnasium puts the cart's top 100 px above the bottom
    canvas.line((0, cart_top), (width, cart_top), 1, (0, 0, 0))
    canvas.rectangle(cart_x - 25, cart_top - 15, cart_x + 25, cart_top + 15, (0, 0, 0))
    axle = (cart_x, cart_top - 7.5)
    pole_length = scale * 2 * float(params.length)
    tip = (axle[0] + pole_length * math.sin(theta), axle[1] - pole_length * math.cos(theta))
    canvas.line(axle, tip, 10, (202, 152, 101))
    canvas.circle(axle, 5, (129, 132, 203))
    return canvas.image()
