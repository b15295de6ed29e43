"""Coverage points of the arithmetic decoder's boundaries (spec notes §3.3, D7), from a stream's content.

* ``arith.renorm-tie.<tie>``: a renormalisation test met at exact equality with a quarter point —
  ``high-q2`` (high = q2 at ``high < q2``), ``low-q2`` (low = q2 at ``low >= q2``), ``low-q1`` (low =
  q1 with high < q3 at the middle test), ``high-q3`` (high = q3 with q1 <= low < q2 at the middle
  test). The stream is decoded again by the reference's pure block decoder, each symbol observed
  from outside: the interval and the model's table before it, the symbol it returns; the §3.3
  narrowing and renormalisation tests are then re-run on that interval (interval only: the tests
  never read ``value``).
* ``arith.lookahead-<p>``: a run of 22 zeros that completes at position p (1..14) of a block's 14-bit
  look-ahead; ``arith.lookahead-rewind-<p>`` / ``arith.lookahead-error-<p>``: the same with the bit
  after it a '1' (the decoder removes it as a stuffing bit and must hand it back) or a '0' (a
  violation that is no error, D7).
"""

from __future__ import annotations

from contextlib import contextmanager

from fbaconf.bitstreams import arith, decoder as dec
from fbaconf.bitstreams.arith import Q1, Q2, Q3, ArithDecoder
from fbaconf.errors import BitstreamError
from fbaconf.profiles.checker import ARITH_BLOCKS, lookahead_stuffing

TIES = ("high-q2", "low-q2", "low-q1", "high-q3")


def renorm_ties(low: int, high: int) -> set[str]:
    """The ties the §3.3 renormalisation tests meet on the interval [low, high] after narrowing."""
    out: set[str] = set()
    while True:
        if high == Q2:
            out.add("high-q2")
        if high < Q2:
            pass
        elif low >= Q2:
            if low == Q2:
                out.add("low-q2")
            low, high = low - Q2, high - Q2
        else:
            if low == Q1 and high < Q3:
                out.add("low-q1")
            if low >= Q1 and high == Q3:
                out.add("high-q3")
            if low >= Q1 and high < Q3:
                low, high = low - Q1, high - Q1
            else:
                return out
        low, high = 2 * low, 2 * high + 1


def _table(model):
    """(c[s], c[s+1], c[0]) of the model as it is now, for the symbol decoded next."""
    if isinstance(model, arith.FastModel):
        a = model.arr.copy()
        return lambda s: (-int(a[s]), -int(a[s + 1]), -int(a[0]))
    if isinstance(model, arith.Model):
        neg = list(model.neg)
        return lambda s: (-neg[s], -neg[s + 1], -neg[0])
    return model.bounds  # a non-adaptive model: its table never changes


@contextmanager
def _observed(hits: set[str]):
    orig = ArithDecoder.decode

    def decode(self, model):
        low, high, table = self.low, self.high, _table(model)
        s = orig(self, model)
        hi_c, lo_c, total = table(s)
        length = high - low + 1
        hits.update(
            f"arith.renorm-tie.{t}"
            for t in renorm_ties(low + (length * lo_c) // total, low - 1 + (length * hi_c) // total)
        )
        return s

    ArithDecoder.decode = decode  # the native fast path stands aside while the class is patched
    try:
        yield
    finally:
        ArithDecoder.decode = orig


def coder_points(data: bytes) -> set[str]:
    """The coder points a valid stream hits (empty for a stream the reference rejects)."""
    hits: set[str] = set()
    with _observed(hits):
        try:
            planes = dec._Decoder(data, None).run().planes
        except BitstreamError:
            return set()
    for p in planes:
        for name, start, length in p.blocks:
            if name not in ARITH_BLOCKS:
                continue
            at = lookahead_stuffing(data, start, length)
            if at is None:
                continue
            slot = (data[at // 8] >> (7 - at % 8)) & 1 if at < 8 * len(data) else 0
            pos = at - start - length
            hits.add(f"arith.lookahead-{pos}")  # the position, whatever follows: both kinds' common point
            hits.add(f"arith.lookahead-{'rewind' if slot else 'error'}-{pos}")
    return hits


__all__ = ["TIES", "coder_points", "renorm_ties"]
