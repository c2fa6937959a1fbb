"""MuJoCo C as an XLA FFI custom call: the ``mujoco_ffi`` backend (``MujocoFfiPhysics``).

The same physics, state layout and results as the ``mujoco_callback`` backend, bit for bit (both
run MuJoCo's batch, mjBatch, on the same float64 state), but the step is a custom call inside the
compiled program (``envs/mujoco/mujoco_ffi.cc``, built by ``envs.mujoco.mujoco_ffi_build``): no
Python runs in a step, and since the program has no host callback JAX's persistent compilation cache
stores it, so a second process loads it instead of compiling it.

The calls, in HLO::

    rl_jax_mujoco_step(key u32[..., 2], state u32[..., 2 (nq + 2 nv)], ctrl f32[..., nu])
        -> state, qpos, qvel, qpos change, diverged, extras...
    rl_jax_mujoco_step_active(key, state, ctrl, active pred[...]) -> as rl_jax_mujoco_step,
        stepping only the envs whose ``active`` is true (the others' state comes back as it
        went in; their other results are unspecified)
    rl_jax_mujoco_forward(key, state) -> qpos, qvel, qpos change, diverged, extras...

``key`` names the model: 64 bits of a BLAKE2b hash of everything a call depends on (the model's
MJB serialisation, frame skip, extras, thread count), registered with the library when the physics
is built. It is an operand, so it is data in the HLO, and the same in every process that builds
the same env: the program's cache key does not change from process to process, and a program
loaded from the cache finds its model registered under the same key (a key that is not registered
fails the call with a message, it does not crash).

vmap: ``vmap_method="broadcast_all"``. Every operand, the key included, gets the full batch shape
under each vmap (envs, seeds, hyperparameter sets); the handler flattens the batch axes and steps
all envs in one threaded call (``nthread`` threads, one per core by default, the caller's
included), as the callback path does.
"""

from __future__ import annotations

import ctypes
import hashlib
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from rl_jax.envs.mujoco import mujoco_ffi_build
from rl_jax.envs.mujoco.mujoco_backend import Array
from rl_jax.envs.mujoco.mujoco_c import MujocoCPhysics

ERROR_BUFFER_SIZE = 1000


def model_bytes(model: mujoco.MjModel) -> bytes:
    """The model's MJB serialisation (``mj_saveModel``): all of it, and nothing per-process."""
    buffer = np.empty(mujoco.mj_sizeModel(model), np.uint8)
    mujoco.mj_saveModel(model, None, buffer)
    return buffer.tobytes()


def register_model(
    model: mujoco.MjModel, frame_skip: int, extras: tuple[str, ...], nthread: int
) -> np.ndarray:
    """Register a model with the library; its key as uint32 ``[2]`` (low, high words)."""
    library = mujoco_ffi_build.load()
    mjb = model_bytes(model)
    names = ",".join(extras)
    digest = hashlib.blake2b(mjb, digest_size=8)
    digest.update(f"|{frame_skip}|{names}|{nthread}".encode())
    key = int.from_bytes(digest.digest(), "little")
    error = ctypes.create_string_buffer(ERROR_BUFFER_SIZE)
    status = library.rl_jax_mujoco_register(
        key, mjb, len(mjb), frame_skip, nthread, names.encode(), error, ERROR_BUFFER_SIZE
    )
    if status != 0:
        raise ValueError(f"the MuJoCo FFI op cannot run this model: {error.value.decode()}")
    return np.array([key & 0xFFFFFFFF, key >> 32], np.uint32)


class MujocoFfiPhysics(MujocoCPhysics):
    """MuJoCo C called as an XLA FFI custom call (see the module docstring)."""

    name = "mujoco_ffi"

    def _connect(self) -> None:
        self.key = register_model(self.model, self.frame_skip, self.extras, self.nthread)

    def _call(self, target: str, with_state: bool, *operands: Array) -> Any:
        call = jax.ffi.ffi_call(
            target, self._result_shapes(with_state), vmap_method="broadcast_all"
        )
        return call(jnp.asarray(self.key), *operands)

    def _call_step(self, state: Array, ctrl: Array, active: Array | None = None) -> Any:
        if active is None:
            return self._call(mujoco_ffi_build.STEP_TARGET, True, state, ctrl)
        active = jnp.asarray(active, jnp.bool_)
        return self._call(mujoco_ffi_build.STEP_ACTIVE_TARGET, True, state, ctrl, active)

    def _call_forward(self, state: Array) -> Any:
        return self._call(mujoco_ffi_build.FORWARD_TARGET, False, state)
