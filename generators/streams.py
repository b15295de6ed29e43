"""Error and special streams of the suites: mutations of valid streams, edits, and streams no encoder option makes."""

from __future__ import annotations

import random

import numpy as np

from fbaconf.bitstreams import bitedit, tables
from fbaconf.bitstreams.bitedit import end_stream, splice
from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.encoder import EncoderOptions, encode
from fbaconf.bitstreams.frames import SET, FapFrames
from fbaconf.bitstreams.syntax import LIST_ORDER
from fbaconf.bitstreams.synth import synthetic_sequence
from fbaconf.conformance.suite import SuiteError
from fbaconf.errors import BitstreamError
from fbaconf.profiles.sample_streams import stuffing_positions, value_overflow_stream, zero_heavy_plane

from .content import make_content
from .recipes import RECIPES

LIST_MARKERS = sum((len(g.faps) + 3) // 4 for g in tables.groups()[1:])  # 18 per new min/max list


def _hl_stream(n: int, fap: int, fields: dict[int, list[int]]) -> bytes:
    f = FapFrames.empty(n, 30.0)
    f.status[:, fap - 1] = SET
    for col, vals in fields.items():
        f.high[:, col] = vals
    return encode(f, EncoderOptions(plane_start_codes="none")).data


def _intra_then_p(a: bytes, b: bytes) -> bytes:
    """A's intra plane followed by B's first predicted plane (same masks and quantiser)."""
    pa, pb = decode(a).planes, decode(b).planes
    joined = splice((a, 0, pa[0].end_offset), (b, pb[1].bit_offset, pb[1].end_offset))
    return end_stream(joined, pa[0].end_offset + pb[1].end_offset - pb[1].bit_offset)


# a predicted high-level field leaves its range: (FAP, the intra plane's fields, the predicted planes' fields)
_HIGH_LEVEL = {
    "viseme-select": (1, {0: [14]}, {0: [0, 5]}),
    "expression-select": (2, {4: [6]}, {4: [0, 4]}),
    "intensity": (1, {2: [63]}, {2: [0, 30]}),
}


def mutate(data: bytes, mutation: str, seed: int) -> bytes:
    """An invalid stream from a valid one (``data``), or built from scratch, for an error case."""
    planes = decode(data).planes
    hdr = planes[0].header_offset
    if mutation == "truncate:plane1-middle":
        p1, p2 = planes[1], planes[2]
        return bitedit.truncate_bits(data, (p1.header_offset + p2.bit_offset) // 2)
    if mutation == "frame-rate-zero":
        return bitedit.set_bits(data, hdr + 4, 12, 0)
    if mutation == "garbage:plane0":
        rng = random.Random(seed)
        cut = (planes[0].header_offset + 40) // 8
        return data[:cut] + bytes(rng.randrange(256) for _ in range(64))
    if mutation == "too-short":
        return data[:3]
    if mutation == "not-face":
        return b"\x00\x00\x01\xb6" + data[4:]
    if mutation == "object-mask":
        return bitedit.set_bits(data, hdr + 1, 2, 0b11)
    if mutation == "first-predicted":
        return bitedit.flip_bit(data, hdr)
    if mutation == "marker":
        return bitedit.flip_bit(data, planes[0].marker_offsets[0][0])
    if mutation == "unexpected-start-code":
        assert data[-4:] == b"\x00\x00\x01\xb1"
        return data[:-1] + b"\xb6"
    if mutation == "first-predicted-decodable":  # a predicted plane first that decodes under default state
        return first_predicted_decodable()
    if mutation == "trailing-zero-byte":
        return trailing_zero_byte()
    if mutation == "time-code-marker":  # the marker bit between time code minutes and seconds
        at, bit = planes[0].marker_offsets[0]  # the time code's marker is the plane's first
        assert planes[0].time_code is not None and bit == 1
        return bitedit.flip_bit(data, at)
    if mutation == "start-code-stuffing":  # next_start_code(): '0' then '1's up to the byte boundary
        p = planes[1]
        assert p.start_code
        return bitedit.flip_bit(data, p.bit_offset)
    if mutation.startswith("list-marker:"):
        return list_marker(data, mutation)
    if mutation == "time-code-hours":
        assert planes[0].time_code is not None
        return bitedit.set_bits(data, hdr + 18, 5, 24)
    if mutation == "stuffing":
        w = zero_heavy_plane()
        _, start, length = decode(w).planes[0].blocks[-1]
        return bitedit.flip_bit(w, stuffing_positions(w, start, length)[0])
    if mutation == "dct-vlc":
        p = planes[0]
        for _name, start, length in p.blocks:
            for b in range(start, start + length):
                bad = bitedit.flip_bit(data, b)
                try:
                    decode(bad)
                except BitstreamError as e:
                    if e.rule in ("invalid-vlc", "run-overflow", "segment-length", "coefficient-overflow"):
                        return bad
        raise SuiteError("no single-bit corruption of the DCT data found", rule="suite-spec")
    if mutation in _HIGH_LEVEL:
        fap, intra, pred = _HIGH_LEVEL[mutation]
        return _intra_then_p(_hl_stream(1, fap, intra), _hl_stream(2, fap, pred))
    if mutation == "value-overflow":
        return value_overflow_stream()
    raise SuiteError(f"unknown mutation {mutation!r}", rule="suite-spec")


def list_marker(data: bytes, mutation: str) -> bytes:
    """``list-marker:<list>:<k>:<m>``: the m-th of the 18 marker bits (notes §1.4: one before every
    fourth FAP of groups 2-10, masked or not) of new-min/max list ``<list>`` (i_max, i_min, p_max,
    p_min) in the k-th intra plane that sends that list, set to 0."""
    _, name, k, m = mutation.split(":")
    if name not in LIST_ORDER or not 0 <= int(m) < LIST_MARKERS:
        raise SuiteError(f"bad mutation {mutation!r}", rule="suite-spec")
    p = [p for p in decode(data).planes if p.is_intra and name in p.new_lists][int(k)]
    # the plane's markers in stream order: the time code's (if any), one per group mask, then the lists sent
    first = (1 if p.time_code is not None else 0) + len(p.group_types)
    at, bit = p.marker_offsets[first + LIST_MARKERS * list(p.new_lists).index(name) + int(m)]
    assert bit == 1
    return bitedit.flip_bit(data, at)


def first_predicted_decodable() -> bytes:
    """The face object start code, then two predicted planes that code nothing (an intra plane
    coding nothing would make them decodable), then the end code: only D2 makes it invalid."""
    data = encode(FapFrames.empty(3, 25.0), EncoderOptions(plane_start_codes="none")).data
    p = decode(data).planes
    assert p[0].is_intra and not p[1].is_intra and p[0].bit_offset == 32
    joined = splice((data, 0, 32), (data, p[1].bit_offset, p[2].end_offset))
    return end_stream(joined, 32 + p[2].end_offset - p[1].bit_offset)


def trailing_zero_byte() -> bytes:
    """A stream without an end code whose last plane ends on a byte boundary, and one more
    0x00 byte: the byte is neither a plane (fba_object_mask 00) nor next_start_code()."""
    for n in range(2, 60):
        data = encode(synthetic_sequence(n, 25.0, seed=3), EncoderOptions(fap_quant=2, end_code=False)).data
        if decode(data).planes[-1].end_offset == len(data) * 8:
            return data + b"\x00"
    raise SuiteError("no byte-aligned stream end found for trailing-zero-byte", rule="suite-spec")


def edit_valid(data: bytes, edit: str) -> bytes:
    """Bit edits that keep a stream decodable (warnings only): ``no-frame-rate``,
    ``frame-rate-first-only``, ``trailing``, ``time-backwards``, ``quant-no-lists``."""
    planes = decode(data).planes
    if edit in ("no-frame-rate", "frame-rate-first-only"):  # every intra plane, or all but the first
        intra = [p for p in planes if p.is_intra and p.frame_rate is not None]
        if edit == "frame-rate-first-only":
            intra = intra[1:]
        out = data
        removed = 0
        for p in intra:  # drop the 13 frame-rate bits of every intra plane (is_frame_rate = 0)
            h = p.header_offset - removed
            out = bitedit.set_bits(bitedit.remove_bits(out, h + 4, 13), h + 3, 1, 0)
            removed += 13
        return bitedit.end_stream(out, planes[-1].end_offset - removed)
    if edit == "trailing":
        return data + b"\x00\x17"
    if edit == "time-backwards":
        p = [p for p in planes if p.is_intra and p.time_code is not None and p.time_code[3] >= 2][0]
        return bitedit.set_bits(data, p.header_offset + 18 + 12, 6, 0)
    if edit == "quant-no-lists":
        p = next(p for p in planes if p.is_intra and p.index > 0 and len(p.new_lists) == 4)
        first_list = p.marker_offsets[10][0]
        p_min_start = p.marker_offsets[10 + 3 * 18][0]
        block_start = p.blocks[0][1]
        removed = block_start - p_min_start
        out = bitedit.remove_bits(data, p_min_start, removed)
        out = bitedit.set_bits(out, first_list - 1, 1, 0)  # is_p_new_min = 0
        return bitedit.end_stream(out, planes[-1].end_offset - removed)
    raise SuiteError(f"unknown edit {edit!r}", rule="suite-spec")


def special_stream(name: str) -> bytes:
    """Streams that need hand-made frames: ``lookahead`` (a stuffing position in the 14-bit look-ahead
    after the viseme block, FAP-DECISION-005), ``splice-rates`` (the frame rate changes at an intra
    plane: 25 Hz then 12.5 Hz)."""
    if name == "lookahead":
        b = np.zeros((68, 4), dtype=np.int64)
        b[:] = (1860, -1860, 1860, -1860)
        f = FapFrames.empty(1, 30.0)
        f.status[0, 0] = f.status[0, 2] = f.status[0, 3] = SET
        f.high[0, :3] = (0, 3, 32)
        f.values[0, 2], f.values[0, 3] = 1860 * 4, 1860 * 2
        return encode(f, EncoderOptions(fap_quant=1, bounds=b, plane_start_codes="none")).data
    if name == "splice-rates":
        a = encode(
            make_content(
                {
                    "frames": 12,
                    "rate": 25,
                    "seed": 31,
                    "visemes": False,
                    "expressions": False,
                    "faps": list(range(3, 20)),
                }
            ),
            EncoderOptions(fap_quant=2, plane_start_codes="none"),
        )
        b = encode(
            make_content(
                {
                    "frames": 8,
                    "rate": 12.5,
                    "seed": 32,
                    "visemes": False,
                    "expressions": False,
                    "faps": list(range(3, 20)),
                }
            ),
            EncoderOptions(fap_quant=2, plane_start_codes="none"),
        )
        pa, pb = decode(a.data).planes, decode(b.data).planes
        joined = splice((a.data, 0, pa[-1].end_offset), (b.data, pb[0].bit_offset, pb[-1].end_offset))
        return end_stream(joined, pa[-1].end_offset + pb[-1].end_offset - pb[0].bit_offset)
    if name in RECIPES:
        return RECIPES[name]()
    raise SuiteError(f"unknown special stream {name!r}", rule="suite-spec")
