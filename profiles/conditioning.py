"""FAP-SCENE-004: a scene whose FDP calibration would rest on an ill-conditioned linear system.

The reference calibrates the default head to a scene's feature points (and maps texture
coordinates) with the RBF interpolation of :mod:`fbaconf.animation.rbf`, which refuses a system
whose condition number exceeds its documented bound rather than let the result depend on the
platform's LAPACK. The checker compiles such a scene the way the reference does and reports the
refusal at the FDP field it comes from. Scenes that do not calibrate (no feature points, or a
downloaded model) are not compiled.
"""

from __future__ import annotations

from fbaconf import rules as R
from fbaconf.animation import engine
from fbaconf.errors import SceneError

from .diagnostics import Diagnostic, diag


def calibrates(scene) -> bool:
    """Whether a Face's FDP sends feature points without a faceSceneGraph (the default head is warped)."""
    for node, _ in scene.walk():
        if (
            getattr(node, "type", None) == "FDP"
            and scene.resolve(node.get("featurePointsCoord")) is not None
            and not node.get("faceSceneGraph")
        ):
            return True
    return False


def conditioning_diagnostics(scene) -> list[Diagnostic]:
    """[FAP-SCENE-004] when the reference refuses the scene's calibration systems, else []. Other
    compile errors are left to the checks that own them."""
    if not hasattr(scene, "walk") or not calibrates(scene):
        return []
    try:
        engine.compile_scene(scene)
    except SceneError as e:
        if e.rule == "calibration-degenerate":
            return [diag(R.SCENE_ILL_CONDITIONED, f"scene: {e.message}", node_path=e.node_path)]
    except Exception:  # noqa: BLE001, S110 - any other failure of the scene is reported by the checks that own it
        pass
    return []
