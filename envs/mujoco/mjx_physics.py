"""The MJX backend: ``mujoco.mjx`` in float32, pure JAX (see ``envs.mujoco.mujoco_backend``)."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from jax.custom_batching import custom_vmap

from rl_jax.envs.mujoco.mujoco_backend import (
    DIVERGENCE_LIMIT,
    POST_CONSTRAINT_EXTRAS,
    Array,
    Measurement,
    Physics,
    extra_field,
    small_cholesky,
    without_warp_lines,
)

with without_warp_lines():  # MJX prints two lines on import where NVIDIA Warp is not installed
    from mujoco import mjx


def _jax_diverged(*arrays: Array) -> Array:
    ok = [jnp.all(jnp.abs(a) <= DIVERGENCE_LIMIT) for a in arrays]
    return ~jnp.all(jnp.stack(ok))


def _map_in_chunks(function: Any, args: Any, size: int, chunk: int) -> Any:
    """``function`` (batched over axis 0) on ``chunk`` rows at a time, in sequence."""
    chunks = -(-size // chunk)
    pad = chunks * chunk - size

    def split(x: Array) -> Array:
        if pad:  # repeat the first rows: valid inputs whose results are dropped
            x = jnp.concatenate([x, x[:pad]], axis=0)
        return x.reshape(chunks, chunk, *x.shape[1:])

    out = jax.lax.map(function, jax.tree.map(split, args))
    return jax.tree.map(lambda x: x.reshape(chunks * chunk, *x.shape[2:])[:size], out)


class MjxPhysics(Physics):
    """``mujoco.mjx`` in float32. State: ``(qpos, qvel, qacc_warmstart)``.

    ``chunk``: under ``vmap`` over more envs than this, step them ``chunk`` at a time in a loop
    instead of all at once. On CPU a contact-rich model then keeps its working set in cache (half
    cheetah's 70 constraint rows per env); the pendulums run best unchunked. Implemented as a custom
    batching rule, so jit, jvp and nested vmaps (seeds x envs: each chunk then holds every seed's
    share) work as before.
    """

    name = "mjx"

    def __init__(
        self,
        model: mujoco.MjModel,
        frame_skip: int,
        extras: tuple[str, ...] = (),
        chunk: int | None = None,
    ):
        super().__init__(model, frame_skip, extras)
        self.mjx_model = mjx.put_model(model, impl="jax")
        # Every field a step reads other than the state and ctrl is recomputed by the forward pass,
        # so one template Data serves every env and only the state travels between steps.
        self._template = mjx.make_data(self.mjx_model, impl="jax")
        self.chunk = chunk
        self._chunked_step = self._make_chunked_step(chunk) if chunk else None

    def from_qpos_qvel(self, qpos: Any, qvel: Any, qacc_warmstart: Any = None) -> tuple:
        """Physics state ``(qpos, qvel, qacc_warmstart)`` in float32; the warm start defaults to
        zero.
        """
        qpos = jnp.asarray(qpos, jnp.float32)
        qvel = jnp.asarray(qvel, jnp.float32)
        warm = jnp.zeros_like(qvel) if qacc_warmstart is None else qacc_warmstart
        return (qpos, qvel, jnp.asarray(warm, jnp.float32))

    def _data(self, state: tuple, ctrl: Array | None = None, template: Any = None) -> mjx.Data:
        qpos, qvel, warm = state
        template = self._template if template is None else template
        data = template.replace(qpos=qpos, qvel=qvel, qacc_warmstart=warm)
        if ctrl is not None:
            data = data.replace(ctrl=jnp.asarray(ctrl, jnp.float32))
        return data

    def _make_chunked_step(self, chunk: int) -> Any:
        stepper = custom_vmap(lambda state, ctrl: self._step(state, ctrl))

        @stepper.def_vmap
        def rule(axis_size: int, in_batched: Any, state: tuple, ctrl: Array) -> tuple:
            broadcast = lambda x, batched: (
                x if batched else jnp.broadcast_to(x, (axis_size, *x.shape))
            )
            args = jax.tree.map(broadcast, (state, ctrl), tuple(in_batched))
            if axis_size <= chunk:
                out = self._batched_step(*args)
            else:
                out = _map_in_chunks(lambda a: self._batched_step(*a), args, axis_size, chunk)
            return out, jax.tree.map(lambda _: True, out)

        return stepper

    def step(
        self, state: tuple, ctrl: Array, active: Array | None = None
    ) -> tuple[tuple, Measurement]:
        """``frame_skip`` MJX steps with ``ctrl``; ``active`` is ignored (MJX steps every env)."""
        ctrl = jnp.asarray(ctrl, jnp.float32)
        if self._chunked_step is None:
            return self._step(state, ctrl)
        return self._chunked_step(state, ctrl)

    def _batched_step(self, state: tuple, ctrl: Array) -> tuple[tuple, Measurement]:
        """``vmap(_step)`` with the template Data given to every env: the frame loop's carry is
        then batched from its first iteration, and ``vmap`` of the loop traces its body once
        (with an unbatched template it traces it twice, to find the carry's batching)."""
        size = ctrl.shape[0]
        template = jax.tree.map(lambda x: jnp.broadcast_to(x, (size, *x.shape)), self._template)
        return jax.vmap(self._step)(state, ctrl, template)

    def _step(self, state: tuple, ctrl: Array, template: Any = None) -> tuple[tuple, Measurement]:
        data = self._data(state, ctrl, template)
        # MJX's own code broadcasts implicitly; allow it even under rank_promotion="raise"
        with jax.numpy_rank_promotion("allow"), small_cholesky():
            data = jax.lax.fori_loop(
                0, self.frame_skip, lambda _, d: mjx.step(self.mjx_model, d), data
            )
            if any(name in POST_CONSTRAINT_EXTRAS for name in self.extras):
                data = mjx.rne_postconstraint(self.mjx_model, data)
        new_state = (data.qpos, data.qvel, data.qacc_warmstart)
        measurement = Measurement(
            qpos=data.qpos,
            qvel=data.qvel,
            qpos_change=data.qpos - state[0],
            extras={name: extra_field(name, data, jnp) for name in self.extras},
            diverged=_jax_diverged(*new_state),
        )
        return new_state, measurement

    def forward(self, state: tuple) -> Measurement:
        """``mjx.forward`` at ``state``: the measurement with current derived fields and no
        position change.
        """
        with jax.numpy_rank_promotion("allow"), small_cholesky():
            data = mjx.forward(self.mjx_model, self._data(state))
        return Measurement(
            qpos=state[0],
            qvel=state[1],
            qpos_change=jnp.zeros_like(state[0]),
            extras={name: _forward_extra(name, data) for name in self.extras},
            diverged=_jax_diverged(state[0], state[1]),
        )

    def to_numpy(self, state: tuple) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Host side: ``(qpos, qvel, qacc_warmstart)`` widened to float64."""
        qpos, qvel, warm = state
        return (
            np.asarray(qpos, np.float64),
            np.asarray(qvel, np.float64),
            np.asarray(warm, np.float64),
        )

    def qpos_qvel(self, state: tuple) -> tuple[Array, Array]:
        """``(qpos, qvel)`` of a state (already float32)."""
        return state[0], state[1]


def _forward_extra(name: str, data: Any) -> Array:
    """An extra after a forward pass; post-constraint fields are zero, as after a reset."""
    value = extra_field(name, data, jnp)
    return jnp.zeros_like(value) if name in POST_CONSTRAINT_EXTRAS else value
