"""MuJoCo envs (half cheetah, inverted pendulum, inverted double pendulum) and the physics
backends that step them (MJX, the MuJoCo C FFI op and its build, a host callback)."""
