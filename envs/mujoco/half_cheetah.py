"""rl_jax/HalfCheetah-v5: gymnasium's MuJoCo half cheetah, on MJX or MuJoCo C.

gymnasium 1.4.0 ``HalfCheetah-v5``: ``half_cheetah.xml`` (Euler, timestep 0.01), frame skip 5
(dt 0.05 s), six joint torques in [-1, 1] (MuJoCo clamps them). Observation ``[qpos[1:], qvel]``
(17; 18 with ``exclude_current_positions_from_observation=False``). Reward
``forward_reward_weight * x_velocity - ctrl_cost_weight * sum(action^2)`` where ``x_velocity`` is
the torso's x displacement over the step divided by dt and the control cost uses the action as
given (unclipped), as gymnasium does. Never terminates; start ``qpos ~ U(-0.1, 0.1)``,
``qvel ~ 0.1 N(0, 1)`` around the default pose; 1,000-step limit.
"""

from __future__ import annotations

import jax.numpy as jnp
from flax import struct

from rl_jax.envs.core.core import Array, float32_field
from rl_jax.envs.mujoco.mujoco_backend import Measurement
from rl_jax.envs.mujoco.mujoco_env import MujocoEnv, MujocoParams


@struct.dataclass
class HalfCheetahParams(MujocoParams):
    """HalfCheetah-v5's reward weights and reset noise (vmappable)."""

    reset_noise_scale: Array = float32_field(0.1)
    forward_reward_weight: Array = float32_field(1.0)
    ctrl_cost_weight: Array = float32_field(0.1)


class HalfCheetah(MujocoEnv[HalfCheetahParams]):
    """gymnasium's HalfCheetah-v5; the module docstring gives its observation and reward."""

    xml_file = "half_cheetah.xml"
    frame_skip = 5
    # Floor contacts: on the states where gymnasium's solver needs the most iterations, 4/4 left
    # MJX up to 0.23 away from gymnasium (C: 26 of 40,000 random-policy states off by up to 3.3),
    # 6 iterations (with 4 line-search iterations) matched to float32 precision.
    mjx_solver = (6, 4)
    # 70 constraint rows per env: stepping 64 envs at a time keeps MJX's working set in cache
    mjx_cpu_chunk = 64
    info_keys = ("x_position", "x_velocity", "reward_forward", "reward_ctrl")
    camera = "track"  # the model's own camera, which follows the torso (gymnasium's stays put)
    params_type = HalfCheetahParams

    current_positions = 1  # x

    @property
    def obs_size(self) -> int:
        """Length of the observation: qpos (without x unless asked) and qvel."""
        return self.observed_qpos_size + self.model.nv

    def observe(self, measurement: Measurement) -> Array:
        """``[qpos, qvel]``, the root's x left out unless asked."""
        return jnp.concatenate([self.observed_qpos(measurement), measurement.qvel])

    def evaluate(self, measurement: Measurement, action: Array, params: HalfCheetahParams):
        """Forward velocity minus the control cost of the raw action; the cheetah never
        terminates.
        """
        x_velocity = measurement.qpos_change[0] / self.dt
        forward_reward = params.forward_reward_weight * x_velocity
        ctrl_cost = params.ctrl_cost_weight * jnp.sum(jnp.square(action))
        info = {
            "x_position": measurement.qpos[0],
            "x_velocity": x_velocity,
            "reward_forward": forward_reward,
            "reward_ctrl": -ctrl_cost,
        }
        return forward_reward - ctrl_cost, jnp.zeros((), jnp.bool_), info

    def reset_info(self, measurement: Measurement) -> dict[str, Array]:
        """The root's x position."""
        return {"x_position": measurement.qpos[0]}
