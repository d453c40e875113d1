"""Pictures of Baxter, rendered headless with MuJoCo's OpenGL renderer.

MuJoCo picks its GL backend when first imported: ``drrl.envs.baxter.model.import_mujoco`` makes that EGL if
libEGL is found (Mesa's llvmpipe draws on CPU-only machines), else OSMesa if libOSMesa is, unless ``MUJOCO_GL``
says otherwise. With neither, the physics runs and rendering raises an error that says what to install.
Shadows and reflections are off by default: on a CPU-only machine they cost about five times the frame time.
Writing frames as videos is ``drrl.video``'s job.
"""

from __future__ import annotations

import os

import numpy as np

from drrl.envs.baxter.model import import_mujoco

# From the front, slightly to the robot's right: the torso, both arms, the targets and the table.
VIEW = {"lookat": (0.4, 0.0, 0.05), "distance": 2.2, "azimuth": 195.0, "elevation": -20.0}
# Close to the right arm's blocks (the stacking tasks).
STACK_VIEW = {"lookat": (0.67, -0.42, -0.13), "distance": 0.75, "azimuth": 215.0, "elevation": -22.0}


class SceneRenderer:
    """RGB frames (height, width, 3) of one model's simulations, from ``view`` (``VIEW`` unless given)."""

    def __init__(
        self, model, width: int = 320, height: int = 240, shadows: bool = False, view: dict | None = None
    ) -> None:
        mujoco = import_mujoco()
        try:
            self._renderer = mujoco.Renderer(model, height, width)
        except Exception as error:  # no display for GLFW, no EGL device, no OSMesa library, ...
            raise RuntimeError(
                f"headless rendering failed with MUJOCO_GL={os.environ.get('MUJOCO_GL', '(unset)')}: {error}. "
                "Set MUJOCO_GL=egl (Debian: libegl1 libegl-mesa0) or MUJOCO_GL=osmesa (libosmesa6) before drrl "
                "imports MuJoCo"
            ) from error
        flags = self._renderer.scene.flags
        flags[mujoco.mjtRndFlag.mjRND_SHADOW] = shadows
        flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = shadows
        view = VIEW if view is None else view
        self._camera = mujoco.MjvCamera()
        self._camera.lookat[:] = view["lookat"]
        self._camera.distance, self._camera.azimuth, self._camera.elevation = (
            view["distance"],
            view["azimuth"],
            view["elevation"],
        )

    def render(self, data) -> np.ndarray:
        """The scene of ``data`` (a ``mujoco.MjData``) as uint8 RGB."""
        self._renderer.update_scene(data, self._camera)
        return self._renderer.render()

    def close(self) -> None:
        self._renderer.close()
