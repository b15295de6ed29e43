"""The DCT mode's own start-code emulation prevention (decision D9): a ``1`` stuffed after 22
zeros of a plane group's payload, written and removed."""

from __future__ import annotations

# ---------------------------------------------------------------------------- emulation prevention
# D9, the DCT mode's own rule (provisional, fbaconf's design like the rest of the mode): inside a
# plane group's payload (everything after segment_length_minus1's first bit ... its last AC
# code) a '1' is inserted after every 22nd consecutive '0', the zero run counted from the last
# '1' of the stream (so header zeros count); after the payload, a run of 20 or more zeros gets a
# '1' too. A zero run therefore never reaches 23 bits, and no byte-aligned 0x000001 can appear
# across the payload or at its end (the next plane header starts with at most two zeros).
STUFF_AFTER = 22
END_STUFF_FROM = 20


class StuffingWriter:
    """A BitWriter seen through the DCT payload's stuffing rule."""

    def __init__(self, w) -> None:
        self.w = w
        self.run = w.trailing_zeros(STUFF_AFTER)

    @property
    def position(self) -> int:
        return self.w.position

    def bit(self, b: int) -> None:
        self.w.bit(b)
        if b:
            self.run = 0
            return
        self.run += 1
        if self.run == STUFF_AFTER:
            self.w.bit(1)
            self.run = 0

    def write(self, value: int, nbits: int) -> None:
        for i in range(nbits - 1, -1, -1):
            self.bit((value >> i) & 1)

    def end(self) -> None:
        if self.run >= END_STUFF_FROM:
            self.w.bit(1)
            self.run = 0


class StuffingReader:
    """A BitReader seen through the DCT payload's stuffing rule: stuffing bits are read,
    checked ('1', else rule ``dct-stuffing``) and dropped."""

    __slots__ = ("r", "err", "run")

    def __init__(self, r, err) -> None:
        self.r = r
        self.err = err
        run, at = 0, r.pos - 1
        while at >= 0 and run < STUFF_AFTER and r.peek(1, at) == 0:
            run += 1
            at -= 1
        self.run = run

    def __getattr__(self, name):  # anything else is the underlying reader's (read-only through here)
        return getattr(self.r, name)

    @property
    def pos(self) -> int:
        return self.r.pos

    @pos.setter
    def pos(self, value: int) -> None:
        self.r.pos = value

    def _stuffing(self) -> None:
        at = self.r.pos
        if self.r.bit("DCT stuffing bit") != 1:
            raise self.err("DCT stuffing bit after 22 consecutive zeros is not '1' (D9)", "dct-stuffing", at)
        self.run = 0

    def bit(self, what: str = "bit") -> int:
        b = self.r.bit(what)
        if b:
            self.run = 0
        else:
            self.run += 1
            if self.run == STUFF_AFTER:
                self._stuffing()
        return b

    def read(self, nbits: int, what: str = "field") -> int:
        v = 0
        for _ in range(nbits):
            v = (v << 1) | self.bit(what)
        return v

    def end(self) -> None:
        if self.run >= END_STUFF_FROM:
            self._stuffing()
