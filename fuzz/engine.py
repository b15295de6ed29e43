"""Fuzzing of face-object bitstream parsers: decoders under test (``fbaconf fuzz --decoder``) and
fbaconf's own decoder, checker and scene readers (``fbaconf fuzz --self``).

Pieces, in the order an input goes through them:

* **Syntax model** (:func:`stream_model`): the reference decoder's plane records plus a walk of
  every plane header giving each field's bit offset and width (``is_intra``, ``frame_rate``,
  ``number_of_frames_to_skip``, mask types and bits, min/max list values, markers...), the
  plane boundaries and the start codes. BT scenes: the node field tables of
  ``scenes/data/bt_nodes.toml``.
* **Generators**: valid streams from random content and encoder options (:func:`gen_valid`),
  random BT scenes from the node tables (:func:`gen_scene`). The same code backs the
  hypothesis strategies :func:`valid_streams`, :func:`near_valid_streams` and :func:`bt_scenes`
  (a :class:`Chooser` is either a ``random.Random`` or a hypothesis ``draw``).
* **Mutators**: field-aware (:data:`FIELD_MUTATORS`: out-of-range field values, zero frame rate,
  huge skip chains, changed masks, wrong min/max lists, out-of-range symbols through shrunk
  alphabets, time codes, broken stuffing, truncation at plane and field boundaries, splices
  of two streams at plane boundaries, dropped/duplicated planes, dictionary tokens) and
  byte-level (:data:`BYTE_MUTATORS`: bit flips, byte insertions/deletions/overwrites, chunk
  duplication, truncation) over a seed corpus (the conformance suites' streams); a
  dictionary (:data:`DICTIONARY`) of start codes and header field patterns. BT: token-level
  mutations with a dictionary of node and field names.
* **Targets**: :class:`DecoderTarget` runs a decoder adapter under its limits
  (:mod:`sandbox`) and classifies what happened; :class:`SelfTarget` calls fbaconf's own
  parsers in-process.
* **Classification** (:class:`Verdict`): ``crash`` (signal, sanitizer report, uncaught
  exception/panic), ``hang`` (timeout), ``memory`` (memory limit), ``output-blowup``,
  ``unexpected-exit`` (an exit code outside the expected set), ``wrong-output`` (a valid
  input decoded differently from the reference, or rejected), and for ``--self``:
  ``exception`` (anything but a typed FbaconfInputError escaping), ``internal-error``
  (rule ``internal`` / checker ``CHECK-INTERNAL``), ``bad-output``, ``round-trip`` (a
  generated stream not decoding to the encoder's reconstruction), ``slow``.
* **Dedup** by (class, signature): the signature is the signal plus a hash of the stack
  (ASan frames, Python/Go/Rust/Java traces) when the output shows one, else the behaviour
  (signal name, exit code, kind of difference).
* **Minimiser** (:func:`minimise`): prefixes at plane boundaries, then delta debugging on
  bytes, then on bits, keeping the same (class, signature).
* **Findings** (:func:`write_finding`): ``DIR/findings/<id>/`` with the minimal and original
  inputs, ``finding.json`` (classification, messages, origin, seed and input index) and
  ``reproduce.sh``; ``DIR/fuzz.json`` the run's statistics. :func:`promote` turns findings into
  cases of the regression suite (``conformance/data/regression.toml``).

Every input is a pure function of (``--seed``, input index) and of the corpus at that point;
the corpus grows (inputs reaching a syntax feature not seen before) only between batches, in
input order, so a run is reproducible from its seed whatever ``-j`` is (up to the time limit).
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import random
import re
import shlex
import sys
import tempfile
import time
import traceback
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

from fbaconf.errors import BitstreamError, FbaconfInputError
from fbaconf.harness.safefs import remove_tree

# ============================================================================ bit helpers


def _as_int(data: bytes) -> tuple[int, int]:
    return int.from_bytes(data, "big"), len(data) * 8


def _as_bytes(v: int, n: int) -> bytes:
    if n <= 0:
        return b""
    pad = (-n) % 8
    return (v << pad).to_bytes((n + pad) // 8, "big")


def get_bits(data: bytes, at: int, n: int) -> int:
    v, N = _as_int(data)
    if at < 0 or at + n > N:
        raise ValueError("read past the end")
    return (v >> (N - at - n)) & ((1 << n) - 1)


def set_bits(data: bytes, at: int, n: int, value: int) -> bytes:
    v, N = _as_int(data)
    if at < 0 or at + n > N:
        raise ValueError("write past the end")
    value &= (1 << n) - 1
    sh = N - at - n
    v = (v & ~(((1 << n) - 1) << sh)) | (value << sh)
    return _as_bytes(v, N)


def insert_bits(data: bytes, at: int, value: int, n: int) -> bytes:
    v, N = _as_int(data)
    at = max(0, min(at, N))
    lo_n = N - at
    hi, lo = v >> lo_n, v & ((1 << lo_n) - 1)
    return _as_bytes((((hi << n) | (value & ((1 << n) - 1))) << lo_n) | lo, N + n)


def remove_bits(data: bytes, at: int, n: int) -> bytes:
    v, N = _as_int(data)
    at = max(0, min(at, N))
    n = min(n, N - at)
    lo_n = N - at - n
    hi, lo = v >> (N - at), v & ((1 << lo_n) - 1)
    return _as_bytes((hi << lo_n) | lo, N - n)


def cut_bits(data: bytes, n: int) -> bytes:
    v, N = _as_int(data)
    n = max(0, min(n, N))
    return _as_bytes(v >> (N - n), n)


def bit_range(data: bytes, a: int, b: int) -> tuple[int, int]:
    """Bits [a, b) as (value, length)."""
    v, N = _as_int(data)
    a, b = max(0, min(a, N)), max(0, min(b, N))
    if b <= a:
        return 0, 0
    return (v >> (N - b)) & ((1 << (b - a)) - 1), b - a


def join_bits(parts: Iterable[tuple[int, int]]) -> bytes:
    v, n = 0, 0
    for pv, pn in parts:
        v = (v << pn) | pv
        n += pn
    return _as_bytes(v, n)


# ============================================================================ syntax model

START_CODES = {"face_object": 0x000001BA, "plane": 0x000001BB, "end": 0x000001B1}

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

ERROR_RULES = ("truncated", "start-code", "object-mask", "first-plane-intra", "frame-rate-zero", "marker",
               "viseme-select-range", "expression-select-range", "value-overflow", "arith-state", "stuffing",
               "invalid-vlc", "coefficient-overflow", "run-overflow", "intensity-range", "segment-length")

# The syntax model's features: what --self and --decoder report as "coverage of the syntax model".
STREAM_FEATURES = (
    "plane:intra", "plane:predicted", "plane:start-code", "plane:frame-rate", "plane:frame-rate-offset",
    "plane:frame-rate-sixteenths", "plane:time-code", "plane:skip", "plane:skip-chain", "plane:gender",
    "plane:fap_quant-0", "plane:fap_quant-31", "mask:00", "mask:01", "mask:10", "mask:11",
    "list:i_max", "list:i_min", "list:p_max", "list:p_min", "coding:arithmetic", "coding:dct",
    "block:viseme", "block:expression", "block:low-level", "stream:end-code", "stream:no-end-code",
    "stream:other-end-code", "stream:several-intra", "stream:ok",
    *(f"rule:{r}" for r in ERROR_RULES))
SCENE_FEATURES = ("scene:ok", "scene:Face", "scene:FDP", "scene:FIT", "scene:FaceDefTables", "scene:FaceDefMesh",
                  "scene:FaceDefTransform", "scene:FAP", "scene:IndexedFaceSet", "scene:DEF", "scene:USE",
                  *(f"rule:{r}" for r in ("bt-token", "bt-eof", "bt-syntax", "bt-number", "bt-string",
                                           "bt-unknown-node", "bt-unknown-field", "bt-node-type", "bt-bool",
                                           "bt-use-undefined", "bt-def-duplicate", "bt-depth",
                                           "bt-duplicate-field")))


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


def stream_model(data: bytes) -> StreamModel:
    """Parse ``data`` with the reference decoder (planes survive an error) and walk the headers."""
    from fbaconf.bitstreams import decoder as dec
    d = dec._Decoder(data, None)
    rule, end_code, end_offset = None, None, 0
    try:
        res = d.run()
        end_code, end_offset = res.end_code, res.end_offset
    except BitstreamError as e:
        rule = e.rule
        end_offset = e.bit_offset
    except Exception:  # noqa: BLE001 - the decoder's own wrapper turns these into rule "internal"
        rule = "internal"
    planes = list(d.planes)
    fields = header_fields(data, planes)
    return StreamModel(data, planes, fields, rule, end_code, end_offset,
                       stream_features(planes, end_code, rule, nbytes=len(data)))


def header_fields(data: bytes, planes) -> list[Field]:
    """Every header field of every (completely decoded) plane: name, bit offset, width."""
    from fbaconf.bitstreams import tables
    from fbaconf.bitstreams.bitio import BitReader
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
                while rd("number_of_frames_to_skip", 4) == 15:
                    pass
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


# ============================================================================ choosers


class Chooser:
    """Source of choices: :class:`RandomChooser` (the fuzz loop) or :class:`DrawChooser` (hypothesis)."""

    def int(self, lo: int, hi: int) -> int:  # pragma: no cover - interface
        raise NotImplementedError

    def choice(self, seq):
        return seq[self.int(0, len(seq) - 1)]

    def bool(self, p: float = 0.5) -> bool:
        return self.int(0, 999) < int(p * 1000)

    def float(self, lo: float, hi: float) -> float:
        return lo + (hi - lo) * self.int(0, 10**6) / 10**6


class RandomChooser(Chooser):
    def __init__(self, rng: random.Random) -> None:
        self.rng = rng

    def int(self, lo: int, hi: int) -> int:
        return self.rng.randint(lo, hi)


class DrawChooser(Chooser):
    def __init__(self, draw) -> None:
        from hypothesis import strategies as st
        self.draw, self.st = draw, st

    def int(self, lo: int, hi: int) -> int:
        return self.draw(self.st.integers(lo, hi))


# ============================================================================ generators: streams

RATES = (25.0, 30.0, 15.0, 12.5, 10.0, 60.0, 7.5, 24.0, 30000 / 1001, 50.0)


@dataclass
class Entry:
    """A corpus entry / an input: bytes (stream) or text encoded UTF-8 (scene)."""
    data: bytes
    kind: str = "stream"  # stream | scene | bifs
    origin: str = "seed"
    valid: bool | None = None  # True: generated valid stream (reference output = recon)
    recon: Any = None  # encoder reconstruction for generated streams (round-trip oracle)
    model: StreamModel | None = None
    corpus_size: int | None = None  # size of the corpus it was made from (regeneration)

    def get_model(self) -> StreamModel:
        if self.model is None:
            self.model = stream_model(self.data)
        return self.model


def gen_valid(ch: Chooser) -> Entry:
    """A valid stream from random procedural content and random encoder options."""
    import numpy as np
    from fbaconf.bitstreams.encoder import EncoderOptions, encode
    from fbaconf.bitstreams.frames import FREE
    from fbaconf.bitstreams.synth import synthetic_sequence
    n = ch.choice((1, 2, 3, 4, 6, 8, 12)) if ch.bool(0.9) else ch.int(16, 40)
    rate = ch.choice(RATES)
    if ch.bool(0.3):
        faps = None
    else:
        faps = sorted({ch.int(3, 68) for _ in range(ch.int(1, 12))})
    frames = synthetic_sequence(n, rate, visemes=ch.bool(0.4), expressions=ch.bool(0.4), faps=faps,
                                seed=ch.int(0, 50))
    if n > 1 and ch.bool(0.3):  # sparse coding: masks, retained/free FAPs
        k = ch.int(2, 4)
        for row in range(1, n):
            for col in range(2, 68):
                if (row + col) % k:
                    frames.status[row, col] = FREE
    if n > 1 and ch.bool(0.25):  # skipped frames
        gaps = [0] + [ch.choice((1, 1, 1, 2, 5, 16, 40)) for _ in range(n - 1)]
        frames.frame_number[:] = np.cumsum(gaps)
        frames.time_ms[:] = frames.frame_number * 1000.0 / rate
    coding = "dct" if ch.bool(0.15) else "arithmetic"
    opts = EncoderOptions(
        fap_quant=ch.choice((0, 1, 1, 2, 4, 8, 16, 31)), intra_period=ch.choice((0, 0, 1, 2, 5)),
        time_codes=ch.bool(0.3), plane_start_codes=ch.choice(("none", "intra", "all")),
        ranges=ch.choice(("auto", "persist")), partial_mask_type=ch.choice((None, 1, 2)),
        gender=ch.int(0, 1), coding=coding, end_code=ch.bool(0.85),
        frame_rate=None if ch.bool(0.8) else ch.choice(("30000/1001", 12.5, 25)))
    if coding == "arithmetic" and n >= 4 and ch.bool(0.1):
        run = ch.int(1, 3)
        opts.coding_per_frame = ["arithmetic" if (k // run) % 2 == 0 else "dct" for k in range(n)]
    try:
        res = encode(frames, opts)
    except FbaconfInputError:
        res = encode(synthetic_sequence(2, 25.0, visemes=False, expressions=False, faps=[3, 19]),
                     EncoderOptions())
        return Entry(res.data, origin="generate:valid(fallback)", valid=True, recon=res.recon)
    return Entry(res.data, origin=f"generate:valid(n={n},q={opts.fap_quant},{coding})", valid=True,
                 recon=res.recon)


# ============================================================================ mutators: streams

def _pick(rng: random.Random, seq):
    return seq[rng.randrange(len(seq))] if seq else None


def _extreme(rng: random.Random, width: int, old: int) -> int:
    top = (1 << width) - 1
    return rng.choice((0, top, top - 1 if top else 0, 1, (old + 1) & top, (old - 1) & top, rng.randint(0, top)))


def m_field_value(rng, e: Entry, corpus) -> bytes | None:
    """A header field set to an extreme or random value (width kept)."""
    m = e.get_model()
    names = sorted({f.name for f in m.fields if f.width <= 8})
    name = _pick(rng, names)
    if name is None:
        return None
    f = _pick(rng, m.fields_named(name))
    return set_bits(e.data, f.offset, f.width, _extreme(rng, f.width, f.value))


def m_zero_frame_rate(rng, e: Entry, corpus) -> bytes | None:
    """frame_rate = seconds = 0 in an intra plane (inserting the fields when it has none)."""
    m = e.get_model()
    fr = m.fields_named("frame_rate")
    if fr and rng.random() < 0.7:
        f = _pick(rng, fr)
        return set_bits(e.data, f.offset, 12, 0)
    flags = m.fields_named("is_frame_rate")
    f = _pick(rng, [x for x in flags if not x.value])
    if f is None:
        return set_bits(e.data, fr[0].offset, 12, 0) if fr else None
    d = set_bits(e.data, f.offset, 1, 1)
    return insert_bits(d, f.offset + 1, rng.choice((0, 1)), 13)


def m_skip_chain(rng, e: Entry, corpus) -> bytes | None:
    """A long number_of_frames_to_skip chain (15, 15, ..., last < 15) in some plane."""
    m = e.get_model()
    flags = m.fields_named("skip_frames")
    f = _pick(rng, flags[:1] if rng.random() < 0.4 else flags)
    if f is None:
        return None
    k = rng.choice((1, 2, 17, 100, 1000, 5000, 20000, 60000))
    chain = ((1 << (4 * k)) - 1) << 4 | rng.randint(0, 14)
    data = e.data
    if f.value:  # replace the existing chain
        chunks = [x for x in m.fields_named("number_of_frames_to_skip") if x.plane == f.plane]
        n_old = sum(x.width for x in chunks)
        data = remove_bits(data, f.offset + 1, n_old)
    else:
        data = set_bits(data, f.offset, 1, 1)
    return insert_bits(data, f.offset + 1, chain, 4 * k + 4)


def m_mask(rng, e: Entry, corpus) -> bytes | None:
    """A changed fap_mask_type or mask bit (the rest of the header is then misread)."""
    m = e.get_model()
    fs = m.fields_named("fap_mask_type", "fap_mask_bit")
    f = _pick(rng, fs)
    if f is None:
        return None
    return set_bits(e.data, f.offset, f.width, (f.value + rng.randint(1, (1 << f.width) - 1)) & ((1 << f.width) - 1))


def m_lists(rng, e: Entry, corpus) -> bytes | None:
    """Wrong min/max lists: flags toggled (values missing or extra) or values changed."""
    m = e.get_model()
    if rng.random() < 0.5:
        f = _pick(rng, m.fields_named("list_flag"))
        if f is None:
            return None
        return set_bits(e.data, f.offset, 1, 1 - f.value)
    vals = m.fields_named("list_value")
    if not vals:
        return None
    data = e.data
    for f in rng.sample(vals, min(len(vals), rng.randint(1, 6))):
        data = set_bits(data, f.offset, 5, rng.choice((0, 1, 31, rng.randint(0, 31))))
    return data


def m_out_of_range(rng, e: Entry, corpus) -> bytes | None:
    """Symbols out of range: the alphabets shrink under the coded symbols (all list values of an
    intra plane set to 0 or 1, or a coarser fap_quant)."""
    m = e.get_model()
    if rng.random() < 0.5:
        vals = m.fields_named("list_value")
        if vals:
            p = _pick(rng, sorted({f.plane for f in vals}))
            data = e.data
            v = rng.choice((0, 1))
            for f in vals:
                if f.plane == p:
                    data = set_bits(data, f.offset, 5, v)
            return data
    f = _pick(rng, m.fields_named("fap_quant"))
    if f is None:
        return None
    return set_bits(e.data, f.offset, 5, rng.choice((31, 16, min(31, f.value * 2 + 1))))


def m_time_code(rng, e: Entry, corpus) -> bytes | None:
    """Time code fields at extremes (hours/minutes/seconds out of range), or a time code inserted."""
    m = e.get_model()
    tc = m.fields_named("time_code_hours", "time_code_minutes", "time_code_seconds")
    tc += [Field("marker_bit", f.offset + 6, 1, f.plane) for f in tc if f.name == "time_code_minutes"]
    if tc and rng.random() < 0.7:
        f = _pick(rng, tc)
        return set_bits(e.data, f.offset, f.width, _extreme(rng, f.width, f.value))
    f = _pick(rng, [x for x in m.fields_named("is_time_code") if not x.value])
    if f is None:
        return None
    value = (rng.randint(0, 31) << 13) | (rng.randint(0, 63) << 7) | (rng.choice((1, 1, 0)) << 6) | rng.randint(0, 63)
    return insert_bits(set_bits(e.data, f.offset, 1, 1), f.offset + 1, value, 18)


def m_stuffing(rng, e: Entry, corpus) -> bytes | None:
    """Broken next_start_code() stuffing before a plane start code or the end code."""
    m = e.get_model()
    stuff = [f for f in m.fields_named("stuffing") if f.width > 0]
    if m.end_code is not None and m.end_offset >= 40:
        i = e.data.rfind(b"\x00\x00\x01", 0, m.end_offset // 8)
        if i > 0:
            stuff.append(Field("stuffing", (i - 1) * 8, 8, -1))
    f = _pick(rng, stuff)
    if f is None:
        return None
    r = rng.random()
    if r < 0.4:
        return set_bits(e.data, f.offset + rng.randrange(f.width), 1, rng.randint(0, 1)) if f.width else None
    if r < 0.7:
        return remove_bits(e.data, f.offset, f.width)
    return insert_bits(e.data, f.offset, 0x7F, 8)


def m_truncate_plane(rng, e: Entry, corpus) -> bytes | None:
    """Truncation at a plane boundary or a header field boundary (+- a few bits)."""
    m = e.get_model()
    cuts = m.boundaries() + [f.offset for f in m.fields] + [f.offset + f.width for f in m.fields]
    c = _pick(rng, cuts)
    if c is None:
        return None
    c += rng.choice((0, 0, 0, -1, 1, -8, 8))
    return cut_bits(e.data, max(0, c))


def m_splice(rng, e: Entry, corpus) -> bytes | None:
    """The first planes of this stream followed by planes of another (state from the wrong stream)."""
    other = _pick(rng, corpus)
    if other is None or other.kind != "stream":
        return None
    a, b = e.get_model(), other.get_model()
    ca = _pick(rng, [p.end_offset for p in a.planes] or [a.nbits])
    cb = _pick(rng, [p.bit_offset for p in b.planes] or [32])
    return join_bits((bit_range(e.data, 0, ca), bit_range(other.data, cb, other.get_model().nbits)))


def m_drop_dup_plane(rng, e: Entry, corpus) -> bytes | None:
    """A plane removed or repeated (a P plane before any intra, a repeated intra...)."""
    m = e.get_model()
    p = _pick(rng, m.planes)
    if p is None:
        return None
    if rng.random() < 0.5:
        return remove_bits(e.data, p.bit_offset, p.end_offset - p.bit_offset)
    v, n = bit_range(e.data, p.bit_offset, p.end_offset)
    return insert_bits(e.data, p.end_offset, v, n)


def m_dictionary(rng, e: Entry, corpus) -> bytes | None:
    """A dictionary token inserted or written over, at a field boundary, byte boundary or anywhere."""
    v, n, _name = _pick(rng, DICTIONARY)
    m = e.get_model()
    r = rng.random()
    N = len(e.data) * 8
    if r < 0.4 and m.fields:
        at = _pick(rng, m.fields).offset
    elif r < 0.7:
        at = rng.randrange(len(e.data) + 1) * 8
    else:
        at = rng.randrange(N + 1)
    if rng.random() < 0.5 and at + n <= N:
        return set_bits(e.data, at, n, v)
    return insert_bits(e.data, at, v, n)


FIELD_MUTATORS: dict[str, Callable] = {
    "field-value": m_field_value, "zero-frame-rate": m_zero_frame_rate, "skip-chain": m_skip_chain,
    "mask": m_mask, "lists": m_lists, "out-of-range-symbols": m_out_of_range, "time-code": m_time_code,
    "stuffing": m_stuffing, "truncate-plane": m_truncate_plane, "splice": m_splice,
    "drop-dup-plane": m_drop_dup_plane, "dictionary": m_dictionary,
}


def b_bitflip(rng, data: bytes, corpus) -> bytes:
    b = bytearray(data)
    if not b:
        return bytes([rng.randrange(256)])
    for _ in range(rng.choice((1, 1, 2, 3, 8))):
        i = rng.randrange(len(b) * 8)
        b[i >> 3] ^= 0x80 >> (i & 7)
    return bytes(b)


def b_insdel(rng, data: bytes, corpus) -> bytes:
    b = bytearray(data)
    for _ in range(rng.randint(1, 4)):
        i = rng.randrange(len(b) + 1)
        if rng.random() < 0.5 and b:
            del b[i:i + rng.choice((1, 1, 2, 4, 16))]
        else:
            b[i:i] = bytes(rng.choice((0x00, 0x01, 0xBA, 0xBB, 0xB1, 0xFF, 0x7F, rng.randrange(256)))
                           for _ in range(rng.choice((1, 1, 2, 4))))
    return bytes(b)


def b_overwrite(rng, data: bytes, corpus) -> bytes:
    b = bytearray(data)
    if not b:
        return b"\x00"
    for _ in range(rng.randint(1, 4)):
        b[rng.randrange(len(b))] = rng.choice((0x00, 0xFF, 0x7F, 0x80, 0x01, rng.randrange(256)))
    return bytes(b)


def b_chunk(rng, data: bytes, corpus) -> bytes:
    """A chunk of this or another input copied somewhere (splice at byte level)."""
    src = data if rng.random() < 0.5 or not corpus else _pick(rng, corpus).data
    if not src:
        return data
    a = rng.randrange(len(src))
    chunk = src[a:a + rng.randint(1, 64)]
    i = rng.randrange(len(data) + 1)
    return data[:i] + chunk + (data[i:] if rng.random() < 0.5 else data[i + len(chunk):])


def b_truncate(rng, data: bytes, corpus) -> bytes:
    return data[:rng.randrange(len(data) + 1)]


BYTE_MUTATORS: dict[str, Callable] = {"bitflip": b_bitflip, "insdel": b_insdel, "overwrite": b_overwrite,
                                      "chunk": b_chunk, "truncate": b_truncate}


def mutate_stream(rng: random.Random, e: Entry, corpus: list[Entry], *, field_share: float = 0.7) -> tuple[bytes, str]:
    """One near-valid input from ``e``: a field-aware mutation (sometimes followed by byte-level ones),
    or byte-level mutations. Returns (data, description)."""
    names = []
    data = None
    if rng.random() < field_share:
        for _ in range(3):
            name = rng.choice(list(FIELD_MUTATORS))
            try:
                data = FIELD_MUTATORS[name](rng, e, corpus)
            except ValueError:
                data = None
            if data is not None:
                names.append(name)
                break
    if data is None or rng.random() < 0.15:
        base = e.data if data is None else data
        name = rng.choice(list(BYTE_MUTATORS))
        data = BYTE_MUTATORS[name](rng, base, corpus)
        names.append(name)
    return data, "+".join(names)


# ============================================================================ BT scenes

_BT_TOKEN = re.compile(r'"(?:[^"\\]|\\.)*"|#[^\n]*|[\[\]{}]|[^\s\[\]{}"#,]+|\s+|.', re.S)
BT_DICTIONARY = ("Face", "FDP", "FIT", "FAP", "Viseme", "Expression", "FaceDefTables", "FaceDefMesh",
                 "FaceDefTransform", "Group", "Transform", "Shape", "IndexedFaceSet", "Coordinate",
                 "TextureCoordinate", "DEF", "USE", "NULL", "TRUE", "FALSE", "[", "]", "{", "}", '"', '"\\',
                 "fdp", "fit", "fap", "featurePointsCoord", "faceDefTables", "coordIndex", "point", "children",
                 "numeratorTerms", "Graph", "FAPs", "intervalBorders", "displacements", "0x7fffffff",
                 "-2147483649", "99999999999999999999", "1e309", "-1e-320", "nan", "inf", "-0", "0x", "1.5.5",
                 "+", "-", "e", "\\", "\u00e9", "\x00", "#")


def _bt_value(ch: Chooser, ftype: str, allowed, depth: int, defs: list[str]) -> str:
    def num(intlike: bool) -> str:
        if intlike:
            return str(ch.choice((0, 1, -1, 2, 5, 22, 68, ch.int(-300, 300), 2**31 - 1, -2**31)))
        return repr(ch.choice((0.0, 1.0, -1.0, 0.5, ch.float(-100.0, 100.0), 1e-3, 3.4e38)))
    sizes = {"SFVec2f": 2, "SFVec3f": 3, "SFColor": 3, "SFRotation": 4, "MFVec2f": 2, "MFVec3f": 3,
             "MFColor": 3, "MFRotation": 4}
    if ftype == "SFInt32":
        return num(True)
    if ftype in ("SFFloat", "SFTime"):
        return num(False)
    if ftype == "SFBool":
        return ch.choice(("TRUE", "FALSE"))
    if ftype == "SFString":
        return '"' + ch.choice(("", "a", "face.png", 'x\\"y', "\\\\")) + '"'
    if ftype in sizes and ftype.startswith("SF"):
        return " ".join(num(False) for _ in range(sizes[ftype]))
    if ftype == "SFNode":
        if depth > 4 or not allowed or ch.bool(0.2):
            return "NULL" if not defs or ch.bool(0.7) else f"USE {ch.choice(defs)}"
        return _bt_node(ch, ch.choice(allowed), depth + 1, defs)
    n = ch.choice((0, 1, 2, 3, 4, 8))
    if ftype == "MFNode":
        if depth > 4 or not allowed:
            return "[]"
        n = min(n, 2)
        return "[" + " ".join(_bt_node(ch, ch.choice(allowed), depth + 1, defs) for _ in range(n)) + "]"
    if ftype == "MFInt32":
        return "[" + " ".join(num(True) for _ in range(n)) + "]"
    if ftype == "MFFloat":
        return "[" + " ".join(num(False) for _ in range(n)) + "]"
    if ftype in sizes:
        return "[" + ", ".join(" ".join(num(False) for _ in range(sizes[ftype])) for _ in range(n)) + "]"
    if ftype == "MFString":
        return "[" + " ".join('"s"' for _ in range(n)) + "]"
    return "NULL"


def _bt_node(ch: Chooser, ntype: str, depth: int, defs: list[str]) -> str:
    from fbaconf.scenes.bt import node_specs
    specs = node_specs().get(ntype, {})
    names = list(specs)
    if ntype == "FAP" and names:
        names = names[:2] + [ch.choice(names[2:]) for _ in range(3)]
    chosen = [n for n in names if ch.bool(0.5)]
    prefix = ""
    if ch.bool(0.15):
        name = f"N{len(defs)}"
        prefix = f"DEF {name} "
        defs.append(name)  # visible to USE after this node (the reader checks order)
    body = " ".join(f"{n} {_bt_value(ch, specs[n].type, specs[n].allowed, depth, defs)}" for n in dict.fromkeys(chosen))
    return f"{prefix}{ntype} {{ {body} }}"


def gen_scene(ch: Chooser) -> Entry:
    """A BT scene from the node tables: a Face (FDP, FIT, FAP, FaceDefTables...) and/or geometry."""
    from fbaconf.scenes.bt import node_specs
    top = ch.choice(("Face", "Face", "Face", "Group", "Transform", "Shape"))
    if top not in node_specs():
        top = "Face"
    text = "\n".join(_bt_node(ch, top, 0, []) for _ in range(ch.int(1, 2))) + "\n"
    return Entry(text.encode("utf-8"), kind="scene", origin="generate:scene")


def mutate_scene(rng: random.Random, e: Entry, corpus: list[Entry]) -> tuple[bytes, str]:
    """Token-level mutations of BT text (numbers at extremes, tokens dropped/duplicated/swapped,
    dictionary words inserted, deep nesting, truncation), or byte-level ones."""
    text = e.data.decode("utf-8", "replace")
    toks = [t for t in _BT_TOKEN.findall(text)]
    sig = [i for i, t in enumerate(toks) if not t.isspace()]
    r = rng.random()
    if not sig or r < 0.12:
        name = rng.choice(list(BYTE_MUTATORS))
        return BYTE_MUTATORS[name](rng, e.data, corpus), name
    i = _pick(rng, sig)
    if r < 0.35:
        nums = [j for j in sig if re.match(r"[+-]?[0-9.]", toks[j])] or sig
        j = _pick(rng, nums)
        toks[j] = rng.choice(("0", "-1", "2147483648", "-2147483649", "1e309", "nan", "1e-400", "0x10",
                              "99999999999999999999999", "68", "69", "-2", "3.5", "1.", ".5e", "--1"))
        what = "bt-number"
    elif r < 0.5:
        del toks[i]
        what = "bt-drop-token"
    elif r < 0.6:
        toks.insert(i, " " + toks[i] + " ")
        what = "bt-dup-token"
    elif r < 0.8:
        toks.insert(i, " " + rng.choice(BT_DICTIONARY) + " ")
        what = "bt-dictionary"
    elif r < 0.87:
        depth = rng.choice((50, 99, 100, 101, 150, 2000))
        toks.insert(i, " Group { children [ " * depth)
        what = "bt-deep-nesting"
    elif r < 0.94:
        toks = toks[:i]
        what = "bt-truncate"
    else:
        j = _pick(rng, sig)
        toks[i], toks[j] = toks[j], toks[i]
        what = "bt-swap"
    return "".join(toks).encode("utf-8", "surrogatepass"), what


def scene_features(scene=None, rule: str | None = None, text: str = "") -> set[str]:
    f: set[str] = set()
    if rule:
        f.add(f"rule:{rule}")
        return f
    f.add("scene:ok")
    for name in ("Face", "FDP", "FIT", "FaceDefTables", "FaceDefMesh", "FaceDefTransform", "FAP",
                 "IndexedFaceSet"):
        if re.search(rf"\b{name}\s*\{{", text):
            f.add(f"scene:{name}")
    if "DEF " in text:
        f.add("scene:DEF")
    if "USE " in text:
        f.add("scene:USE")
    return f


# ============================================================================ corpus

def conformance_seeds(root: Path | None = None) -> list[Entry]:
    """The conformance suites' streams (``*.fba``) as seed corpus; empty when no suites are built."""
    from fbaconf.conformance.suite import suites_root
    root = Path(root) if root else suites_root()
    out = []
    if root.is_dir():
        for p in sorted(root.glob("*/*.fba")):
            out.append(Entry(p.read_bytes(), origin=f"seed:{p.parent.name}/{p.name}"))
    return out


def scene_seeds(root: Path | None = None, max_bytes: int = 8000) -> list[Entry]:
    """Small BT scenes of the suites plus generated Face-family scenes."""
    from fbaconf.conformance.suite import suites_root
    root = Path(root) if root else suites_root()
    out = []
    if root.is_dir():
        for p in sorted(root.glob("*/*.bt")):
            if p.stat().st_size <= max_bytes:
                out.append(Entry(p.read_bytes(), kind="scene", origin=f"seed:{p.parent.name}/{p.name}"))
    try:
        from fbaconf.scenes import bt
        from fbaconf.conformance.build import make_scene
        for name in ("fit:chain", "calibration:all"):
            out.append(Entry(bt.write(make_scene(name)).encode(), kind="scene", origin=f"seed:make_scene({name})"))
    except Exception:  # noqa: BLE001 - optional seeds
        pass
    rng = RandomChooser(random.Random(7))
    out.extend(gen_scene(rng) for _ in range(4))
    return out


def short_prefixes(entries: list[Entry], max_planes: int = 3) -> list[Entry]:
    """Valid short streams: the first 1..max_planes planes of each entry, then the end code."""
    from fbaconf.profiles.bitedit import end_stream
    out = []
    for e in entries:
        m = e.get_model()
        if m.error_rule:
            continue
        for k in range(1, min(max_planes, len(m.planes)) + 1):
            if k == len(m.planes):
                break
            out.append(Entry(end_stream(e.data, m.planes[k - 1].end_offset), origin=f"{e.origin}[:{k} planes]"))
    return out


def default_seeds() -> list[Entry]:
    seeds = conformance_seeds()
    if not seeds:
        ch = RandomChooser(random.Random(1))
        seeds = [gen_valid(ch) for _ in range(12)]
    return seeds


# ============================================================================ verdicts and targets

CLASSES = ("crash", "hang", "memory", "output-blowup", "unexpected-exit", "accepted-invalid", "wrong-output", "exception",
           "internal-error", "bad-output", "round-trip", "slow")


@dataclass
class Verdict:
    cls: str
    signature: str  # dedup key within the class (signal + stack hash, or behaviour)
    message: str
    detail: dict = field(default_factory=dict)

    @property
    def key(self) -> str:
        return f"{self.cls}:{self.signature}"


class FuzzSetupError(FbaconfInputError):
    """The fuzz run cannot start or continue (decoder not runnable, no seeds...)."""
    rule = "fuzz-setup"


def stack_hash(text: str) -> tuple[str, str] | None:
    """(kind, short hash) of the crash report a decoder printed — the harness's one crash
    classifier (:func:`fbaconf.harness.exits.crash_report`)."""
    from fbaconf.harness.exits import crash_report
    r = crash_report(text)
    return (r.kind, r.signature) if r else None


@dataclass
class ExecResult:
    verdict: Verdict | None
    features: set[str] = field(default_factory=set)


class DecoderTarget:
    """A decoder adapter under its limits (command manifests through the sandbox; in-process
    Python adapters called directly)."""

    def __init__(self, adapter, work_root: Path, *, kind: str = "stream", timeout_s: float | None = None,
                 expected_exit: Iterable[int] | None = None, oracle: bool = True,
                 scene_stream: bytes | None = None) -> None:
        from fbaconf.harness.adapters import CommandAdapter
        from fbaconf.harness.sandbox import Limits
        self.adapter = adapter
        self.kind = kind
        self.work_root = Path(work_root)
        self.work_root.mkdir(parents=True, exist_ok=True)
        lim = adapter.limits
        self.limits = lim if timeout_s is None else Limits(min(lim.timeout_s, timeout_s), lim.memory_mb,
                                                           lim.memory_kind, lim.output_mb, lim.processes)
        # The decoder's documented reject codes (manifest reject_exit_codes), unless overridden;
        # 0 (decoded) and 69 (not supported) are always expected endings.
        self.reject_exit_codes = (frozenset(expected_exit) - {0, 69} if expected_exit is not None
                                  else frozenset(getattr(adapter, "reject_exit_codes", (1, 2))))
        self.oracle = oracle and kind == "stream" and "faps" in adapter.outputs
        self.is_command = isinstance(adapter, CommandAdapter)
        self.scene_stream = scene_stream
        if kind == "stream" and "fba" not in adapter.inputs:
            raise FuzzSetupError(f"decoder {adapter.name} does not accept binary streams (inputs: "
                                 f"{', '.join(adapter.inputs)})")
        if kind == "scene" and "scene" not in adapter.inputs:
            raise FuzzSetupError(f"decoder {adapter.name} accepts no BT scene (inputs: {', '.join(adapter.inputs)})")

    @property
    def name(self) -> str:
        return self.adapter.name

    def ext(self) -> str:
        return "bt" if self.kind == "scene" else "fba"

    # ---------------------------------------------------------------- job
    def _job(self, data: bytes, workdir: Path):
        from fbaconf.harness.adapters import Job
        ind, outd = workdir / "in", workdir / "out"
        ind.mkdir(parents=True)
        outd.mkdir()
        values: dict[str, str] = {}
        if self.kind == "scene":
            sp = ind / "input.bt"
            sp.write_bytes(data)
            fp = ind / "stream.fba"
            fp.write_bytes(self.scene_stream or b"")
            values.update(scene=str(sp), scene_bt=str(sp), fba=str(fp), input=str(fp))
        else:
            fp = ind / "input.fba"
            fp.write_bytes(data)
            values.update(fba=str(fp), input=str(fp))
        ext = "fap" if self.adapter.faps_format == "fap" else "npz"
        values.update(faps_out=str(outd / f"faps.{ext}"), vertices_out=str(outd / "vertices.npz"),
                      images_dir=str(outd / "images"), faps_out_dir=str(outd / "faces"))
        (outd / "images").mkdir()
        (outd / "faces").mkdir()
        return Job(workdir=workdir, values=values, frames=0)

    def argv_for(self, job) -> list[str]:
        try:
            return self.adapter.argv("decode", job)
        except KeyError as e:
            raise FuzzSetupError(f"[commands] decode needs {{{e.args[0]}}}, which a fuzz input does not have") from None

    def execute(self, inp: Entry) -> ExecResult:
        workdir = Path(tempfile.mkdtemp(prefix="x-", dir=self.work_root))
        try:
            job = self._job(inp.data, workdir)
            if self.is_command:
                return ExecResult(self._run_command(inp, job))
            return ExecResult(self._run_python(inp, job))
        finally:
            try:
                remove_tree(workdir)
            except OSError:
                pass

    def _run_command(self, inp: Entry, job) -> Verdict | None:
        from fbaconf.harness import exits, sandbox
        from fbaconf.harness.runner import hidden_from_decoders
        argv = self.argv_for(job)
        res = sandbox.run(argv, job.workdir, self.limits, env=self.adapter.env,
                          view=self.adapter.sandbox_view(argv, job.workdir, hidden=hidden_from_decoders()))
        ending = exits.classify(res, self.limits, self.reject_exit_codes)
        if ending.kind == "setup":
            raise FuzzSetupError(f"cannot run the decoder: {ending.message}")
        detail = {"exit_code": res.returncode, "signal": res.signal, "elapsed_s": round(res.elapsed_s, 3),
                  "maxrss_mb": round(res.maxrss_mb, 1), "stderr_tail": res.stderr_tail[-1500:]}
        return self.verdict_for(ending, inp, job, detail)

    def verdict_for(self, ending, inp: Entry, job, detail: dict) -> Verdict | None:
        """The finding (or None) for one process ending — the run's classifier
        (:mod:`fbaconf.harness.exits`), so fuzz and run judge an ending the same way."""
        k = ending.kind
        rep = ending.report
        if k == "timeout":
            return Verdict("hang", "timeout", ending.message, detail)
        if k == "memory":
            return Verdict("memory", "memory-limit", ending.message, detail)
        if k == "output-limit":
            return Verdict("output-blowup", "output-limit", ending.message, detail)
        if k == "crash":
            sig = ":".join(x for x in (detail.get("signal") or "", rep.kind if rep else "",
                                       rep.signature if rep else "") if x)
            return Verdict("crash", sig or "crash", ending.message, {**detail, "crash_kind": rep.kind if rep else None})
        if k == "unexpected":
            rc = detail.get("exit_code")
            return Verdict("unexpected-exit", f"exit-{rc}", ending.message, detail)
        rc = {"decoded": 0, "not-supported": 69}.get(k, detail.get("exit_code"))
        return self._oracle(inp, job, rc, detail)

    def _run_python(self, inp: Entry, job) -> Verdict | None:
        from fbaconf.harness.adapters import NotSupportedError
        t0 = time.perf_counter()
        try:
            self.adapter.run(job)
            rc = 0
        except NotSupportedError:
            rc = 69
        except FbaconfInputError:
            rc = 2
        except MemoryError:
            return Verdict("memory", "MemoryError", "in-process decoder raised MemoryError")
        except Exception as e:  # noqa: BLE001 - the finding
            tb = traceback.format_exc()
            st = stack_hash(tb)
            return Verdict("crash", f"{type(e).__name__}:{st[1] if st else ''}",
                           f"in-process decoder raised {type(e).__name__}: {e}", {"traceback": tb[-2000:]})
        dt = time.perf_counter() - t0
        if dt > self.limits.timeout_s:
            return Verdict("hang", "timeout", f"in-process decoder took {dt:.1f} s")
        return self._oracle(inp, job, rc, {"exit_code": rc})

    def _oracle(self, inp: Entry, job, rc: int, detail: dict) -> Verdict | None:
        if rc == 69:
            return None
        if rc == 0 and self.kind == "stream":
            rule = reference_rejection(inp)
            if rule is not None:  # as in the run's error cases: decoding garbage silently is a defect
                return Verdict("accepted-invalid", f"rule:{rule}", f"exit code 0 on a stream the reference rejects "
                               f"(rule {rule}): decoded an invalid stream without complaint", detail)
        if not self.oracle:
            return None
        expected = reference_if_valid(inp)
        if expected is None:
            return None
        if rc != 0:
            return Verdict("wrong-output", "rejected-valid", f"rejected a valid stream (exit code {rc})", detail)
        from fbaconf.harness import compare as cmp
        path = job.path("faps_out")
        if path is None or not path.is_file():
            return Verdict("wrong-output", "no-output", "exit code 0 but no FAP output for a valid stream", detail)
        try:
            got = cmp.load_output_faps(path)
        except cmp.OutputError as e:
            return Verdict("wrong-output", "unreadable-output", f"unreadable FAP output: {e}", detail)
        r = cmp.compare_faps(expected, got, text_output=path.suffix.lower() == ".fap")
        if r.outcome.ok:
            return None
        what = (r.first_difference or {}).get("what", "value")
        return Verdict("wrong-output", f"differs:{what}", r.message, {**detail, "first_difference": r.first_difference})


def reference_rejection(inp: Entry) -> str | None:
    """The rule the reference decoder rejects ``inp`` with, or None when it decodes it."""
    from fbaconf.bitstreams.decoder import decode
    if inp.valid:
        return None
    try:
        decode(inp.data)
    except FbaconfInputError as e:
        return e.rule
    return None


def reference_if_valid(inp: Entry):
    """The reference FapFrames when ``inp`` is a valid stream (generated valid, or decoded by the
    reference with no error and no decision-dependent diagnostic), else None."""
    from fbaconf.bitstreams.decoder import decode
    try:
        frames = decode(inp.data).frames
    except FbaconfInputError:
        return None
    if inp.valid:
        return frames
    if len(frames) == 0:  # no plane: nothing to compare, and rejecting it is no defect
        return None
    from fbaconf.profiles.checker import check_stream
    diags = check_stream(inp.data)
    if any(d.severity == "error" or d.code.startswith("FAP-DECISION") for d in diags):
        return None
    return frames


class SelfTarget:
    """fbaconf's own parsers in-process: the decoder (typed errors only, sane output, round trip of
    generated streams), the checker (never raises, no internal diagnostic), the BT scene reader
    and the binary BIFS reader (typed errors only)."""
    name = "self"

    def __init__(self, *, checker_every: int = 4, slow_s: float = 5.0, scene_stream: bytes | None = None) -> None:
        from fbaconf.scenes import bt
        from fbaconf.bitstreams import decoder
        from fbaconf.profiles import checker
        self.bt, self.decoder, self.checker = bt, decoder, checker
        try:
            from fbaconf.scenes import bifs
        except ImportError:  # pragma: no cover - optional stage
            bifs = None
        self.bifs = bifs
        self.checker_every = max(1, checker_every)
        self.slow_s = slow_s
        self.count = 0
        self.scene_stream = scene_stream
        self.kind = "stream"

    def ext(self) -> str:
        return "fba"

    def execute(self, inp: Entry) -> ExecResult:
        self.count += 1
        t0 = time.perf_counter()
        feats: set[str] = set()
        try:
            v = getattr(self, f"_{inp.kind}")(inp, feats)
        except Exception as e:  # noqa: BLE001 - anything escaping is the finding
            tb = traceback.format_exc()
            st = stack_hash(tb)
            where = _innermost_fbaconf_frame(e)
            v = Verdict("exception", f"{inp.kind}:{type(e).__name__}:{where}:{st[1] if st else ''}",
                        f"{inp.kind} parser raised {type(e).__name__}: {e} (at {where})", {"traceback": tb[-3000:]})
        dt = time.perf_counter() - t0
        if v is None and dt > self.slow_s:
            v = Verdict("slow", f"{inp.kind}", f"{inp.kind} input took {dt:.1f} s (> {self.slow_s:g} s)",
                        {"seconds": dt})
        return ExecResult(v, feats)

    def _stream(self, inp: Entry, feats: set[str]) -> Verdict | None:
        import numpy as np
        data = inp.data
        try:
            res = self.decoder.decode(data)
        except FbaconfInputError as e:
            rule = getattr(e, "rule", "?")
            feats.add(f"rule:{rule}")
            if rule == "internal":
                return Verdict("internal-error", f"decoder:{e.message.split(':')[0][:80]}",
                               f"decoder internal failure: {e}")
            res = None
        if res is not None:
            feats |= stream_features(res.planes, res.end_code, None)
            fr = res.frames
            if fr.values.dtype != np.int32 or not np.isfinite(fr.time_ms).all() or len(fr.values) != len(fr.status):
                return Verdict("bad-output", "decoder:frames", "decoded FapFrames malformed (dtype, non-finite "
                               "times or inconsistent lengths)")
            if inp.recon is not None:
                from fbaconf.harness.compare import compare_faps
                r = compare_faps(inp.recon, fr, text_output=False)
                if not r.outcome.ok:
                    return Verdict("round-trip", f"decoder:{(r.first_difference or {}).get('what')}",
                                   f"generated stream decodes differently from the encoder's reconstruction: "
                                   f"{r.message}", {"first_difference": r.first_difference})
        if self.count % self.checker_every == 0:
            return self._check(data, None)
        return None

    def _check(self, data: bytes, scene) -> Verdict | None:
        from fbaconf import rules as R
        rep = self.checker.analyse(data, scene=scene, claim="simple@1" if scene is None else "predictable@2",
                                   smallest_claim=True)
        bad = [d for d in rep.diagnostics if d.code == R.CHECK_INTERNAL or d.code not in R.CODES]
        if bad:
            msg = bad[0].message
            return Verdict("internal-error", f"checker:{re.sub(r'[0-9]+', 'N', msg)[:80]}",
                           f"checker internal failure: {msg}")
        return None

    def _scene(self, inp: Entry, feats: set[str]) -> Verdict | None:
        try:
            text = inp.data.decode("utf-8")
        except UnicodeDecodeError:
            text = inp.data.decode("utf-8", "replace")
        try:
            scene = self.bt.parse(text)
        except FbaconfInputError as e:
            feats.add(f"rule:{getattr(e, 'rule', '?')}")
            return None
        feats |= scene_features(scene, None, text)
        if self.scene_stream is not None and self.count % self.checker_every == 0:
            return self._check(self.scene_stream, scene)
        if self.bifs is not None and hasattr(self.bifs, "encode") and self.count % self.checker_every == 1:
            try:  # a scene the reader accepts either encodes and reads back, or is refused with a typed error
                blob = self.bifs.encode(scene)
            except FbaconfInputError:
                return None
            self.bifs.decode(blob)
        return None

    def _bifs(self, inp: Entry, feats: set[str]) -> Verdict | None:
        if self.bifs is None:
            return None
        try:
            self.bifs.decode(inp.data)
            feats.add("bifs:ok")
        except FbaconfInputError as e:
            feats.add(f"bifs-rule:{getattr(e, 'rule', '?')}")
        return None


def _innermost_fbaconf_frame(e: BaseException) -> str:
    tb = traceback.extract_tb(e.__traceback__)
    for fr in reversed(tb):
        if "fbaconf" in fr.filename or "/work/" in fr.filename:
            return f"{Path(fr.filename).name}:{fr.lineno}"
    return f"{Path(tb[-1].filename).name}:{tb[-1].lineno}" if tb else "?"


# ============================================================================ minimiser

def ddmin(units: list, test: Callable[[list], bool], *, budget: Callable[[], bool]) -> list:
    """Delta debugging (complement removal, Zeller & Hildebrandt) of ``units`` keeping ``test`` true."""
    n = 2
    while len(units) >= 2 and budget():
        chunk = math.ceil(len(units) / n)
        reduced = False
        # try removing chunks from the end first: truncations are the commonest reduction
        for i in reversed(range(0, len(units), chunk)):
            if not budget():
                break
            cand = units[:i] + units[i + chunk:]
            if cand and test(cand):
                units = cand
                n = max(n - 1, 2)
                reduced = True
                break
        if not reduced:
            if n >= len(units):
                break
            n = min(len(units), n * 2)
    return units


@dataclass
class MinimiseStats:
    tests: int = 0
    seconds: float = 0.0
    bytes_before: int = 0
    bytes_after: int = 0


def minimise(data: bytes, test: Callable[[bytes], bool], *, max_tests: int = 600, max_seconds: float = 30.0,
             boundaries: list[int] | None = None, bits: bool = True) -> tuple[bytes, MinimiseStats]:
    """The smallest input found that still passes ``test`` (same classification): prefixes at
    plane boundaries, then ddmin on bytes, then on bits (inputs up to 512 bytes)."""
    t0 = time.perf_counter()
    stats = MinimiseStats(bytes_before=len(data))
    cache: dict[bytes, bool] = {data: True}

    def budget() -> bool:
        return stats.tests < max_tests and time.perf_counter() - t0 < max_seconds

    def t(cand: bytes) -> bool:
        if cand in cache:
            return cache[cand]
        stats.tests += 1
        ok = bool(test(cand))
        cache[cand] = ok
        return ok

    best = data
    for b in sorted(set(boundaries or [])):  # shortest plane-boundary prefix first
        if not budget():
            break
        cand = cut_bits(best, b)
        if len(cand) < len(best) and t(cand):
            best = cand
            break
    if budget():
        best = bytes(ddmin(list(best), lambda u: t(bytes(u)), budget=budget))
    if bits and len(best) <= 512 and budget():
        from fbaconf.profiles.bitedit import from_bits, to_bits
        bl = ddmin(list(to_bits(best)), lambda u: t(from_bits("".join(u))), budget=budget)
        cand = from_bits("".join(bl))
        if len(cand) <= len(best) and t(cand):
            best = cand
    stats.seconds = time.perf_counter() - t0
    stats.bytes_after = len(best)
    return best, stats


# ============================================================================ the engine

@dataclass
class Finding:
    id: str
    verdict: Verdict
    original: Entry
    index: int  # input index (with the seed, regenerates the original)
    found_at_s: float
    hits: int = 1
    minimal: bytes | None = None
    min_stats: MinimiseStats | None = None
    min_verdict: Verdict | None = None
    path: Path | None = None


@dataclass
class Stats:
    execs: int = 0
    started: float = field(default_factory=time.perf_counter)
    findings: int = 0
    hits: int = 0
    features: set[str] = field(default_factory=set)
    universe: tuple[str, ...] = STREAM_FEATURES
    corpus: int = 0
    minimise_s: float = 0.0
    by_origin: dict[str, int] = field(default_factory=dict)

    @property
    def elapsed(self) -> float:
        return time.perf_counter() - self.started

    cpu_started: float = field(default_factory=time.process_time)

    @property
    def rate(self) -> float:
        return self.execs / max(1e-9, self.elapsed - self.minimise_s)

    @property
    def cpu_s(self) -> float:
        return time.process_time() - self.cpu_started

    def coverage(self) -> tuple[int, int]:
        u = set(self.universe)
        return len(self.features & u), len(u)

    def line(self) -> str:
        c, n = self.coverage()
        return (f"[{self.elapsed:6.1f}s] execs {self.execs} ({self.rate:,.0f}/s)  findings {self.findings}"
                f" ({self.hits} hits)  syntax coverage {c}/{n} ({100.0 * c / max(1, n):.0f}%)  corpus {self.corpus}")


class Progress:
    def __init__(self, enabled: bool | None, stream=None) -> None:
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty() if enabled is None else enabled
        self.enabled = enabled is not False
        self.last = 0.0

    def update(self, stats: Stats, force: bool = False) -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        every = 0.25 if self.tty else 10.0
        if not force and now - self.last < every:
            return
        self.last = now
        if self.tty:
            self.stream.write("\r" + stats.line() + "\x1b[K")
        else:
            self.stream.write(stats.line() + "\n")
        self.stream.flush()

    def message(self, text: str) -> None:
        if not self.enabled:
            return
        self.stream.write(("\r\x1b[K" if self.tty else "") + text + "\n")
        self.stream.flush()

    def close(self, stats: Stats) -> None:
        if self.enabled:
            self.update(stats, force=True)
            if self.tty:
                self.stream.write("\n")
                self.stream.flush()


class Fuzzer:
    """The loop: generate a batch of inputs (pure function of seed and index), run it (``jobs`` in
    parallel), then, in input order, record coverage, grow the corpus and handle findings
    (dedup, minimise, write)."""

    def __init__(self, target, seeds: list[Entry], *, seed: int = 0, seconds: float = 60.0, jobs: int = 1,
                 out_dir: Path | None = None, kind: str = "stream", progress: bool | None = None,
                 minimise_seconds: float = 30.0, minimise_tests: int = 600, max_execs: int | None = None,
                 scene_seeds_: list[Entry] | None = None, kinds: tuple[str, ...] | None = None,
                 decoder_info: dict | None = None, max_corpus: int = 400, valid_pool: int = 24,
                 fresh_valid_share: float = 0.04, prefer_short: float = 0.5, run_seeds_first: int = 64,
                 stop_on: Callable[[Finding], bool] | None = None) -> None:
        if not seeds and kind == "stream":
            raise FuzzSetupError("no seed streams (build the suites: fbaconf suites build)")
        self.target = target
        self.seed = int(seed)
        self.seconds = float(seconds)
        self.jobs = max(1, int(jobs))
        self.out_dir = Path(out_dir) if out_dir else None
        self.kinds = kinds or (kind,)
        self.corpus: dict[str, list[Entry]] = {"stream": list(seeds), "scene": list(scene_seeds_ or []),
                                               "bifs": []}
        if "scene" in self.kinds and not self.corpus["scene"]:
            self.corpus["scene"] = scene_seeds()
        if "bifs" in self.kinds:
            self.corpus["bifs"] = _bifs_seeds(self.corpus["scene"])
        self.fresh_valid_share = fresh_valid_share
        self.prefer_short = prefer_short
        self.run_seeds_first = run_seeds_first
        ch = RandomChooser(random.Random(self.seed))
        self.valid_pool = [gen_valid(ch) for _ in range(valid_pool)] if "stream" in self.kinds else []
        self.progress = Progress(progress)
        self.minimise_seconds = minimise_seconds
        self.minimise_tests = minimise_tests
        self.max_execs = max_execs
        self.stop_on = stop_on
        self.stopped = False
        self.max_corpus = max_corpus
        self.findings: dict[str, Finding] = {}
        self.stats = Stats(universe=tuple(u for k in self.kinds for u in
                                          (STREAM_FEATURES if k == "stream" else SCENE_FEATURES if k == "scene"
                                           else ())))
        self.decoder_info = decoder_info or {}
        self.stats.corpus = sum(len(v) for v in self.corpus.values())

    # ---------------------------------------------------------------- generation
    def make_input(self, index: int, corpus_size: int | None = None) -> Entry:
        """Input ``index`` of this seed. The corpus only grows (between batches, in input order),
        so the input depends on the seed, the index and the corpus size then (recorded in each
        finding as ``corpus_size``; pass it to regenerate an input after the run)."""
        kind = self.kinds[index % len(self.kinds)]
        n = len(self.corpus[kind]) if corpus_size is None else corpus_size
        e = self._make_input(index, kind, self.corpus[kind][:n])
        e.corpus_size = n
        return e

    def _make_input(self, index: int, kind: str, corpus: list[Entry]) -> Entry:
        rng = random.Random(self.seed * 1_000_003 + index)
        if kind == "stream":
            n_seed = len(corpus)
            if index < n_seed and index < self.run_seeds_first:  # run the seeds themselves first
                e = corpus[index]
                return Entry(e.data, origin=e.origin, valid=e.valid, recon=e.recon, model=e.model)
            r = rng.random()
            if r < self.fresh_valid_share:  # a new valid stream (encoding is slow: kept rare in-process)
                return gen_valid(RandomChooser(rng))
            if r < 0.06 and self.valid_pool:  # a generated valid stream as it is (round-trip oracle)
                e = self.valid_pool[rng.randrange(len(self.valid_pool))]
                return Entry(e.data, origin=e.origin, valid=True, recon=e.recon, model=e.model)
            if r < 0.12 and self.valid_pool:
                e = self.valid_pool[rng.randrange(len(self.valid_pool))]
            else:
                e = corpus[rng.randrange(n_seed)]
                if rng.random() < self.prefer_short:  # tournament: the shorter of two entries
                    e2 = corpus[rng.randrange(n_seed)]
                    e = e if len(e.data) <= len(e2.data) else e2
            data, how = mutate_stream(rng, e, corpus)
            return Entry(data, origin=f"mutate:{how}<-{e.origin}")
        if kind == "scene":
            if rng.random() < 0.1 or not corpus:
                return gen_scene(RandomChooser(rng))
            e = corpus[rng.randrange(len(corpus))]
            data, how = mutate_scene(rng, e, corpus)
            return Entry(data, kind="scene", origin=f"mutate:{how}<-{e.origin}")
        e = corpus[rng.randrange(len(corpus))] if corpus else Entry(b"", kind="bifs")
        name = rng.choice(list(BYTE_MUTATORS))
        return Entry(BYTE_MUTATORS[name](rng, e.data, corpus), kind="bifs", origin=f"mutate:{name}<-{e.origin}")

    # ---------------------------------------------------------------- loop
    def run(self) -> Stats:
        st = self.stats
        st.started = time.perf_counter()
        st.cpu_started = time.process_time()
        deadline = st.started + self.seconds
        index = 0
        batch = 1 if self.jobs == 1 else 4 * self.jobs
        pool = ThreadPoolExecutor(self.jobs) if self.jobs > 1 else None
        try:
            while (time.perf_counter() < deadline and not self.stopped
                   and (self.max_execs is None or index < self.max_execs)):
                n = batch if self.max_execs is None else min(batch, self.max_execs - index)
                inputs = [self.make_input(index + k) for k in range(n)]
                if pool is None:
                    outs = [self.target.execute(inputs[0])]
                else:
                    outs = list(pool.map(self.target.execute, inputs))
                for k, (inp, out) in enumerate(zip(inputs, outs)):
                    self._record(index + k, inp, out, deadline)
                index += n
                self.progress.update(st)
        finally:
            if pool is not None:
                pool.shutdown(wait=True)
        self.progress.close(st)
        return st

    def _record(self, index: int, inp: Entry, out: ExecResult, deadline: float) -> None:
        st = self.stats
        st.execs += 1
        feats = out.features
        if not feats and inp.kind == "stream" and not isinstance(self.target, SelfTarget):
            m = inp.get_model()  # coverage of the syntax model by what we sent the decoder
            feats = m.features
        elif not feats and inp.kind == "scene" and not isinstance(self.target, SelfTarget):
            feats = _scene_feats_of(inp)
        new = feats - st.features
        if new:
            st.features |= new
            pool = self.corpus[inp.kind]
            if len(inp.data) <= 4096 and len(pool) < self.max_corpus and out.verdict is None:
                pool.append(Entry(inp.data, kind=inp.kind, origin=f"corpus#{index}", valid=inp.valid,
                                  recon=inp.recon))
                st.corpus += 1
        if out.verdict is not None:
            self._finding(index, inp, out.verdict, deadline)

    def _finding(self, index: int, inp: Entry, v: Verdict, deadline: float) -> None:
        st = self.stats
        st.hits += 1
        f = self.findings.get(v.key)
        if f is not None:
            f.hits += 1
            return
        fid = f"{v.cls}-{hashlib.sha256(v.key.encode()).hexdigest()[:8]}"
        f = Finding(fid, v, inp, index, st.elapsed)
        self.findings[v.key] = f
        st.findings += 1
        self.progress.message(f"finding {fid}: {v.cls} ({v.signature}): {v.message[:160]} — input #{index}, "
                              f"{len(inp.data)} bytes, {inp.origin[:80]}")
        t0 = time.perf_counter()
        self._minimise(f, deadline)
        st.minimise_s += time.perf_counter() - t0
        if self.out_dir is not None:
            write_finding(self.out_dir, f, self)
        if self.stop_on is not None and self.stop_on(f):
            self.stopped = True

    def _minimise(self, f: Finding, deadline: float) -> None:
        key = f.verdict.key
        kind = f.original.kind
        last: dict[str, Verdict | None] = {}

        def test(cand: bytes) -> bool:
            out = self.target.execute(Entry(cand, kind=kind, origin="minimise"))
            ok = out.verdict is not None and out.verdict.key == key
            if ok:
                last["v"] = out.verdict
            return ok
        bounds = None
        if kind == "stream":
            try:
                bounds = f.original.get_model().boundaries()
            except Exception:  # noqa: BLE001
                bounds = None
        budget = max(min(self.minimise_seconds, deadline - time.perf_counter()), min(10.0, self.minimise_seconds))
        f.minimal, f.min_stats = minimise(f.original.data, test, max_tests=self.minimise_tests,
                                          max_seconds=budget, boundaries=bounds)
        f.min_verdict = last.get("v", f.verdict)
        self.progress.message(f"  minimised {f.id}: {f.min_stats.bytes_before} -> {f.min_stats.bytes_after} bytes "
                              f"({f.min_stats.tests} tests, {f.min_stats.seconds:.1f} s)")

    def summary(self) -> dict:
        st = self.stats
        c, n = st.coverage()
        return {"format": "fbaconf.fuzz/1", "target": getattr(self.target, "name", "?"), "seed": self.seed,
                "seconds": round(st.elapsed, 2), "fuzz_seconds": round(st.elapsed - st.minimise_s, 2),
                "execs": st.execs, "execs_per_s": round(st.rate, 1), "jobs": self.jobs,
                "cpu_seconds": round(st.cpu_s, 2), "execs_per_cpu_s": round(st.execs / max(1e-9, st.cpu_s), 1),
                "findings": st.findings, "finding_hits": st.hits,
                "syntax_coverage": {"covered": c, "total": n, "features": sorted(st.features),
                                    "missing": sorted(set(st.universe) - st.features)},
                "corpus": st.corpus, "decoder": self.decoder_info,
                "finding_ids": [f.id for f in self.findings.values()]}


def _scene_feats_of(inp: Entry) -> set[str]:
    from fbaconf.scenes import bt
    text = inp.data.decode("utf-8", "replace")
    try:
        scene = bt.parse(text)
    except FbaconfInputError as e:
        return {f"rule:{getattr(e, 'rule', '?')}"}
    return scene_features(scene, None, text)


def _bifs_seeds(scenes: list[Entry]) -> list[Entry]:
    try:
        from fbaconf.scenes import bt
        from fbaconf.scenes import bifs
    except ImportError:  # pragma: no cover
        return []
    out = []
    for e in scenes:
        try:
            out.append(Entry(bifs.encode(bt.parse(e.data.decode("utf-8"))), kind="bifs", origin=f"bifs({e.origin})"))
        except Exception:  # noqa: BLE001 - scenes the BIFS encoder does not cover
            continue
    return out


# ============================================================================ findings on disk

def write_finding(out_dir: Path, f: Finding, fz: Fuzzer) -> Path:
    from fbaconf._atomic import atomic_write_bytes, atomic_write_text
    d = Path(out_dir) / "findings" / f.id
    d.mkdir(parents=True, exist_ok=True)
    ext = {"scene": "bt", "bifs": "bifs"}.get(f.original.kind, "fba")
    atomic_write_bytes(d / f"original.{ext}", f.original.data)
    minimal = f.minimal if f.minimal is not None else f.original.data
    atomic_write_bytes(d / f"minimal.{ext}", minimal)
    target = fz.target
    info = fz.decoder_info
    replay = ["fbaconf", "fuzz"] + (["--self"] if isinstance(target, SelfTarget) else
                                    ["--decoder", str(info.get("manifest") or info.get("name", "?"))])
    if f.original.kind != "stream":
        replay += ["--target", f.original.kind]
    replay += ["--replay", str((d / f"minimal.{ext}").resolve())]
    command = None
    if isinstance(target, DecoderTarget) and target.is_command:
        from fbaconf.harness.adapters import Job
        wd = "/tmp/fbaconf-repro"
        values = {"input": str((d / f"minimal.{ext}").resolve()), "fba": str((d / f"minimal.{ext}").resolve()),
                  "faps_out": f"{wd}/faps.{'fap' if target.adapter.faps_format == 'fap' else 'npz'}",
                  "vertices_out": f"{wd}/vertices.npz", "images_dir": f"{wd}/images", "faps_out_dir": f"{wd}/faces"}
        if f.original.kind == "scene":
            values.update(scene=values["input"], scene_bt=values["input"], input=str((d / "stream.fba").resolve()),
                          fba=str((d / "stream.fba").resolve()))
            atomic_write_bytes(d / "stream.fba", target.scene_stream or b"")
        try:
            command = target.adapter.argv("decode", Job(Path(wd), values))
        except KeyError:
            command = None
        lim = target.limits
        script = ["#!/bin/sh", f"# reproduce finding {f.id}: {f.verdict.cls} ({f.verdict.signature})",
                  f"# limits: timeout {lim.timeout_s:g} s, memory {lim.memory_mb} MB ({lim.memory_kind}), "
                  f"output {lim.output_mb} MB", f"mkdir -p {wd}/images {wd}/faces"]
        if lim.memory_kind == "address-space" and lim.memory_mb:
            script.append(f"ulimit -v {lim.memory_mb * 1024}")
        if command:
            envs = " ".join(f"{k}={shlex.quote(v)}" for k, v in target.adapter.env.items())
            script.append(f"{envs + ' ' if envs else ''}timeout {lim.timeout_s:g} {shlex.join(command)}")
            script.append('echo "exit status: $?"')
        atomic_write_text(d / "reproduce.sh", "\n".join(script) + "\n")
        os.chmod(d / "reproduce.sh", 0o755)
    mv = f.min_verdict or f.verdict
    doc = {
        "format": "fbaconf.fuzz-finding/1", "id": f.id, "class": f.verdict.cls, "signature": f.verdict.signature,
        "message": f.verdict.message, "minimal_message": mv.message, "target": getattr(target, "name", "?"),
        "input_kind": f.original.kind, "decoder": info, "seed": fz.seed, "input_index": f.index, "corpus_size": f.original.corpus_size,
        "origin": f.original.origin, "input_valid": bool(f.original.valid),
        "found_at_s": round(f.found_at_s, 2), "hits": f.hits,
        "original": {"file": f"original.{ext}", "bytes": len(f.original.data),
                     "sha256": hashlib.sha256(f.original.data).hexdigest()},
        "minimal": {"file": f"minimal.{ext}", "bytes": len(minimal), "sha256": hashlib.sha256(minimal).hexdigest()},
        "minimisation": ({"tests": f.min_stats.tests, "seconds": round(f.min_stats.seconds, 2)}
                         if f.min_stats else None),
        "detail": {k: v for k, v in (mv.detail or {}).items()},
        "reproduce": {"fbaconf": shlex.join(replay), "command": command,
                      "regenerate": f"input #{f.index} of seed {fz.seed} (corpus size {f.original.corpus_size})"},
    }
    atomic_write_text(d / "finding.json", json.dumps(doc, indent=1, default=str) + "\n")
    f.path = d
    return d


def write_summary(out_dir: Path, fz: Fuzzer) -> dict:
    from fbaconf._atomic import atomic_write_text
    doc = fz.summary()
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    atomic_write_text(Path(out_dir) / "fuzz.json", json.dumps(doc, indent=1) + "\n")
    return doc


def load_findings(fuzz_dir: Path) -> list[tuple[Path, dict]]:
    out = []
    for p in sorted((Path(fuzz_dir) / "findings").glob("*/finding.json")):
        try:
            out.append((p.parent, json.loads(p.read_text("utf-8"))))
        except (OSError, ValueError) as e:
            raise FuzzSetupError(f"unreadable finding {p}: {e}") from None
    return out


# ============================================================================ promote

REGRESSION_SUITE = "simple-l1-regression"
REGRESSION_HEADER = f"""# fbaconf regression suite: fuzz findings promoted by `fbaconf fuzz --promote DIR`.
#
# Each case is a committed input under conformance/data/regression/ (generator = "file"). With
# `expect` (the error diagnostics fbaconf check gives for it) it is an error case: a decoder must
# terminate cleanly within its limits (reject or conceal) — a crash, hang or memory blow-up fails.
# Without `expect` the input is a valid stream whose reference output becomes the golden.
# Appended by the tool; edit descriptions freely, keep ids stable.

[[suite]]
name = "{REGRESSION_SUITE}"
claim = "simple@1"
group = "regression"
description = "Simple profile, level 1: inputs that crashed, hung or blew up decoders (fuzz findings)"
"""


def _toml_str(s: str) -> str:
    return json.dumps(s, ensure_ascii=False)


def promote(fuzz_dir: Path, data_dir: Path | None = None, *, log: Callable[[str], None] = print) -> list[dict]:
    """Copy each stream finding's minimal input to ``data_dir/regression/<id>.fba`` and append a
    ``[[case]]`` to ``data_dir/regression.toml`` (created with its ``[[suite]]`` table). Returns
    the cases added (ids already present are skipped)."""
    import tomllib
    from fbaconf._atomic import atomic_write_bytes, atomic_write_text
    from fbaconf.bitstreams.decoder import decode
    from fbaconf.profiles.checker import check_stream
    if data_dir is None:
        from fbaconf.conformance.suite import package_root
        data_dir = package_root() / "data"
    data_dir = Path(data_dir)
    reg = data_dir / "regression.toml"
    text = reg.read_text("utf-8") if reg.is_file() else REGRESSION_HEADER
    try:
        existing = {c["id"] for c in tomllib.loads(text).get("case", [])}
    except tomllib.TOMLDecodeError as e:
        raise FuzzSetupError(f"{reg}: not valid TOML: {e}") from None
    findings = load_findings(fuzz_dir)
    if not findings:
        raise FuzzSetupError(f"no findings under {Path(fuzz_dir) / 'findings'}")
    added = []
    for d, doc in findings:
        if doc.get("input_kind", "stream") != "stream":
            log(f"skipped {doc['id']}: a {doc.get('input_kind')} finding (the regression suite holds streams)")
            continue
        cid = f"fuzz-{doc['id']}"
        if cid in existing:
            log(f"skipped {cid}: already in {reg.name}")
            continue
        data = (d / doc["minimal"]["file"]).read_bytes()
        valid = True
        try:
            decode(data)
        except FbaconfInputError:
            valid = False
        codes = sorted({x.code for x in check_stream(data, claim="simple@1") if x.severity == "error"})
        if codes:
            valid = False
        rel = f"regression/{cid}.fba"
        (data_dir / "regression").mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(data_dir / rel, data)
        dec = doc.get("decoder") or {}
        origin = str(doc.get("origin", "")).split("<-")[-1]
        desc = (f"fuzz finding {doc['id']}: {doc['class']} ({doc['signature']}) of decoder "
                f"{dec.get('name', doc.get('target', '?'))}; minimal input of {len(data)} bytes "
                f"(from {origin})")[:300]
        lines = ["", "[[case]]", f"suite = {_toml_str(REGRESSION_SUITE)}", f"id = {_toml_str(cid)}",
                 f"description = {_toml_str(desc)}", 'generator = "file"', f"file = {_toml_str(rel)}"]
        if not valid:
            lines.append("expect = [" + ", ".join(_toml_str(c) for c in codes) + "]")
        text = text.rstrip("\n") + "\n" + "\n".join(lines) + "\n"
        existing.add(cid)
        case = {"id": cid, "file": rel, "valid": valid, "expect": None if valid else codes}
        added.append(case)
        log(f"promoted {cid}: {rel} ({len(data)} bytes, " +
            ("valid stream: decode case, run `fbaconf golden regenerate`" if valid else
             f"error case, expect {codes}") + ")")
    tomllib.loads(text)  # never write a file the suite builder cannot read
    atomic_write_text(reg, text)
    return added


# ============================================================================ replay

def replay(target, data: bytes, kind: str = "stream") -> Verdict | None:
    return target.execute(Entry(data, kind=kind, origin="replay")).verdict


# ============================================================================ hypothesis strategies

def valid_streams():
    """Hypothesis strategy: valid streams (bytes) from the generator (content + encoder options)."""
    from hypothesis import strategies as st
    return st.composite(lambda draw: gen_valid(DrawChooser(draw)).data)()


def valid_entries():
    """Hypothesis strategy: valid stream :class:`Entry` objects (with the encoder's reconstruction)."""
    from hypothesis import strategies as st
    return st.composite(lambda draw: gen_valid(DrawChooser(draw)))()


def near_valid_streams(seeds: list[bytes] | None = None):
    """Hypothesis strategy: a valid stream (generated, or one of ``seeds``) with 1-3 mutations."""
    from hypothesis import strategies as st

    @st.composite
    def strat(draw):
        if seeds and draw(st.booleans()):
            e = Entry(draw(st.sampled_from(seeds)))
        else:
            e = gen_valid(DrawChooser(draw))
        rng = random.Random(draw(st.integers(0, 2**32 - 1)))
        data = e.data
        for _ in range(draw(st.integers(1, 3))):
            data, _how = mutate_stream(rng, Entry(data), [e])
        return data
    return strat()


def bt_scenes(mutated: bool = False):
    """Hypothesis strategy: BT scene text from the node tables (``mutated``: plus token mutations)."""
    from hypothesis import strategies as st

    @st.composite
    def strat(draw):
        e = gen_scene(DrawChooser(draw))
        if mutated:
            rng = random.Random(draw(st.integers(0, 2**32 - 1)))
            data, _ = mutate_scene(rng, e, [e])
            return data.decode("utf-8", "replace")
        return e.data.decode("utf-8")
    return strat()


__all__ = ["BYTE_MUTATORS", "CLASSES", "DICTIONARY", "DecoderTarget", "Entry", "FIELD_MUTATORS", "Finding",
           "FuzzSetupError", "Fuzzer", "SelfTarget", "StreamModel", "Verdict", "bt_scenes", "conformance_seeds",
           "ddmin", "gen_scene", "gen_valid", "minimise", "mutate_scene", "mutate_stream", "near_valid_streams",
           "promote", "replay", "scene_seeds", "short_prefixes", "stack_hash", "stream_model", "valid_streams",
           "write_finding", "write_summary"]
