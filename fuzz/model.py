"""The syntax model of a face-object stream for fuzzing: start codes and header fields found in the
bytes, the features a run reports as its coverage."""

from __future__ import annotations

import collections
import threading
from dataclasses import dataclass

from fbaconf.bitstreams import decoder as dec, tables
from fbaconf.bitstreams.bitio import BitReader
from fbaconf.errors import BitstreamError

START_CODES = {"face_object": 0x000001BA, "plane": 0x000001BB, "end": 0x000001B1}
SKIP_CHUNK_FIELDS = 64  # header_fields: chunks of a skip chain listed one by one (the rest as one field)

# Start codes and header field patterns, as (bit value, bit width, name).
DICTIONARY: list[tuple[int, int, str]] = [
    (0x000001BA, 32, "face_object_start_code"),
    (0x000001BB, 32, "face_object_plane_start_code"),
    (0x000001B1, 32, "visual_object_sequence_end_code"),
    (0x000001, 24, "start_code_prefix"),
    (0x7F, 8, "stuffing byte (aligned next_start_code)"),
    (0x7FBB, 16, "stuffing + plane start code tail"),
    (0b101, 3, "intra plane, fba_object_mask 01"),
    (0b001, 3, "predicted plane, fba_object_mask 01"),
    (0b111, 3, "intra plane, fba_object_mask 11 (BAPs)"),
    (0b1_00011001_0000_0, 14, "is_frame_rate + 25 Hz"),
    (0b1_00000000_0000_0, 14, "is_frame_rate + 0 Hz"),
    (0b1_11111111_1111_1, 14, "is_frame_rate + max rate, offset"),
    (0b1_00000_000000_1_000000, 19, "is_time_code 00:00:00"),
    (0b1_11111_111111_0_111111, 19, "is_time_code 31:63 bad marker 63"),
    (0b1_1111_1111_1111_1111_0000, 21, "skip_frames + chain 15+15+15+15+0"),
    (0b11111, 5, "fap_quant 31"),
    (0b00000, 5, "fap_quant 0"),
    (0b1_11, 3, "marker + mask type 11 (all)"),
    (0b1_00, 3, "marker + mask type 00 (none)"),
    (0b1_01_1111, 7, "marker + mask type 01 + bits"),
    (0b1111, 4, "all four new min/max list flags"),
    (0b11111, 5, "list value 31"),
    (0xFFFF, 16, "ones (arithmetic coder)"),
    (0x0000, 16, "zeros (arithmetic coder)"),
]

ERROR_RULES = (
    "truncated",
    "start-code",
    "object-mask",
    "first-plane-intra",
    "frame-rate-zero",
    "marker",
    "viseme-select-range",
    "expression-select-range",
    "value-overflow",
    "arith-state",
    "stuffing",
    "invalid-vlc",
    "coefficient-overflow",
    "run-overflow",
    "intensity-range",
    "segment-length",
)

# The syntax model's features: what --self and --decoder report as "coverage of the syntax model".
STREAM_FEATURES = (
    "plane:intra",
    "plane:predicted",
    "plane:start-code",
    "plane:frame-rate",
    "plane:frame-rate-offset",
    "plane:frame-rate-sixteenths",
    "plane:time-code",
    "plane:skip",
    "plane:skip-chain",
    "plane:gender",
    "plane:fap_quant-0",
    "plane:fap_quant-31",
    "mask:00",
    "mask:01",
    "mask:10",
    "mask:11",
    "list:i_max",
    "list:i_min",
    "list:p_max",
    "list:p_min",
    "coding:arithmetic",
    "coding:dct",
    "block:viseme",
    "block:expression",
    "block:low-level",
    "stream:end-code",
    "stream:no-end-code",
    "stream:other-end-code",
    "stream:several-intra",
    "stream:ok",
    *(f"rule:{r}" for r in ERROR_RULES),
)
SCENE_FEATURES = (
    "scene:ok",
    "scene:Face",
    "scene:FDP",
    "scene:FIT",
    "scene:FaceDefTables",
    "scene:FaceDefMesh",
    "scene:FaceDefTransform",
    "scene:FAP",
    "scene:IndexedFaceSet",
    "scene:DEF",
    "scene:USE",
    *(
        f"rule:{r}"
        for r in (
            "bt-token",
            "bt-eof",
            "bt-syntax",
            "bt-number",
            "bt-string",
            "bt-unknown-node",
            "bt-unknown-field",
            "bt-node-type",
            "bt-bool",
            "bt-use-undefined",
            "bt-def-duplicate",
            "bt-depth",
            "bt-duplicate-field",
        )
    ),
)


@dataclass
class Field:
    name: str
    offset: int  # bit offset
    width: int
    plane: int
    value: int = 0


@dataclass
class StreamModel:
    """What the syntax model knows of one stream."""

    data: bytes
    planes: list  # PlaneInfo records of the planes decoded completely
    fields: list[Field]
    error_rule: str | None
    end_code: int | None
    end_offset: int
    features: set[str]

    @property
    def nbits(self) -> int:
        return len(self.data) * 8

    def fields_named(self, *names: str) -> list[Field]:
        return [f for f in self.fields if f.name in names]

    def boundaries(self) -> list[int]:
        """Bit offsets of plane starts, plane headers and plane ends (sorted, unique)."""
        out = {32}
        for p in self.planes:
            out.update((p.bit_offset, p.header_offset, p.end_offset))
        return sorted(x for x in out if 0 < x <= self.nbits)


_PARSES: collections.OrderedDict[bytes, tuple] = collections.OrderedDict()
_PARSES_KEEP = 8
_PARSES_LOCK = threading.Lock()


def reference_parse(data: bytes, keep: bool = True):
    """(planes, frames, error rule, end code, end offset) of ``data`` by the reference decoder
    (the planes decoded before an error survive it; frames None on an error). The last few
    parses are kept (``keep``): the coverage features and the oracle of one input share one parse."""
    with _PARSES_LOCK:
        hit = _PARSES.get(data)
        if hit is not None:
            _PARSES.move_to_end(data)
            return hit
    d = dec._Decoder(data, None)
    rule, end_code, end_offset, frames = None, None, 0, None
    try:
        res = d.run()
        end_code, end_offset, frames = res.end_code, res.end_offset, res.frames
    except BitstreamError as e:
        rule = e.rule
        end_offset = e.bit_offset
    except Exception:  # noqa: BLE001 - the decoder's own wrapper turns these into rule "internal"
        rule = "internal"
    out = (tuple(d.planes), frames, rule, end_code, end_offset)
    if not keep:
        return out
    with _PARSES_LOCK:
        _PARSES[data] = out
        while len(_PARSES) > _PARSES_KEEP:
            _PARSES.popitem(last=False)
    return out


def parsed(data: bytes) -> bool:
    """Whether the reference's parse of ``data`` is at hand (its coverage costs nothing)."""
    with _PARSES_LOCK:
        return data in _PARSES


def _parse(data: bytes, keep: bool = True):
    """(planes, error rule, end code, end offset) of ``data`` by the reference decoder."""
    planes, _frames, rule, end_code, end_offset = reference_parse(data, keep)
    return list(planes), rule, end_code, end_offset


def stream_model(data: bytes) -> StreamModel:
    """Parse ``data`` with the reference decoder (planes survive an error) and walk the headers."""
    planes, rule, end_code, end_offset = _parse(data)
    return StreamModel(
        data,
        planes,
        header_fields(data, planes),
        rule,
        end_code,
        end_offset,
        stream_features(planes, end_code, rule, nbytes=len(data)),
    )


def features_of(data: bytes) -> set[str]:
    """The syntax-model features of ``data`` alone (no header walk: what coverage needs). A parse
    made for them is not kept: which parses are at hand (:func:`parsed`) then does not depend on
    whether the coverage helper or the loop made it (fuzz/features_ahead.py)."""
    planes, rule, end_code, _end = _parse(data, keep=False)
    return stream_features(planes, end_code, rule, nbytes=len(data))


def header_fields(data: bytes, planes) -> list[Field]:
    """Every header field of every (completely decoded) plane: name, bit offset, width."""
    r = BitReader(data)
    out: list[Field] = []
    groups = tables.groups()
    for info in planes:
        r.pos = info.header_offset
        idx = info.index

        def rd(name: str, w: int) -> int:
            at = r.pos
            v = r.read(w)
            out.append(Field(name, at, w, idx, v))
            return v

        try:
            if info.start_code:
                out.append(Field("plane_start_code", info.header_offset - 32, 32, idx, START_CODES["plane"]))
                out.append(Field("stuffing", info.bit_offset, info.header_offset - 32 - info.bit_offset, idx))
            intra = rd("is_intra", 1)
            rd("fba_object_mask", 2)
            if intra:
                if rd("is_frame_rate", 1):
                    rd("frame_rate", 8), rd("seconds", 4), rd("frequency_offset", 1)
                if rd("is_time_code", 1):
                    rd("time_code_hours", 5), rd("time_code_minutes", 6), rd("marker_bit", 1)
                    rd("time_code_seconds", 6)
            if rd("skip_frames", 1):
                n15 = r.ones_run() // 4  # chunks of 15: one field each up to 64, then one for the rest
                for _ in range(min(n15, SKIP_CHUNK_FIELDS)):
                    rd("number_of_frames_to_skip", 4)
                if n15 > SKIP_CHUNK_FIELDS:
                    rest = n15 - SKIP_CHUNK_FIELDS
                    out.append(Field("number_of_frames_to_skip", r.pos, 4 * rest, idx, 15))
                    r.pos += 4 * rest
                rd("number_of_frames_to_skip", 4)
            if not intra:
                continue
            rd("fap_quant", 5)
            coded = [False] * 69
            for g in groups:
                rd("marker_bit", 1)
                t = rd("fap_mask_type", 2)
                for fap in g.faps:
                    if t == 3:
                        coded[fap] = True
                    elif t:
                        coded[fap] = bool(rd("fap_mask_bit", 1))
            rd("suggested_gender", 1)
            if rd("coding_type", 1):
                continue
            flags = [rd("list_flag", 1) for _ in range(4)]
            for li in range(4):
                if not flags[li]:
                    continue
                for g in groups[1:]:
                    for j, fap in enumerate(g.faps):
                        if j % 4 == 0:
                            rd("marker_bit", 1)
                        if coded[fap]:
                            rd("list_value", 5)
        except BitstreamError:
            continue
    return out


def stream_features(planes, end_code, rule, nbytes: int = 0) -> set[str]:
    f: set[str] = set()
    n_intra = 0
    for p in planes:
        f.add("plane:intra" if p.is_intra else "plane:predicted")
        n_intra += bool(p.is_intra)
        if p.start_code:
            f.add("plane:start-code")
        if p.frame_rate is not None:
            f.add("plane:frame-rate")
            if p.frame_rate.frequency_offset:
                f.add("plane:frame-rate-offset")
            if p.frame_rate.seconds:
                f.add("plane:frame-rate-sixteenths")
        if p.time_code is not None:
            f.add("plane:time-code")
        if p.skip:
            f.add("plane:skip-chain" if p.skip >= 15 else "plane:skip")
        if p.is_intra:
            if p.gender:
                f.add("plane:gender")
            if p.fap_quant in (0, 31):
                f.add(f"plane:fap_quant-{p.fap_quant}")
            for t in p.group_types:
                f.add(f"mask:{t:02b}")
            for name in p.new_lists:
                f.add(f"list:{name}")
        f.add("coding:dct" if p.coding_type else "coding:arithmetic")
        for b in p.blocks:
            f.add(f"block:{b[0].split()[0]}")
    if n_intra > 1:
        f.add("stream:several-intra")
    if rule:
        f.add(f"rule:{rule}")
    else:
        f.add("stream:ok")
        if end_code == START_CODES["end"]:
            f.add("stream:end-code")
        elif end_code is None:
            f.add("stream:no-end-code")
        else:
            f.add("stream:other-end-code")
    return f
