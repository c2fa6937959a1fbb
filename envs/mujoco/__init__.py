"""MuJoCo envs (gymnasium's v5 inverted pendulum, inverted double pendulum, half cheetah, hopper,
walker, swimmer, reacher, ant, humanoid; one file each) and the physics backends that step them
(MJX, the MuJoCo C FFI op and its build, a host callback)."""

from rl_jax.envs.mujoco import opengl

# Before any module of this package imports mujoco: a MUJOCO_GL naming a library this machine
# cannot load would make `import mujoco` itself fail, and only rendering needs OpenGL
# (envs.mujoco.opengl). No OpenGL is chosen here.
opengl.guard_import()
