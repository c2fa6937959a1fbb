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
    compiles far faster than MJX, and steps the contact-rich half cheetah several times faster,
    where MJX pays for every potential contact; on the two pendulums MJX is about as fast
    (bench/bench_mujoco.py compares them). The jitted program reaches MuJoCo C in one of two
    ways, with bit-identical results:

    ``mujoco_ffi``
        an XLA FFI custom call (``envs.mujoco.mujoco_ffi``), compiled on first use with the system
        C++ compiler: no Python runs in a step, and the program can be stored in JAX's persistent
        compilation cache. What ``mujoco`` means when the op builds and JAX's default device is a
        CPU (its handlers exist for the CPU platform only; on a GPU ``mujoco`` is the callback).
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
import io
import os
import re
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any, NamedTuple

import gymnasium.envs.mujoco as gym_mujoco
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from jax.typing import ArrayLike

from rl_jax.envs.core.registry import BackendError
from rl_jax.envs.mujoco import mujoco_ffi_build

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
        return "mujoco_ffi" if mujoco_ffi_build.available() else "mujoco_callback"
    return name


def engine(backend: str) -> str:
    """The physics engine of a backend name: "mujoco" (C) or "mjx"."""
    return "mjx" if _backend_name(backend) == "mjx" else "mujoco"


def gymnasium_asset(xml_file: str) -> Path:
    """Path of an MJCF file shipped with the installed gymnasium package."""
    path = Path(gym_mujoco.__file__).resolve().parent / "assets" / xml_file
    if not path.exists():
        raise FileNotFoundError(f"gymnasium ships no MuJoCo asset {xml_file!r} (looked in {path})")
    return path


def load_model(
    xml_file: str, iterations: int | None = None, ls_iterations: int | None = None
) -> mujoco.MjModel:
    """gymnasium's model, with other constraint-solver iteration limits where given (None: the
    model's own, which is what gymnasium runs: MuJoCo's 100/50 unless the XML sets them, as
    Humanoid's 50 iterations of PGS).

    The model is the one ``mujoco.MjModel.from_xml_path`` compiles from gymnasium's XML, bit for
    bit in every field, but compiled without the deprecated ``<compiler settotalmass>`` that
    half_cheetah.xml uses (MuJoCo warns about it on stdout and in ``MUJOCO_LOG.TXT`` in the
    current directory at every compile): ``set_total_mass`` scales the compiled masses the way
    the compiler does."""
    spec = mujoco.MjSpec.from_file(str(gymnasium_asset(xml_file)))
    total_mass = spec.compiler.settotalmass
    if total_mass > 0:
        spec.compiler.settotalmass = -1.0  # MuJoCo's default: masses as the geoms make them
    model = spec.compile()
    if total_mass > 0:
        set_total_mass(model, total_mass)
    if iterations is not None:
        model.opt.iterations = iterations
    if ls_iterations is not None:
        model.opt.ls_iterations = ls_iterations
    return model


def set_total_mass(model: mujoco.MjModel, total_mass: float) -> None:
    """Scale a compiled model's masses and inertias to ``total_mass``, and what depends on them,
    exactly as MuJoCo's compiler does for ``<compiler settotalmass>``: ``mj_setTotalmass``, then
    ``mj_setConst`` (the constants computed from the masses: subtree masses, inverse weights),
    then the statistics the compiler computes once ``mj_setConst`` has run and that no function
    updates later: the mean body mass and the mean diagonal of the mass matrix at ``qpos0``
    (which scales the constraint solver's tolerance). The sums run in MuJoCo's order, so the
    model equals the compiler's bit for bit (tests/envs/test_mujoco_model.py)."""
    mujoco.mj_setTotalmass(model, total_mass)
    data = mujoco.MjData(model)
    mujoco.mj_setConst(model, data)
    if model.nbody > 1:
        mean_mass = 0.0
        for mass in model.body_mass[1:]:
            mean_mass += float(mass)
        model.stat.meanmass = mean_mass / (model.nbody - 1)
    if model.nv:
        mujoco.mj_resetData(model, data)  # qpos0
        mujoco.mj_forward(model, data)
        mass_matrix = np.zeros((model.nv, model.nv))
        mujoco.mj_fullM(model, data, mass_matrix)
        mean_inertia = 0.0
        for dof in range(model.nv):
            mean_inertia += float(mass_matrix[dof, dof])
        model.stat.meaninertia = mean_inertia / model.nv


#: The lines ``mujoco/mjx/warp/__init__.py`` prints with ``print()`` when it is imported and NVIDIA
#: Warp is not installed, one for ``warp`` and one for ``mujoco_warp``. Importing ``mujoco.mjx``
#: (or brax, which imports it) imports that package, and MuJoCo has no setting (environment
#: variable or logger) that silences them. MJX's JAX implementation, the one these envs use,
#: needs no Warp.
WARP_ABSENT = re.compile(r"Failed to import (mujoco_)?warp: No module named 'warp(\..+)?'")


@contextlib.contextmanager
def without_warp_lines() -> Iterator[None]:
    """Import ``mujoco.mjx`` (or brax) inside this block: the lines MJX prints on import where
    Warp is not installed (``WARP_ABSENT``) are dropped; anything else printed meanwhile (a Warp
    that is installed and fails says why) passes on to stdout."""
    if "mujoco.mjx.warp" in sys.modules:  # imported before: importing it again prints nothing
        yield
        return
    printed = io.StringIO()
    try:
        with contextlib.redirect_stdout(printed):
            yield
    finally:
        kept = [line for line in printed.getvalue().splitlines() if not WARP_ABSENT.fullmatch(line)]
        if kept:
            print("\n".join(kept), flush=True)


# Extras computed from qpos rather than read from mjData. The C backend evaluates them in float64
# before rounding: sin/cos of a float32-rounded angle of a pendulum that has spun many turns would
# lose digits (|angle| = 100 rad has a float32 spacing of 8e-6).
COMPUTED_EXTRAS = {"sin_qpos": "sin", "cos_qpos": "cos"}
# Fields mj_step leaves stale (MuJoCo computes them only for sensors that need them). gymnasium
# calls mj_rnePostConstraint after every step to get them (Ant's and Humanoid's contact forces
# cfrc_ext), and never after a reset, where mj_resetData zeroed them: the backends do the same,
# and report them as zero after a forward pass.
POST_CONSTRAINT_EXTRAS = ("cacc", "cfrc_int", "cfrc_ext")


def extra_field(name: str, data: Any, numpy_like: Any) -> Any:
    """An extra of ``data`` (mjData, mjx.Data, or a batch's bound arrays), by name."""
    if name in COMPUTED_EXTRAS:
        return getattr(numpy_like, COMPUTED_EXTRAS[name])(data.qpos)
    # mjx.Data keeps the fields only its JAX implementation computes (cfrc_ext, cinert, cacc,
    # cfrc_int) in ``_impl``; reading them from Data itself is deprecated (a warning per access)
    impl = getattr(data, "_impl", None)
    if impl is not None and name not in getattr(type(data), "__dataclass_fields__", {}):
        return getattr(impl, name)
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


# ---- small dense Cholesky, unrolled ----------------------------------------------------------
SMALL_CHOLESKY_MAX = 16


def _unrolled_cholesky_lower(a: Array) -> list[list[Array]]:
    """Lower Cholesky factor of one small SPD matrix as nested lists of scalars (zero above the
    diagonal)."""
    n = a.shape[-1]
    zero = jnp.zeros_like(a[..., 0, 0])
    lower = [[zero] * n for _ in range(n)]
    for j in range(n):
        diagonal = a[..., j, j] - sum(
            (lower[j][k] ** 2 for k in range(j)), jnp.zeros_like(a[..., 0, 0])
        )
        lower[j][j] = jnp.sqrt(diagonal)
        for i in range(j + 1, n):
            dot = sum((lower[i][k] * lower[j][k] for k in range(j)), jnp.zeros_like(a[..., 0, 0]))
            lower[i][j] = (a[..., i, j] - dot) / lower[j][j]
    return lower


def _small_cho_factor(
    a: Array, lower: bool = False, overwrite_a: bool = False, check_finite: bool = True
) -> tuple[Array, bool]:
    """``jax.scipy.linalg.cho_factor`` for small matrices: the same factor, unrolled.

    XLA:CPU runs a batched ``cho_factor`` as one LAPACK call per matrix, whose per-call overhead
    dominates for MJX's 3x3..9x9 mass and Newton matrices; unrolled scalar code is vectorised across
    the whole batch of envs instead. The other triangle is zero, which scipy leaves unspecified.
    """
    del overwrite_a, check_finite
    n = a.shape[-1]
    rows = _unrolled_cholesky_lower(a)
    zero = jnp.zeros_like(a[..., 0, 0])
    factor = jnp.stack(
        [jnp.stack([rows[i][j] if j <= i else zero for j in range(n)], -1) for i in range(n)], -2
    )
    return (factor if lower else jnp.swapaxes(factor, -1, -2)), lower


def _small_cho_solve(
    c_and_lower: tuple[Array, bool],
    b: Array,
    overwrite_b: bool = False,
    check_finite: bool = True,
) -> Array:
    """``jax.scipy.linalg.cho_solve`` for factors of ``_small_cho_factor`` (vector or matrix b)."""
    del overwrite_b, check_finite
    c, lower = c_and_lower
    factor = c if lower else jnp.swapaxes(c, -1, -2)  # L with A = L L^T
    n = factor.shape[-1]
    y: dict[int, Array] = {}
    for i in range(n):  # L y = b
        y[i] = (b[i] - sum((factor[i, k] * y[k] for k in range(i)), jnp.zeros_like(b[i]))) / factor[
            i, i
        ]
    x: dict[int, Array] = {}
    for i in reversed(range(n)):  # L^T x = y
        tail = sum((factor[k, i] * x[k] for k in range(i + 1, n)), jnp.zeros_like(b[i]))
        x[i] = (y[i] - tail) / factor[i, i]
    return jnp.stack([x[i] for i in range(n)])


@contextlib.contextmanager
def small_cholesky() -> Any:
    """While MJX is traced, route small ``cho_factor``/``cho_solve`` calls to unrolled code.

    Larger matrices, and solves this does not handle, go to the originals. Only tracing happens
    inside the block, so the patch is in effect for exactly the MJX code we trace; it computes the
    same factorisation, so any other code traced at the same moment would stay correct too.
    """
    linalg = jax.scipy.linalg
    original_factor, original_solve = linalg.cho_factor, linalg.cho_solve

    def cho_factor(a: ArrayLike, *args: bool, **kwargs: bool) -> tuple[Array, bool]:
        if jnp.ndim(a) == 2 and jnp.shape(a)[-1] <= SMALL_CHOLESKY_MAX:
            return _small_cho_factor(jnp.asarray(a), *args, **kwargs)
        return original_factor(a, *args, **kwargs)

    def cho_solve(
        c_and_lower: tuple[ArrayLike, bool], b: ArrayLike, *args: bool, **kwargs: bool
    ) -> Array:
        c, lower = c_and_lower
        if jnp.ndim(c) == 2 and jnp.shape(c)[-1] <= SMALL_CHOLESKY_MAX and jnp.ndim(b) in (1, 2):
            small = (jnp.asarray(c), lower)
            return _small_cho_solve(small, jnp.asarray(b), *args, **kwargs)
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
        """Zeros shaped like the requested derived fields, with optional leading batch axes."""
        return {
            name: jnp.zeros(batch_shape + shape, jnp.float32)
            for name, shape in self._extra_shapes.items()
        }
