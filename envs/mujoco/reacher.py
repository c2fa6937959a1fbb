"""rl_jax/Reacher-v5: gymnasium's MuJoCo two-link arm reaching for a target, on MJX or MuJoCo C.

gymnasium 1.4.0 ``Reacher-v5``: ``reacher.xml`` (RK4, timestep 0.01), frame skip 2 (dt 0.02 s),
two joint torques in [-1, 1] (MuJoCo clamps them). Observation (10): ``[cos(qpos[:2]),
sin(qpos[:2]), qpos[2:] (the target's x, y), qvel[:2], (fingertip - target)[:2]]``, the two
positions being the bodies' ``xpos`` that MuJoCo leaves after the step, i.e. computed at the start
of the last substep — exactly what gymnasium's ``get_body_com`` reads. Reward ``reward_dist +
reward_ctrl`` with ``reward_dist = -reward_dist_weight * |fingertip - target|`` (3-D, from those
same positions after the step) and ``reward_ctrl = -reward_control_weight * sum(action^2)`` (the
action as given, unclipped). Never terminates. Start: arm ``qpos ~ U(-0.1, 0.1)`` around the
default pose, the target uniform in the open disc of radius 0.2 (gymnasium's rejection sampling
of the square), arm ``qvel ~ U(-0.005, 0.005)``, target at rest; 50-step limit.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from rl_jax.envs.core.core import Array, EnvParams, PRNGKey, float32_field
from rl_jax.envs.mujoco.mujoco_backend import Measurement
from rl_jax.envs.mujoco.mujoco_env import MujocoEnv

# gymnasium's fixed reset ranges (not constructor keywords there, so not params here)
_ARM_QPOS_NOISE, _ARM_QVEL_NOISE, _GOAL_RADIUS = 0.1, 0.005, 0.2
# Candidates for the rejection sampling of the goal: each lands in the disc with probability
# pi/4, so all 16 miss with probability (1 - pi/4)^16 ~ 2e-11 (the goal is then the centre).
_GOAL_CANDIDATES = 16


@struct.dataclass
class ReacherParams(EnvParams):
    """Reacher-v5's reward weights (vmappable)."""

    reward_dist_weight: Array = float32_field(1.0)
    reward_control_weight: Array = float32_field(1.0)


def sample_goal(key: PRNGKey) -> Array:
    """Uniform in the open disc of radius 0.2: gymnasium's loop (uniform in the square, kept if
    inside the disc) over a fixed number of candidates, the first one inside taken."""
    candidates = jax.random.uniform(
        key, (_GOAL_CANDIDATES, 2), jnp.float32, -_GOAL_RADIUS, _GOAL_RADIUS
    )
    inside = jnp.linalg.norm(candidates, axis=-1) < _GOAL_RADIUS
    first = jnp.argmax(inside)
    return jnp.where(inside[first], candidates[first], 0.0)


class Reacher(MujocoEnv[ReacherParams]):
    """gymnasium's Reacher-v5; the module docstring gives its observation and reward."""

    xml_file = "reacher.xml"
    frame_skip = 2
    max_episode_steps = 50
    # Nothing collides (every geom has contype 0); only the elbow's limit (+-3 rad) and the
    # target's (which it never reaches on its own) can bind. In C, 2 iterations reproduced
    # gymnasium exactly on 40,000 random-policy states and on states at and beyond every limit; 1
    # did not (tests/envs/test_mujoco_parity.py checks MJX).
    mjx_solver = (2, 4)
    # sin/cos of the joint angles in the backend's precision: joint0 is unlimited and may turn many
    # times, where a float32 angle would lose digits.
    extras = ("xpos", "sin_qpos", "cos_qpos")
    forward_at_reset = True  # the reset observation includes the body positions
    info_keys = ("reward_dist", "reward_ctrl")
    camera = {"trackbodyid": 0}
    params_type = ReacherParams

    @property
    def obs_size(self) -> int:
        """10: cos and sin of both arm joints, the target position, two joint velocities and the
        fingertip-to-target vector.
        """
        return 10

    def _fingertip_to_target(self, measurement: Measurement) -> Array:
        xpos = measurement.extras["xpos"]
        return xpos[self.model.body("fingertip").id] - xpos[self.model.body("target").id]

    def observe(self, measurement: Measurement) -> Array:
        """``[cos, sin of the arm, target, arm velocities, fingertip - target (x, y)]``, as
        gymnasium's.
        """
        extras = measurement.extras
        return jnp.concatenate(
            [
                extras["cos_qpos"][:2],
                extras["sin_qpos"][:2],
                measurement.qpos[2:],
                measurement.qvel[:2],
                self._fingertip_to_target(measurement)[:2],
            ]
        )

    def evaluate(self, measurement: Measurement, action: Array, params: ReacherParams):
        """Minus the fingertip's distance to the target minus the control cost; never terminates."""
        distance = jnp.linalg.norm(self._fingertip_to_target(measurement))
        reward_dist = -distance * params.reward_dist_weight
        reward_ctrl = -jnp.sum(jnp.square(action)) * params.reward_control_weight
        info = {"reward_dist": reward_dist, "reward_ctrl": reward_ctrl}
        return reward_dist + reward_ctrl, jnp.zeros((), jnp.bool_), info

    def sample_start(self, key: PRNGKey, params: ReacherParams) -> tuple[Array, Array]:
        """Arm joints uniform around the default pose, a target drawn in the disc of radius 0.2,
        and small uniform arm velocities (the target's are 0), as gymnasium's ``reset_model``.
        """
        key_qpos, key_goal, key_qvel = jax.random.split(key, 3)
        nq, nv = self._init_qpos.shape[0], self.model.nv
        noise = jax.random.uniform(key_qpos, (nq,), jnp.float32, -_ARM_QPOS_NOISE, _ARM_QPOS_NOISE)
        qpos = (jnp.asarray(self._init_qpos) + noise).at[2:].set(sample_goal(key_goal))
        qvel = jax.random.uniform(key_qvel, (nv,), jnp.float32, -_ARM_QVEL_NOISE, _ARM_QVEL_NOISE)
        return qpos, qvel.at[2:].set(0.0)
