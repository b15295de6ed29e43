"""Bit-exact reader and writer, MSB first, that always know their bit position.

Also the MPEG-4 start codes and next_start_code() stuffing (spec notes 1.1, decision D1):
stuffing is one '0' bit then '1' bits up to the byte boundary, or the byte 0x7F when
already aligned.
"""

from __future__ import annotations

import re

import numpy as np

from fbaconf.errors import BitstreamError

_NOT_FF = re.compile(rb"[^\xff]")

START_CODE_PREFIX = 0x000001
FACE_OBJECT_START_CODE = 0x000001BA
FACE_OBJECT_PLANE_START_CODE = 0x000001BB
VISUAL_OBJECT_SEQUENCE_END_CODE = 0x000001B1

START_CODE_NAMES = {
    FACE_OBJECT_START_CODE: "face_object_start_code",
    FACE_OBJECT_PLANE_START_CODE: "face_object_plane_start_code",
    VISUAL_OBJECT_SEQUENCE_END_CODE: "visual_object_sequence_end_code",
}


class BitWriter:
    __slots__ = ("_buf", "_acc", "_nacc", "start_codes")

    def __init__(self) -> None:
        self._buf = bytearray()
        self._acc = 0
        self._nacc = 0
        self.start_codes: list[int] = []

    @property
    def position(self) -> int:
        """Number of bits written so far."""
        return len(self._buf) * 8 + self._nacc

    def write(self, value: int, nbits: int) -> None:
        if nbits == 0:
            return
        if value < 0 or value >> nbits:
            raise ValueError(f"value {value} does not fit in {nbits} bits")
        acc = (self._acc << nbits) | value
        n = self._nacc + nbits
        while n >= 8:
            n -= 8
            self._buf.append((acc >> n) & 0xFF)
        self._acc = acc & ((1 << n) - 1)
        self._nacc = n

    def bit(self, b: int) -> None:
        acc = (self._acc << 1) | b
        n = self._nacc + 1
        if n == 8:
            self._buf.append(acc)
            self._acc = 0
            self._nacc = 0
        else:
            self._acc = acc
            self._nacc = n

    def trailing_zeros(self, limit: int = 64) -> int:
        """How many '0' bits end what was written (counted up to ``limit``)."""
        n = 0
        acc, k = self._acc, self._nacc
        while k and n < limit:
            if acc & 1:
                return n
            acc >>= 1
            k -= 1
            n += 1
        i = len(self._buf) - 1
        while i >= 0 and n < limit:
            b = self._buf[i]
            if b:
                return n + ((b & -b).bit_length() - 1)
            n += 8
            i -= 1
        return min(n, limit)

    def next_start_code(self) -> None:
        """Stuffing before a start code: '0' then '1's to the byte boundary (0x7F if aligned)."""
        n = 8 - self._nacc if self._nacc else 8
        self.write((1 << (n - 1)) - 1, n)

    def start_code(self, code: int) -> None:
        """A start code (byte-aligned by the caller); its byte offset is recorded in
        ``start_codes`` (the only places a 0x000001 prefix may stand, D9)."""
        self.start_codes.append(self.position // 8)
        self.write(code, 32)

    def getvalue(self) -> bytes:
        """The bytes written; a final partial byte is padded with zero bits."""
        if self._nacc:
            return bytes(self._buf) + bytes([(self._acc << (8 - self._nacc)) & 0xFF])
        return bytes(self._buf)


class BitReader:
    """Reads an immutable byte string bit by bit. ``pos`` is the bit offset of the next bit.

    Reads past the end raise a truncation error naming the field, except through
    :meth:`peek_bit_lenient`, which returns 0 past the end (the arithmetic decoder's
    look-ahead may run past the last byte; the block end it computes is checked)."""

    __slots__ = ("data", "pos", "nbits", "plane", "frame", "file", "_bits")

    def __init__(self, data: bytes, *, file: str | None = None) -> None:
        self.data = bytes(data)
        self.pos = 0
        self.nbits = len(self.data) * 8
        self.plane: int | None = None
        self.frame: int | None = None
        self.file = file
        self._bits: bytes | None = None

    @property
    def bits(self) -> bytes:
        """The stream as one byte (0 or 1) per bit, for the arithmetic decoder's inner loop."""
        if self._bits is None:
            self._bits = np.unpackbits(np.frombuffer(self.data, dtype=np.uint8)).tobytes()
        return self._bits

    def error(self, message: str, rule: str, *, bit_offset: int | None = None, fap: int | None = None):
        return BitstreamError(
            message,
            bit_offset=self.pos if bit_offset is None else bit_offset,
            rule=rule,
            plane=self.plane,
            frame=self.frame,
            fap=fap,
            file=self.file,
        )

    @property
    def remaining(self) -> int:
        return self.nbits - self.pos

    def read(self, nbits: int, what: str = "field") -> int:
        if nbits == 0:
            return 0
        pos = self.pos
        end = pos + nbits
        if end > self.nbits:
            raise self.error(f"stream ends inside {what} ({nbits} bits needed, {self.nbits - pos} left)", "truncated")
        first = pos >> 3
        last = (end + 7) >> 3
        chunk = int.from_bytes(self.data[first:last], "big")
        value = (chunk >> ((last << 3) - end)) & ((1 << nbits) - 1)
        self.pos = end
        return value

    def bit(self, what: str = "bit") -> int:
        pos = self.pos
        if pos >= self.nbits:
            raise self.error(f"stream ends before {what}", "truncated")
        self.pos = pos + 1
        return (self.data[pos >> 3] >> (7 - (pos & 7))) & 1

    def ones_run(self, at: int | None = None) -> int:
        """How many consecutive '1' bits start at ``at`` (default: pos), up to the stream end."""
        pos = self.pos if at is None else at
        if pos >= self.nbits:
            return 0
        data = self.data
        i, off = pos >> 3, pos & 7
        lead = 8 - ((~(data[i] << off)) & 0xFF).bit_length()  # leading ones of the byte's rest
        if lead < 8 - off:
            return lead
        m = _NOT_FF.search(data, i + 1)
        j = m.start() if m else len(data)
        count = 8 - off + (j - i - 1) * 8
        if m:
            count += 8 - ((~data[j]) & 0xFF).bit_length()
        return min(count, self.nbits - pos)

    def skip_chain(self, what: str = "number_of_frames_to_skip") -> int:
        """A chain of 4-bit chunks where 15 continues and the first chunk < 15 ends it; returns
        the sum. Reads whole runs of 1111 at once (a hostile chain can be megabits long); the
        errors and the final position are those of reading it chunk by chunk."""
        n15 = self.ones_run() // 4
        self.pos += 4 * n15
        return 15 * n15 + self.read(4, what)  # < 15: the run of ones ended inside it

    def peek(self, nbits: int, at: int | None = None) -> int | None:
        """The next nbits at ``at`` (default: pos) without moving, or None past the end."""
        pos = self.pos if at is None else at
        end = pos + nbits
        if end > self.nbits:
            return None
        first = pos >> 3
        last = (end + 7) >> 3
        chunk = int.from_bytes(self.data[first:last], "big")
        return (chunk >> ((last << 3) - end)) & ((1 << nbits) - 1)

    def stuffing_length(self, at: int | None = None) -> int:
        pos = self.pos if at is None else at
        r = pos & 7
        return 8 - r if r else 8

    def start_code_ahead(self, at: int | None = None) -> tuple[int, int] | None:
        """If valid next_start_code() stuffing followed by a start code (0x000001xx) begins at
        ``at``, return (start code, bit length of stuffing + code); else None."""
        pos = self.pos if at is None else at
        n = self.stuffing_length(pos)
        stuff = self.peek(n, pos)
        if stuff is None or stuff != (1 << (n - 1)) - 1:
            return None
        code = self.peek(32, pos + n)
        if code is None or code >> 8 != START_CODE_PREFIX:
            return None
        return code, n + 32
