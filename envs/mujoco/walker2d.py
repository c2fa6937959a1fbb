"""rl_jax/Walker2d-v5: gymnasium's MuJoCo two-legged walker, on MJX or MuJoCo C.

gymnasium 1.4.0 ``Walker2d-v5``: ``walker2d_v5.xml`` (RK4, timestep 0.002; v5's model, whose two
feet have the same friction, 1.9), frame skip 4 (dt 0.008 s), six joint torques in [-1, 1] (MuJoCo
clamps them). Observation ``[qpos[1:], clip(qvel, -10, 10)]`` (17; 18 with
``exclude_current_positions_from_observation=False``). Reward ``forward_reward_weight * x_velocity
+ healthy_reward * is_healthy - ctrl_cost_weight * sum(action^2)``, as the hopper's
(``envs.mujoco.hopper``). Healthy: the height ``qpos[1]`` in (0.8, 2) and the torso angle
``qpos[2]`` in (-1, 1), open intervals; no range on the other state components (unlike the
hopper). The healthy reward is paid whenever healthy; terminated when not (if
``terminate_when_unhealthy``). Start ``qpos, qvel ~ U(-0.005, 0.005)`` around the default pose;
1,000-step limit.
"""

from __future__ import annotations

from flax import struct

from rl_jax.envs.core.core import Array, float32_field
from rl_jax.envs.mujoco.hopper import Hopper, HopperLikeParams
from rl_jax.envs.mujoco.mujoco_backend import Measurement
from rl_jax.envs.mujoco.mujoco_env import MujocoParams


@struct.dataclass
class Walker2dParams(MujocoParams):
    """Walker2d-v5's reward weights, reset noise and health ranges (vmappable)."""

    reset_noise_scale: Array = float32_field(5e-3)
    forward_reward_weight: Array = float32_field(1.0)
    ctrl_cost_weight: Array = float32_field(1e-3)
    #: paid on every step that ends healthy
    healthy_reward: Array = float32_field(1.0)
    #: gymnasium's ``healthy_z_range`` and ``healthy_angle_range``: open intervals for the height
    #: ``qpos[1]`` and the torso angle ``qpos[2]``
    healthy_z_min: Array = float32_field(0.8)
    healthy_z_max: Array = float32_field(2.0)
    healthy_angle_min: Array = float32_field(-1.0)
    healthy_angle_max: Array = float32_field(1.0)


class Walker2d(Hopper):
    """The hopper's observation, reward, termination and reset, on the walker's model and health
    ranges (the constructor takes the same keywords, less ``healthy_state_range``)."""

    xml_file = "walker2d_v5.xml"
    frame_skip = 4
    # Floor contacts of both legs. In C, on 40,000 random-policy states (each stepped once), 6
    # iterations left one state off gymnasium's solve by 3.9e-3 (relative); 7 matched to 2e-9,
    # and MJX with 7 matches gymnasium to float32 precision (tests/envs/test_mujoco_parity.py).
    mjx_solver = (7, 4)
    camera = {"trackbodyid": 2, "distance": 4.0, "lookat": (0.0, 0.0, 1.15), "elevation": -20.0}
    params_type = Walker2dParams
    range_keywords = {
        "healthy_z_range": ("healthy_z_min", "healthy_z_max"),
        "healthy_angle_range": ("healthy_angle_min", "healthy_angle_max"),
    }

    def is_healthy(self, measurement: Measurement, params: HopperLikeParams) -> Array:
        """Whether height and torso angle both lie inside their open healthy ranges."""
        z, angle = measurement.qpos[1], measurement.qpos[2]
        healthy_z = (params.healthy_z_min < z) & (z < params.healthy_z_max)
        healthy_angle = (params.healthy_angle_min < angle) & (angle < params.healthy_angle_max)
        return healthy_z & healthy_angle
