"""What the checker reads of the optional scene: the tools it uses and its measured sizes (for the
profile and level checks), and the scene's own diagnostics."""

from __future__ import annotations

import importlib
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fbaconf import rules as R
from fbaconf.animation.facedef import validate_borders
from fbaconf.animation.faceparams import NUM_FEATURE_POINTS, fdp_point_rows
from fbaconf.errors import SceneError

from .diagnostics import Diagnostic, diag


# ---------------------------------------------------------------------------- scene summary
@dataclass
class SceneSummary:
    """What the profile/level checks need from a scene: tools used and measured sizes.

    ``tools``: tool id -> node path of its first use. ``measures``: limit id -> (value,
    node path of the worst case). ``faces``: Face nodes in the scene."""

    faces: int = 0
    tools: dict[str, str] = field(default_factory=dict)
    measures: dict[str, tuple[float, str]] = field(default_factory=dict)

    def measure(self, key: str, value: float, path: str) -> None:
        cur = self.measures.get(key)
        if cur is None or value > cur[0]:
            self.measures[key] = (float(value), path)


def image_size(path: Path) -> tuple[int, int] | None:
    """(width, height) of an image file: the PNG header directly, other formats through
    OpenImageIO when installed; None when unknown."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(24)
    except OSError:
        return None
    if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
        return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
    try:
        import OpenImageIO as oiio  # noqa: PLC0415 (image I/O loads on first use)

        inp = oiio.ImageInput.open(str(path))
        if not inp:
            return None
        spec = inp.spec()
        inp.close()
        return int(spec.width), int(spec.height)
    except Exception:  # noqa: BLE001 - an image the reader cannot open: no size to check
        return None


class SceneStructureError(ValueError):
    """A scene the reader accepts but whose Face nodes break fbaconf's conventions."""

    def __init__(self, message: str, node_path: str | None = None) -> None:
        super().__init__(message)
        self.node_path = node_path


def summarize_scene(scene: Any, base_dir: Path | None = None) -> SceneSummary:
    """SceneSummary of a parsed ``fbaconf.scenes.bt.Scene`` (duck-typed). Texture sizes are
    read from the image files of ImageTexture nodes under an FDP (URLs relative to
    ``base_dir``, default: the scene file's folder)."""
    s = SceneSummary()
    if base_dir is None and getattr(scene, "file", None):
        base_dir = Path(scene.file).parent
    resolve = scene.resolve
    nodes = list(scene.walk())
    s.faces = sum(1 for n, _ in nodes if n.type == "Face")
    for n, path in nodes:
        if n.type == "FDP":
            fpc = resolve(n.get("featurePointsCoord"))
            if fpc is not None:
                s.tools.setdefault("fdp_feature_points", f"{path}.featurePointsCoord")
                rows, sent = fdp_point_rows(fpc.get("point") if fpc.type == "Coordinate" else [])
                if len(rows) != NUM_FEATURE_POINTS:
                    raise SceneStructureError(
                        f"featurePointsCoord must list the 84 feature points in label order (unsent ones as "
                        f"3.4e38), got {len(rows)}",
                        node_path=f"{path}.featurePointsCoord",
                    )
                s.measure("fdp_feature_points", int(sent.sum()), f"{path}.featurePointsCoord")
            if resolve(n.get("textureCoord")) is not None or n.get("useOrthoTexture"):
                s.tools.setdefault("fdp_texture", f"{path}.textureCoord")
            tables_ = n.get("faceDefTables")
            if len(tables_):
                s.tools.setdefault("downloaded_model", f"{path}.faceDefTables")
            entries = 0
            for t in tables_:
                t = resolve(t)
                if t is not None:
                    entries += len(t.get("faceDefMesh")) + len(t.get("faceDefTransform"))
            if len(tables_):
                s.measure("facedeftables_entries", entries, f"{path}.faceDefTables")
        elif n.type == "FaceDefMesh":
            nb = len(n.get("intervalBorders"))
            s.measure("intervals_per_facedefmesh", max(nb - 1, 0), f"{path}.intervalBorders")
            try:  # the rules the engine applies: >= 2 borders, finite, strictly increasing, a 0
                validate_borders(n.get("intervalBorders"), node_path=f"{path}.intervalBorders")
            except SceneError as e:
                raise SceneStructureError(e.message, node_path=f"{path}.intervalBorders") from None
        elif n.type == "FIT":
            s.tools.setdefault("fit", path)
            faps = [int(x) for x in n.get("FAPs")]
            nodes_n, cur = 0, 0
            for x in faps:
                if x == -1:
                    nodes_n += cur > 0
                    cur = 0
                else:
                    cur += 1
            nodes_n += cur > 0
            s.measure("fit_nodes", nodes_n, f"{path}.FAPs")
            s.measure("fit_links", len(n.get("Graph")) // 2, f"{path}.Graph")
            terms = [int(x) for x in n.get("numeratorTerms")] + [int(x) for x in n.get("denominatorTerms")]
            s.measure("fit_terms", max(terms, default=0), f"{path}.numeratorTerms")
    for n, path in nodes:
        if n.type == "ImageTexture" and "FDP" in re.split(r"[.\[\]]", path):
            for url in n.get("url")[:1]:
                p = Path(url)
                if not p.is_absolute() and base_dir is not None:
                    p = base_dir / p
                size = image_size(p)
                if size is not None:
                    s.measure("texture_width", size[0], f"{path}.url")
                    s.measure("texture_height", size[1], f"{path}.url")
    vertices, vpath = 0, ""
    for n, path in nodes:
        if n.type == "IndexedFaceSet" and "faceSceneGraph" in path:
            s.tools.setdefault("downloaded_model", path)
            coord = resolve(n.get("coord"))
            if coord is not None and coord.type == "Coordinate":
                vertices += len(coord.get("point"))
                vpath = vpath or path
    if vertices:
        s.measure("mesh_vertices", vertices, vpath)
    return s


def load_scene(scene, out: list[Diagnostic]) -> SceneSummary | None:
    if scene is None:
        return None
    if isinstance(scene, SceneSummary):
        return scene
    if isinstance(scene, (str, Path)):
        try:
            importlib.import_module("fbaconf.scenes.bt")  # optional: the scene readers (BT, and BIFS on it)
            bifs = importlib.import_module("fbaconf.scenes.bifs")
        except Exception as e:  # noqa: BLE001 - ImportError, or a reader that fails to import
            out.append(
                diag(
                    R.SCENE_UNAVAILABLE,
                    f"scene {scene}: no scene reader in this build "
                    f"({type(e).__name__}: {e}); the scene was not checked",
                )
            )
            return None
        try:
            parsed = bifs.load_scene(scene)  # binary BIFS or BT text, by extension
        except OSError as e:
            out.append(diag(R.SCENE_INVALID, f"scene {scene} cannot be read: {e.strerror or e}"))
            return None
        except Exception as e:  # noqa: BLE001 - TextFormatError / SceneError / anything the reader raises
            path = getattr(e, "node_path", None)
            line = getattr(e, "line", None)
            where = f" (line {line}, column {getattr(e, 'column', '?')})" if line is not None else ""
            if getattr(e, "bit_offset", None) is not None:  # a binary BIFS scene
                where = f" (BIFS bit offset {e.bit_offset}, rule {getattr(e, 'rule', '?')})"
            out.append(diag(R.SCENE_INVALID, f"scene {scene}{where}: {getattr(e, 'message', e)}", node_path=path))
            return None
        scene = parsed
    try:
        _interop(scene, out)
    except Exception:  # noqa: BLE001, S110 - the interop note never stops the check
        pass
    # FAP-SCENE-004; loaded with the scene readers (it compiles the scene the way the reference does)
    out.extend(importlib.import_module("fbaconf.profiles.conditioning").conditioning_diagnostics(scene))
    try:
        return summarize_scene(scene)
    except SceneStructureError as e:
        out.append(diag(R.SCENE_INVALID, f"scene: {e}", node_path=e.node_path))
        return None
    except Exception as e:  # noqa: BLE001 - any other failure of an untrusted scene is reported
        out.append(diag(R.SCENE_INVALID, f"scene structure not understood: {type(e).__name__}: {e}"))
        return None


def _interop(scene, out: list[Diagnostic]) -> None:
    """D10: where fbaconf follows the seed and GPAC's MP4Box does not (one warning per scene)."""
    if not hasattr(scene, "walk"):
        return
    defs = scene.defs()
    for node, path in scene.walk():
        if getattr(node, "type", None) != "FaceDefMesh":
            continue
        ref = node.fields.get("faceSceneGraphNode")
        target = defs.get(ref.name) if hasattr(ref, "name") and not hasattr(ref, "type") else ref
        if getattr(target, "type", None) == "IndexedFaceSet":
            out.append(
                diag(
                    R.SCENE_INTEROP_FDM,
                    "FaceDefMesh.faceSceneGraphNode references an IndexedFaceSet "
                    "(as the seed defines it); MP4Box refuses this USE when decoding BIFS",
                    node_path=path,
                )
            )
            return
