"""The stream checker: face object bytes (+ optional scene) + optional claim -> diagnostics.

Parsing is the reference decoder's (``fbaconf.bitstreams.decoder``); the checker reads the
per-plane records it keeps (:class:`PlaneInfo`: offsets, header fields, new lists, block
spans) and adds its own light-weight checks on top. What the decoder refuses becomes one
diagnostic at the bit offset where parsing stopped (``BitstreamError.rule`` -> code, see
``fbaconf.rules.code_for_rule``); everything parsed before that point is still checked.

``check_stream`` never raises: an unexpected exception becomes ``FAP-CHECK-002``.

Checks that the syntax makes impossible and that therefore have no code: masks, fap_quant
and min/max lists outside intra planes (predicted planes carry no such fields); new lists
for unmasked FAPs (a list carries values only for masked FAPs); symbols outside the
signalled ranges (the alphabet is built from the ranges, so no symbol can leave them).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fbaconf import rules as R
from fbaconf.bitstreams import decoder as dec, tables
from fbaconf.bitstreams.bitio import FACE_OBJECT_START_CODE, VISUAL_OBJECT_SEQUENCE_END_CODE
from fbaconf.bitstreams.emulation import find_emulations
from fbaconf.bitstreams.syntax import (
    CODING_DCT,
    INTENSITY_MAX,
    intensity_bound,
    intensity_bound_ceil,
    intensity_step,
)
from fbaconf.bitstreams.tables import NUM_FAPS
from fbaconf.errors import BitstreamError

from .decisions import ARITH_BLOCKS, check_decisions, lookahead_stuffing
from .diagnostics import Diagnostic, diag
from .model import Claim, ProfileSet, load_profiles
from .scenecheck import SceneStructureError, SceneSummary, image_size, load_scene, summarize_scene  # noqa: F401 (re-exported)

# Level limit id -> diagnostic code (limits with bounds = stream | scene).
LIMIT_CODES = {
    "bitrate": R.LEVEL_BITRATE,
    "coded_frame_rate": R.LEVEL_FRAME_RATE,
    "faces": R.LEVEL_FACES,
    "fdp_feature_points": R.LEVEL_FDP_POINTS,
    "fit_nodes": R.LEVEL_FIT_NODES,
    "fit_links": R.LEVEL_FIT_LINKS,
    "fit_terms": R.LEVEL_FIT_TERMS,
    "texture_width": R.LEVEL_TEXTURE,
    "texture_height": R.LEVEL_TEXTURE,
    "mesh_vertices": R.LEVEL_MESH_VERTICES,
    "facedeftables_entries": R.LEVEL_FDT_ENTRIES,
    "intervals_per_facedefmesh": R.LEVEL_INTERVALS,
}

# Unit of a limit in the data file -> factor to the checker's measure.
UNIT_FACTORS = {"kbit/s": 1000.0}

UNREADABLE_CODES = frozenset({R.INPUT_UNREADABLE, R.SYNTAX_TOO_SHORT, R.SYNTAX_NOT_FACE})
UNIDIRECTIONAL = tuple(f.number for f in tables.fap_table() if f.direction == "U")
WINDOW_MS = 1000.0
_EPS_MS = 1e-6


# ---------------------------------------------------------------------------- report
@dataclass
class Report:
    diagnostics: list[Diagnostic]
    summary: dict
    unreadable: bool = False
    claim: Claim | None = None
    smallest_claim: Claim | None = None
    fits: dict[str, bool] = field(default_factory=dict)


def check_stream(
    data: bytes,
    *,
    scene=None,
    claim: Claim | str | None = None,
    file: str | None = None,
    profiles: ProfileSet | None = None,
) -> list[Diagnostic]:
    """All diagnostics for a face object stream, in stream order. Never raises on any stream or
    scene content; only a malformed ``claim`` string raises ValueError (a usage error).

    ``scene``: None, a BT file path (read with ``fbaconf.scenes.bt`` when available), a
    parsed ``bt.Scene``, or a :class:`SceneSummary`."""
    return analyse(data, scene=scene, claim=claim, file=file, profiles=profiles).diagnostics


def analyse(
    data: bytes,
    *,
    scene=None,
    claim: Claim | str | None = None,
    file: str | None = None,
    profiles: ProfileSet | None = None,
    smallest_claim: bool = False,
) -> Report:
    """The full check: diagnostics, a summary, the smallest admissible claim. Never raises."""
    out: list[Diagnostic] = []
    summary: dict = {"bytes": len(data) if isinstance(data, (bytes, bytearray)) else 0}
    rep = Report(out, summary)
    if isinstance(claim, str):  # a bad claim is a usage error (ValueError), not a stream problem
        claim = Claim.parse(claim, profiles or load_profiles())
    try:
        _analyse(bytes(data), scene, claim, file, profiles, smallest_claim, rep)
    except Exception as e:  # noqa: BLE001 - a checker bug must not crash the caller
        out.append(diag(R.CHECK_INTERNAL, f"internal checker failure: {type(e).__name__}: {e}"))
    out.sort(key=lambda d: d.location.sort_key())
    rep.unreadable = any(d.code in UNREADABLE_CODES for d in out)
    return rep


class _Stream:
    """What was parsed: plane records, decoded frames, the error that stopped parsing."""

    def __init__(self, data: bytes, file: str | None) -> None:
        self.data = data
        self.error: BitstreamError | None = None
        self.result = None
        self.dct_plane: int | None = None
        dobj = dec._Decoder(data, file) if hasattr(dec, "_Decoder") else None
        try:
            if dobj is not None:
                self.result = dobj.run()
            else:  # pragma: no cover - decoder without the internal class
                self.result = dec.decode(data, file=file)
        except BitstreamError as e:
            self.error = e
        if self.result is not None:
            self.planes = list(self.result.planes)
            self.frames = self.result.frames
        elif dobj is not None:
            self.planes = list(dobj.planes)
            self.frames = dobj._frames()
        else:  # pragma: no cover
            self.planes = []
            self.frames = self.error.partial
        if self.error is not None and self.error.rule == "dct-unsupported":
            self.dct_plane = self.error.plane


def _analyse(data: bytes, scene, claim, file, profiles, want_smallest: bool, rep: Report) -> None:
    out = rep.diagnostics
    ps = profiles or load_profiles()
    if isinstance(claim, str):
        claim = Claim.parse(claim, ps)
    rep.claim = claim
    summary = rep.summary
    if len(data) < 4:
        out.append(diag(R.SYNTAX_TOO_SHORT, f"input has {len(data)} byte(s): not a face object stream", bit_offset=0))
        return
    first = int.from_bytes(data[:4], "big")
    if first != FACE_OBJECT_START_CODE:
        out.append(
            diag(
                R.SYNTAX_NOT_FACE,
                f"input starts with 0x{first:08X}, not face_object_start_code 0x000001BA",
                bit_offset=0,
            )
        )
        return
    st = _Stream(data, file)
    planes = st.planes
    _syntax(st, out)
    _semantics(st, out)
    check_decisions(st, _rows(st), out)
    tools = _tools(st)
    measures = _measures(st, summary)
    sc = load_scene(scene, out)
    if sc is not None:
        for t, path in sc.tools.items():
            tools.setdefault(t, {"node_path": path})
        for k, (v, path) in sc.measures.items():
            measures[k] = (v, {"node_path": path})
    faces = max(1, sc.faces if sc is not None else 1)
    measures["faces"] = (float(faces), {"node_path": "Face"} if sc is not None and sc.faces > 1 else {})
    summary.update(
        planes=len(planes),
        frames=len(_rows(st)),
        intra_planes=sum(1 for p in planes if p.is_intra),
        complete=st.error is None,
        parsed_to_bit=(st.error.bit_offset if st.error is not None else st.result.end_offset),
        frame_rate=_first_rate(planes),
        faces=faces,
        tools=sorted(tools),
        end_code=(f"0x{st.result.end_code:08X}" if st.result is not None and st.result.end_code is not None else None),
    )
    # claims
    fits = {}
    for c in ps.claims():
        fits[str(c)] = not _claim_violations(ps, c, tools, measures)
    rep.fits = fits
    smallest = next((c for c in ps.claims() if fits[str(c)]), None)
    rep.smallest_claim = smallest
    summary["smallest_claim"] = str(smallest) if smallest is not None else None
    if claim is not None:
        out.extend(_claim_violations(ps, claim, tools, measures))
        summary["limits"] = _limit_table(ps, claim, measures)
    if want_smallest and smallest is None:
        top = ps.claims()[-1]
        why = sorted({d.code for d in _claim_violations(ps, top, tools, measures)})
        out.append(
            diag(
                R.CLAIM_NONE,
                f"no profile@level defined in profiles.toml admits this stream (even {top} "
                f"is violated: {', '.join(why)})",
            )
        )


def _first_rate(planes) -> float | None:
    for p in planes:
        if p.frame_rate is not None:
            return round(float(p.frame_rate.rate), 6)
    return None


# ---------------------------------------------------------------------------- syntax
def _syntax(st: _Stream, out: list[Diagnostic]) -> None:
    e = st.error
    if e is not None:
        code = R.code_for_rule(e.rule, R.SYNTAX_OTHER)
        if code == R.CHECK_DCT:
            msg = (
                f"plane {e.plane} uses coding_type 1 (DCT segment mode), which this checker cannot parse; "
                "the rest of the stream was not checked"
            )
        elif code == R.SYNTAX_OTHER:
            msg = f"parsing stopped: {e.message} [rule {e.rule}]"
        else:
            msg = f"parsing stopped: {e.message}"
        out.append(diag(code, msg, bit_offset=e.bit_offset, plane=e.plane, fap=e.fap))
        return
    res = st.result
    nbits = len(st.data) * 8
    for byte in find_emulations(st.data, res):
        plane = next((p.index for p in reversed(res.planes) if p.bit_offset <= byte * 8), None)
        out.append(
            diag(
                R.SYNTAX_EMULATION,
                f"start-code emulation: a byte-aligned 0x000001 at byte {byte} that is "
                f"no start code (D9); a decoder that scans for start codes stops there",
                bit_offset=byte * 8,
                plane=plane,
            )
        )
    if res.end_code is None:
        out.append(
            diag(R.SYNTAX_NO_END_CODE, "the stream ends without the end code 0x000001B1", bit_offset=res.end_offset)
        )
    elif res.end_code != VISUAL_OBJECT_SEQUENCE_END_CODE:
        out.append(
            diag(
                R.SYNTAX_UNEXPECTED_START_CODE,
                f"start code 0x{res.end_code:08X} ends the face object (expected a plane start code or "
                "the end code 0x000001B1); the data after it was not checked",
                bit_offset=res.end_offset - 32,
            )
        )
    elif res.end_offset < nbits:
        extra = (nbits - res.end_offset) // 8
        out.append(diag(R.SYNTAX_TRAILING, f"{extra} byte(s) after the end code", bit_offset=res.end_offset))


# ---------------------------------------------------------------------------- semantics
def _time_code_offset(p) -> int:
    return p.header_offset + 3 + 1 + (13 if p.frame_rate is not None else 0) + 1


def _semantics(st: _Stream, out: list[Diagnostic]) -> None:
    planes = st.planes
    prev_t = None
    for p in planes:
        if p.time_code is not None:
            h, m, _, s = p.time_code
            bad = [
                f"{name} {v} > {lim}"
                for name, v, lim in (("hours", h, 23), ("minutes", m, 59), ("seconds", s, 59))
                if v > lim
            ]
            if bad:
                out.append(
                    diag(
                        R.SEM_TIME_CODE_RANGE,
                        "time code out of range: " + ", ".join(bad),
                        bit_offset=_time_code_offset(p),
                        plane=p.index,
                        frame=p.frame_number,
                    )
                )
        # a time code has whole-second resolution: it goes backwards only when it is earlier
        # than the whole second the previous plane lies in
        if (
            prev_t is not None
            and p.time_code is not None
            and p.time_ms < np.floor((prev_t + _EPS_MS) / 1000.0) * 1000.0 - _EPS_MS
        ):
            out.append(
                diag(
                    R.SEM_TIME_BACKWARDS,
                    f"time code {p.time_ms / 1000.0:g} s is earlier than the second "
                    f"of the previous plane ({prev_t:.3f} ms)",
                    bit_offset=p.bit_offset,
                    plane=p.index,
                    frame=p.frame_number,
                    time_ms=p.time_ms,
                )
            )
        prev_t = p.time_ms
    rows = _rows(st)
    if not rows:
        return
    fr = st.frames
    ks = np.array([k for k, _ in rows], dtype=np.int64)
    rp = [p for _, p in rows]
    coded = np.array([p.coded if p.coded is not None else np.zeros(NUM_FAPS, bool) for p in rp])
    high = fr.high[ks]
    # the top under D5 and under the other reading (0..ceil(63/q)): a value between the two is out of
    # range only under D5 (FAP-SEM-009); beyond both, or negative, under every reading (FAP-SEM-006)
    top, top_other = (
        np.array(
            [
                max(INTENSITY_MAX, bound(int(p.fap_quant)) * intensity_step(int(p.fap_quant)))
                if p.coding_type != CODING_DCT
                else INTENSITY_MAX
                for p in rp
            ]
        )
        for bound in (intensity_bound, intensity_bound_ceil)
    )
    for col, fap, name in ((2, 0, "viseme_blend"), (5, 1, "expression_intensity1"), (7, 1, "expression_intensity2")):
        v = high[:, col]
        for code, bad, shown in (
            (R.SEM_INTENSITY, (v < 0) | (v > top_other), top),
            (R.SEM_INTENSITY_D5, (v > top) & (v <= top_other), top),
        ):
            for j in np.nonzero(coded[:, fap] & bad)[0]:
                p = rp[j]
                other = f" (0..{int(top_other[j])} under the other reading)" if top_other[j] != top[j] else ""
                out.append(
                    diag(
                        code,
                        f"{name} = {int(v[j])} outside 0..{int(shown[j])}{other}",
                        bit_offset=p.bit_offset,
                        plane=p.index,
                        frame=int(fr.frame_number[ks[j]]),
                        fap=fap + 1,
                    )
                )
    # negative values of unidirectional FAPs (D4 warning)
    vals = fr.values[ks]
    for f in UNIDIRECTIONAL:
        bad = np.nonzero(coded[:, f - 1] & (vals[:, f - 1] < 0))[0]
        for j in bad:
            p = rp[j]
            out.append(
                diag(
                    R.DECISION_UNIDIRECTIONAL_NEGATIVE,
                    f"unidirectional FAP {f} decodes to {int(vals[j, f - 1])} < 0",
                    bit_offset=p.bit_offset,
                    plane=p.index,
                    frame=int(fr.frame_number[ks[j]]),
                    fap=f,
                )
            )


def _rows(st: _Stream) -> list[tuple[int, Any]]:
    """(frame row, plane) for every decoded frame row (a DCT plane group has several rows)."""
    fr = st.frames
    if fr is None or len(fr) == 0:
        return []
    by_off = {p.bit_offset: p for p in st.planes}
    out = []
    for k, off in enumerate(fr.bit_offset.tolist()):
        p = by_off.get(int(off))
        if p is not None:
            out.append((k, p))
    return out


# ---------------------------------------------------------------------------- tools and measures
def _tools(st: _Stream) -> dict[str, dict]:
    tools: dict[str, dict] = {}
    for p in st.planes:
        loc = {"bit_offset": p.bit_offset, "plane": p.index, "frame": p.frame_number}
        tools.setdefault("dct" if p.coding_type == CODING_DCT else "arithmetic", loc)
        if p.coded is not None and (p.coded[0] or p.coded[1]):
            tools.setdefault("high_level_faps", {**loc, "fap": 1 if p.coded[0] else 2})
    if st.dct_plane is not None:
        tools.setdefault("dct", {"bit_offset": st.error.bit_offset, "plane": st.dct_plane})
    return tools


def _measures(st: _Stream, summary: dict) -> dict[str, tuple[float, dict]]:
    """Peak bits and peak frames over a sliding one-second window [t, t + 1 s).

    Plane bits run from the plane's first bit to the next plane's (the object start code
    counts with the first plane); a DCT plane group's bits are spread evenly over its frames."""
    planes = st.planes
    m: dict[str, tuple[float, dict]] = {}
    rows = _rows(st)
    if not planes or not rows:
        summary.update(peak_bitrate_bps=0, peak_frame_rate_hz=0, duration_s=0.0)
        return m
    starts = np.array([p.bit_offset for p in planes], dtype=np.int64)
    ends = np.append(starts[1:], planes[-1].end_offset)
    pbits = (ends - starts).astype(np.float64)
    pbits[0] += starts[0]
    index_of = {p.index: i for i, p in enumerate(planes)}
    pi = np.array([index_of[p.index] for _, p in rows], dtype=np.int64)
    nrows = np.bincount(pi, minlength=len(planes))
    bits = pbits[pi] / nrows[pi]
    t = st.frames.time_ms[np.array([k for k, _ in rows], dtype=np.int64)]
    order = np.argsort(t, kind="stable")
    ts, bs = t[order], bits[order]
    cum = np.concatenate(([0.0], np.cumsum(bs)))
    hi = np.searchsorted(ts, ts + WINDOW_MS - _EPS_MS, side="left")
    idx = np.arange(len(ts))
    win_bits = cum[hi] - cum[idx]
    win_frames = hi - idx
    kb = int(np.argmax(win_bits))
    kf = int(np.argmax(win_frames))

    def loc(j: int) -> dict:
        k, p = rows[int(order[j])]
        return {
            "bit_offset": p.bit_offset,
            "plane": p.index,
            "frame": int(st.frames.frame_number[k]),
            "time_ms": float(ts[j]),
        }

    peak_bits = float(np.round(win_bits[kb], 6))
    m["bitrate"] = (peak_bits, loc(kb))
    m["coded_frame_rate"] = (float(win_frames[kf]), loc(kf))
    summary.update(
        peak_bitrate_bps=int(round(peak_bits)),
        peak_frame_rate_hz=int(win_frames[kf]),
        duration_s=round(float(ts[-1] - ts[0]) / 1000.0, 6),
    )
    return m


def _limit_table(ps: ProfileSet, claim: Claim, measures: dict) -> list[dict]:
    """Every limit of the claim with its provenance and, for stream/scene limits, the measure."""
    rows = []
    for lim in ps.limits_for(claim):
        f = UNIT_FACTORS.get(lim.unit, 1.0)
        m = measures.get(lim.id)
        measured = None if m is None or lim.bounds == "decoder" else round(m[0] / f, 6)
        rows.append(
            {
                "limit": lim.id,
                "kind": lim.kind,
                "value": lim.value(claim.level),
                "unit": lim.unit,
                "provenance": lim.provenance,
                "bounds": lim.bounds,
                "measured": measured,
                "ok": None if measured is None else bool(measured <= lim.value(claim.level) + 1e-9),
            }
        )
    return rows


def _claim_violations(ps: ProfileSet, claim: Claim, tools: dict, measures: dict) -> list[Diagnostic]:
    out = []
    prof = ps.profiles[claim.profile]
    for t, loc in tools.items():
        if t not in prof.tools:
            desc = ps.tools[t].description if t in ps.tools else t
            out.append(diag(R.PROFILE_TOOL, f"tool {t!r} ({desc}) is not in profile {prof.name}", **loc))
    for lim in ps.limits_for(claim):
        if lim.bounds == "decoder" or lim.kind != "max" or lim.id not in measures:
            continue
        code = LIMIT_CODES.get(lim.id)
        if code is None:
            continue
        value, loc = measures[lim.id]
        limit = lim.value(claim.level) * UNIT_FACTORS.get(lim.unit, 1.0)
        if value > limit + 1e-9:
            shown = value / UNIT_FACTORS.get(lim.unit, 1.0)
            out.append(
                diag(
                    code,
                    f"{lim.description}: {shown:g} {lim.unit} > {lim.value(claim.level):g} {lim.unit} "
                    f"allowed at {prof.name}@{claim.level} ({lim.provenance} limit)",
                    **loc,
                )
            )
    return out


__all__ = [
    "ARITH_BLOCKS",
    "Report",
    "SceneSummary",
    "analyse",
    "check_stream",
    "lookahead_stuffing",
    "summarize_scene",
    "LIMIT_CODES",
]
