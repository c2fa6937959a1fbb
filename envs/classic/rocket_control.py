"""Classical controllers for the 1-D rocket, to measure learned policies against.

The rocket (``envs/classic/rocket.py``) is the double integrator ``x' = v``, ``v' = u`` with
``|u| <= 1``, held for ``dt = 0.01`` s per step. Control theory solves "come to rest at the origin"
for it in closed form, so a learned policy can be judged by how close it gets to:

* ``TimeOptimal``: the minimum-time (bang-bang) feedback. Full thrust towards the switching curve
  ``x = -v|v|/2``, then full thrust the other way along it. From ``(1, 0)``: ``u = -1`` until
  ``t = 1`` s, ``u = +1`` until it arrives at ``(0, 0)`` at ``t* = 2`` s (step 200).
  ``time_optimal_arrival_time`` gives ``t*`` from any start.
* ``lqr(q1, q2, r)``: the linear-quadratic regulator, saturated to ``[-1, 1]``; ``pd`` for any
  other linear law.

Sampled every ``dt``, the textbook law ``u = -sign(x + v|v|/2)`` does not come to rest: rounding
puts the state a hair off the curve, it switches a step late, and then its sign flips about the
curve and the origin. From ``(1, 0)`` it first enters the 0.01 box at step 231 and keeps dropping
out of it until step 498. ``TimeOptimal`` therefore (documented at the class):
  1. aims each step at the point of the switching curve one step ahead (the thrust that lands on
     it, which saturates to the textbook ``-sign(s)`` wherever the curve is out of reach), and
  2. once two steps of bounded thrust can stop the rocket exactly, uses the linear deadbeat law
     that does so, whose closed loop has both eigenvalues at 0: it holds the origin to rounding.
From ``(1, 0)`` it enters ``|x|, |v| <= 0.01`` at step 200, is at rest to rounding (``< 1e-6``)
from step 202 on, and even meets the faithful env's 1e-8 goal there.

``simulate(controller, start, steps, env)`` rolls any ``obs -> action`` callable (these, or
``rl_jax.load_policy(...)``) through the registered env's own jitted step from an exact start,
ignoring termination so that staying at the goal is measured too; ``settle_step`` and
``summarize`` turn a trajectory into the numbers of ``envs.classic.rocket_comparison``.

Everything here except ``simulate`` is numpy on plain floats; controllers take one observation
``[2]`` or a batch ``[..., 2]`` and return thrust ``[..., 1]``.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any

import jax
import numpy as np

from rl_jax import envs
from rl_jax.envs.classic.rocket import Rocket

DT = 0.01  # the rocket's seconds per step (RocketParams.dt)
TOLERANCE = 0.01  # the "come to rest" box |x|, |v| <= TOLERANCE (RocketSettle's goal box)
# Q = diag(LQR_Q1, LQR_Q2), R = LQR_R: see ``lqr``.
LQR_Q1, LQR_Q2, LQR_R = 1.0, 0.25, 1 / 64

Controller = Callable[[np.ndarray], np.ndarray]


# ---- time-optimal (bang-bang) -----------------------------------------------------------------


def switching_function(x: Any, v: Any) -> np.ndarray:
    """``s = x + v|v|/2``: zero on the switching curve, positive above it (there ``u = -1``)."""
    x, v = np.asarray(x, np.float64), np.asarray(v, np.float64)
    return x + v * np.abs(v) / 2


def time_optimal_arrival_time(x: float, v: float) -> float:
    """The least time in which ``|u| <= 1`` brings ``(x, v)`` to rest at the origin.

    Above the curve (``s > 0``) the thrust is -1 and then +1, and the two arcs meet on the curve
    at speed ``sqrt(s')`` with ``s' = x + v^2/2``: ``t* = v + 2 sqrt(x + v^2/2)``. Below it the
    mirror image: ``t* = -v + 2 sqrt(v^2/2 - x)``. On the curve both give ``|v|``.
    """
    if switching_function(x, v) > 0:
        return float(v + 2 * np.sqrt(x + v * v / 2))
    return float(-v + 2 * np.sqrt(v * v / 2 - x))


def deadbeat_thrusts(x: Any, v: Any, dt: float = DT) -> tuple[np.ndarray, np.ndarray]:
    """The two thrusts that bring ``(x, v)`` exactly to ``(0, 0)`` in two steps of ``dt``.

    With thrust held over a step the rocket moves exactly as
    ``x' = x + v dt + u dt^2/2``, ``v' = v + u dt``; solving ``x_2 = v_2 = 0`` gives
    ``u_0 = -(x / dt^2 + 1.5 v / dt)`` and ``u_1 = (x / dt + v / 2) / dt``. Linear in the state,
    so its closed loop is linear with both eigenvalues at 0.
    """
    x, v = np.asarray(x, np.float64), np.asarray(v, np.float64)
    return -(x / dt**2 + 1.5 * v / dt), (x / dt + v / 2) / dt


def curve_landing_thrust(x: Any, v: Any, dt: float = DT) -> np.ndarray:
    """The thrust in [-1, 1] whose next state lies on the switching curve, or the nearest.

    One step of thrust ``u`` ends at speed ``w = v + u dt`` and position ``x + dt (v + w)/2``,
    so landing on the curve means ``c + dt w/2 + w|w|/2 = 0`` with ``c = x + dt v/2``. The left
    side increases with ``w``: its one root is ``w = -sign(c) (sqrt(dt^2 + 8|c|) - dt)/2``.
    Clipping ``u`` keeps the sign of the textbook ``-sign(s)`` wherever the curve is out of reach.
    """
    x, v = np.asarray(x, np.float64), np.asarray(v, np.float64)
    c = x + dt * v / 2
    w = -np.sign(c) * (np.sqrt(dt**2 + 8 * np.abs(c)) - dt) / 2
    return np.clip((w - v) / dt, -1.0, 1.0)


@dataclasses.dataclass(frozen=True)
class TimeOptimal:
    """The minimum-time feedback for the sampled rocket, which also holds the origin.

    Outside the deadbeat region: ``curve_landing_thrust`` (bang-bang towards the switching
    curve, then along it). Inside it, where both ``deadbeat_thrusts`` are within [-1, 1]: the
    deadbeat law, which stops the rocket in two steps and keeps it stopped. The region is a thin
    parallelogram around the end of the curve (``|x| <~ 2e-4``, ``|v| <~ 0.02`` at dt 0.01), the
    last two steps of a time-optimal arrival, so the arrival time is the bang-bang one.
    """

    dt: float = DT

    def __call__(self, obs: Any) -> np.ndarray:
        obs = np.asarray(obs, np.float64)
        x, v = obs[..., 0], obs[..., 1]
        first, second = deadbeat_thrusts(x, v, self.dt)
        deadbeat = (np.abs(first) <= 1) & (np.abs(second) <= 1)
        thrust = np.where(deadbeat, first, curve_landing_thrust(x, v, self.dt))
        return thrust[..., None].astype(np.float32)


# ---- linear laws --------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class LinearFeedback:
    """``u = clip(-k_x x - k_v v, -1, 1)``: a PD law, LQR's gains among them."""

    position_gain: float
    velocity_gain: float

    def __call__(self, obs: Any) -> np.ndarray:
        obs = np.asarray(obs, np.float64)
        thrust = -self.position_gain * obs[..., 0] - self.velocity_gain * obs[..., 1]
        return np.clip(thrust, -1.0, 1.0)[..., None].astype(np.float32)


def lqr_gains(q1: float = LQR_Q1, q2: float = LQR_Q2, r: float = LQR_R) -> tuple[float, float]:
    """``K = R^-1 B^T P`` for ``A = [[0, 1], [0, 0]]``, ``B = [0, 1]^T``, ``Q = diag(q1, q2)``,
    ``R = r``: ``(sqrt(q1/r), sqrt(q2/r + 2 sqrt(q1/r)))``, from ``riccati_solution``."""
    solution = riccati_solution(q1, q2, r)
    return float(solution[0, 1] / r), float(solution[1, 1] / r)


def riccati_solution(q1: float = LQR_Q1, q2: float = LQR_Q2, r: float = LQR_R) -> np.ndarray:
    """The stabilising ``P`` of ``A^T P + P A - P B R^-1 B^T P + Q = 0`` for the rocket.

    Entry by entry the equation reads ``p12^2 = q1 r``, ``p22^2 = r (q2 + 2 p12)`` and
    ``p11 = p12 p22 / r``; the positive roots make ``P`` positive definite.
    """
    p12 = np.sqrt(q1 * r)
    p22 = np.sqrt(r * (q2 + 2 * p12))
    return np.array([[p12 * p22 / r, p12], [p12, p22]])


def lqr(q1: float = LQR_Q1, q2: float = LQR_Q2, r: float = LQR_R) -> LinearFeedback:
    """The LQR law for ``Q = diag(q1, q2)``, ``R = r``, saturated to [-1, 1].

    Default ``Q = diag(1, 1/4)``, ``R = 1/64``: gains ``(8, 4 sqrt 2)``, a double closed-loop
    pole at ``-2 sqrt 2`` (critically damped: unsaturated, it does not overshoot). From ``(1, 0)``
    it asks for ``u = -8``, so it starts saturated like bang-bang, then slides in without
    crossing the origin: inside the 0.01 box from step 319 (3.19 s) on. Simulated alternatives
    from ``(1, 0)``: ``q2 = 0`` (damping 0.71) overshoots to ``x = -0.07`` and settles at step
    341; poles at 2 rad/s (``q1 / r = 16``, critically damped) settle at step 392.
    """
    return LinearFeedback(*lqr_gains(q1, q2, r))


def pd(position_gain: float, velocity_gain: float) -> LinearFeedback:
    """The PD law ``u = clip(-kp x - kd v, -1, 1)``."""
    return LinearFeedback(position_gain, velocity_gain)


# ---- rolling a controller through the env ------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Trajectory:
    """One rollout: the state at every step, start first (step ``i`` is time ``i * dt``), and
    per step the thrust applied (after the env's clipping), the reward and termination."""

    positions: np.ndarray  # [steps + 1]
    velocities: np.ndarray  # [steps + 1]
    thrusts: np.ndarray  # [steps]
    rewards: np.ndarray  # [steps]
    terminated: np.ndarray  # [steps] bool: what the env signalled (the rollout went on)
    dt: float
    env_id: str
    goal_tolerance: float  # the env's own goal box (1e-8 for the faithful rocket)

    @property
    def times(self) -> np.ndarray:
        """Seconds since the start, one per recorded position."""
        return np.arange(self.positions.shape[0]) * self.dt


def _rocket(env: Any) -> Any:
    """The registered rocket env an id (or env, wrapped or not) names."""
    env = envs.make(env) if isinstance(env, str) else env
    env = getattr(env, "unwrapped", env)
    if not isinstance(env, Rocket):
        raise TypeError(f"{env!r} is not a rocket env")
    return env


@functools.lru_cache(maxsize=8)
def _jitted_step(env: Any) -> Callable:
    key = jax.random.key(0)  # the rocket's step is deterministic
    return jax.jit(lambda state, action, params: env.step(key, state, action, params))


def simulate(
    controller: Controller,
    start: tuple[float, float] = (1.0, 0.0),
    steps: int = 500,
    env: Any = "rl_jax/Rocket-v0",
    params: Any = None,
) -> Trajectory:
    """Roll ``controller`` (numpy ``obs -> action``) from the exact ``start`` for ``steps``.

    It goes through the env's own jitted step (float32, RK4), and does not stop where the env
    terminates: the faithful rocket ends an episode at the 1e-8 goal, and whether a controller
    then stays put is part of what is measured. ``summarize`` still scores the return only up to
    the env's own episode end.
    """
    env = _rocket(env)
    params = env.default_params if params is None else params
    step = _jitted_step(env)
    state, obs = env.state_from_vector(np.asarray(start, np.float32), params)
    observations, thrusts, rewards, terminated = [np.asarray(obs)], [], [], []
    for _ in range(steps):
        action = np.asarray(controller(np.asarray(obs)), np.float32).reshape(1)
        state, timestep = step(state, action, params)
        obs, reward, done = jax.device_get((timestep.obs, timestep.reward, timestep.terminated))
        observations.append(np.asarray(obs))
        thrusts.append(float(np.clip(action[0], -1.0, 1.0)))
        rewards.append(float(reward))
        terminated.append(bool(done))
    states = np.stack(observations).astype(np.float64)
    return Trajectory(
        positions=states[:, 0],
        velocities=states[:, 1],
        thrusts=np.asarray(thrusts),
        rewards=np.asarray(rewards),
        terminated=np.asarray(terminated, bool),
        dt=float(params.dt),
        env_id=env.id or type(env).__name__,
        goal_tolerance=float(params.goal_tolerance),
    )


# ---- what a trajectory achieved -----------------------------------------------------------------


def _inside(positions: Any, velocities: Any, tolerance: float) -> np.ndarray:
    positions, velocities = np.asarray(positions), np.asarray(velocities)
    return (np.abs(positions) <= tolerance) & (np.abs(velocities) <= tolerance)


def settle_step(positions: Any, velocities: Any, tolerance: float = TOLERANCE) -> int | None:
    """The first step from which ``|x|, |v| <= tolerance`` holds to the end; None if it never
    does (the last state is outside). The box is closed, as the env's ``in_goal_box``."""
    outside = np.flatnonzero(~_inside(positions, velocities, tolerance))
    if outside.size == 0:
        return 0
    last_outside = int(outside[-1])
    return None if last_outside == len(np.asarray(positions)) - 1 else last_outside + 1


def first_entry_step(positions: Any, velocities: Any, tolerance: float = TOLERANCE) -> int | None:
    """The first step inside the box, whether or not the state stays; None if never."""
    inside = np.flatnonzero(_inside(positions, velocities, tolerance))
    return int(inside[0]) if inside.size else None


@dataclasses.dataclass(frozen=True)
class Summary:
    """What a trajectory achieved, as ``rocket_comparison``'s table shows it."""

    settle_step: int | None  # from here on inside the box to the end; None: never settled
    settle_time: float | None  # settle_step * dt, seconds
    first_entry_step: int | None  # first step inside the box (it may have left again)
    kept: bool  # settled, so inside the box at the last step and every step from settle_step
    steps: int
    episode_return: float  # rewards up to the env's own episode end (see episode_end)
    episode_end: str  # "time limit", "goal at step N" or "crashed at step N"
    final_position: float
    final_velocity: float


def summarize(trajectory: Trajectory, tolerance: float = TOLERANCE) -> Summary:
    """Settling and return of ``trajectory``.

    The return is the env's episode return: it stops at the first step the env terminated
    (the faithful rocket's +500 at the 1e-8 goal, or a crash), because past that point the env
    would have reset, and summing a goal bonus paid on every later step would be meaningless.
    """
    positions, velocities = trajectory.positions, trajectory.velocities
    settled = settle_step(positions, velocities, tolerance)
    ends = np.flatnonzero(trajectory.terminated)
    steps = int(trajectory.rewards.shape[0])
    if ends.size:
        end = int(ends[0]) + 1  # step numbers count states: the first step leads to state 1
        at_goal = _inside(positions[end], velocities[end], trajectory.goal_tolerance)
        episode_end = f"{'goal' if at_goal else 'crashed'} at step {end}"
    else:
        end, episode_end = steps, "time limit"
    return Summary(
        settle_step=settled,
        settle_time=None if settled is None else settled * trajectory.dt,
        first_entry_step=first_entry_step(positions, velocities, tolerance),
        kept=settled is not None,
        steps=steps,
        episode_return=float(np.sum(trajectory.rewards[:end])),
        episode_end=episode_end,
        final_position=float(positions[-1]),
        final_velocity=float(velocities[-1]),
    )
