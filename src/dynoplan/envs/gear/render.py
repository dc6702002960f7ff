"""Offscreen rendering of the gear scene (``MUJOCO_GL=egl`` or ``osmesa`` for headless use).

Shadows and reflections are switched off: with software rendering they cost about ten
times more than the rest of the frame.
"""

import mujoco
import numpy as np
import numpy.typing as npt


class SceneRenderer:
    """Renders RGB frames of a model from a named camera.

    Args:
        model: the compiled scene.
        width, height: frame size in pixels (at most the model's offscreen buffer,
            1280 x 960).
        camera: name of a camera of the model (``"overview"`` or ``"closeup"``).
    """

    def __init__(self, model: mujoco.MjModel, width: int = 640, height: int = 480,
                 camera: str = "overview") -> None:
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera) < 0:
            raise ValueError(f"unknown camera {camera!r}")
        self.camera = camera
        self._renderer = mujoco.Renderer(model, height=height, width=width)
        flags = self._renderer.scene.flags
        flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
        flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False

    def render(self, data: mujoco.MjData) -> npt.NDArray[np.uint8]:
        """(height, width, 3) uint8 RGB image of ``data``."""
        self._renderer.update_scene(data, camera=self.camera)
        frame: npt.NDArray[np.uint8] = self._renderer.render()
        return frame

    def close(self) -> None:
        self._renderer.close()
