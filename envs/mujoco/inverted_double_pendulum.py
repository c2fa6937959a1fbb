"""rl_jax/InvertedDoublePendulum-v5: gymnasium's MuJoCo double cart-pole, on MJX or MuJoCo C.

gymnasium 1.4.0 ``InvertedDoublePendulum-v5``: ``inverted_double_pendulum.xml`` (RK4, timestep
0.01), frame skip 5 (dt 0.05 s), action in [-1, 1] (MuJoCo clamps it). Observation (9):
``[cart x, sin(angles) (2), cos(angles) (2), clip(qvel, -10, 10) (3), clip(qfrc_constraint[0],
-10, 10)]``. The tip position and the constraint force are those MuJoCo leaves after the step,
i.e. computed at the start of the last substep — exactly what gymnasium reads. Reward
``healthy_reward * (not terminated) - (0.01 x_tip^2 + (y_tip - 2)^2) - (1e-3 w1^2 + 5e-3 w2^2)``
with ``w`` the two hinge velocities; terminated when the tip height ``y_tip <= 1``. Start:
``qpos ~ U(-0.1, 0.1)``, ``qvel ~ 0.1 N(0, 1)`` around the default pose; 1,000-step limit.
"""

from __future__ import annotations

import jax.numpy as jnp
from flax import struct

from rl_jax.envs.core.core import Array, float32_field
from rl_jax.envs.mujoco.mujoco_backend import Measurement
from rl_jax.envs.mujoco.mujoco_env import MujocoEnv, MujocoParams

_CLIP = 10.0  # gymnasium clips velocities and the constraint force in the observation


@struct.dataclass
class InvertedDoublePendulumParams(MujocoParams):
    """InvertedDoublePendulum-v5's reward weights, reset noise and tip heights (vmappable)."""

    reset_noise_scale: Array = float32_field(0.1)
    healthy_reward: Array = float32_field(10.0)
    #: the episode ends when the tip height drops to this or below
    min_tip_height: Array = float32_field(1.0)
    target_tip_height: Array = float32_field(2.0)
    #: distance penalty ``x_weight * x_tip^2 + y_weight * (y_tip - target)^2``
    distance_x_weight: Array = float32_field(0.01)
    distance_y_weight: Array = float32_field(1.0)
    #: velocity penalty weights of the first and second hinge
    velocity_weight_1: Array = float32_field(1e-3)
    velocity_weight_2: Array = float32_field(5e-3)


class InvertedDoublePendulum(MujocoEnv[InvertedDoublePendulumParams]):
    """gymnasium's InvertedDoublePendulum-v5; the module docstring gives its observation and
    reward.
    """

    xml_file = "inverted_double_pendulum.xml"
    frame_skip = 5
    # Only the slider limit can bind (the hinges are unlimited, nothing collides): one Newton step
    # solves it; 2/4 matched gymnasium on 40,000 random-policy states in C.
    mjx_solver = (2, 4)
    extras = ("site_xpos", "qfrc_constraint", "sin_qpos", "cos_qpos")
    forward_at_reset = True  # the reset observation includes the slider's constraint force
    info_keys = ("reward_survive", "distance_penalty", "velocity_penalty")
    camera = {"trackbodyid": 0, "distance": 4.1225, "lookat": (0.0, 0.0, 0.1225)}
    params_type = InvertedDoublePendulumParams

    @property
    def obs_size(self) -> int:
        """9: the cart position, sin and cos of both hinges, three velocities and the slider's
        constraint force.
        """
        return 9

    def observe(self, measurement: Measurement) -> Array:
        """``[x, sin(hinges), cos(hinges), qvel, slider force]``, velocities and force clipped to
        +-10.
        """
        qpos, qvel = measurement.qpos, measurement.qvel
        force = measurement.extras["qfrc_constraint"][:1]
        return jnp.concatenate(
            [
                qpos[:1],
                measurement.extras["sin_qpos"][1:],
                measurement.extras["cos_qpos"][1:],
                jnp.clip(qvel, -_CLIP, _CLIP),
                jnp.clip(force, -_CLIP, _CLIP),
            ]
        )

    def evaluate(
        self, measurement: Measurement, action: Array, params: InvertedDoublePendulumParams
    ):
        """Alive bonus minus the tip's distance and the hinges' velocity penalties; terminated
        when the tip drops to ``min_tip_height``.
        """
        tip = measurement.extras["site_xpos"][0]
        x, y = tip[0], tip[2]
        terminated = y <= params.min_tip_height
        w1, w2 = measurement.qvel[1], measurement.qvel[2]
        distance_penalty = (
            params.distance_x_weight * x**2
            + params.distance_y_weight * (y - params.target_tip_height) ** 2
        )
        velocity_penalty = params.velocity_weight_1 * w1**2 + params.velocity_weight_2 * w2**2
        alive_bonus = jnp.where(terminated, 0.0, params.healthy_reward)
        reward = alive_bonus - distance_penalty - velocity_penalty
        info = {
            "reward_survive": alive_bonus,
            "distance_penalty": -distance_penalty,
            "velocity_penalty": -velocity_penalty,
        }
        return reward, terminated, info
