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

import os
from bisect import bisect_left

import numpy as np

from . import readings, syntax as _syntax, tables as _tables
from .bitio import BitReader, BitWriter

TOP = 65535
Q1 = 16384
Q2 = 32768
Q3 = 49152
MAX_FREQUENCY = 16383
ZERO_RUN_LIMIT = 22
LOOKAHEAD = 14  # 16 primed bits - 2 flush bits

# Error messages of a block (shared by the pure decoder and the native fast path)
MSG_ARITH_STATE = "arithmetic decoder state out of range (corrupt block)"
MSG_STUFFING = "stuffing bit after 22 consecutive zeros is not '1'"
MSG_TRUNCATED = "stream ends inside an arithmetic-coded block"


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

    __slots__ = (
        "r",
        "bits",
        "nb",
        "pos",
        "low",
        "high",
        "value",
        "zeros",
        "count",
        "start",
        "stuffing",
        "bad_stuffing",
    )

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
            raise self.r.error(MSG_ARITH_STATE, "arith-state")
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
                    raise r.error(MSG_TRUNCATED, "truncated")
                r.pos = at
                raise r.error(MSG_STUFFING, "stuffing")
        end = self.start + used + sum(1 for c in self.stuffing if c <= used)
        if readings.active(readings.REWIND_14):  # the other reading of D7 (S1): 14 stream bits back
            end = self.pos - LOOKAHEAD
        if end > r.nbits:
            r.pos = r.nbits
            raise r.error(MSG_TRUNCATED, "truncated")
        r.pos = end
        return end - self.start


# ---------------------------------------------------------------------------- native fast path
#
# bitstreams/_fastarith.c (an optional C extension built by setup.py) runs whole blocks:
# the same coder, models held as int32 c tables in a "pool", blocks described by int32
# "spec" rows (n, pool offset or -1 for a uniform non-adaptive model, lo, step, index).
# The classes above stay the reference; the fast path is used only when the extension is
# importable, FBACONF_PURE_PYTHON is unset (or '0'), and the classes above are the
# originals (tests monkeypatch them to simulate faults).

PURE_PYTHON_ENV = "FBACONF_PURE_PYTHON"

try:
    from . import _fastarith as _native_module
except ImportError:  # not built (no compiler): the pure path is used
    _native_module = None

_PURE_DECODER = {k: ArithDecoder.__dict__[k] for k in ("__init__", "_bit", "_stuffing", "decode", "finish")}
_PURE_ENCODER = {k: ArithEncoder.__dict__[k] for k in ("__init__", "_emit", "_bit_plus_follow", "encode", "flush")}


def native_available() -> bool:
    """True when the C extension was built and imports."""
    return _native_module is not None


def native():
    """The C extension module, or None when missing or FBACONF_PURE_PYTHON is set."""
    if _native_module is None or os.environ.get(PURE_PYTHON_ENV, "").strip() not in ("", "0"):
        return None
    return _native_module


def native_decoder():
    """The extension for the decoder, or None (also when ArithDecoder was replaced or patched)."""
    mod = native()
    if (
        mod is None
        or readings.pure_required()
        or any(ArithDecoder.__dict__.get(k) is not v for k, v in _PURE_DECODER.items())
    ):
        return None
    return mod


def native_encoder():
    """The extension for the encoder, or None (also when ArithEncoder was replaced or patched)."""
    mod = native()
    if mod is None or any(ArithEncoder.__dict__.get(k) is not v for k, v in _PURE_ENCODER.items()):
        return None
    return mod


def tdiv_array(a: np.ndarray, d: int) -> np.ndarray:
    """C-style truncating division of an int array by d > 0 (syntax.alphabet, vectorised)."""
    a = np.asarray(a, dtype=np.int64)
    return np.where(a < 0, -((-a) // d), a // d)


def block_spec(n, lo, step=0, idx=0, adaptive: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """Spec rows (int32[k, 5]) of a block and, for adaptive models, a fresh pool holding
    one uniform c table (c[k] = n - k) per row."""
    n = np.atleast_1d(np.asarray(n, dtype=np.int64))
    k = len(n)
    if k and (n.min() < 1 or n.max() > MAX_FREQUENCY):
        raise ValueError(f"alphabet size outside 1..{MAX_FREQUENCY}")
    spec = np.zeros((k, 5), dtype=np.int32)
    spec[:, 0] = n
    spec[:, 2] = lo
    spec[:, 3] = step
    spec[:, 4] = idx
    if not adaptive:
        spec[:, 1] = -1
        return spec, None
    sizes = n + 1
    offs = np.cumsum(sizes) - sizes
    spec[:, 1] = offs
    total = int(sizes.sum())
    pool = (np.repeat(n, sizes) - (np.arange(total) - np.repeat(offs, sizes))).astype(np.int32)
    return spec, pool


def append_bits(w: BitWriter, data: bytes, nbits: int) -> None:
    """Append the first nbits of ``data`` (MSB first) to a BitWriter."""
    if nbits <= 0:
        return
    nacc = w._nacc
    if nacc == 0:
        full = nbits >> 3
        w._buf += data[:full]
        rem = nbits & 7
        w._acc = data[full] >> (8 - rem) if rem else 0
        w._nacc = rem
        return
    value = int.from_bytes(data, "big") >> (len(data) * 8 - nbits)
    acc = (w._acc << nbits) | value
    n = nacc + nbits
    rem = n & 7
    w._buf += (acc >> rem).to_bytes(n >> 3, "big")
    w._acc = acc & ((1 << rem) - 1)
    w._nacc = rem


class NativeSegment:
    """Block specs and adaptive model pools of one segment (intra plane + the P planes after it)
    for the native fast path (decoder and encoder): the same alphabets and models as the pure path (D4, D5)."""

    __slots__ = (
        "idx",
        "bounds",
        "q",
        "istep",
        "steps",
        "vis_i",
        "exp_i",
        "low_i",
        "vis_p",
        "vis_pool",
        "exp_p",
        "exp_pool",
        "low_p",
        "low_pool",
    )

    def __init__(self, coded_low: list[int], bounds: np.ndarray, q: int) -> None:
        self.idx = idx = np.asarray(coded_low, dtype=np.int64) - 1
        self.bounds = bounds[idx].copy()  # bounds of the coded FAPs, fixed until the next intra plane
        self.q = q
        d = q if q > 0 else 1
        self.istep = _syntax.intensity_step(q)
        ib = _syntax.intensity_bound(q)
        self.steps = _tables.quant_steps()[idx].astype(np.int64) * q if q > 0 else np.ones(len(idx), np.int64)
        V, E = _syntax.VISEME_SELECT_MAX, _syntax.EXPRESSION_SELECT_MAX
        self.vis_i, _ = block_spec([V + 1, V + 1, ib + 1], 0)
        self.exp_i, _ = block_spec([E + 1, ib + 1, E + 1, ib + 1], 0)
        lo = tdiv_array(self.bounds[:, 1], d)
        hi = tdiv_array(self.bounds[:, 0], d)
        self.low_i, _ = block_spec(hi - lo + 1, lo, self.steps, idx)
        self.low_p = self.low_pool = self.vis_p = self.vis_pool = self.exp_p = self.exp_pool = None

    def build_p(self) -> None:
        """The P models, created at the first predicted plane (uniform, adaptive)."""
        q = self.q
        d = q if q > 0 else 1
        ib = _syntax.intensity_bound(q)
        V, E = _syntax.VISEME_SELECT_MAX, _syntax.EXPRESSION_SELECT_MAX
        self.vis_p, self.vis_pool = block_spec([2 * V + 1, 2 * V + 1, 2 * ib + 1], [-V, -V, -ib], adaptive=True)
        self.exp_p, self.exp_pool = block_spec(
            [2 * E + 1, 2 * ib + 1, 2 * E + 1, 2 * ib + 1], [-E, -ib, -E, -ib], adaptive=True
        )
        lo = tdiv_array(self.bounds[:, 3], d)
        hi = tdiv_array(self.bounds[:, 2], d)
        self.low_p, self.low_pool = block_spec(hi - lo + 1, lo, self.steps, self.idx, adaptive=True)
