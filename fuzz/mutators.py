"""Mutators of streams: structure-aware (the C mutator, and field-level ones in Python) and byte-level,
with a dictionary of the syntax's tokens."""

from __future__ import annotations

import random
from collections.abc import Callable

from fbaconf.bitstreams.bitedit import bit_range, insert_bits, join_bits, remove_bits, set_bits, truncate_bits

from . import cmutator
from .inputs import STRESS_BYTES, Entry, InputKind
from .model import DICTIONARY, Field


def _pick(rng: random.Random, seq):
    return seq[rng.randrange(len(seq))] if seq else None


def draw(rng: random.Random, corpus: list[Entry], pick: Callable = _pick) -> Entry | None:
    """A corpus entry drawn with ``pick`` (one uniformly by default), a stream of thousands of
    frames (over STRESS_BYTES: it was run as a seed) only when four draws in a row are such
    streams: an input made from one, or spliced or crossed with one, costs the oracle hundreds of
    times another (14-20 KB of a stress stream's planes), and a splice its model (a third of a
    second to build). The loop's parents and the second streams of splices and crossovers."""
    e = None
    for _ in range(4):
        e = pick(rng, corpus)
        if e is None or len(e.data) <= STRESS_BYTES:
            break
    return e


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
    return truncate_bits(e.data, max(0, c))


def m_splice(rng, e: Entry, corpus) -> bytes | None:
    """The first planes of this stream followed by planes of another (state from the wrong stream)."""
    other = draw(rng, corpus)
    if other is None or other.kind != InputKind.STREAM:
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
    "field-value": m_field_value,
    "zero-frame-rate": m_zero_frame_rate,
    "skip-chain": m_skip_chain,
    "mask": m_mask,
    "lists": m_lists,
    "out-of-range-symbols": m_out_of_range,
    "time-code": m_time_code,
    "stuffing": m_stuffing,
    "truncate-plane": m_truncate_plane,
    "splice": m_splice,
    "drop-dup-plane": m_drop_dup_plane,
    "dictionary": m_dictionary,
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
            del b[i : i + rng.choice((1, 1, 2, 4, 16))]
        else:
            b[i:i] = bytes(
                rng.choice((0x00, 0x01, 0xBA, 0xBB, 0xB1, 0xFF, 0x7F, rng.randrange(256)))
                for _ in range(rng.choice((1, 1, 2, 4)))
            )
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
    chunk = src[a : a + rng.randint(1, 64)]
    i = rng.randrange(len(data) + 1)
    return data[:i] + chunk + (data[i:] if rng.random() < 0.5 else data[i + len(chunk) :])


def b_truncate(rng, data: bytes, corpus) -> bytes:
    return data[: rng.randrange(len(data) + 1)]


BYTE_MUTATORS: dict[str, Callable] = {
    "bitflip": b_bitflip,
    "insdel": b_insdel,
    "overwrite": b_overwrite,
    "chunk": b_chunk,
    "truncate": b_truncate,
}


def mutate_stream(
    rng: random.Random, e: Entry, corpus: list[Entry], *, field_share: float = 0.7, native: bool = True
) -> tuple[bytes, str]:
    """One near-valid input from ``e``: a structure-aware mutation (sometimes followed by byte-level
    ones), or byte-level mutations. Returns (data, description).

    The structure-aware share goes to the C mutator (``fba_mutator.c``, the one the exported
    libFuzzer and AFL++ builds use: 1-3 mutations or a crossover, no Python parse of ``e``) when it
    is built (``native`` and a C compiler), with a third left to the Python field mutators (a
    dictionary token, a broken stuffing, a chain of 60,000 skips); without it, all of it to them."""
    names: list[str] = []
    data = None
    if rng.random() < field_share:
        lib = cmutator.library() if native else None
        if lib is not None and rng.random() < 2 / 3:
            other = draw(rng, corpus) if rng.random() < 0.1 else None
            if other is not None and other.kind == InputKind.STREAM and other is not e:
                data = cmutator.cross(lib, e.data, other.data, rng.getrandbits(32))
                names.append("c-cross")
            else:
                data = e.data
                for _ in range(rng.choice((1, 1, 1, 2, 3))):
                    data = cmutator.mutate(lib, data, rng.getrandbits(32))
                names.append("c-structure")
        else:
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
