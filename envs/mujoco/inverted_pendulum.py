"""rl_jax/InvertedPendulum-v5: gymnasium's MuJoCo cart-pole, on MJX or MuJoCo C.

gymnasium 1.4.0 ``InvertedPendulum-v5``: ``inverted_pendulum.xml`` (RK4, timestep 0.02), frame
skip 2 (dt 0.04 s), action = cart force in [-3, 3] (MuJoCo clamps it), observation
``[qpos (cart x, pole angle), qvel]`` (4), reward 1 while the pole is upright and 0 on the step
that ends the episode, terminated when ``|angle| > 0.2`` (or the state is not finite), start
``qpos, qvel ~ U(-0.01, 0.01)`` around the default pose, 1,000-step limit.
"""

from __future__ import annotations

import jax.numpy as jnp
from flax import struct

from rl_jax.envs.core.core import Array, float32_field
from rl_jax.envs.mujoco.mujoco_backend import Measurement
from rl_jax.envs.mujoco.mujoco_env import MujocoEnv, MujocoParams


@struct.dataclass
class InvertedPendulumParams(MujocoParams):
    """InvertedPendulum-v5's reset noise, pole-angle limit and reward per step (vmappable)."""

    reset_noise_scale: Array = float32_field(0.01)
    #: the pole is healthy while ``|angle| <= max_pole_angle`` (rad)
    max_pole_angle: Array = float32_field(0.2)
    #: reward per healthy step
    healthy_reward: Array = float32_field(1.0)


class InvertedPendulum(MujocoEnv[InvertedPendulumParams]):
    """gymnasium's InvertedPendulum-v5; the module docstring gives its observation and reward."""

    xml_file = "inverted_pendulum.xml"
    frame_skip = 2
    # Only the slider and hinge limits bind. With both active at once 2 iterations fell short of
    # gymnasium's solve (in C, 4 of 40,000 random-policy states); 3 matched.
    mjx_solver = (3, 4)
    info_keys = ("reward_survive",)
    camera = {"trackbodyid": 0, "distance": 2.04}
    params_type = InvertedPendulumParams

    qvel_noise = "uniform"  # gymnasium samples both qpos and qvel uniformly

    @property
    def obs_size(self) -> int:
        """4: cart position, pole angle and their velocities."""
        return 4

    def observe(self, measurement: Measurement) -> Array:
        """``[qpos, qvel]``."""
        return jnp.concatenate([measurement.qpos, measurement.qvel])

    def evaluate(self, measurement: Measurement, action: Array, params: InvertedPendulumParams):
        """``healthy_reward`` per step while the pole stays within ``max_pole_angle``; 0 and
        terminated once it leaves.
        """
        terminated = jnp.abs(measurement.qpos[1]) > params.max_pole_angle
        reward = jnp.where(terminated, 0.0, params.healthy_reward)
        return reward, terminated, {"reward_survive": reward}
