"""A rocket hovering under gravity and air drag, written in pure JAX on rl_jax's env API."""

import jax
import jax.numpy as jnp
from flax import struct

from rl_jax import envs


@struct.dataclass
class HoverState(envs.EnvState):  # envs.EnvState holds `time`, the steps since reset
    height: jax.Array  # [] metres above the ground
    velocity: jax.Array  # [] metres per second, upwards positive


@struct.dataclass
class HoverParams(envs.EnvParams):  # dynamic: jit sees them as inputs, vmap can sweep them
    gravity: float = 9.81
    drag: float = 0.1  # quadratic air drag per unit mass
    max_thrust: float = 19.62  # thrust at action +1; action 0 gives half of it, which hovers
    target: float = 1.0  # the height to hover at
    ceiling: float = 3.0  # the episode ends at the ground or above the ceiling
    crash_penalty: float = 100.0
    dt: float = 0.02  # seconds per agent step: one RK4 step


def rk4_step(y: jax.Array, thrust: jax.Array, params: HoverParams) -> jax.Array:
    """One classical Runge-Kutta step of d/dt (height, velocity) with the thrust held."""

    def derivative(y):
        height, velocity = y
        drag = params.drag * velocity * jnp.abs(velocity)
        return jnp.stack([velocity, thrust - params.gravity - drag])

    k1 = derivative(y)
    k2 = derivative(y + params.dt / 2 * k1)
    k3 = derivative(y + params.dt / 2 * k2)
    k4 = derivative(y + params.dt * k3)
    return y + params.dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


class HoverRocket(envs.Environment):
    """Hover at `target`: obs (height, velocity), one action in [-1, 1] sets the thrust."""

    max_episode_steps = 200  # static: the base class sets `truncated` when time reaches it

    @property
    def default_params(self) -> HoverParams:
        return HoverParams()

    def reset_env(self, key, params):
        height_key, velocity_key = jax.random.split(key)
        height = jax.random.uniform(height_key, (), minval=0.2, maxval=2.0)
        velocity = jax.random.uniform(velocity_key, (), minval=-1.0, maxval=1.0)
        state = HoverState(time=jnp.int32(0), height=height, velocity=velocity)
        return state, jnp.stack([height, velocity])

    def step_env(self, key, state, action, params):
        thrust = (jnp.clip(action[0], -1.0, 1.0) + 1.0) / 2.0 * params.max_thrust
        y = rk4_step(jnp.stack([state.height, state.velocity]), thrust, params)
        height, velocity = y[0], y[1]
        crashed = (height <= 0.0) | (height >= params.ceiling)  # terminal: no bootstrapping
        reward = -((height - params.target) ** 2) - 0.1 * velocity**2
        reward = jnp.where(crashed, reward - params.crash_penalty, reward)
        state = HoverState(time=state.time + 1, height=height, velocity=velocity)
        return state, y, reward, crashed, {}  # (state, obs, reward, terminated, info)

    def observation_space(self, params=None):
        return envs.Box(low=[0.0, -10.0], high=[3.0, 10.0])

    def action_space(self, params=None):
        return envs.Box(low=-1.0, high=1.0, shape=(1,))


envs.register("examples/HoverRocket-v0", HoverRocket, max_episode_steps=200)
