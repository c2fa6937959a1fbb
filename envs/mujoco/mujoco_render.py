"""Frames of a MuJoCo model's state through MuJoCo's own renderer, as gymnasium draws them.

The camera is gymnasium's free-camera settings of the env (``lookat``, ``distance``,
``elevation``, ``trackbodyid``, ...) or the name of a camera of the model. One
``mujoco.Renderer`` is kept per size and reused for every frame; ``envs.mujoco.opengl`` picks
the OpenGL backend (headless: EGL, else OSMesa) when the first one is made.
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np

from rl_jax.envs.mujoco import opengl


class SceneRenderer:
    """RGB frames ``[height, width, 3]`` uint8 of ``model`` at given ``(qpos, qvel)``."""

    def __init__(self, model: mujoco.MjModel, camera: dict[str, Any] | str):
        self.model = model
        self.camera = camera
        self._renderer: mujoco.Renderer | None = None

    def render(self, qpos: np.ndarray, qvel: np.ndarray, width: int, height: int) -> np.ndarray:
        """RGB frame ``[height, width, 3]`` uint8 of the model at ``(qpos, qvel)``, after
        ``mj_forward``.
        """
        data = mujoco.MjData(self.model)
        data.qpos[:], data.qvel[:] = qpos, qvel
        mujoco.mj_forward(self.model, data)
        renderer = self._renderer
        if renderer is None or (renderer.width, renderer.height) != (width, height):
            opengl.prepare_rendering()
            self._renderer = renderer = mujoco.Renderer(self.model, height=height, width=width)
        renderer.update_scene(data, self._scene_camera())
        return renderer.render()

    def _scene_camera(self) -> mujoco.MjvCamera | str:
        if isinstance(self.camera, str):
            return self.camera
        camera = mujoco.MjvCamera()
        mujoco.mjv_defaultFreeCamera(self.model, camera)
        for name, value in self.camera.items():
            if name == "lookat":
                camera.lookat[:] = value
            else:
                setattr(camera, name, value)
        if "trackbodyid" in self.camera:
            camera.type = mujoco.mjtCamera.mjCAMERA_TRACKING
        return camera
