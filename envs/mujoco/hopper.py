"""rl_jax/Hopper-v5: gymnasium's MuJoCo one-legged hopper, on MJX or MuJoCo C.

gymnasium 1.4.0 ``Hopper-v5``: ``hopper.xml`` (RK4, timestep 0.002), frame skip 4 (dt 0.008 s),
three joint torques in [-1, 1] (MuJoCo clamps them). Observation ``[qpos[1:], clip(qvel, -10,
10)]`` (11; 12 with ``exclude_current_positions_from_observation=False``). Reward
``forward_reward_weight * x_velocity + healthy_reward * is_healthy - ctrl_cost_weight *
sum(action^2)``, with ``x_velocity`` the torso's x displacement over the step divided by dt and the
action as given (unclipped). Healthy: the height ``qpos[1]``, the torso angle ``qpos[2]`` and every
other state component ``[qpos[2:], qvel]`` strictly inside their ranges; v5 pays the healthy reward
whenever the hopper is healthy, also with ``terminate_when_unhealthy=False``, and terminates when
it is not (if ``terminate_when_unhealthy``). Start ``qpos, qvel ~ U(-0.005, 0.005)`` around the
default pose; 1,000-step limit.
"""

from __future__ import annotations

from typing import Any, Protocol

import jax.numpy as jnp
from flax import struct

from rl_jax.envs.core.core import Array, float32_field
from rl_jax.envs.mujoco.mujoco_backend import Measurement
from rl_jax.envs.mujoco.mujoco_env import MujocoEnv, MujocoParams

_VELOCITY_CLIP = 10.0  # gymnasium clips the observed velocities (not those of the health check)


@struct.dataclass
class HopperParams(MujocoParams):
    """Hopper-v5's reward weights, reset noise and health ranges (vmappable)."""

    reset_noise_scale: Array = float32_field(5e-3)
    forward_reward_weight: Array = float32_field(1.0)
    ctrl_cost_weight: Array = float32_field(1e-3)
    #: paid on every step that ends healthy
    healthy_reward: Array = float32_field(1.0)
    #: gymnasium's ``healthy_z_range``, ``healthy_angle_range`` and ``healthy_state_range``: open
    #: intervals for the height ``qpos[1]``, the angle ``qpos[2]`` and each of ``[qpos[2:], qvel]``
    healthy_z_min: Array = float32_field(0.7)
    healthy_z_max: Array = float32_field(float("inf"))
    healthy_angle_min: Array = float32_field(-0.2)
    healthy_angle_max: Array = float32_field(0.2)
    healthy_state_min: Array = float32_field(-100.0)
    healthy_state_max: Array = float32_field(100.0)


class HopperLikeParams(Protocol):
    """What the hopper's step reads of its params: ``HopperParams``, or ``Walker2dParams`` on
    ``Walker2d``, which runs this step with its own health check."""

    @property
    def forward_reward_weight(self) -> Array: ...
    @property
    def ctrl_cost_weight(self) -> Array: ...
    @property
    def healthy_reward(self) -> Array: ...
    @property
    def healthy_z_min(self) -> Array: ...
    @property
    def healthy_z_max(self) -> Array: ...
    @property
    def healthy_angle_min(self) -> Array: ...
    @property
    def healthy_angle_max(self) -> Array: ...


class Hopper(MujocoEnv):
    """gymnasium's Hopper-v5; the module docstring gives its observation, reward and termination."""

    xml_file = "hopper.xml"
    frame_skip = 4
    # Floor contacts and the leg's contacts with the torso. In C, on 40,000 random-policy states
    # (each stepped once), 4 iterations left 3 states off gymnasium's solve by up to 4.5e-5
    # (relative); 5 matched to 3e-10, and MJX with 5 matches gymnasium to float32 precision
    # (tests/envs/test_mujoco_parity.py).
    mjx_solver = (5, 4)
    info_keys = (
        "x_position",
        "z_distance_from_origin",
        "x_velocity",
        "reward_forward",
        "reward_ctrl",
        "reward_survive",
    )
    camera = {"trackbodyid": 2, "distance": 3.0, "lookat": (0.0, 0.0, 1.15), "elevation": -20.0}
    params_type: type = HopperParams  # as MujocoEnv's: Walker2d, a subclass, sets its own
    qvel_noise = "uniform"
    current_positions = 1  # x
    range_keywords = {
        "healthy_z_range": ("healthy_z_min", "healthy_z_max"),
        "healthy_angle_range": ("healthy_angle_min", "healthy_angle_max"),
        "healthy_state_range": ("healthy_state_min", "healthy_state_max"),
    }

    def __init__(
        self,
        backend: str | None = None,
        fidelity: str = "parity",
        nthread: int | None = None,
        terminate_when_unhealthy: bool = True,
        **keywords: Any,
    ):
        self.terminate_when_unhealthy = bool(terminate_when_unhealthy)
        super().__init__(backend, fidelity, nthread, **keywords)

    @property
    def obs_size(self) -> int:
        """Length of the observation: qpos (without x unless asked) and qvel."""
        return self.observed_qpos_size + self.model.nv

    def observe(self, measurement: Measurement) -> Array:
        """``[qpos, clip(qvel, -10, 10)]``, the root's x left out unless asked."""
        qpos = self.observed_qpos(measurement)
        return jnp.concatenate([qpos, jnp.clip(measurement.qvel, -_VELOCITY_CLIP, _VELOCITY_CLIP)])

    def is_healthy(self, measurement: Measurement, params: HopperLikeParams) -> Array:
        """Whether height, torso angle and the rest of the state all lie inside their open
        healthy ranges.
        """
        assert isinstance(params, HopperParams)  # Walker2d, whose params are not, overrides this
        z, angle = measurement.qpos[1], measurement.qpos[2]
        state = jnp.concatenate([measurement.qpos[2:], measurement.qvel])
        healthy_state = jnp.all(
            (params.healthy_state_min < state) & (state < params.healthy_state_max)
        )
        healthy_z = (params.healthy_z_min < z) & (z < params.healthy_z_max)
        healthy_angle = (params.healthy_angle_min < angle) & (angle < params.healthy_angle_max)
        return healthy_state & healthy_z & healthy_angle

    def evaluate(self, measurement: Measurement, action: Array, params: HopperLikeParams):
        """Hopper-v5's reward (forward velocity, healthy bonus, control cost), its termination
        when unhealthy and gymnasium's info terms.
        """
        x_velocity = measurement.qpos_change[0] / self.dt
        healthy = self.is_healthy(measurement, params)
        forward_reward = params.forward_reward_weight * x_velocity
        healthy_reward = jnp.where(healthy, params.healthy_reward, 0.0)
        ctrl_cost = params.ctrl_cost_weight * jnp.sum(jnp.square(action))
        terminated = ~healthy & self.terminate_when_unhealthy
        info = {
            **self.reset_info(measurement),
            "x_velocity": x_velocity,
            "reward_forward": forward_reward,
            "reward_ctrl": -ctrl_cost,
            "reward_survive": healthy_reward,
        }
        return forward_reward + healthy_reward - ctrl_cost, terminated, info

    def reset_info(self, measurement: Measurement) -> dict[str, Array]:
        """The root's x position and its height change since the default pose."""
        return {
            "x_position": measurement.qpos[0],
            "z_distance_from_origin": measurement.qpos[1] - self._init_qpos[1],
        }
