"""MuJoCo C in float64 on a thread pool: the state layout and results both ways of calling it
share (the FFI op, ``envs.mujoco.mujoco_ffi``; the host callback, ``envs.mujoco.mujoco_callback``).
"""

from __future__ import annotations

import os
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from rl_jax.envs.mujoco.float64_bits import (
    bits_to_float64,
    float32_to_float64_bits,
    float64_bits_to_float32,
    float64_to_bits,
)
from rl_jax.envs.mujoco.mujoco_backend import Array, Measurement, Physics


def default_thread_count() -> int:
    """Cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


class MujocoCPhysics(Physics):
    """MuJoCo C in float64 on a thread pool; subclasses say how the program calls it.

    State: uint32 ``[2 * (nq + 2 nv)]``, the float64 bits of ``qpos, qvel, qacc_warmstart``.
    A call returns, in this order: (for a step) the new state, then qpos, qvel, qpos change,
    diverged, and the extras in ``self.extras`` order (``_result_shapes``).
    """

    name = "mujoco"

    def __init__(
        self,
        model: mujoco.MjModel,
        frame_skip: int,
        extras: tuple[str, ...] = (),
        nthread: int | None = None,
    ):
        if model.na or model.nmocap or model.nplugin:
            raise ValueError("the C backend supports models without activations, mocap, plugins")
        super().__init__(model, frame_skip, extras)
        self.nthread = default_thread_count() if nthread is None else int(nthread)
        self.state_size = self.nq + 2 * self.nv
        self._connect()

    def _connect(self) -> None:
        """What a way of calling MuJoCo C prepares once the model is known (workspaces, an op
        registration); called at the end of ``__init__``."""

    # -- building states ---------------------------------------------------------------------
    def from_qpos_qvel(self, qpos: Any, qvel: Any, qacc_warmstart: Any = None) -> Array:
        """Exact: float64 numpy inputs keep all their bits; float32/traced inputs are widened."""
        parts = [qpos, qvel, np.zeros(np.shape(qvel)) if qacc_warmstart is None else qacc_warmstart]
        if all(isinstance(p, np.ndarray | float | int) for p in parts):
            vector = np.concatenate([np.asarray(p, np.float64) for p in parts], axis=-1)
            return jnp.asarray(float64_to_bits(vector))
        vector32 = jnp.concatenate([jnp.asarray(p, jnp.float32) for p in parts], axis=-1)
        bits = float32_to_float64_bits(vector32)
        return bits.reshape(*bits.shape[:-2], 2 * bits.shape[-2])

    def to_numpy(self, state: Array) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Host side: ``(qpos, qvel, qacc_warmstart)`` decoded from the state's float64 bits."""
        values = bits_to_float64(np.asarray(state))
        nq, nv = self.nq, self.nv
        return values[..., :nq], values[..., nq : nq + nv], values[..., nq + nv :]

    def qpos_qvel(self, state: Array) -> tuple[Array, Array]:
        """float32 ``(qpos, qvel)`` decoded from the state's float64 bits, inside JAX."""
        values = float64_bits_to_float32(state[..., : 2 * (self.nq + self.nv)])
        return values[..., : self.nq], values[..., self.nq :]

    # -- results of a call -------------------------------------------------------------------
    def _result_shapes(self, with_state: bool) -> tuple:
        f32 = jnp.float32
        shapes = [
            jax.ShapeDtypeStruct((self.nq,), f32),
            jax.ShapeDtypeStruct((self.nv,), f32),
            jax.ShapeDtypeStruct((self.nq,), f32),
            jax.ShapeDtypeStruct((), jnp.bool_),
            *(jax.ShapeDtypeStruct(s, f32) for s in self._extra_shapes.values()),
        ]
        if with_state:
            shapes.insert(0, jax.ShapeDtypeStruct((2 * self.state_size,), jnp.uint32))
        return tuple(shapes)

    def _measurement(self, outputs: Any) -> Measurement:
        qpos, qvel, change, diverged, *extras = outputs
        return Measurement(
            qpos, qvel, change, dict(zip(self.extras, extras, strict=True)), diverged
        )

    def step(
        self, state: Array, ctrl: Array, active: Array | None = None
    ) -> tuple[Array, Measurement]:
        """``frame_skip`` substeps of MuJoCo C's ``mj_step``; envs where ``active`` is False are
        skipped.
        """
        outputs = self._call_step(state, jnp.asarray(ctrl, jnp.float32), active)
        return outputs[0], self._measurement(outputs[1:])

    def forward(self, state: Array) -> Measurement:
        """MuJoCo C's ``mj_forward`` at ``state``, returned as a measurement."""
        return self._measurement(self._call_forward(state))

    def _call_step(self, state: Array, ctrl: Array, active: Array | None = None) -> Any:
        """The results of ``_result_shapes(True)`` for a (batch of) state and control; envs where
        ``active`` is False may be skipped (see ``Physics.step``)."""
        raise NotImplementedError

    def _call_forward(self, state: Array) -> Any:
        """The results of ``_result_shapes(False)`` for a (batch of) state."""
        raise NotImplementedError
