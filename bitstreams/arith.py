"""The adaptive arithmetic coder of the face object (spec notes section 3, decision D7).

16-bit registers (top 65535, q1 16384, q2 32768, q3 49152), cumulative frequency tables
``c`` in *descending* suffix-sum form (c[0] = total, c[n] = 0), symbol s occupying
[c[s+1], c[s]). Models adapt (P models) by +1 with halving at total 16383.

Start-code emulation prevention: the encoder writes a '1' right after every 22nd
consecutive '0' it emits (eagerly, flush bits included); the decoder removes it.
End of block (D7): the decoder primes 16 bits and reads one per renormalisation, the
encoder's flush makes the block 14 arithmetic bits shorter than what the decoder read,
so the next field starts right after the arithmetic input bit that is 15th from the end
(plus a stuffing bit that directly follows it). A stuffing violation inside those 14
look-ahead bits is not an error: those bits belong to the next field.
"""
from __future__ import annotations

from bisect import bisect_left

import numpy as np

from .bitio import BitReader, BitWriter

TOP = 65535
Q1 = 16384
Q2 = 32768
Q3 = 49152
MAX_FREQUENCY = 16383
ZERO_RUN_LIMIT = 22
LOOKAHEAD = 14  # 16 primed bits - 2 flush bits


class Model:
    """An adaptive frequency model over symbols 0..n-1 (uniform when created).

    ``neg`` holds -c (ascending) so a bisection finds a symbol; ``adaptive`` False gives
    the I-plane model, which codes one symbol per intra plane and is re-created at each
    intra plane, so its adaptation never has an effect (spec notes 3.2)."""

    __slots__ = ("n", "neg", "adaptive", "uniform")

    def __init__(self, n: int, adaptive: bool = True) -> None:
        if n < 1:
            raise ValueError("alphabet must have at least one symbol")
        if n > MAX_FREQUENCY:
            raise ValueError(f"alphabet of {n} symbols exceeds the coder's maximum frequency {MAX_FREQUENCY}")
        self.n = n
        self.adaptive = adaptive
        self.uniform = True
        # c[k] = n - k  ->  neg[k] = k - n
        self.neg = list(range(-n, 1))

    def total(self) -> int:
        return -self.neg[0]

    def bounds(self, s: int) -> tuple[int, int, int]:
        """(c[s], c[s+1], c[0]) for symbol s."""
        neg = self.neg
        return -neg[s], -neg[s + 1], -neg[0]

    def find(self, target: int) -> int:
        """The symbol s with c[s+1] <= target < c[s]."""
        if self.uniform:
            k = self.n - target
            return (k if k > 1 else 1) - 1
        # first k >= 1 with c[k] <= target  <=>  neg[k] >= -target
        return bisect_left(self.neg, -target, 1) - 1

    def update(self, s: int) -> None:
        if not self.adaptive:
            return
        neg = self.neg
        if -neg[0] == MAX_FREQUENCY:
            n = self.n
            freqs = [(neg[k + 1] - neg[k] + 1) >> 1 for k in range(n)]
            acc = 0
            neg[n] = 0
            for k in range(n - 1, -1, -1):
                acc += freqs[k]
                neg[k] = -acc
        for k in range(s + 1):
            neg[k] -= 1
        self.uniform = False


class FastModel(Model):
    """Same model, numpy-backed update (faster for large alphabets)."""

    __slots__ = ("arr",)

    def __init__(self, n: int, adaptive: bool = True) -> None:
        super().__init__(n, adaptive)
        self.arr = np.array(self.neg, dtype=np.int64)

    def total(self) -> int:
        return -int(self.arr[0])

    def bounds(self, s: int) -> tuple[int, int, int]:
        a = self.arr
        return -int(a[s]), -int(a[s + 1]), -int(a[0])

    def find(self, target: int) -> int:
        if self.uniform:
            k = self.n - target
            return (k if k > 1 else 1) - 1
        return int(self.arr.searchsorted(-target)) - 1

    def update(self, s: int) -> None:
        if not self.adaptive:
            return
        a = self.arr
        if -int(a[0]) == MAX_FREQUENCY:
            f = (np.diff(a) + 1) >> 1
            a[:-1] = -np.cumsum(f[::-1])[::-1]
            a[-1] = 0
        a[: s + 1] -= 1
        self.uniform = False


class UniformModel:
    """A non-adaptive uniform model (the I-plane models): c[k] = n - k, no table needed."""

    __slots__ = ("n",)
    uniform = True

    def __init__(self, n: int) -> None:
        if not 1 <= n <= MAX_FREQUENCY:
            raise ValueError(f"alphabet size {n} outside 1..{MAX_FREQUENCY}")
        self.n = n

    def total(self) -> int:
        return self.n

    def bounds(self, s: int) -> tuple[int, int, int]:
        n = self.n
        return n - s, n - s - 1, n

    def find(self, target: int) -> int:
        k = self.n - target
        return (k if k > 1 else 1) - 1

    def update(self, s: int) -> None:
        pass


def make_model(n: int, adaptive: bool = True) -> Model:
    """The model class used by encoder and decoder (both produce identical tables)."""
    if not adaptive:
        return UniformModel(n)
    return FastModel(n) if n > 64 else Model(n)


class ArithEncoder:
    """Encodes symbols into a BitWriter. One instance per block: :meth:`flush` ends it."""

    __slots__ = ("w", "low", "high", "pending", "zeros", "arith_bits")

    def __init__(self, writer: BitWriter) -> None:
        self.w = writer
        self.low = 0
        self.high = TOP
        self.pending = 0
        self.zeros = 0
        self.arith_bits = 0  # arithmetic output bits written (stuffing excluded)

    def _emit(self, b: int) -> None:
        w = self.w
        w.bit(b)
        self.arith_bits += 1
        if b:
            self.zeros = 0
        else:
            self.zeros += 1
            if self.zeros == ZERO_RUN_LIMIT:
                w.bit(1)
                self.zeros = 0

    def _bit_plus_follow(self, b: int) -> None:
        self._emit(b)
        if self.pending:
            ob = 1 - b
            for _ in range(self.pending):
                self._emit(ob)
            self.pending = 0

    def encode(self, model: Model, s: int) -> None:
        if not 0 <= s < model.n:
            raise ValueError(f"symbol index {s} outside alphabet of {model.n}")
        hi_c, lo_c, total = model.bounds(s)
        low = self.low
        length = self.high - low + 1
        high = low - 1 + (length * hi_c) // total
        low = low + (length * lo_c) // total
        while True:
            if high < Q2:
                self._bit_plus_follow(0)
            elif low >= Q2:
                self._bit_plus_follow(1)
                low -= Q2
                high -= Q2
            elif low >= Q1 and high < Q3:
                self.pending += 1
                low -= Q1
                high -= Q1
            else:
                break
            low <<= 1
            high = (high << 1) | 1
        self.low = low
        self.high = high
        model.update(s)

    def flush(self) -> None:
        self.pending += 1
        self._bit_plus_follow(0 if self.low < Q1 else 1)
        self.low = 0
        self.high = TOP
        self.zeros = 0


class ArithDecoder:
    """Decodes one block from a BitReader positioned at the block's first bit.

    Call :meth:`finish` after the last symbol: it moves the reader to the first bit after
    the block (D7) and raises for a stuffing violation inside the block. Bits past the end
    of the data read as 0 (look-ahead); :meth:`finish` checks the block itself is complete."""

    __slots__ = ("r", "bits", "nb", "pos", "low", "high", "value", "zeros", "count", "start", "stuffing",
                 "bad_stuffing")

    def __init__(self, reader: BitReader) -> None:
        self.r = reader
        self.bits = reader.bits
        self.nb = reader.nbits
        self.start = self.pos = reader.pos
        self.low = 0
        self.high = TOP
        self.zeros = 0
        self.count = 0  # arithmetic input bits read (stuffing excluded)
        self.stuffing: list[int] = []  # arith bit counts after which a stuffing bit was consumed
        self.bad_stuffing: list[tuple[int, int]] = []  # (arith count, stream bit offset) of '0' stuffing
        v = 0
        for _ in range(16):
            v = (v << 1) | self._bit()
        self.value = v

    def _bit(self) -> int:
        pos = self.pos
        b = self.bits[pos] if pos < self.nb else 0
        self.pos = pos + 1
        self.count += 1
        if b:
            self.zeros = 0
        else:
            self.zeros += 1
            if self.zeros == ZERO_RUN_LIMIT:
                self._stuffing()
        return b

    def _stuffing(self) -> None:
        at = self.pos
        if (self.bits[at] if at < self.nb else 0) != 1:
            self.bad_stuffing.append((self.count, at))
        self.pos = at + 1
        self.stuffing.append(self.count)
        self.zeros = 0

    def decode(self, model) -> int:
        low = self.low
        high = self.high
        value = self.value
        length = high - low + 1
        total = model.total()
        target = ((value - low + 1) * total - 1) // length
        if not 0 <= target < total:
            self.r.pos = self.pos
            raise self.r.error("arithmetic decoder state out of range (corrupt block)", "arith-state")
        s = model.find(target)
        hi_c, lo_c, _ = model.bounds(s)
        high = low - 1 + (length * hi_c) // total
        low = low + (length * lo_c) // total
        bits = self.bits
        nb = self.nb
        pos = self.pos
        zeros = self.zeros
        count = self.count
        while True:
            if high < Q2:
                pass
            elif low >= Q2:
                value -= Q2
                low -= Q2
                high -= Q2
            elif low >= Q1 and high < Q3:
                value -= Q1
                low -= Q1
                high -= Q1
            else:
                break
            low <<= 1
            high = (high << 1) | 1
            b = bits[pos] if pos < nb else 0
            pos += 1
            count += 1
            if b:
                zeros = 0
            else:
                zeros += 1
                if zeros == ZERO_RUN_LIMIT:
                    self.pos, self.count = pos, count
                    self._stuffing()
                    pos = self.pos
                    zeros = 0
            value = (value << 1) | b
        self.pos = pos
        self.zeros = zeros
        self.count = count
        self.low = low
        self.high = high
        self.value = value
        model.update(s)
        return s

    def finish(self) -> int:
        """Reposition the reader after the block; return the block's length in bits."""
        r = self.r
        used = self.count - LOOKAHEAD
        for count, at in self.bad_stuffing:
            if count <= used:
                if at >= r.nbits:  # the "zeros" were read past the end of the data
                    r.pos = r.nbits
                    raise r.error("stream ends inside an arithmetic-coded block", "truncated")
                r.pos = at
                raise r.error("stuffing bit after 22 consecutive zeros is not '1'", "stuffing")
        end = self.start + used + sum(1 for c in self.stuffing if c <= used)
        if end > r.nbits:
            r.pos = r.nbits
            raise r.error("stream ends inside an arithmetic-coded block", "truncated")
        r.pos = end
        return end - self.start


def symbols_to_bits(symbols: list[int], alphabets: list[int], adaptive: bool = True) -> bytes:
    """Helper for tests: code one block of symbols (each with its own fresh model)."""
    w = BitWriter()
    enc = ArithEncoder(w)
    models = {}
    for s, n in zip(symbols, alphabets):
        m = models.setdefault(n, make_model(n, adaptive))
        enc.encode(m, s)
    enc.flush()
    return w.getvalue()
