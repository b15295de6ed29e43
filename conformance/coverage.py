"""Coverage of the conformance suites, measured on the spec's coverage model.

The model is a data file, ``data/coverage.toml``: points (id, clause, description) and
families of points (one per value). The extractors below compute which points a case hits
FROM ITS CONTENT, never from its labels: each stream is decoded with the reference decoder
and its plane records (:class:`PlaneInfo`: masks, fap_quant, lists, symbols, time codes, skip,
DCT groups...) and FapFrames are inspected; each scene is parsed and compiled (FaceDefTables
intervals and the effective FAP values that reach them, FIT graph shapes, FDP subsets); the
profile/level measures come from the stream checker (``fbaconf.profiles.checker.analyse``),
compared with every level's limits; error streams are classified by the checker's diagnostics.

``fbaconf suites coverage [--json]`` prints point -> cases and ends with ``coverage: K/N points``.
"""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from fbaconf.bitstreams import decoder as dec, tables
from fbaconf.bitstreams.arith import MAX_FREQUENCY, ZERO_RUN_LIMIT
from fbaconf.bitstreams.faptext import read_fap_file, read_fap_text
from fbaconf.bitstreams.frames import FREE, RETAINED, SET
from fbaconf.bitstreams.syntax import CODING_DCT, LIST_ORDER, MASK_INTERPOLATE, MASK_RETAIN, alphabet
from fbaconf.bitstreams.tables import RANGE_DELTA
from fbaconf.errors import BitstreamError, FbaconfInputError
from fbaconf.profiles.checker import ARITH_BLOCKS, analyse, lookahead_stuffing
from fbaconf.profiles.model import load_profiles

from .coder_coverage import coder_points
from .coverage_scene import scene_points
from .suite import CaseKind, load_suites

FORMAT = "fbaconf.coverage/1"
BITRATE_BAND = 0.10  # "at the limit" for the (continuous) bitrate: within the top 10 % below it


@dataclass(frozen=True)
class Point:
    id: str
    clause: str
    description: str


def _values(spec) -> list:
    if isinstance(spec, str):
        m = re.fullmatch(r"(-?\d+)\.\.(-?\d+)", spec.strip())
        if not m:
            raise ValueError(f"coverage.toml: bad values range {spec!r}")
        return list(range(int(m.group(1)), int(m.group(2)) + 1))
    return list(spec)


def _names() -> dict[str, dict]:
    return {
        "fap": {str(f.number): f.name for f in tables.fap_table()},
        "viseme": {str(n): p for n, p, _ in tables.visemes()},
        "expression": {str(n): name for n, name in tables.expressions()},
    }


def load_model(path: Path | None = None) -> list[Point]:
    """Every coverage point of the model, in file order."""
    text = (
        Path(path).read_text("utf-8")
        if path
        else resources.files("fbaconf.conformance").joinpath("data/coverage.toml").read_text("utf-8")
    )
    d = tomllib.loads(text)
    if d.get("format") != FORMAT:
        raise ValueError(f"coverage model: format must be {FORMAT}")
    names = _names()
    bidir = {f.number for f in tables.fap_table() if f.direction != "U"}
    items = [("point", p) for p in d.get("point", [])] + [("family", f) for f in d.get("family", [])]
    # keep file order: tomllib groups arrays by key, so order by the position of each id in the text
    items.sort(key=lambda kv: text.find(f'id = "{kv[1]["id"]}"'))
    out: list[Point] = []
    for kind, it in items:
        if kind == "point":
            out.append(Point(it["id"], it["clause"], it["description"]))
            continue
        prefix = it["id"].split(".", 1)[0]
        for v in _values(it["values"]):
            if it.get("only") == "bidirectional" and int(v) not in bidir:
                continue
            name = names.get(prefix, {}).get(str(v), "")
            out.append(Point(it["id"].format(v=v), it["clause"], it["description"].format(v=v, name=name)))
    ids = [p.id for p in out]
    dup = {i for i in ids if ids.count(i) > 1}
    if dup:
        raise ValueError(f"coverage model: duplicate point ids {sorted(dup)}")
    return out


# ------------------------------------------------------------------ stream extractors


def _decode_any(data: bytes):
    """(planes, frames, error) of the reference decoder, also for invalid streams."""
    d = dec._Decoder(data, None)
    try:
        res = d.run()
        return res.planes, res.frames, None, res
    except BitstreamError as e:
        return list(d.planes), d._frames() if d.rows_values else None, e, None


def stream_points(data: bytes) -> set[str]:  # noqa: C901
    """Points hit by decoding one valid face object stream."""
    hits: set[str] = set()
    planes, frames, err, res = _decode_any(data)
    if err is not None or frames is None:
        return hits
    if res.end_code is not None:
        hits.add("stream.end-code")
    else:
        hits.add("stream.no-end-code")
    if res.end_offset + 8 <= len(data) * 8 and res.end_code is not None:
        hits.add("stream.trailing-data")
    default = tables.default_bounds()
    bounds = default.copy()
    seen_p = False
    pred_count: dict[int, int] = {}  # predicted symbols per FAP model since the segment's intra plane
    quants, prev_coded, prev_rate = set(), None, None
    ever_set = np.zeros(tables.NUM_FAPS, dtype=bool)  # FAPs coded by an intra plane so far
    qp = tables.quant_steps()
    group_of = tables.group_of_fap()
    any_rate = False
    for k, p in enumerate(planes):
        hits.add("plane.start-code" if p.start_code else "plane.no-start-code")
        if p.skip:
            hits.add("skip.frames")
            if k == 0:
                hits.add("skip.first-plane")
            if p.skip >= 15:
                hits.add("skip.chain")
        dct = p.coding_type == CODING_DCT
        if p.is_intra:
            hits.add("plane.intra")
            if seen_p:
                hits.add("plane.intra-after-predicted")
            q = p.fap_quant
            if not dct:
                quants.add(q)
                hits.add(
                    "fap_quant.0"
                    if q == 0
                    else "fap_quant.1"
                    if q == 1
                    else "fap_quant.31"
                    if q == 31
                    else "fap_quant.mid"
                )
            for t in p.group_types:
                hits.add(f"mask.type-{t}")
            if prev_coded is not None and not np.array_equal(prev_coded, p.coded):
                hits.add("mask.change")
            prev_coded = p.coded
            if p.coded is not None:
                hits |= _keep_or_free(p.group_types, p.coded, ever_set, group_of)
                ever_set |= np.asarray(p.coded, dtype=bool)
            if p.gender:
                hits.add("plane.gender-1")
            if p.frame_rate is not None:
                any_rate = True
                fr = p.frame_rate
                hits.add(
                    "rate.offset" if fr.frequency_offset else "rate.integer" if fr.seconds == 0 else "rate.sixteenths"
                )
                if fr.seconds and fr.frequency_offset:
                    hits.add("rate.sixteenths")
                if prev_rate is not None and fr.rate != prev_rate:
                    hits.add("rate.change")
                prev_rate = fr.rate
            if p.time_code is not None:
                hits.add("timecode.present")
                h, m, _, s = p.time_code
                if (h, m, s) != (0, 0, 0):
                    hits.add("timecode.nonzero")
            if not dct:
                sent = {f for vals in p.new_lists.values() for f in vals}
                for f in p.symbols:
                    if f in sent:
                        continue
                    if np.array_equal(bounds[f - 1], default[f - 1]):
                        hits.add(f"defaults.fap.{f}")  # coded under its default ranges
                    else:
                        hits.add("lists.persist-intra")  # ranges from an earlier plane's lists
                if not p.new_lists:
                    hits.add("lists.none")
                for li, name in enumerate(LIST_ORDER):
                    vals = p.new_lists.get(name)
                    if vals is None:
                        continue
                    hits.add(f"lists.{name}")
                    for fap, v in vals.items():
                        if v == 0:
                            hits.add("lists.value-0")
                        if v == 31:
                            hits.add("lists.value-31")
                        if li % 2 and v:
                            hits.add("lists.min-below-zero")
                        bounds[fap - 1, li] = v * RANGE_DELTA if li % 2 == 0 else -v * RANGE_DELTA
        else:
            hits.add("plane.predicted")
            seen_p = True
        if dct:
            hits.add("dct.segment")
            hits.add("dct.segment-full" if p.segment_length == 16 else "dct.segment-short")
            if not p.is_intra:
                hits.add("dct.predicted")
            if p.coded is not None and (p.coded[0] or p.coded[1]):
                hits.add("dct.highlevel")
            continue
        names = [b[0] for b in p.blocks]
        if {"viseme", "expression", "low-level"} <= set(names):
            hits.add("arith.three-blocks")
        if p.coded is not None and (p.coded[0] or p.coded[1]) and not p.is_intra:
            hits.add("highlevel.predicted")
        if p.coded is not None and (p.coded[0] or p.coded[1]) and p.fap_quant > 1:
            hits.add("highlevel.quantised")
        q = p.fap_quant
        if p.is_intra:
            pred_count = {}
        for f, s in p.symbols.items():
            if s and q and qp[f - 1] > 1:
                hits.add("fap_quant.qp-step")
            i_ab = alphabet(int(bounds[f - 1, 1]), int(bounds[f - 1, 0]), q)
            p_ab = alphabet(int(bounds[f - 1, 3]), int(bounds[f - 1, 2]), q)
            if i_ab != p_ab:
                hits.add("lists.i-not-p" if p.is_intra else "lists.p-not-i")
            if p.is_intra:
                lo, hi = i_ab
                if s == lo:
                    hits.add("symbol.intra-min")
                if s == hi:
                    hits.add("symbol.intra-max")
            else:
                lo, hi = p_ab
                pred_count[f] = pred_count.get(f, 0) + 1
                # an adaptive model starts at one count per symbol and halves at a total of
                # MAX_FREQUENCY before an update (notes §3.3): the update after this many halves it
                if pred_count[f] + (hi - lo + 1) > MAX_FREQUENCY:
                    hits.add("arith.model-rescale")
                if s == lo:
                    hits.add("symbol.predicted-min")
                if s == hi:
                    hits.add("symbol.predicted-max")
                if s == 0:
                    hits.add("symbol.predicted-zero")
        for name, start, length in p.blocks:
            if name in ARITH_BLOCKS:
                if _has_stuffing(data, start, length):
                    hits.add("arith.stuffing")
                if lookahead_stuffing(data, start, length) is not None:
                    hits.add("arith.lookahead-stuffing")
    if len(quants) > 1:
        hits.add("fap_quant.change")
    hits |= _retained_across_quant(planes, frames)
    if planes and not any_rate:
        hits.add("rate.none")
    if len({p.coding_type for p in planes}) > 1:
        hits.add("coding.switch")
    hits |= frames_points(frames)
    hits |= coder_points(data)
    return hits


def _keep_or_free(types, coded, ever_set, group_of) -> set[str]:
    """``mask.keep-or-free``: an intra plane whose group of mask type 01 or 10 leaves out a FAP an
    earlier intra plane coded (D3: 01 keeps it, 10 frees it; never set, both leave it FREE).
    ``group_of``: each FAP's group (1-based), as :func:`tables.group_of_fap` gives it."""
    if len(types) != tables.NUM_GROUPS:
        return set()
    group_type = np.asarray(types)[group_of - 1]
    left = ~np.asarray(coded, dtype=bool) & ever_set & np.isin(group_type, (MASK_RETAIN, MASK_INTERPOLATE))
    return {"mask.keep-or-free"} if left.any() else set()


def stream_points_through(data: bytes, row: int) -> set[str] | None:
    """The points of ``data``'s planes up to and including the one that decodes output frame
    ``row`` (the stream cut after that plane, as a stream without an end code): what a decoder
    had read when it wrote that frame. None when the stream does not decode that far."""
    planes, frames, err, _ = _decode_any(data)
    if err is not None or frames is None or not 0 <= row < len(frames.bit_offset):
        return None
    start = int(frames.bit_offset[row])  # a DCT segment's frames all come from its one plane
    plane = next((p for p in planes if p.bit_offset == start), None)
    if plane is None:
        return None
    end = plane.end_offset
    cut = bytearray(data[: (end + 7) // 8])
    if end % 8:
        cut[-1] &= 0xFF << (8 - end % 8) & 0xFF  # the rest of the last byte zero: read as padding
    return stream_points(bytes(cut))


def _retained_across_quant(planes, frames) -> set[str]:
    """``retained.quant-change``: a FAP holds (RETAINED) in a plane of another fap_quant than the
    plane that last set it — the held value is the dequantised one, not re-scaled (notes §3.3)."""
    if frames is None or len(frames) != len(planes):
        return set()
    quant, last = None, {}
    for k, p in enumerate(planes):
        if p.is_intra:
            quant = p.fap_quant
        st = frames.status[k]
        for j in np.nonzero(st == SET)[0]:
            last[int(j)] = quant
        for j in np.nonzero(st == RETAINED)[0]:
            if last.get(int(j), quant) != quant:
                return {"retained.quant-change"}
    return set()


def text_points(text: str) -> set[str]:
    """The forms of a raw .fap text (players): what real tools write (docs/fap-text.md)."""
    hits: set[str] = set()
    if "\r\n" in text:
        hits.add("text.crlf")
    lines = [ln.split("#", 1)[0].strip() for ln in text.replace("\r\n", "\n").split("\n")]
    raw = [ln.strip() for ln in text.replace("\r\n", "\n").split("\n")]
    if any(ln.startswith("#") for ln in raw[1:]) or any("#" in ln and not ln.startswith("#") for ln in raw):
        hits.add("text.comment")
    body = [ln for ln in lines if ln]
    if not body:
        return hits
    head = body[0].split()
    if head and head[0] in ("2.0", "2.1", "2.2"):
        hits.add(f"text.version-{head[0]}")
    if len(head) > 4:
        hits.add("text.name-spaces")
    if head and head[-1] == "0":
        hits.add("text.count-0")
    rows = body[1:]
    if any(len(r.split()) == 69 and set(r.split()) <= {"0", "1"} for r in rows):
        hits.add("text.mask-69")
    if any(re.search(r"\d\.\d", r) for r in rows):
        hits.add("text.fractional")
    return hits


def raw_text_points(path: Path) -> set[str]:
    """:func:`text_points` of a raw .fap file, plus what its reading shows: frame numbers past
    the header's count, gaps (frames held), values wrapped over several lines."""
    text = Path(path).read_bytes().decode("utf-8", errors="replace")
    hits = text_points(text)
    try:
        frames, header, _warnings = read_fap_text(text)
    except FbaconfInputError:
        return hits
    fn = np.asarray(frames.frame_number)
    if header.declared_frames and len(fn) and (fn >= header.declared_frames).any():
        hits.add("text.frame-past-count")
    if len(fn) > 1 and (np.diff(fn) > 1).any():
        hits.add("text.gap")
    body = [ln for ln in (x.split("#", 1)[0].strip() for x in text.splitlines()) if ln]
    if len(body) > 1 + 2 * len(frames):
        hits.add("text.wrapped")
    return hits


def _has_stuffing(data: bytes, start: int, length: int) -> bool:
    bits = np.unpackbits(np.frombuffer(data, dtype=np.uint8))
    seg = bits[start : start + length]
    zeros = 0
    k = 0
    while k < len(seg):
        if seg[k]:
            zeros = 0
        else:
            zeros += 1
            if zeros == ZERO_RUN_LIMIT:
                return True
        k += 1
    return False


def frames_points(frames) -> set[str]:
    """Points of decoded FapFrames: FAPs set, negatives, statuses, visemes/expressions."""
    hits: set[str] = set()
    st = frames.status
    if st.size == 0:
        return hits
    for j in np.nonzero((st == SET).any(axis=0))[0]:
        hits.add(f"fap.{j + 1}")
    neg = ((frames.values < 0) & (st != FREE)).any(axis=0)
    for j in np.nonzero(neg)[0]:
        if j >= 2:
            hits.add(f"fap.{j + 1}.negative")
    if (st == RETAINED).any():
        hits.add("status.retained")
    ever = np.logical_or.accumulate(st == SET, axis=0)
    if ((st == FREE) & np.vstack([np.zeros((1, st.shape[1]), bool), ever[:-1]])).any():
        hits.add("status.free-after-set")
    if (~ever[-1]).any():
        hits.add("status.free-never-set")
    h = frames.high
    vis = st[:, 0] != FREE
    exp = st[:, 1] != FREE
    for v in np.unique(np.concatenate([h[vis, 0], h[vis, 1]])):
        hits.add(f"viseme.{int(v)}")
    for v in np.unique(np.concatenate([h[exp, 4], h[exp, 6]])):
        hits.add(f"expression.{int(v)}")
    if vis.any():
        if (h[vis, 2] == 0).any():
            hits.add("highlevel.blend-0")
        if (h[vis, 2] == 63).any():
            hits.add("highlevel.blend-max")
        if (h[vis, 3] != 0).any():
            hits.add("highlevel.viseme_def")
    if exp.any():
        ints = np.concatenate([h[exp, 5], h[exp, 7]])
        if (ints == 0).any():
            hits.add("highlevel.intensity-0")
        if (ints == 63).any():
            hits.add("highlevel.intensity-max")
        if (h[exp, 8] != 0).any():
            hits.add("highlevel.init_face")
        if (h[exp, 9] != 0).any():
            hits.add("highlevel.expression_def")
    return hits


# ------------------------------------------------------------------ claims, limits, diagnostics


def claim_points(data: bytes | None, scene_path: Path | None, faces: int = 1, face_streams=None) -> tuple[set, dict]:
    """Smallest-claim and level-limit points from the checker; returns (hits, measures)."""
    ps = load_profiles()
    hits: set[str] = set()
    streams = face_streams or [data]
    top = ps.claims()[-1]
    measures: dict[str, float] = {}
    smallest = []
    for i, s in enumerate(streams):
        rep = analyse(s, scene=str(scene_path) if (scene_path and i == 0) else None, claim=top, smallest_claim=True)
        for row in rep.summary.get("limits", []):
            if row["measured"] is not None:
                measures[row["limit"]] = max(measures.get(row["limit"], 0.0), float(row["measured"]))
        if rep.smallest_claim is not None:
            smallest.append(rep.smallest_claim)
    measures["faces"] = float(max(faces, measures.get("faces", 1.0)))
    # the smallest claim admitting the case: every stream, and the number of faces
    if smallest:
        need = max(smallest)
        for c in ps.claims():
            if c >= need and all(
                measures[lim.id] <= lim.value(c.level) + 1e-9 for lim in ps.limits_for(c) if lim.id == "faces"
            ):
                hits.add(f"claim.{c}")
                break
    for lim in ps.limits_for(top):
        if lim.bounds == "decoder" or lim.kind != "max" or lim.id not in measures:
            continue
        for level in ps.levels:
            limit = float(lim.value(level))
            m = measures[lim.id]
            if lim.id == "bitrate":
                if (1 - BITRATE_BAND) * limit <= m <= limit + 1e-9:
                    hits.add(f"limit.{lim.id}@{level}")
            elif abs(m - limit) < 1e-9:
                hits.add(f"limit.{lim.id}@{level}")
    return hits, measures


def diagnostic_points(data: bytes, scene_path: Path | None, error_case: bool) -> tuple[set, set]:
    """(points, codes): checker codes of a stream -> diag.* (valid streams) or error.* points."""
    rep = analyse(data, scene=None)
    codes = {d.code for d in rep.diagnostics}
    prefix = "error." if error_case else "diag."
    return {prefix + c for c in codes}, codes


# ------------------------------------------------------------------ cases


@dataclass
class CaseCoverage:
    case: str  # full id suite/case
    claim: str
    points: set[str] = field(default_factory=set)
    codes: set[str] = field(default_factory=set)
    measures: dict[str, float] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)


def case_points(case) -> CaseCoverage:
    """Coverage points hit by one conformance case (computed from its files)."""
    cc = CaseCoverage(case.full_id, case.claim)
    hits = cc.points
    try:
        if case.kind == CaseKind.ERROR and case.input_path("fba") is None and case.input_path("fap") is not None:
            hits.add("text.fap")  # an invalid .fap text (players): the rule its reading breaks
            hits |= raw_text_points(case.input_path("fap"))
            try:
                read_fap_file(case.input_path("fap"))
            except FbaconfInputError as e:
                hits.add(f"error.{e.rule}")
            return cc
        if case.kind == CaseKind.ERROR:
            data = case.input_path("fba").read_bytes()
            pts, cc.codes = diagnostic_points(data, None, True)
            hits |= pts
            return cc
        if case.kind == CaseKind.MULTI:
            streams = [p.read_bytes() for p in case.face_paths()]
            hits.add("faces.multi")
            states = set()
            for s in streams:
                pts = stream_points(s)
                hits |= pts
                states.add(frozenset(x for x in pts if x.startswith(("fap_quant.", "mask.", "lists.", "rate."))))
            if len(states) > 1:
                hits.add("faces.states-differ")  # the faces' decoder states differ: no shared state
            h, cc.measures = claim_points(None, None, faces=len(streams), face_streams=streams)
            hits |= h
            return cc
        fba = case.input_path("fba")
        scene = case.input_path("scene")
        if case.input_path("fap") is not None:
            hits.add("text.fap")
            if case.group == "text":  # a raw file in a form real tools write, not fbaconf's rewrite
                hits |= raw_text_points(case.input_path("fap"))
        frames = None
        if fba is not None:
            data = fba.read_bytes()
            hits |= stream_points(data)
            pts, cc.codes = diagnostic_points(data, None, False)
            hits |= pts
            h, cc.measures = claim_points(data, scene)
            hits |= h
            _, frames, _, _ = _decode_any(data)
        elif case.input_path("fap") is not None:
            frames = read_fap_file(case.input_path("fap"))[0]
            hits |= frames_points(frames)
        if "vertices" in case.stages or "images" in case.stages or scene is not None:
            hits |= scene_points(scene, frames)
    except Exception as e:  # noqa: BLE001 - a coverage tool must report, not crash
        cc.problems.append(f"{type(e).__name__}: {e}")
    return cc


def case_coverages(suites=None) -> list[tuple]:
    """(case, CaseCoverage) of every case of the suites (default: the built ones)."""
    suites = suites if suites is not None else load_suites()
    return [(c, case_points(c)) for s in suites for c in s.cases]


def compute(suites=None, model: list[Point] | None = None, computed: list[tuple] | None = None) -> dict:
    """{"points": [...], "cases": [...], "covered": K, "total": N, "unknown": {...}} (of ``computed``,
    the pairs of :func:`case_coverages`, when given)."""
    computed = computed if computed is not None else case_coverages(suites)
    model = model or load_model()
    ids = {p.id for p in model}
    by_point: dict[str, list[str]] = {p.id: [] for p in model}
    cases = []
    unknown: dict[str, list[str]] = {}
    for _, cc in computed:
        cases.append(cc)
        for pid in sorted(cc.points):
            if pid in ids:
                by_point[pid].append(cc.case)
            else:
                unknown.setdefault(pid, []).append(cc.case)
    covered = sum(1 for v in by_point.values() if v)
    return {
        "format": "fbaconf.coverage-report/1",
        "total": len(model),
        "covered": covered,
        "points": [
            {"id": p.id, "clause": p.clause, "description": p.description, "cases": by_point[p.id]} for p in model
        ],
        "cases": [
            {
                "case": c.case,
                "claim": c.claim,
                "points": sorted(c.points & ids),
                "codes": sorted(c.codes),
                "measures": c.measures,
                "problems": c.problems,
            }
            for c in cases
        ],
        "unknown": unknown,
    }


def format_table(rep: dict, width: int = 100) -> str:
    lines = [f"{'coverage point':40s} {'clause':34s} cases"]
    for p in rep["points"]:
        cs = p["cases"]
        shown = ", ".join(cs[:3]) + (f" (+{len(cs) - 3})" if len(cs) > 3 else "") if cs else "-- NOT HIT --"
        lines.append(f"{p['id']:40s} {p['clause'][:34]:34s} {shown}")
    missing = [p for p in rep["points"] if not p["cases"]]
    if missing:
        lines.append("")
        lines.append(f"not hit ({len(missing)}):")
        for p in missing:
            lines.append(f"  {p['id']}: {p['description']} [{p['clause']}]")
    probs = [(c["case"], pr) for c in rep["cases"] for pr in c["problems"]]
    for case, pr in probs:
        lines.append(f"problem: {case}: {pr}")
    lines.append(f"coverage: {rep['covered']}/{rep['total']} points")
    return "\n".join(lines)


__all__ = [
    "Point",
    "load_model",
    "case_points",
    "case_coverages",
    "compute",
    "format_table",
    "stream_points",
    "scene_points",
]
