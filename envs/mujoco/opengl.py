"""OpenGL for MuJoCo rendering, chosen only when a frame is drawn; never needed to import or step.

MuJoCo's Python package picks its OpenGL backend from ``MUJOCO_GL`` when ``mujoco`` is first
imported, and with ``MUJOCO_GL=egl`` (or ``osmesa``) on a machine whose libEGL (libOSMesa) is
missing or broken, that import itself fails (PyOpenGL raises ``AttributeError`` from inside
``import mujoco``). GPU servers and slim containers often have no libEGL, and nothing but
rendering needs OpenGL. So:

* ``guard_import()`` runs before our first ``import mujoco`` (in ``envs.mujoco``'s
  ``__init__``): a ``MUJOCO_GL`` (and matching ``PYOPENGL_PLATFORM``) naming a library that
  cannot be loaded here is set aside, so that the import, training, evaluation and policy loading
  work; the request is remembered and reported if something later renders.
* ``prepare_rendering()`` runs before a ``mujoco.Renderer`` is made: it picks the backend (an
  explicit, loadable ``MUJOCO_GL``; a display's default; else headless EGL, else OSMesa) and
  installs its ``GLContext`` into MuJoCo, or raises ``OpenGLUnavailableError`` whose one-line
  message says what to install.

Loadability is probed with ``ctypes`` (dlopen plus the one entry point MuJoCo's context needs),
which imports no OpenGL binding: a failed probe leaves PyOpenGL free to pick another platform.
"""

from __future__ import annotations

import ctypes
import os

# backend -> (shared libraries to try, symbol MuJoCo's context calls first)
_LIBRARIES: dict[str, tuple[tuple[str, ...], str]] = {
    "egl": (("libEGL.so.1", "libEGL.so"), "eglQueryString"),
    "osmesa": (("libOSMesa.so.8", "libOSMesa.so.6", "libOSMesa.so"), "OSMesaCreateContextExt"),
}
HEADLESS_ORDER = ("egl", "osmesa")
INSTALL_HINT = (
    "install EGL (apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri) or OSMesa "
    "(apt-get install libosmesa6); training, evaluation and loading policies need neither"
)

#: the MUJOCO_GL value guard_import set aside because its library cannot be loaded, if any
set_aside: str | None = None


class OpenGLUnavailableError(RuntimeError):
    """Rendering was asked for on a machine with no usable OpenGL backend (one-line message)."""


def loadable(backend: str) -> bool:
    """Whether ``backend``'s library ("egl" or "osmesa") loads here and has its entry point."""
    names, symbol = _LIBRARIES[backend]
    for name in names:
        try:
            library = ctypes.CDLL(name)
        except OSError:
            continue
        if hasattr(library, symbol):
            return True
    return False


def _requested() -> str:
    return os.environ.get("MUJOCO_GL", "").strip().lower()


def guard_import() -> None:
    """Before ``import mujoco``: set aside a ``MUJOCO_GL`` whose library cannot be loaded."""
    global set_aside
    requested = _requested()
    if requested in _LIBRARIES and not loadable(requested):
        set_aside = requested
        del os.environ["MUJOCO_GL"]
        if os.environ.get("PYOPENGL_PLATFORM", "").strip().lower() == requested:
            del os.environ["PYOPENGL_PLATFORM"]


def choose_backend() -> str:
    """The OpenGL backend rendering will use: "egl", "osmesa", or the display's ("default")."""
    if set_aside is not None:
        raise OpenGLUnavailableError(
            f"no OpenGL backend for headless rendering (MUJOCO_GL={set_aside}, whose library "
            f"cannot be loaded here): {INSTALL_HINT}"
        )
    requested = _requested()
    if requested in _LIBRARIES:
        return requested
    if requested or os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        return "default"  # an explicit choice MuJoCo knows (glfw, glx), or a display: its own
    platform = os.environ.get("PYOPENGL_PLATFORM", "").strip().lower()
    order = (platform,) if platform in _LIBRARIES else HEADLESS_ORDER
    for backend in order:
        if loadable(backend):
            return backend
    raise OpenGLUnavailableError(
        f"no OpenGL backend for headless rendering (no display, no EGL or OSMesa library): "
        f"{INSTALL_HINT}"
    )


def prepare_rendering() -> str:
    """Install the chosen backend's ``GLContext`` into MuJoCo before a ``Renderer`` is made.

    MuJoCo bound its context class when it was imported (GLFW when ``MUJOCO_GL`` was unset);
    a headless machine needs EGL's or OSMesa's instead. Returns the backend's name.
    """
    backend = choose_backend()
    if backend == "default":
        return backend
    # Imported only to render: these modules load OpenGL libraries (and only one backend's can)
    from mujoco.rendering.classic import gl_context

    context = getattr(gl_context, "GLContext", None)
    if context is None or not context.__module__.startswith(f"mujoco.{backend}"):
        if backend == "egl":
            from mujoco.egl import GLContext
        else:
            from mujoco.osmesa import GLContext
        gl_context.GLContext = GLContext
    return backend
