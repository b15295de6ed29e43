"""The comparison ladder: how one case's process ending and outputs become its outcome.

First the ending (:func:`outcome_for`: set-up failures are Error, crashes Crash, a reject is a
Pass on an invalid stream and a Fail on a valid one), then — when a valid stream decoded —
each stage the case compares against its goldens, in order: FAPs exactly (:mod:`.faps`),
vertices and effective FAPs within tolerance (:mod:`.vertices`), images with OpenImageIO and
CIEDE2000 (:mod:`.images`). The worst stage decides.
"""

from __future__ import annotations

import os
import re
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from fbaconf.animation.stateio import load_npz
from fbaconf.bitstreams.frames import FapFrames
from fbaconf.bitstreams.tables import fap_table
from fbaconf.conformance.suite import Case, CaseKind
from fbaconf.harness.adapters import Job
from fbaconf.harness.results import Outcome, StageResult
from fbaconf.isolation.endings import Ending, EndingKind

from .base import DEFAULT_MAX_BYTES, OutputError
from .faps import compare_faps
from .images import compare_images
from .loaders import check_output_file, load_output_faps, load_output_vertices, open_npz
from .tolerances import ImageTolerances, VertexTolerances
from .vertices import compare_vertices, part_namer


def outcome_for(
    ending: Ending, *, invalid_stream: bool = False, conceal_allowed: bool = False
) -> tuple[Outcome, str] | None:
    """The case outcome of an ending, or None when the outputs decide (a valid stream decoded).

    Valid streams: a reject is a Fail. Invalid streams (the error groups): a reject is a Pass;
    exit 0 is a Fail ("decoded an invalid stream without complaint") unless the case allows
    concealment, in which case the outputs decide. Set-up failures are Error, never Pass."""
    k, msg = ending.kind, ending.message
    if k == EndingKind.SETUP:
        return Outcome.ERROR, msg
    if k == EndingKind.TIMEOUT:
        return Outcome.TIMEOUT, msg
    if k in (EndingKind.MEMORY, EndingKind.CRASH):
        return Outcome.CRASH, msg
    if k == EndingKind.OUTPUT_LIMIT:
        return Outcome.FAIL, msg
    if k == EndingKind.NOT_SUPPORTED:
        return Outcome.NOT_SUPPORTED, msg
    if k == EndingKind.UNEXPECTED:
        return Outcome.FAIL, msg
    if invalid_stream:
        if k == EndingKind.REJECT:
            return Outcome.PASS, f"invalid stream rejected cleanly ({msg})"
        if conceal_allowed:
            return None
        return Outcome.FAIL, (
            f"{msg}: decoded an invalid stream without complaint; a conformant decoder "
            f"rejects it with a documented exit code"
        )
    if k == EndingKind.REJECT:
        return Outcome.FAIL, f"{msg}: a valid stream was rejected"
    return None


def compare_outputs(
    case: Case,
    job: Job,
    *,
    golden: Path,
    outputs: list[str],
    out_dir: Path,
    gdir: Path | None = None,
    stages_of_case: list[str] | None = None,
) -> list[StageResult]:
    """Each stage the case compares and the decoder outputs, judged against the goldens under
    ``golden`` (or in ``gdir``: what another reading gives, conformance/golden.py); failing images
    leave artefacts under ``out_dir``. ``stages_of_case``: the stages to compare instead of the
    case's (an invalid stream that another reading decodes compares its FAPs)."""
    gdir = gdir if gdir is not None else case.golden_dir(golden)
    stages: list[StageResult] = []
    if case.kind == CaseKind.MULTI:
        outd = job.need("faps_out_dir")
        for i, (src, gold) in enumerate(zip(case.face_paths(), case.goldens.get("faces", []))):
            expected = FapFrames.load_npz(gdir / gold)
            cand = [outd / f"{src.stem}.{ext}" for ext in ("npz", "fap")]
            got_path = next((p for p in cand if os.path.lexists(p)), None)
            if got_path is None:
                stages.append(
                    StageResult(
                        f"faps[face {i}]",
                        Outcome.FAIL,
                        f"no output for face {i} ({src.name}): expected {cand[0].name} or "
                        f"{cand[1].name} in the output folder",
                    )
                )
                continue
            stages.append(_faps_stage(expected, got_path, f"faps[face {i}]"))
        return stages
    for stage in case.stages if stages_of_case is None else stages_of_case:
        if stage not in outputs:
            continue
        if stage == "faps":
            gp = gdir / case.goldens.get("faps", "faps.npz")
            if not gp.is_file():
                stages.append(
                    StageResult("faps", Outcome.ERROR, f"golden missing: {gp} (run fbaconf golden regenerate)")
                )
                continue
            text_in = job.values.get("input", "").lower().endswith(".fap")
            stages.append(_faps_stage(FapFrames.load_npz(gp), job.need("faps_out"), "faps", text_in))
        elif stage == "vertices":
            stages.append(_vertices_stage(case, gdir, job))
        elif stage == "images":
            stages.append(_images_stage(case, gdir, job, out_dir))
    return stages


def _faps_stage(expected: FapFrames, got_path: Path, name: str, text_input: bool = False) -> StageResult:
    """Decoded FAPs, exactly. With ``.fap`` text output there is no SET/RETAINED distinction to
    compare, only the values of every FAP the standard fixes; a player (``.fap`` input) is
    compared on its state (:mod:`.faps`)."""
    if got_path is None or not os.path.lexists(got_path):
        return StageResult(
            name, Outcome.FAIL, "decoder exited 0 but wrote no FAP output" + (f" ({got_path.name})" if got_path else "")
        )
    try:
        # A generous cap from the expected length keeps a hostile output from costing the
        # harness memory far beyond what the case can need.
        got = load_output_faps(got_path, max_bytes=min(DEFAULT_MAX_BYTES, (1 << 20) + 8192 * len(expected.values)))
    except OutputError as e:
        return StageResult(name, Outcome.FAIL, f"unreadable FAP output: {e}")
    r = compare_faps(expected, got, text_output=got_path.suffix.lower() == ".fap", player=text_input)
    r.stage = name
    return r


def _vertices_stage(case: Case, gdir: Path, job: Job) -> StageResult:
    tol = dict(case.tolerances.get("vertices", {}))
    key = tol.pop("key", "vertices")
    gp = gdir / case.goldens["vertices"]
    if not gp.is_file():
        return StageResult("vertices", Outcome.ERROR, f"golden missing: {gp} (run fbaconf golden regenerate)")
    got_path = job.path("vertices_out")
    if got_path is None or not os.path.lexists(got_path):
        return StageResult("vertices", Outcome.FAIL, "decoder exited 0 but wrote no vertices output")
    if key == "extra_fap_values":
        return _effective_faps_stage(gp, got_path, tol)
    expected = load_output_vertices(gp, key=key)
    try:
        got = load_output_vertices(got_path, key=key)
    except OutputError as e:
        return StageResult("vertices", Outcome.FAIL, f"unreadable vertices output: {e}")
    vt = VertexTolerances.from_dict(None, tol)
    part_of = _part_lookup(gp) if key == "vertices" else None
    what = "vertices" if key == "vertices" else key.removeprefix("extra_")
    r = compare_vertices(expected, got, max_tol=vt.max_tol, rms_tol=vt.rms_tol, part_of=part_of, what=what)
    r.stage = what if what == "vertices" else f"vertices[{what}]"
    return r


def _load_effective(path: Path) -> np.ndarray:
    """``extra_fap_values`` of a vertices output, read as defensively as every output."""
    check_output_file(path, DEFAULT_MAX_BYTES)
    with open_npz(path, DEFAULT_MAX_BYTES) as z:
        if "extra_fap_values" not in z:
            raise ValueError("no array 'extra_fap_values' (effective FAP values after FIT and left/right fill)")
        a = z.get("extra_fap_values")
    if a.ndim != 2 or a.shape[1] != 68 or a.dtype.kind not in "fiu":
        raise ValueError(f"'extra_fap_values' must be numbers [frames, 68], not {a.dtype}{list(a.shape)}")
    return a.astype(np.float64)


def _effective_faps_stage(golden: Path, got_path: Path, tol: dict[str, Any]) -> StageResult:
    """Effective FAPs after FIT / left-right fill (FaceState extra ``fap_values``), float tolerance."""
    name = "effective_faps"
    exp = _load_effective(golden)
    try:
        got = _load_effective(got_path)
    except Exception as e:  # noqa: BLE001 - untrusted file
        return StageResult(name, Outcome.FAIL, f"unreadable effective FAP output: {type(e).__name__}: {e}")
    if got.shape != exp.shape:
        return StageResult(
            name,
            Outcome.FAIL,
            f"shape {list(got.shape)}, expected {list(exp.shape)}",
            first_difference={"what": "shape", "expected": list(exp.shape), "got": list(got.shape)},
        )
    atol = float(tol.get("max_tol", 1e-6))
    diff = np.abs(np.nan_to_num(got - exp, nan=np.inf))
    per_frame = diff.max(axis=1) if diff.size else np.zeros(0)
    series = {"max |effective FAP error|": [float(x) for x in np.minimum(per_frame, 1e30)]}
    bad = np.argwhere(diff > atol)
    if len(bad) == 0:
        return StageResult(
            name,
            Outcome.PASS,
            "effective FAPs match",
            metrics={"max_abs_diff": float(diff.max(initial=0))},
            series=series,
        )
    f, j = (int(x) for x in bad[0])
    fd = {"frame": f, "fap": j + 1, "name": fap_table()[j].name, "expected": float(exp[f, j]), "got": float(got[f, j])}
    return StageResult(
        name,
        Outcome.FAIL,
        f"frame {f}, FAP {j + 1} ({fd['name']}): expected {exp[f, j]:g}, got {got[f, j]:g} "
        f"(tolerance {atol:g}); {len(bad)} value(s) off",
        first_difference=fd,
        metrics={"max_abs_diff": float(diff.max()), "values_differing": float(len(bad))},
        series=series,
    )


def _part_lookup(golden_vertices: Path) -> Callable[[int], str | None] | None:
    """Mesh part names of the golden FaceState, for naming a diverging vertex."""
    try:
        return part_namer(load_npz(golden_vertices).parts)
    except (OSError, ValueError, KeyError):
        return None


def image_frame_numbers(names: list[str]) -> list[int] | None:
    """The sequence frame number of each image (``frame_00010.png`` -> 10), so reports name
    the frames the scenario lists, not their positions; None if a name does not say."""
    out = []
    for n in names:
        m = re.fullmatch(r"frame_(\d+)\.png", n)
        if not m:
            return None
        out.append(int(m.group(1)))
    return out


def _images_stage(case: Case, gdir: Path, job: Job, out_dir: Path) -> StageResult:
    names = case.goldens.get("images", [])
    expected = [gdir / n for n in names]
    missing = [p for p in expected if not p.is_file()]
    if missing:
        return StageResult("images", Outcome.ERROR, f"golden missing: {missing[0]} (run fbaconf golden regenerate)")
    got = [job.path("images_dir") / n for n in names]
    tol = ImageTolerances.from_dict(None, case.tolerances.get("images", {}))
    art = out_dir / "artefacts" / case.suite / case.id
    r = compare_images(expected, got, tol, art, relative_to=out_dir, frames=image_frame_numbers(names))
    if r.outcome == Outcome.PASS:
        shutil.rmtree(art, ignore_errors=True)
    return r
