"""What a decoder's case folder holds: exactly the input forms its manifest accepts, copied in
— nothing derived from the goldens, no other case's files (docs/harness.md, "What a decoder
sees"). The harness fills the command from what :func:`stage` returns."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from fbaconf.conformance.suite import Case

    from .subject import Decoder

# Suffixes of the forms a case's expected results come in (or could be mistaken for): an
# auxiliary file with one of them is never staged, whatever a suite lists.
_NEVER_AUXILIARY = frozenset({".fap", ".fba", ".npz", ".bt", ".bifs", ".json"})


def staged_inputs(adapter: Decoder, case: Case) -> dict[str, Path]:
    """What a decoder's case folder holds (placeholder -> the suite file copied there): exactly
    the input forms ``adapter.inputs`` accepts — the ``.fba`` when it accepts ``fba`` (never the
    case's ``.fap``: that text is the reference decoding, i.e. the expected output); the
    ``.fap`` only for a program that takes the text form and not the binary one (a player);
    the BT and/or binary BIFS scene when it accepts ``scene``/``bifs``; the rendering
    scenario; and the files a scene names by relative URL (textures)."""
    out: dict[str, Path] = {}
    fba, fap = case.input_path("fba"), case.input_path("fap")
    if "fba" in adapter.inputs and fba is not None:
        out["fba"] = out["input"] = fba
    elif "fap" in adapter.inputs and fap is not None:
        out["fap"] = out["input"] = fap
    bt, bifs = case.input_path("scene"), case.input_path("bifs")
    if "scene" in adapter.inputs and bt is not None:
        out["scene_bt"] = out["scene"] = bt
    if "bifs" in adapter.inputs and bifs is not None:
        out["scene_bifs"] = bifs
        out.setdefault("scene", bifs)
    scenario = case.input_path("scenario")
    if scenario is not None:
        out["scenario"] = scenario
    return out


def auxiliary_files(case: Case) -> list[Path]:
    """The files a case lists beside its inputs (a texture its scene names by a relative URL):
    never one of the case's input or golden forms."""
    if case.suite_dir is None:
        return []
    named = {v for k, v in case.inputs.items() if k != "faces" and isinstance(v, str)}
    named |= set(case.inputs.get("faces", []))
    return [
        case.suite_dir / rel
        for rel in case.sha256
        if rel not in named and Path(rel).suffix.lower() not in _NEVER_AUXILIARY
    ]


def stage(adapter: Decoder, case: Case, workdir: Path) -> tuple[dict[str, str], list[str]]:
    """Make ``workdir``: ``in/`` with copies of :func:`staged_inputs` and :func:`auxiliary_files`
    and of each face stream, ``out/`` (with ``images/`` and ``faces/``) for what the decoder
    writes. Returns (placeholder -> path, the face streams' paths)."""
    ind, outd = workdir / "in", workdir / "out"
    ind.mkdir(parents=True)
    outd.mkdir()
    values: dict[str, str] = {}
    for key, src in staged_inputs(adapter, case).items():
        dst = ind / src.name
        if not dst.exists():
            shutil.copyfile(src, dst)
        values[key] = str(dst)
    for src in auxiliary_files(case):
        if src.is_file() and not (ind / src.name).exists():
            shutil.copyfile(src, ind / src.name)
    ext = "fap" if adapter.faps_format == "fap" else "npz"
    values.update(
        faps_out=str(outd / f"faps.{ext}"),
        vertices_out=str(outd / "vertices.npz"),
        images_dir=str(outd / "images"),
        faps_out_dir=str(outd / "faces"),
    )
    (outd / "images").mkdir()
    (outd / "faces").mkdir()
    faces = []
    for src in case.face_paths():
        shutil.copyfile(src, ind / src.name)
        faces.append(str(ind / src.name))
    return values, faces
