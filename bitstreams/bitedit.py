"""Bit-level editing of streams: the one copy of the bit helpers the checker's test streams,
the suite builder and the fuzzer use.

All offsets are bit offsets, MSB first (the BitReader convention). Streams are returned as
bytes; a final partial byte is padded with zero bits. Reads past the end raise ValueError;
inserts and removals clamp their offset to the stream.
"""

from __future__ import annotations

from fbaconf.bitstreams.bitio import VISUAL_OBJECT_SEQUENCE_END_CODE, BitWriter


def to_bits(data: bytes) -> str:
    return "".join(f"{b:08b}" for b in data)


def from_bits(bits: str) -> bytes:
    if len(bits) % 8:
        bits += "0" * (8 - len(bits) % 8)
    return bytes(int(bits[i : i + 8], 2) for i in range(0, len(bits), 8))


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
    """Overwrite n bits at ``at`` with ``value`` (its low n bits)."""
    v, N = _as_int(data)
    if at < 0 or at + n > N:
        raise ValueError("write past the end")
    value &= (1 << n) - 1
    sh = N - at - n
    v = (v & ~(((1 << n) - 1) << sh)) | (value << sh)
    return _as_bytes(v, N)


def flip_bit(data: bytes, at: int) -> bytes:
    return set_bits(data, at, 1, 1 - get_bits(data, at, 1))


def remove_bits(data: bytes, at: int, n: int) -> bytes:
    v, N = _as_int(data)
    at = max(0, min(at, N))
    n = min(n, N - at)
    lo_n = N - at - n
    hi, lo = v >> (N - at), v & ((1 << lo_n) - 1)
    return _as_bytes((hi << lo_n) | lo, N - n)


def insert_bits(data: bytes, at: int, value: int, n: int) -> bytes:
    v, N = _as_int(data)
    at = max(0, min(at, N))
    lo_n = N - at
    hi, lo = v >> lo_n, v & ((1 << lo_n) - 1)
    return _as_bytes((((hi << n) | (value & ((1 << n) - 1))) << lo_n) | lo, N + n)


def bit_range(data: bytes, a: int, b: int) -> tuple[int, int]:
    """Bits [a, b) as (value, length)."""
    v, N = _as_int(data)
    a, b = max(0, min(a, N)), max(0, min(b, N))
    if b <= a:
        return 0, 0
    return (v >> (N - b)) & ((1 << (b - a)) - 1), b - a


def join_bits(parts) -> bytes:
    """Concatenate (value, length) bit runs."""
    v, n = 0, 0
    for pv, pn in parts:
        v = (v << pn) | pv
        n += pn
    return _as_bytes(v, n)


def splice(*parts: tuple[bytes, int, int]) -> bytes:
    """Concatenate bit ranges (data, start, end) of several streams."""
    return from_bits("".join(to_bits(d)[a:b] for d, a, b in parts))


def truncate_bits(data: bytes, n: int) -> bytes:
    """The first n bits (zero-padded to a byte)."""
    v, N = _as_int(data)
    n = max(0, min(n, N))
    return _as_bytes(v >> (N - n), n)


def end_stream(data: bytes, end_bit: int, *, end_code: bool = True) -> bytes:
    """The first ``end_bit`` bits, then next_start_code() stuffing and the end code 0x000001B1."""
    s = to_bits(data)[:end_bit]
    if end_code:
        w = BitWriter()
        for ch in s:
            w.bit(int(ch))
        w.next_start_code()
        w.start_code(VISUAL_OBJECT_SEQUENCE_END_CODE)
        return w.getvalue()
    return from_bits(s)


__all__ = [
    "bit_range",
    "end_stream",
    "flip_bit",
    "from_bits",
    "get_bits",
    "insert_bits",
    "join_bits",
    "remove_bits",
    "set_bits",
    "splice",
    "to_bits",
    "truncate_bits",
]
