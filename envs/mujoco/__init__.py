"""MuJoCo envs (gymnasium's v5 inverted pendulum, inverted double pendulum, half cheetah, hopper,
walker, swimmer, reacher, ant, humanoid; one file each) and the physics backends that step them
(MJX, the MuJoCo C FFI op and its build, a host callback)."""
