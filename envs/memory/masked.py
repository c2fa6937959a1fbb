"""Velocity-masked envs: the partially observed ids that memory-based learners are compared on,
each a registered env under ``MaskObservation``.

``rl_jax/CartPoleNoVel-v1`` and ``rl_jax/PendulumNoVel-v1`` are RL Zoo's ids (rl_zoo3's
``MaskVelocityWrapper``, on which sb3-contrib's RecurrentPPO results were measured): gymnasium's
env with the velocity entries *set to zero*, so the observation and its space keep gymnasium's
shape. CartPole keeps the cart position and pole angle (entries 0 and 2; the velocities 1 and 3
read 0), Pendulum keeps cos and sin of the angle (0 and 1; the angular velocity 2 reads 0).

``rl_jax/{Hopper,Walker2d,HalfCheetah,Ant}-P-v5`` are the position-only ("-P") variants of Ni,
Eysenbach and Salakhutdinov 2022, "Recurrent Model-Free RL Can Be a Strong Baseline for Many
POMDPs" (their ``HopperBLT-P-v0`` and so on, on PyBullet's robots), here on gymnasium's v5 MuJoCo
envs: the observation is its qpos part alone, the velocities (and Ant's contact forces) are
*dropped*, as that paper's wrapper drops them. With the default keywords that is Hopper's entries
0-4 of 11 (``qpos[1:]``: height, torso angle, thigh, leg, foot), Walker2d's and HalfCheetah's 0-7
of 17 (``qpos[1:]``) and Ant's 0-12 of 105 (``qpos[2:]``: height, torso quaternion, 8 joint
angles); the count follows ``exclude_current_positions_from_observation``. Everything else
(reward, termination, limits, keywords, reset options) is the wrapped env's.

``gymnasium_twin(env_id)`` makes gymnasium's own env masked alike (``gymnasium.make`` of the
base id under ``GymnasiumMask``), where ``rl-jax evaluate RUN --gymnasium`` replays a run's
policies.

MuJoCo is imported only when a MuJoCo variant is made.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import gymnasium
import numpy as np

from rl_jax.envs.classic.cartpole import CartPole
from rl_jax.envs.classic.pendulum import Pendulum
from rl_jax.envs.core.wrappers import MaskObservation

if TYPE_CHECKING:
    from rl_jax.envs.mujoco.mujoco_env import MujocoEnv

#: RL Zoo's velocity entries of the two classic envs, which its ids observe as zeros
CARTPOLE_VELOCITIES = (1, 3)
PENDULUM_VELOCITIES = (2,)

#: each masked id's gymnasium env: the one it masks, and whose twin ``gymnasium_twin`` makes
GYMNASIUM_BASES = {
    "rl_jax/CartPoleNoVel-v1": "CartPole-v1",
    "rl_jax/PendulumNoVel-v1": "Pendulum-v1",
    "rl_jax/Hopper-P-v5": "Hopper-v5",
    "rl_jax/Walker2d-P-v5": "Walker2d-v5",
    "rl_jax/HalfCheetah-P-v5": "HalfCheetah-v5",
    "rl_jax/Ant-P-v5": "Ant-v5",
}
#: the velocity entries of the NoVel ids' observations
_VELOCITIES = {"CartPole-v1": CARTPOLE_VELOCITIES, "Pendulum-v1": PENDULUM_VELOCITIES}


def _unmasked(size: int, velocities: tuple[int, ...]) -> list[int]:
    """The entries of a ``size``-entry observation that are not velocities."""
    return [i for i in range(size) if i not in velocities]


def cartpole_no_velocity(
    sutton_barto_reward: bool = False, kinematics_integrator: str = "euler"
) -> MaskObservation:
    """``rl_jax/CartPoleNoVel-v1``: CartPole-v1 observing ``(x, 0, theta, 0)``."""
    keep = _unmasked(4, CARTPOLE_VELOCITIES)
    env = CartPole(sutton_barto_reward, kinematics_integrator)
    return MaskObservation(env, keep, zero_others=True)


def pendulum_no_velocity() -> MaskObservation:
    """``rl_jax/PendulumNoVel-v1``: Pendulum-v1 observing ``(cos theta, sin theta, 0)``."""
    keep = _unmasked(3, PENDULUM_VELOCITIES)
    return MaskObservation(Pendulum(), keep, zero_others=True)


def positions_only(env: MujocoEnv) -> MaskObservation:
    """``env`` observing the qpos part of its observation alone (it comes first in every
    gymnasium v5 locomotion env)."""
    return MaskObservation(env, range(env.observed_qpos_size))


def hopper_positions(backend: str | None = None, **keywords: Any) -> MaskObservation:
    """``rl_jax/Hopper-P-v5``: Hopper-v5 observing ``qpos[1:]`` (5 of 11 entries)."""
    from rl_jax.envs.mujoco.hopper import Hopper

    return positions_only(Hopper(backend=backend, **keywords))


def walker2d_positions(backend: str | None = None, **keywords: Any) -> MaskObservation:
    """``rl_jax/Walker2d-P-v5``: Walker2d-v5 observing ``qpos[1:]`` (8 of 17 entries)."""
    from rl_jax.envs.mujoco.walker2d import Walker2d

    return positions_only(Walker2d(backend=backend, **keywords))


def half_cheetah_positions(backend: str | None = None, **keywords: Any) -> MaskObservation:
    """``rl_jax/HalfCheetah-P-v5``: HalfCheetah-v5 observing ``qpos[1:]`` (8 of 17 entries)."""
    from rl_jax.envs.mujoco.half_cheetah import HalfCheetah

    return positions_only(HalfCheetah(backend=backend, **keywords))


def ant_positions(backend: str | None = None, **keywords: Any) -> MaskObservation:
    """``rl_jax/Ant-P-v5``: Ant-v5 observing ``qpos[2:]`` (13 of 105 entries: no velocities,
    no contact forces)."""
    from rl_jax.envs.mujoco.ant import Ant

    return positions_only(Ant(backend=backend, **keywords))


class GymnasiumMask(gymnasium.ObservationWrapper):
    """A gymnasium env observing the entries ``keep`` of its one-dimensional Box observation, as
    ``MaskObservation`` shows ours: the others dropped, or with ``zero_others`` set to zero
    (the space then stays the env's)."""

    def __init__(self, env: gymnasium.Env, keep: list[int], zero_others: bool = False):
        super().__init__(env)
        space = env.observation_space
        if not isinstance(space, gymnasium.spaces.Box) or len(space.shape) != 1:
            raise TypeError(f"GymnasiumMask needs a one-dimensional Box observation, got {space}")
        self.keep, self.zero_others = list(keep), zero_others
        self._masked = np.ones(space.shape[0], np.bool_)
        self._masked[self.keep] = False
        if not zero_others:
            low, high = space.low[self.keep], space.high[self.keep]
            self.observation_space = gymnasium.spaces.Box(low, high, dtype=space.dtype)

    def observation(self, observation: np.ndarray) -> np.ndarray:
        if self.zero_others:
            return np.where(self._masked, np.zeros_like(observation), observation)
        return observation[self.keep]


def gymnasium_twin(env_id: str, **keywords: Any) -> GymnasiumMask:
    """gymnasium's own env masked as the masked id ``env_id`` (a key of ``GYMNASIUM_BASES``)
    masks ours: ``gymnasium.make`` of its base env with ``keywords`` (gymnasium's: none of
    our ``backend``), under ``GymnasiumMask``. NoVel ids zero the same velocity entries; -P ids
    keep the qpos part, whose size gymnasium's v5 env states (``observation_structure``, which
    follows ``exclude_current_positions_from_observation`` as ``observed_qpos_size`` does)."""
    base = GYMNASIUM_BASES[env_id]
    env = gymnasium.make(base, **keywords)
    if base in _VELOCITIES:
        (size,) = env.observation_space.shape or (0,)
        return GymnasiumMask(env, _unmasked(size, _VELOCITIES[base]), zero_others=True)
    structure: dict[str, int] = vars(env.unwrapped)["observation_structure"]
    return GymnasiumMask(env, list(range(structure["qpos"])))
