"""Bit-level editing of streams, for building checker test cases (and fuzzing seeds).

All offsets are bit offsets, MSB first (the BitReader convention). Streams are returned as
bytes; a final partial byte is padded with zero bits. Meant for small test streams: the
editing goes through a '0'/'1' text form.
"""
from __future__ import annotations

from fbaconf.bitstreams.bitio import BitWriter, VISUAL_OBJECT_SEQUENCE_END_CODE


def to_bits(data: bytes) -> str:
    return "".join(f"{b:08b}" for b in data)


def from_bits(bits: str) -> bytes:
    if len(bits) % 8:
        bits += "0" * (8 - len(bits) % 8)
    return bytes(int(bits[i:i + 8], 2) for i in range(0, len(bits), 8))


def get_bits(data: bytes, at: int, n: int) -> int:
    s = to_bits(data)[at:at + n]
    if len(s) != n:
        raise ValueError("read past the end")
    return int(s, 2) if n else 0


def set_bits(data: bytes, at: int, n: int, value: int) -> bytes:
    """Overwrite n bits at ``at`` with ``value``."""
    s = to_bits(data)
    if at + n > len(s) or value < 0 or value >> n:
        raise ValueError("bad set_bits")
    return from_bits(s[:at] + format(value, f"0{n}b") + s[at + n:])


def flip_bit(data: bytes, at: int) -> bytes:
    return set_bits(data, at, 1, 1 - get_bits(data, at, 1))


def remove_bits(data: bytes, at: int, n: int) -> bytes:
    s = to_bits(data)
    return from_bits(s[:at] + s[at + n:])


def insert_bits(data: bytes, at: int, value: int, n: int) -> bytes:
    s = to_bits(data)
    return from_bits(s[:at] + format(value, f"0{n}b") + s[at:])


def splice(*parts: tuple[bytes, int, int]) -> bytes:
    """Concatenate bit ranges (data, start, end) of several streams."""
    return from_bits("".join(to_bits(d)[a:b] for d, a, b in parts))


def truncate_bits(data: bytes, n: int) -> bytes:
    """The first n bits (zero-padded to a byte)."""
    return from_bits(to_bits(data)[:n])


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


__all__ = ["end_stream", "flip_bit", "from_bits", "get_bits", "insert_bits", "remove_bits", "set_bits", "splice",
           "to_bits", "truncate_bits"]
