"""The 1-D rocket as a plain numpy ``gymnasium.Env``: the baseline of ``bench_classic``.

This is how a gymnasium user writes the rocket of ``envs/classic/rocket.py`` (same spec: RK4 step of
``x' = v, v' = u``, same reward, termination, 500-step truncation and reset), stepped one env at a
time from Python.
"""

from __future__ import annotations

import gymnasium
import numpy as np


class NumpyRocketEnv(gymnasium.Env):
    metadata = {"render_modes": []}

    def __init__(self, dt: float = 0.01, max_episode_steps: int = 500):
        self.dt = dt
        self.max_episode_steps = max_episode_steps
        self.observation_space = gymnasium.spaces.Box(-3.0, 3.0, (2,), np.float32)
        self.action_space = gymnasium.spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.state = np.zeros(2, np.float32)
        self.steps = 0

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        magnitude = self.np_random.uniform(0.5, 1.0, 2)
        sign = self.np_random.choice([-1.0, 1.0], 2)
        self.state = (magnitude * sign).astype(np.float32)
        self.steps = 0
        return self.state.copy(), {}

    def _derivative(self, y: np.ndarray, u: np.float32) -> np.ndarray:
        return np.array([y[1], u], np.float32)

    def step(self, action):
        u = np.float32(np.clip(action, -1.0, 1.0)[0])
        y, dt = self.state, np.float32(self.dt)
        k1 = self._derivative(y, u)
        k2 = self._derivative(y + dt / 2 * k1, u)
        k3 = self._derivative(y + dt / 2 * k2, u)
        k4 = self._derivative(y + dt * k3, u)
        self.state = y + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        x, v = self.state
        reward = 1 / (x**2 + 1)
        reward = reward - 10 * abs(v) if x * v > 0 else reward + 1 / (v**2 + 1)
        terminated = False
        if abs(x) > 2 or abs(v) > 2:
            terminated, reward = True, reward - 500
        if self._at_goal():
            terminated, reward = True, reward + 500
        self.steps += 1
        truncated = self.steps >= self.max_episode_steps
        return self.state.copy(), float(reward), terminated, truncated, {}

    def _at_goal(self) -> bool:
        # The original's test; it is most of this step's cost.
        return bool(np.allclose(self.state, 0, atol=1e-8))


class ScalarGoalNumpyRocketEnv(NumpyRocketEnv):
    """The same env with the goal test on scalars instead of ``np.allclose`` (a faster baseline)."""

    def _at_goal(self) -> bool:
        x, v = self.state
        return abs(x) <= 1e-8 and abs(v) <= 1e-8
