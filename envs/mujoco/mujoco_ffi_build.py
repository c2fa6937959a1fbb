"""Build and load the library of the MuJoCo FFI custom calls (``envs/mujoco/mujoco_ffi.cc``).

The library is compiled on first use with the system C++ compiler (``$CXX``, else ``g++``)
against jaxlib's XLA FFI headers (``jax.ffi.include_dir()``) and the mujoco wheel's headers and
``libmujoco.so``. It is kept in ``~/.cache/rl_jax/mujoco_ffi/`` (``$XDG_CACHE_HOME`` respected)
under a name that hashes the source, the compiler and its flags, and the mujoco, jax and jaxlib
versions, so any change to them builds it anew and nothing built is ever committed.
``make install`` builds it ahead of first use (``python -m rl_jax.envs.mujoco.mujoco_ffi_build``).

At load, the MuJoCo header version the library was compiled against must equal ``mj_version()``
of the MuJoCo library it runs with, and that of the Python bindings. Then the two handlers are
registered with XLA as ``STEP_TARGET``, ``STEP_ACTIVE_TARGET`` and ``FORWARD_TARGET``.

``load()`` returns the library or raises ``FfiUnavailable`` with a one-line reason (no compiler,
a failed build, a version mismatch); ``available()`` is the same as a bool that prints the reason
once per process, for callers that fall back to the ``pure_callback`` path.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import sys
import threading
from pathlib import Path
from typing import TypedDict

import jax
import jaxlib
import mujoco

SOURCE = Path(__file__).with_name("mujoco_ffi.cc")
STEP_TARGET = "rl_jax_mujoco_step"
STEP_ACTIVE_TARGET = "rl_jax_mujoco_step_active"
FORWARD_TARGET = "rl_jax_mujoco_forward"
FLAGS = ("-O2", "-std=c++17", "-shared", "-fPIC")
BUILD_TIMEOUT_SECONDS = 600


class FfiUnavailable(RuntimeError):
    """The FFI library cannot be built or loaded here; the message is one line."""


def cache_dir() -> Path:
    """Where the compiled MuJoCo FFI library is cached: ``$XDG_CACHE_HOME/rl_jax/mujoco_ffi``."""
    base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    return base / "rl_jax" / "mujoco_ffi"


def _mujoco_paths() -> tuple[Path, Path]:
    """(include dir, shared library) of the installed mujoco wheel."""
    package = Path(mujoco.__file__).resolve().parent
    libraries = sorted(package.glob("libmujoco.so*"))
    if not libraries or not (package / "include" / "mujoco" / "mjbatch.h").exists():
        raise FfiUnavailable(f"the mujoco package in {package} has no headers or libmujoco.so")
    return package / "include", libraries[-1]


def _compiler() -> str:
    name = os.environ.get("CXX", "g++")
    path = shutil.which(name)
    if path is None:
        raise FfiUnavailable(f"no C++ compiler found (looked for {name!r})")
    return path


def compile_command(output: Path) -> list[str]:
    """The compiler command line that builds the FFI step into ``output``, against the installed
    mujoco and jax headers.
    """
    mujoco_include, mujoco_library = _mujoco_paths()
    return [
        _compiler(),
        *FLAGS,
        "-isystem",
        jax.ffi.include_dir(),
        "-isystem",
        str(mujoco_include),
        str(SOURCE),
        "-o",
        str(output),
        f"-L{mujoco_library.parent}",
        f"-l:{mujoco_library.name}",
        f"-Wl,-rpath,{mujoco_library.parent}",
    ]


def library_path() -> Path:
    """Where the library for this source, compiler and these versions lives (built or not)."""
    compiler = _compiler()
    version = subprocess.run(
        [compiler, "--version"], capture_output=True, text=True, check=False
    ).stdout.splitlines()[:1]
    identity = [*compile_command(Path("out")), *version, mujoco.__version__, jax.__version__]
    identity += [jaxlib.__version__, sys.platform]
    digest = hashlib.sha256(SOURCE.read_bytes())
    digest.update("\n".join(identity).encode())
    return cache_dir() / f"mujoco_ffi-{digest.hexdigest()[:16]}.so"


def build() -> Path:
    """The library, compiled now unless already built for this source and these versions."""
    path = library_path()
    if path.exists():
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_suffix(f".{os.getpid()}.tmp")  # renamed into place: builds may race
    # One line, so that the first use's pause (g++ compiling the op) is not a silent hang.
    print(f"rl_jax: building the MuJoCo FFI op (once) into {path.parent} ...", file=sys.stderr)
    try:
        result = subprocess.run(
            compile_command(partial),
            capture_output=True,
            text=True,
            timeout=BUILD_TIMEOUT_SECONDS,
            check=False,
        )
    except subprocess.TimeoutExpired as error:
        raise FfiUnavailable(f"compiling {SOURCE.name} timed out") from error
    if result.returncode != 0:
        partial.unlink(missing_ok=True)
        errors = [line for line in result.stderr.splitlines() if "error" in line]
        detail = (errors or result.stderr.splitlines() or ["no output"])[0]
        raise FfiUnavailable(f"compiling {SOURCE.name} failed: {detail}")
    os.replace(partial, path)
    return path


def _check_versions(library: ctypes.CDLL) -> None:
    header = library.rl_jax_mujoco_header_version()
    linked = library.rl_jax_mujoco_library_version()
    if not header == linked == mujoco.mj_version():
        raise FfiUnavailable(
            f"MuJoCo version mismatch: headers {header}, library {linked}, "
            f"Python bindings {mujoco.mj_version()}"
        )


def _declare(library: ctypes.CDLL) -> None:
    library.rl_jax_mujoco_register.restype = ctypes.c_int
    library.rl_jax_mujoco_register.argtypes = [
        ctypes.c_uint64,  # key
        ctypes.c_void_p,  # MJB buffer
        ctypes.c_int64,  # its size
        ctypes.c_int,  # frame skip
        ctypes.c_int,  # threads
        ctypes.c_char_p,  # extras, comma-separated
        ctypes.c_char_p,  # error message buffer
        ctypes.c_int,  # its size
    ]


_lock = threading.Lock()


class _LoadState(TypedDict, total=False):
    """What ``load`` found: the library or the error, then whether the fallback was told."""

    library: ctypes.CDLL
    error: FfiUnavailable
    notified: bool


_state: _LoadState = {}


def load() -> ctypes.CDLL:
    """The loaded library with its XLA targets registered (built first if needed)."""
    with _lock:
        if "library" in _state:
            return _state["library"]
        if "error" in _state:
            raise _state["error"]
        if jax.default_backend() != "cpu":  # the handlers are registered for the CPU platform
            _state["error"] = FfiUnavailable(
                f"the op is a CPU custom call and JAX's default device here is "
                f"{jax.default_backend()}; JAX_PLATFORMS=cpu runs it on the CPU"
            )
            raise _state["error"]
        try:
            library = ctypes.CDLL(str(build()))
            _check_versions(library)
            _declare(library)
            _register_targets(library)
        except FfiUnavailable as error:
            _state["error"] = error
            raise
        except OSError as error:  # dlopen: a missing symbol or library
            _state["error"] = FfiUnavailable(f"loading the MuJoCo FFI library failed: {error}")
            raise _state["error"] from error
        _state["library"] = library
        return library


def _register_targets(library: ctypes.CDLL) -> None:
    targets = (
        (STEP_TARGET, "RlJaxMujocoStep"),
        (STEP_ACTIVE_TARGET, "RlJaxMujocoStepActive"),
        (FORWARD_TARGET, "RlJaxMujocoForward"),
    )
    for name, symbol in targets:
        handler = getattr(library, symbol)
        jax.ffi.register_ffi_target(name, jax.ffi.pycapsule(handler), platform="cpu")


def available() -> bool:
    """Whether ``load()`` succeeds; if not, print why (once per process) on stderr."""
    try:
        load()
        return True
    except FfiUnavailable as error:
        if not _state.get("notified"):
            _state["notified"] = True
            print(
                f"rl_jax: MuJoCo C through jax.pure_callback, not the FFI op ({error}); "
                "programs with MuJoCo envs will not be stored in the compilation cache",
                file=sys.stderr,
            )
        return False


def main() -> int:
    """``python -m rl_jax.envs.mujoco.mujoco_ffi_build``: build now (as ``make install`` does)."""
    try:
        load()
    except FfiUnavailable as error:
        print(f"rl_jax: MuJoCo FFI op not built ({error}); the pure_callback path will be used")
        return 0  # not an error for make install: the callback path works everywhere
    print(f"MuJoCo FFI op: {library_path()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
