"""Interchangeable physics backends for the MuJoCo envs: MJX (pure JAX) and MuJoCo C.

Every backend steps a batch of envs inside the caller's jitted program and exposes the same small
API (``Physics``): build a physics state from ``qpos``/``qvel`` (and optionally the solver warm
start), advance it by ``frame_skip`` substeps with a control, and report a ``Measurement`` — the
float32 quantities an env needs for its observation, reward and termination.

``mjx``
    ``mujoco.mjx``: pure JAX, jit/vmap-able and forward-mode differentiable (MJX's solver loop
    has no reverse mode), float32. The physics state is
    ``(qpos, qvel, qacc_warmstart)`` in float32. The default on GPU/TPU.

``mujoco``
    MuJoCo C (float64) stepping the whole batch on a thread pool (MuJoCo's batch, ``mjBatch``,
    one thread per core). Not differentiable. The default on CPU: bit-identical to gymnasium,
    compiles in a second or two (MJX: 10-60 s), and 4-6x faster than MJX on the contact-rich half
    cheetah; on the two pendulums MJX is about as fast or up to ~1.5x faster from 64 envs on
    (bench/bench_mujoco.py). The jitted program reaches MuJoCo C in one of two ways, with
    bit-identical results:

    ``mujoco_ffi``
        an XLA FFI custom call (``envs.mujoco.mujoco_ffi``), compiled on first use with the system
        C++ compiler: no Python runs in a step, and the program can be stored in JAX's persistent
        compilation cache. What ``mujoco`` means when the op builds.
    ``mujoco_callback``
        ``jax.pure_callback`` into ``mujoco.batch`` (``MujocoCallbackPhysics``): needs no
        compiler, but JAX does not cache programs with host callbacks, so each process compiles
        them again. What ``mujoco`` falls back to, with one line on stderr, when the op cannot be
        built.

    Under any number of nested vmaps (envs, seeds, hyperparameters) both receive the whole batch
    at once (``vmap_method="broadcast_all"``), flatten its axes and step every env in one
    threaded call.

Choosing a backend: ``envs.make(id, backend=...)`` with one of ``BACKEND_NAMES``; otherwise the
environment variable ``RL_JAX_MUJOCO_BACKEND``; otherwise ``"mujoco"`` when JAX's default device
is a CPU and ``"mjx"`` on accelerators (see ``default_backend``). An env's ``backend`` attribute is
the engine, "mujoco" or "mjx"; its ``physics.name`` is the concrete backend.

Exactness of the C backend. JAX runs without x64, yet the C physics state must stay float64 so
that trajectories are bit-identical to gymnasium's. The state therefore travels through JAX as the
raw bits of the float64 values, two uint32 words per number (little-endian order, so a host-side
``.view(np.float64)`` recovers the numbers with no arithmetic). Bits are copied, never rounded, so
a state can be carried, checkpointed and resumed exactly (and moved between ``mujoco_ffi`` and
``mujoco_callback``); everything MuJoCo needs is in that state and the control, so a step is a
pure function of its inputs (the host keeps only scratch batches that every call overwrites).
MuJoCo's batch is used rather than ``mujoco.rollout`` because it carries the solver warm start
(``qacc_warmstart``) across calls and exposes derived fields (site positions, constraint forces)
after the step, both needed for bit-identical gymnasium parity; its results do not depend on the
thread count.

Non-finite physics. MuJoCo C resets a simulation whose qpos/qvel/qacc becomes NaN, infinite or
larger than ``mjMAXVAL`` (1e10) and counts a warning; MJX just propagates NaN. Both backends report
this as ``Measurement.diverged`` (warnings raised, or any state value non-finite or beyond 1e10),
and the env layer ends the episode (see ``envs.mujoco.mujoco_env``).
"""

from __future__ import annotations

import contextlib
import os
import threading
from pathlib import Path
from typing import Any, NamedTuple

# Headless machines render through EGL (MuJoCo picks its GL backend when first imported).
if "MUJOCO_GL" not in os.environ and not os.environ.get("DISPLAY"):
    os.environ["MUJOCO_GL"] = "egl"

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402
from mujoco import mjx  # noqa: E402

from envs.core.registry import BackendError  # noqa: E402

Array = jax.Array

BACKENDS = ("mujoco", "mjx")  # physics engines
C_BACKENDS = ("mujoco_ffi", "mujoco_callback")  # the two ways to MuJoCo C, concrete backends
BACKEND_NAMES = ("mujoco", *C_BACKENDS, "mjx")  # what backend= and the env variable accept
BACKEND_ENV_VAR = "RL_JAX_MUJOCO_BACKEND"
# MuJoCo C treats |x| > mjMAXVAL as a diverged simulation; MJX is held to the same line.
DIVERGENCE_LIMIT = float(mujoco.mjMAXVAL)
_INSTABILITY_WARNINGS = [
    int(mujoco.mjtWarning.mjWARN_BADQPOS),
    int(mujoco.mjtWarning.mjWARN_BADQVEL),
    int(mujoco.mjtWarning.mjWARN_BADQACC),
]


def default_backend() -> str:
    """``$RL_JAX_MUJOCO_BACKEND`` if set, else "mujoco" on CPU and "mjx" on accelerators."""
    chosen = os.environ.get(BACKEND_ENV_VAR, "").strip().lower()
    if chosen:
        try:
            return _backend_name(chosen)
        except BackendError as error:
            raise BackendError(f"{error} (from ${BACKEND_ENV_VAR})") from None
    return "mujoco" if jax.default_backend() == "cpu" else "mjx"


def _backend_name(backend: str) -> str:
    name = backend.strip().lower()
    if name in ("c", "mujoco_c", "cpu"):
        name = "mujoco"
    if name not in BACKEND_NAMES:
        raise BackendError(
            f"unknown MuJoCo backend {backend!r}; choose one of {', '.join(BACKEND_NAMES)}"
        )
    return name


def resolve_backend(backend: str | None) -> str:
    """The concrete backend, one of ``C_BACKENDS`` or "mjx", for a name of ``BACKEND_NAMES``.

    "mujoco" is the FFI op when it builds here (the first call may compile it), else the callback.
    """
    name = default_backend() if backend is None else _backend_name(backend)
    if name == "mujoco":
        from envs.mujoco import mujoco_ffi_build

        return "mujoco_ffi" if mujoco_ffi_build.available() else "mujoco_callback"
    return name


def engine(backend: str) -> str:
    """The physics engine of a backend name: "mujoco" (C) or "mjx"."""
    return "mjx" if _backend_name(backend) == "mjx" else "mujoco"


def gymnasium_asset(xml_file: str) -> Path:
    """Path of an MJCF file shipped with the installed gymnasium package."""
    import gymnasium.envs.mujoco as gym_mujoco

    path = Path(gym_mujoco.__file__).resolve().parent / "assets" / xml_file
    if not path.exists():
        raise FileNotFoundError(f"gymnasium ships no MuJoCo asset {xml_file!r} (looked in {path})")
    return path


def load_model(xml_file: str, iterations: int, ls_iterations: int) -> mujoco.MjModel:
    """gymnasium's model with the given constraint-solver iteration limits."""
    model = mujoco.MjModel.from_xml_path(str(gymnasium_asset(xml_file)))
    model.opt.iterations = iterations
    model.opt.ls_iterations = ls_iterations
    return model


# Extras computed from qpos rather than read from mjData. The C backend evaluates them in float64
# before rounding: sin/cos of a float32-rounded angle of a pendulum that has spun many turns would
# lose digits (|angle| = 100 rad has a float32 spacing of 8e-6).
COMPUTED_EXTRAS = {"sin_qpos": "sin", "cos_qpos": "cos"}


def extra_field(name: str, data: Any, numpy_like: Any) -> Any:
    """An extra of ``data`` (mjData, mjx.Data, or a batch's bound arrays), by name."""
    if name in COMPUTED_EXTRAS:
        return getattr(numpy_like, COMPUTED_EXTRAS[name])(data.qpos)
    return getattr(data, name)


class Measurement(NamedTuple):
    """What an env reads after a step (or a forward pass), float32.

    ``qpos_change`` is ``qpos_after - qpos_before`` computed in the backend's own precision, so
    that a velocity derived from it (half cheetah's forward reward) keeps float64 accuracy on the C
    backend even when positions are large. ``extras`` holds the derived ``mjData`` fields the env
    asked for, as MuJoCo leaves them after ``mj_step``: computed at the start of the last substep,
    exactly what gymnasium reads.
    """

    qpos: Array  # [nq]
    qvel: Array  # [nv]
    qpos_change: Array  # [nq]
    extras: dict[str, Array]  # name -> field, e.g. site_xpos [nsite, 3]
    diverged: Array  # [] bool


# ---- float32 -> float64 bits, in JAX without x64 -----------------------------------------------
def float32_to_float64_bits(x: Array) -> Array:
    """``[...]`` float32 -> ``[..., 2]`` uint32, the (low, high) words of the exact float64 value.

    Widening float32 to float64 is exact; this does it with integer ops so that it runs inside a
    jitted program without x64. Handles zeros, subnormals, infinities and NaN like numpy's
    ``astype(np.float64)``.
    """
    bits = jax.lax.bitcast_convert_type(jnp.asarray(x, jnp.float32), jnp.uint32)
    sign = bits & jnp.uint32(0x80000000)
    exponent = (bits >> 23) & jnp.uint32(0xFF)
    mantissa = bits & jnp.uint32(0x7FFFFF)
    is_subnormal = (exponent == 0) & (mantissa != 0)
    # A float32 subnormal is a normal float64: shift its leading 1 up to the implicit-bit position.
    shift = jax.lax.clz(mantissa) - jnp.uint32(8)
    normalized = (mantissa << shift) & jnp.uint32(0x7FFFFF)
    exponent64 = jnp.where(exponent == 0xFF, jnp.uint32(0x7FF), exponent + jnp.uint32(1023 - 127))
    exponent64 = jnp.where(exponent == 0, jnp.uint32(0), exponent64)
    exponent64 = jnp.where(is_subnormal, jnp.uint32(1023 - 126) - shift, exponent64)
    mantissa = jnp.where(is_subnormal, normalized, mantissa)
    high = sign | (exponent64 << 20) | (mantissa >> 3)
    low = (mantissa & jnp.uint32(0x7)) << 29
    return jnp.stack([low, high], axis=-1)


def float64_bits_to_float32(bits: Array) -> Array:
    """uint32 ``[..., 2 n]`` (low, high words) -> float32 ``[..., n]``, rounded to nearest even.

    The float32 view JAX code reads (observations at reset); the exact values stay in the bits.
    Magnitudes below float32's normal range (2**-126) become signed zero, as XLA:CPU's float32
    arithmetic flushes them anyway.
    """
    words = bits.reshape(*bits.shape[:-1], -1, 2)
    low, high = words[..., 0], words[..., 1]
    sign = high & jnp.uint32(0x80000000)
    exponent = ((high >> 20) & jnp.uint32(0x7FF)).astype(jnp.int32)
    mantissa_high = high & jnp.uint32(0xFFFFF)
    # 23 kept mantissa bits: 20 from the high word and the top 3 of the low word.
    mantissa = (mantissa_high << 3) | (low >> 29)
    remainder = low & jnp.uint32(0x1FFFFFFF)
    half = jnp.uint32(0x10000000)
    round_up = (remainder > half) | ((remainder == half) & ((mantissa & 1) == 1))
    exponent32 = exponent - (1023 - 127)
    # Adding the rounding bit may carry into the exponent (and up to infinity): that is correct.
    magnitude = (jnp.clip(exponent32, 0, 255).astype(jnp.uint32) << 23) + mantissa
    magnitude = magnitude + round_up.astype(jnp.uint32)
    value = jax.lax.bitcast_convert_type(sign | magnitude, jnp.float32)
    infinity = jax.lax.bitcast_convert_type(sign | jnp.uint32(0x7F800000), jnp.float32)
    zero = jax.lax.bitcast_convert_type(sign, jnp.float32)
    is_nan = (exponent == 0x7FF) & ((mantissa_high != 0) | (low != 0))
    value = jnp.where(exponent32 >= 255, infinity, value)
    value = jnp.where(exponent32 <= 0, zero, value)
    return jnp.where(is_nan, jnp.float32(jnp.nan), value)


def float64_to_bits(x: np.ndarray) -> np.ndarray:
    """Host side: float64 ``[..., n]`` -> uint32 ``[..., 2 * n]`` (exact, little-endian words)."""
    x = np.ascontiguousarray(np.asarray(x, np.float64))
    return x.view(np.uint32).reshape(*x.shape[:-1], 2 * x.shape[-1])


def bits_to_float64(bits: np.ndarray) -> np.ndarray:
    """Host side: uint32 ``[..., 2 * n]`` -> float64 ``[..., n]``."""
    return np.ascontiguousarray(np.asarray(bits, np.uint32)).view(np.float64)


def _jax_diverged(*arrays: Array) -> Array:
    ok = [jnp.all(jnp.abs(a) <= DIVERGENCE_LIMIT) for a in arrays]
    return ~jnp.all(jnp.stack(ok))


# ---- small dense Cholesky, unrolled ----------------------------------------------------------
SMALL_CHOLESKY_MAX = 16


def _unrolled_cholesky_lower(a: Array) -> list[list[Array]]:
    """Lower Cholesky factor of one small SPD matrix as nested lists of scalars."""
    n = a.shape[-1]
    lower = [[None] * n for _ in range(n)]
    for j in range(n):
        diagonal = a[..., j, j] - sum(
            (lower[j][k] ** 2 for k in range(j)), jnp.zeros_like(a[..., 0, 0])
        )
        lower[j][j] = jnp.sqrt(diagonal)
        for i in range(j + 1, n):
            dot = sum((lower[i][k] * lower[j][k] for k in range(j)), jnp.zeros_like(a[..., 0, 0]))
            lower[i][j] = (a[..., i, j] - dot) / lower[j][j]
    return lower


def _small_cho_factor(a, lower=False, overwrite_a=False, check_finite=True):
    """``jax.scipy.linalg.cho_factor`` for small matrices: the same factor, unrolled.

    XLA:CPU runs a batched ``cho_factor`` as one LAPACK call per matrix, whose per-call overhead
    dominates for MJX's 3x3..9x9 mass and Newton matrices; unrolled scalar code is vectorised across
    the whole batch of envs instead (measured ~7x faster for 1,024 9x9 factorisations). The other
    triangle is zero, which scipy leaves unspecified.
    """
    del overwrite_a, check_finite
    n = a.shape[-1]
    rows = _unrolled_cholesky_lower(a)
    zero = jnp.zeros_like(a[..., 0, 0])
    factor = jnp.stack(
        [jnp.stack([rows[i][j] if j <= i else zero for j in range(n)], -1) for i in range(n)], -2
    )
    return (factor if lower else jnp.swapaxes(factor, -1, -2)), lower


def _small_cho_solve(c_and_lower, b, overwrite_b=False, check_finite=True):
    """``jax.scipy.linalg.cho_solve`` for factors of ``_small_cho_factor`` (vector or matrix b)."""
    del overwrite_b, check_finite
    c, lower = c_and_lower
    factor = c if lower else jnp.swapaxes(c, -1, -2)  # L with A = L L^T
    n = factor.shape[-1]
    y = [None] * n
    for i in range(n):  # L y = b
        y[i] = (b[i] - sum((factor[i, k] * y[k] for k in range(i)), jnp.zeros_like(b[i]))) / factor[
            i, i
        ]
    x = [None] * n
    for i in reversed(range(n)):  # L^T x = y
        tail = sum((factor[k, i] * x[k] for k in range(i + 1, n)), jnp.zeros_like(b[i]))
        x[i] = (y[i] - tail) / factor[i, i]
    return jnp.stack(x)


@contextlib.contextmanager
def small_cholesky() -> Any:
    """While MJX is traced, route small ``cho_factor``/``cho_solve`` calls to unrolled code.

    Larger matrices, and solves this does not handle, go to the originals. Only tracing happens
    inside the block, so the patch is in effect for exactly the MJX code we trace; it computes the
    same factorisation, so any other code traced at the same moment would stay correct too.
    """
    linalg = jax.scipy.linalg
    original_factor, original_solve = linalg.cho_factor, linalg.cho_solve

    def cho_factor(a, *args, **kwargs):
        if a.ndim == 2 and a.shape[-1] <= SMALL_CHOLESKY_MAX:
            return _small_cho_factor(a, *args, **kwargs)
        return original_factor(a, *args, **kwargs)

    def cho_solve(c_and_lower, b, *args, **kwargs):
        c = c_and_lower[0]
        if c.ndim == 2 and c.shape[-1] <= SMALL_CHOLESKY_MAX and b.ndim in (1, 2):
            return _small_cho_solve(c_and_lower, b, *args, **kwargs)
        return original_solve(c_and_lower, b, *args, **kwargs)

    linalg.cho_factor, linalg.cho_solve = cho_factor, cho_solve
    try:
        yield
    finally:
        linalg.cho_factor, linalg.cho_solve = original_factor, original_solve


class Physics:
    """Backend interface. ``state`` pytrees are backend-specific; shapes are static."""

    name: str = ""

    def __init__(self, model: mujoco.MjModel, frame_skip: int, extras: tuple[str, ...] = ()):
        self.model = model
        self.frame_skip = frame_skip
        self.extras = tuple(extras)
        self.nq, self.nv, self.nu = model.nq, model.nv, model.nu
        data = mujoco.MjData(model)
        self._extra_shapes = {name: np.shape(extra_field(name, data, np)) for name in self.extras}

    def from_qpos_qvel(self, qpos: Any, qvel: Any, qacc_warmstart: Any = None) -> Any:
        """Physics state; ``qacc_warmstart`` defaults to zero, as after ``mj_resetData``."""
        raise NotImplementedError

    def step(self, state: Any, ctrl: Array, active: Array | None = None) -> tuple[Any, Measurement]:
        """``frame_skip`` substeps of ``mj_step`` with ``ctrl`` (gymnasium's ``do_simulation``).

        ``active`` (bool, per env under vmap) may let a backend skip the envs where it is False:
        their results are then unspecified, and the caller keeps their old state
        (``MujocoEnv.step_active``). Backends are free to step them anyway."""
        raise NotImplementedError

    def forward(self, state: Any) -> Measurement:
        """``mj_forward`` at ``state`` (gymnasium's ``set_state``): derived fields are current."""
        raise NotImplementedError

    def to_numpy(self, state: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Host side: ``(qpos, qvel, qacc_warmstart)`` float64, for rendering and tests."""
        raise NotImplementedError

    def qpos_qvel(self, state: Any) -> tuple[Array, Array]:
        """float32 ``(qpos, qvel)`` of a state, inside JAX."""
        raise NotImplementedError

    def empty_extras(self, batch_shape: tuple[int, ...] = ()) -> dict[str, Array]:
        return {
            name: jnp.zeros(batch_shape + shape, jnp.float32)
            for name, shape in self._extra_shapes.items()
        }


# ---- MJX ----------------------------------------------------------------------------------------
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
    instead of all at once. On CPU a contact-rich model then keeps its working set in cache
    (half cheetah, 4,096 envs: ~1.25x faster with chunks of 32-128); the pendulums are fastest
    unchunked. Implemented as a custom batching rule, so jit, jvp and nested vmaps (seeds x envs:
    each chunk then holds every seed's share) work as before.
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
        self._chunked_step = self._make_chunked_step() if chunk else None

    def from_qpos_qvel(self, qpos: Any, qvel: Any, qacc_warmstart: Any = None) -> tuple:
        qpos = jnp.asarray(qpos, jnp.float32)
        qvel = jnp.asarray(qvel, jnp.float32)
        warm = jnp.zeros_like(qvel) if qacc_warmstart is None else qacc_warmstart
        return (qpos, qvel, jnp.asarray(warm, jnp.float32))

    def _data(self, state: tuple, ctrl: Array | None = None) -> mjx.Data:
        qpos, qvel, warm = state
        data = self._template.replace(qpos=qpos, qvel=qvel, qacc_warmstart=warm)
        if ctrl is not None:
            data = data.replace(ctrl=jnp.asarray(ctrl, jnp.float32))
        return data

    def _make_chunked_step(self) -> Any:
        from jax.custom_batching import custom_vmap

        stepper = custom_vmap(self._step)

        @stepper.def_vmap
        def rule(axis_size: int, in_batched: Any, state: tuple, ctrl: Array) -> tuple:
            broadcast = lambda x, batched: (
                x if batched else jnp.broadcast_to(x, (axis_size, *x.shape))
            )
            args = jax.tree.map(broadcast, (state, ctrl), tuple(in_batched))
            batched_step = jax.vmap(self._step)
            if axis_size <= self.chunk:
                out = batched_step(*args)
            else:
                out = _map_in_chunks(lambda a: batched_step(*a), args, axis_size, self.chunk)
            return out, jax.tree.map(lambda _: True, out)

        return stepper

    def step(
        self, state: tuple, ctrl: Array, active: Array | None = None
    ) -> tuple[tuple, Measurement]:
        ctrl = jnp.asarray(ctrl, jnp.float32)
        if self._chunked_step is None:
            return self._step(state, ctrl)
        return self._chunked_step(state, ctrl)

    def _step(self, state: tuple, ctrl: Array) -> tuple[tuple, Measurement]:
        data = self._data(state, ctrl)
        # MJX's own code broadcasts implicitly; allow it even under rank_promotion="raise"
        with jax.numpy_rank_promotion("allow"), small_cholesky():
            data = jax.lax.fori_loop(
                0, self.frame_skip, lambda _, d: mjx.step(self.mjx_model, d), data
            )
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
        with jax.numpy_rank_promotion("allow"), small_cholesky():
            data = mjx.forward(self.mjx_model, self._data(state))
        return Measurement(
            qpos=state[0],
            qvel=state[1],
            qpos_change=jnp.zeros_like(state[0]),
            extras={name: extra_field(name, data, jnp) for name in self.extras},
            diverged=_jax_diverged(state[0], state[1]),
        )

    def to_numpy(self, state: tuple) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return tuple(np.asarray(x, np.float64) for x in state)

    def qpos_qvel(self, state: tuple) -> tuple[Array, Array]:
        return state[0], state[1]


# ---- MuJoCo C: what both ways of calling it share ----------------------------------------------
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

    # -- building states ---------------------------------------------------------------------
    def from_qpos_qvel(self, qpos: Any, qvel: Any, qacc_warmstart: Any = None) -> Array:
        """Exact: float64 numpy inputs keep all their bits; float32/traced inputs are widened."""
        parts = [qpos, qvel, np.zeros(np.shape(qvel)) if qacc_warmstart is None else qacc_warmstart]
        if all(isinstance(p, np.ndarray | float | int) for p in parts):
            vector = np.concatenate([np.asarray(p, np.float64) for p in parts], axis=-1)
            return jnp.asarray(float64_to_bits(vector))
        vector = jnp.concatenate([jnp.asarray(p, jnp.float32) for p in parts], axis=-1)
        bits = float32_to_float64_bits(vector)
        return bits.reshape(*bits.shape[:-2], 2 * bits.shape[-2])

    def to_numpy(self, state: Array) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        values = bits_to_float64(np.asarray(state))
        nq, nv = self.nq, self.nv
        return values[..., :nq], values[..., nq : nq + nv], values[..., nq + nv :]

    def qpos_qvel(self, state: Array) -> tuple[Array, Array]:
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
        outputs = self._call_step(state, jnp.asarray(ctrl, jnp.float32), active)
        return outputs[0], self._measurement(outputs[1:])

    def forward(self, state: Array) -> Measurement:
        return self._measurement(self._call_forward(state))

    def _call_step(self, state: Array, ctrl: Array, active: Array | None = None) -> Any:
        """The results of ``_result_shapes(True)`` for a (batch of) state and control; envs where
        ``active`` is False may be skipped (see ``Physics.step``)."""
        raise NotImplementedError

    def _call_forward(self, state: Array) -> Any:
        """The results of ``_result_shapes(False)`` for a (batch of) state."""
        raise NotImplementedError


# ---- MuJoCo C through jax.pure_callback ---------------------------------------------------------
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
        from mujoco import batch as mujoco_batch

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

    def load(self, qpos: np.ndarray, qvel: np.ndarray, warmstart: np.ndarray) -> None:
        self.qpos[:], self.qvel[:], self.warmstart[:] = qpos, qvel, warmstart
        self.time[:] = 0.0
        self.warnings[...] = 0

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

    def __init__(
        self,
        model: mujoco.MjModel,
        frame_skip: int,
        extras: tuple[str, ...] = (),
        nthread: int | None = None,
    ):
        super().__init__(model, frame_skip, extras, nthread)
        self._workspaces = _HostWorkspaces(model, self.nthread, self.extras)

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

    def _host_outputs(self, work: _Workspace, qpos_before: np.ndarray, batch_shape: tuple) -> list:
        qpos, qvel = work.qpos, work.qvel
        magnitude = np.maximum(np.abs(qpos).max(axis=1), np.abs(qvel).max(axis=1))
        diverged = work.unstable() | ~(magnitude <= DIVERGENCE_LIMIT)  # NaN compares False
        outputs = [
            qpos.astype(np.float32),
            qvel.astype(np.float32),
            (qpos - qpos_before).astype(np.float32),
            diverged,
            *(self._host_extra(name, work).astype(np.float32) for name in self.extras),
        ]
        return [o.reshape(batch_shape + o.shape[1:]) for o in outputs]

    @staticmethod
    def _host_extra(name: str, work: _Workspace) -> np.ndarray:
        if name in COMPUTED_EXTRAS:
            return extra_field(name, work, np)
        return work.outputs[name]

    def _host_step(self, state: np.ndarray, ctrl: np.ndarray) -> tuple:
        batch_shape = ctrl.shape[:-1]
        qpos, qvel, warmstart = self._split(state)
        work = self._workspaces.get("step", qpos.shape[0])
        with work.lock:
            work.load(qpos, qvel, warmstart)
            work.ctrl[:] = ctrl.reshape(-1, self.nu)
            work.batch.step(nstep=self.frame_skip)
            new_values = np.concatenate([work.qpos, work.qvel, work.warmstart], axis=1)
            new_state = float64_to_bits(new_values).reshape(batch_shape + (2 * self.state_size,))
            return (new_state, *self._host_outputs(work, qpos, batch_shape))

    def _host_forward(self, state: np.ndarray) -> tuple:
        batch_shape = state.shape[:-1]
        qpos, qvel, warmstart = self._split(state)
        work = self._workspaces.get("forward", qpos.shape[0])
        with work.lock:
            work.load(qpos, qvel, warmstart)
            work.batch.forward()
            return tuple(self._host_outputs(work, qpos, batch_shape))


def make_physics(
    backend: str,
    model: mujoco.MjModel,
    frame_skip: int,
    extras: tuple[str, ...] = (),
    nthread: int | None = None,
    mjx_chunk: int | None = None,
) -> Physics:
    backend = resolve_backend(backend)
    if backend == "mjx":
        return MjxPhysics(model, frame_skip, extras, mjx_chunk)
    if backend == "mujoco_ffi":
        from envs.mujoco.mujoco_ffi import MujocoFfiPhysics

        return MujocoFfiPhysics(model, frame_skip, extras, nthread)
    return MujocoCallbackPhysics(model, frame_skip, extras, nthread)
