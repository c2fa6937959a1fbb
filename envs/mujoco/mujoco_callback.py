"""MuJoCo C called through ``jax.pure_callback`` into ``mujoco.batch`` on the host: needs no
compiler; what the ``mujoco`` backend falls back to when the FFI op cannot be built (see
``envs.mujoco.mujoco_backend``)."""

from __future__ import annotations

import threading
from typing import Any

import jax
import mujoco
import numpy as np
from mujoco import batch as mujoco_batch

from rl_jax.envs.mujoco.float64_bits import bits_to_float64, float64_to_bits
from rl_jax.envs.mujoco.mujoco_backend import (
    _INSTABILITY_WARNINGS,
    COMPUTED_EXTRAS,
    DIVERGENCE_LIMIT,
    POST_CONSTRAINT_EXTRAS,
    Array,
    extra_field,
)
from rl_jax.envs.mujoco.mujoco_c import MujocoCPhysics


def _state_columns(model: mujoco.MjModel, component: mujoco.mjtState) -> slice:
    """Columns of one component in an ``mjSTATE_INTEGRATION`` row (components in bit order)."""
    offset = 0
    for bit in range(int(mujoco.mjtState.mjNSTATE)):
        spec = 1 << bit
        if spec & int(mujoco.mjtState.mjSTATE_INTEGRATION) and spec < int(component):
            offset += mujoco.mj_stateSize(model, spec)
    return slice(offset, offset + mujoco.mj_stateSize(model, int(component)))


class _Workspace:
    """A scratch ``mujoco.batch.Batch`` of ``nsim`` simulations and views into it.

    It holds nothing a result depends on: every call writes the full physics state (qpos, qvel,
    warm start, controls, time) of every simulation before stepping, and stepping changes no other
    part of a simulation's state row in these models (no activations, mocap or plugins). The lock
    serialises concurrent callbacks (XLA may run a step and a reset callback at once).
    """

    def __init__(self, model: mujoco.MjModel, nsim: int, nthread: int, outputs: tuple[str, ...]):
        self.batch = mujoco_batch.Batch(model, nsim, nthread=nthread)
        self.lock = threading.Lock()
        state = self.batch.state
        columns = lambda c: state[:, _state_columns(model, c)]
        self.time = columns(mujoco.mjtState.mjSTATE_TIME)
        self.qpos = columns(mujoco.mjtState.mjSTATE_QPOS)
        self.qvel = columns(mujoco.mjtState.mjSTATE_QVEL)
        self.warmstart = columns(mujoco.mjtState.mjSTATE_WARMSTART)
        self.ctrl = columns(mujoco.mjtState.mjSTATE_CTRL)
        # derived fields are copied out after a call only if bound before it
        self.outputs = {
            name: self.batch.bind(name) for name in outputs if name not in COMPUTED_EXTRAS
        }
        self.warnings = self.batch.warning
        self.model, self.state = model, state
        # mujoco.batch has no hook for mj_rnePostConstraint after a step: a model whose extras
        # need it is stepped env by env in Python instead (step_with_post_constraint)
        self.post_constraint = any(name in POST_CONSTRAINT_EXTRAS for name in outputs)
        if self.post_constraint:
            self.data = mujoco.MjData(model)
            self.own_outputs = {name: np.zeros_like(array) for name, array in self.outputs.items()}

    def load(self, qpos: np.ndarray, qvel: np.ndarray, warmstart: np.ndarray) -> None:
        self.qpos[:], self.qvel[:], self.warmstart[:] = qpos, qvel, warmstart
        self.time[:] = 0.0
        self.warnings[...] = 0

    def step_with_post_constraint(self, frame_skip: int) -> None:
        """gymnasium's do_simulation on each loaded row: frame_skip mj_steps, then
        mj_rnePostConstraint; the field extras are copied out of each env's mjData."""
        model, data, spec = self.model, self.data, mujoco.mjtState.mjSTATE_INTEGRATION
        for i in range(self.state.shape[0]):
            mujoco.mj_resetData(model, data)
            mujoco.mj_setState(model, data, self.state[i], spec)
            mujoco.mj_step(model, data, nstep=frame_skip)
            mujoco.mj_rnePostConstraint(model, data)
            mujoco.mj_getState(model, data, self.state[i], spec)
            self.warnings[i, :, 1] = [w.number for w in data.warning]
            for name, array in self.own_outputs.items():
                array[i] = getattr(data, name).reshape(array.shape[1:])

    def unstable(self) -> np.ndarray:
        """Per simulation: MuJoCo met (and reset after) a NaN/inf/huge qpos, qvel or qacc."""
        return np.any(self.warnings[:, _INSTABILITY_WARNINGS, 1] > 0, axis=1)


class _HostWorkspaces:
    """The workspaces of one model, one per (operation, batch size), made on first use."""

    def __init__(self, model: mujoco.MjModel, nthread: int, outputs: tuple[str, ...]):
        self.model, self.nthread, self.outputs = model, nthread, outputs
        self._workspaces: dict[tuple[str, int], _Workspace] = {}
        self._guard = threading.Lock()

    def get(self, operation: str, nsim: int) -> _Workspace:
        with self._guard:
            key = (operation, nsim)
            if key not in self._workspaces:
                self._workspaces[key] = _Workspace(self.model, nsim, self.nthread, self.outputs)
            return self._workspaces[key]


class MujocoCallbackPhysics(MujocoCPhysics):
    """MuJoCo C called through ``jax.pure_callback`` (``mujoco.batch`` on the host)."""

    name = "mujoco_callback"

    def _connect(self) -> None:
        self._workspaces = _HostWorkspaces(self.model, self.nthread, self.extras)

    def _call_step(self, state: Array, ctrl: Array, active: Array | None = None) -> Any:
        # Steps every env: the host batch is cheap to fill, and skipping would need a second
        # workspace layout for the pure_callback path, which is not the default.
        shapes = self._result_shapes(True)
        return jax.pure_callback(self._host_step, shapes, state, ctrl, vmap_method="broadcast_all")

    def _call_forward(self, state: Array) -> Any:
        shapes = self._result_shapes(False)
        return jax.pure_callback(self._host_forward, shapes, state, vmap_method="broadcast_all")

    # -- host side ---------------------------------------------------------------------------
    def _split(self, state: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        values = bits_to_float64(state).reshape(-1, self.state_size)
        nq, nv = self.nq, self.nv
        return values[:, :nq], values[:, nq : nq + nv], values[:, nq + nv :]

    def _host_outputs(
        self, work: _Workspace, qpos_before: np.ndarray, batch_shape: tuple, stepped: bool
    ) -> list:
        qpos, qvel = work.qpos, work.qvel
        magnitude = np.maximum(np.abs(qpos).max(axis=1), np.abs(qvel).max(axis=1))
        diverged = work.unstable() | ~(magnitude <= DIVERGENCE_LIMIT)  # NaN compares False
        outputs = [
            qpos.astype(np.float32),
            qvel.astype(np.float32),
            (qpos - qpos_before).astype(np.float32),
            diverged,
            *(self._host_extra(name, work, stepped).astype(np.float32) for name in self.extras),
        ]
        return [o.reshape(batch_shape + o.shape[1:]) for o in outputs]

    @staticmethod
    def _host_extra(name: str, work: _Workspace, stepped: bool) -> np.ndarray:
        if name in COMPUTED_EXTRAS:
            return extra_field(name, work, np)
        if work.post_constraint and stepped:
            return work.own_outputs[name]
        if name in POST_CONSTRAINT_EXTRAS:  # after a forward pass, as after gymnasium's reset
            return np.zeros_like(work.outputs[name])
        return work.outputs[name]

    def _host_step(self, state: np.ndarray, ctrl: np.ndarray) -> tuple:
        batch_shape = ctrl.shape[:-1]
        qpos, qvel, warmstart = self._split(state)
        work = self._workspaces.get("step", qpos.shape[0])
        with work.lock:
            work.load(qpos, qvel, warmstart)
            work.ctrl[:] = ctrl.reshape(-1, self.nu)
            if work.post_constraint:
                work.step_with_post_constraint(self.frame_skip)
            else:
                work.batch.step(nstep=self.frame_skip)
            new_values = np.concatenate([work.qpos, work.qvel, work.warmstart], axis=1)
            new_state = float64_to_bits(new_values).reshape(batch_shape + (2 * self.state_size,))
            return (new_state, *self._host_outputs(work, qpos, batch_shape, stepped=True))

    def _host_forward(self, state: np.ndarray) -> tuple:
        batch_shape = state.shape[:-1]
        qpos, qvel, warmstart = self._split(state)
        work = self._workspaces.get("forward", qpos.shape[0])
        with work.lock:
            work.load(qpos, qvel, warmstart)
            work.batch.forward()
            return tuple(self._host_outputs(work, qpos, batch_shape, stepped=False))
