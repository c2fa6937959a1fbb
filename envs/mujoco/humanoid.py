"""rl_jax/Humanoid-v5: gymnasium's MuJoCo humanoid, on MJX or MuJoCo C.

gymnasium 1.4.0 ``Humanoid-v5``: ``humanoid.xml`` (RK4, timestep 0.003, PGS solver with 50
iterations), frame skip 5 (dt 0.015 s), 17 joint torques in [-0.4, 0.4] (MuJoCo clamps them).
Observation ``[qpos[2:], qvel, cinert[1:], cvel[1:], qfrc_actuator[6:], cfrc_ext[1:]]`` (348;
each of the last four can be left out with its ``include_*_in_observation`` keyword, +2 with
``exclude_current_positions_from_observation=False``); ``cfrc_ext`` is what
``mj_rnePostConstraint`` gives after the step (zero at a reset). Reward ``forward_reward_weight *
x_velocity + healthy_reward * is_healthy - ctrl_cost_weight * sum(action^2) -
clip(contact_cost_weight * sum(cfrc_ext^2), contact_cost_range)``, with ``x_velocity`` the
displacement of the mass-weighted centre of the bodies' ``xipos`` over the step divided by dt,
where gymnasium reads ``xipos`` as MuJoCo left it: at the start of the last substep of this step
and of the previous one (or at the reset), so this env remembers last step's centre. Healthy:
``qpos[2]`` strictly inside ``healthy_z_range``; terminated when unhealthy if
``terminate_when_unhealthy``. Start ``qpos, qvel ~ U(-0.01, 0.01)`` around the default pose;
1,000-step limit. gymnasium's info also carries the tendon lengths and velocities (arrays, not
reward terms): left out here.

MJX implements the CG and Newton solvers, not PGS: on MJX this env solves the same constraint
problem with Newton (``MujocoEnv.build_model``), so it matches gymnasium to the solvers'
convergence, not to float32 rounding as on MuJoCo C; MJX's RK4 also advances the free joint's
orientation otherwise than MuJoCo C 4.0's, and orients a capsule's friction pyramid along the world
axes where MuJoCo C aligns it with the capsule (tests/envs/test_mujoco_parity.py compares them
statistically).
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
import numpy as np
from flax import struct

from rl_jax.envs.core.core import Array, float32_field
from rl_jax.envs.mujoco.mujoco_backend import Measurement
from rl_jax.envs.mujoco.mujoco_env import (
    REMEMBERED_KEY,
    MujocoEnv,
    MujocoParams,
    planar_position_info,
)

_INCLUDES = ("cinert", "cvel", "qfrc_actuator", "cfrc_ext")


@struct.dataclass
class HumanoidParams(MujocoParams):
    """Humanoid-v5's reward weights, reset noise, contact-cost clip and healthy height range
    (vmappable).
    """

    reset_noise_scale: Array = float32_field(1e-2)
    forward_reward_weight: Array = float32_field(1.25)
    ctrl_cost_weight: Array = float32_field(0.1)
    contact_cost_weight: Array = float32_field(5e-7)
    healthy_reward: Array = float32_field(5.0)
    #: gymnasium's ``contact_cost_range`` (the clip of the contact cost) and ``healthy_z_range``
    contact_cost_min: Array = float32_field(-float("inf"))
    contact_cost_max: Array = float32_field(10.0)
    healthy_z_min: Array = float32_field(1.0)
    healthy_z_max: Array = float32_field(2.0)


class Humanoid(MujocoEnv[HumanoidParams]):
    """gymnasium's Humanoid-v5; the module docstring gives its observation, reward and
    termination.
    """

    xml_file = "humanoid.xml"
    frame_skip = 5
    # Newton (MJX has no PGS), measured in C on 40,000 random-policy states (each stepped once):
    # converged Newton (100/50) is itself off gymnasium's PGS by 3.7e-5 (relative, 99th percentile)
    # up to 0.07 in qpos/qvel, and up to 2.5 in the contact forces, whose split among contacts PGS's
    # 50 iterations leave unconverged; against converged Newton, 6 iterations (with 4 line-search
    # iterations) left states off by up to 8.5e-2, 7 by 2.2e-3, 8 by 4.2e-5, below MJX's float32
    # error at contacts (tests/envs/test_mujoco_parity.py).
    mjx_solver = (8, 4)
    mjx_cpu_chunk = 64
    extras = ("xipos", *_INCLUDES)
    forward_at_reset = True  # the reset observation holds cinert, cvel and qfrc_actuator
    current_positions = 2  # x, y
    remembers = 2  # the bodies' mass centre x, y as MuJoCo left them
    info_keys = (
        "x_position",
        "y_position",
        "distance_from_origin",
        "x_velocity",
        "y_velocity",
        "reward_survive",
        "reward_forward",
        "reward_ctrl",
        "reward_contact",
    )
    camera = {"trackbodyid": 1, "distance": 4.0, "lookat": (0.0, 0.0, 2.0), "elevation": -20.0}
    params_type = HumanoidParams
    qvel_noise = "uniform"
    range_keywords = {
        "contact_cost_range": ("contact_cost_min", "contact_cost_max"),
        "healthy_z_range": ("healthy_z_min", "healthy_z_max"),
    }

    def __init__(
        self,
        backend: str | None = None,
        fidelity: str = "parity",
        nthread: int | None = None,
        terminate_when_unhealthy: bool = True,
        include_cinert_in_observation: bool = True,
        include_cvel_in_observation: bool = True,
        include_qfrc_actuator_in_observation: bool = True,
        include_cfrc_ext_in_observation: bool = True,
        **keywords: Any,
    ):
        self.terminate_when_unhealthy = bool(terminate_when_unhealthy)
        flags = (
            include_cinert_in_observation,
            include_cvel_in_observation,
            include_qfrc_actuator_in_observation,
            include_cfrc_ext_in_observation,
        )
        self.observed = tuple(name for name, flag in zip(_INCLUDES, flags, strict=True) if flag)
        super().__init__(backend, fidelity, nthread, **keywords)

    @property
    def obs_size(self) -> int:
        """Length of the observation: qpos, qvel and each included derived field (cinert, cvel,
        qfrc_actuator, cfrc_ext) without the world body.
        """
        model = self.model
        sizes = {"cinert": 10, "cvel": 6, "cfrc_ext": 6}
        size = self.observed_qpos_size + model.nv
        for name in self.observed:
            size += model.nv - 6 if name == "qfrc_actuator" else sizes[name] * (model.nbody - 1)
        return size

    def observe(self, measurement: Measurement) -> Array:
        """``[qpos, qvel, cinert, cvel, qfrc_actuator, cfrc_ext]`` (those included), as
        gymnasium's.
        """
        qpos = self.observed_qpos(measurement)
        parts = [qpos, measurement.qvel]
        for name in self.observed:
            value = measurement.extras[name]
            parts.append(value[6:] if name == "qfrc_actuator" else value[1:].reshape(-1))
        return jnp.concatenate(parts)

    def remember(self, measurement: Measurement) -> Array:
        """The x, y position of the centre of mass, which the next step's velocity is measured
        from.
        """
        mass = np.asarray(self.model.body_mass, np.float64)
        weights = (mass / mass.sum()).astype(np.float32)
        return jnp.sum(weights[:, None] * measurement.extras["xipos"], axis=0)[:2]

    def evaluate(self, measurement: Measurement, action: Array, params: HumanoidParams):
        """Humanoid-v5's reward (centre-of-mass velocity, healthy bonus, control and clipped
        contact costs), its termination when unhealthy and gymnasium's info terms.
        """
        velocity = (self.remember(measurement) - measurement.extras[REMEMBERED_KEY]) / self.dt
        z = measurement.qpos[2]
        healthy = (params.healthy_z_min < z) & (z < params.healthy_z_max)
        forward_reward = params.forward_reward_weight * velocity[0]
        healthy_reward = jnp.where(healthy, params.healthy_reward, 0.0)
        ctrl_cost = params.ctrl_cost_weight * jnp.sum(jnp.square(action))
        contact_cost = jnp.clip(
            params.contact_cost_weight * jnp.sum(jnp.square(measurement.extras["cfrc_ext"])),
            params.contact_cost_min,
            params.contact_cost_max,
        )
        info = {
            **self.reset_info(measurement),
            "x_velocity": velocity[0],
            "y_velocity": velocity[1],
            "reward_survive": healthy_reward,
            "reward_forward": forward_reward,
            "reward_ctrl": -ctrl_cost,
            "reward_contact": -contact_cost,
        }
        reward = forward_reward + healthy_reward - ctrl_cost - contact_cost
        return reward, ~healthy & self.terminate_when_unhealthy, info

    def reset_info(self, measurement: Measurement) -> dict[str, Array]:
        """The torso's planar position and its distance from the origin."""
        return planar_position_info(measurement.qpos)
