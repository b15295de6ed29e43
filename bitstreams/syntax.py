"""Face object syntax pieces shared by the reference encoder and decoder.

Every reading the public sources leave open is decided here, in one place, with the
decision id of ../shared/spec/fap-bitstream.md (D1-D7):

- D1 the 2-bit fba_object_mask must be 01 (FAPs only); a plane start code may precede a plane.
- D3 mask types: 0 none, 1 per-FAP mask + keep previous (RETAINED), 2 per-FAP mask + may
  interpolate (FREE), 3 all FAPs of the group.
- D4 ranges in "fap_quant = 1" units, lists in multiples of 60, alphabets from truncating
  division by q = max(fap_quant, 1) at each intra plane.
- D5 high-level alphabets (and the other reading of the blend/intensity alphabet, to tell where
  a stream depends on D5).
- D6 timing.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from fractions import Fraction

import numpy as np

from . import readings, tables

FAPS_MASK = 0b01  # D1: fba_object_mask, second bit = FAPs
MASK_NONE, MASK_RETAIN, MASK_INTERPOLATE, MASK_ALL = 0, 1, 2, 3
MASK_TYPE_NAMES = {0: "00 none", 1: "01 mask, keep previous", 2: "10 mask, may interpolate", 3: "11 all"}
CODING_ARITHMETIC, CODING_DCT = 0, 1

# High-level alphabets (D5)
VISEME_SELECT_MAX = 14
EXPRESSION_SELECT_MAX = 6
INTENSITY_MAX = 63

# Order of the new min/max lists (spec notes 1.4)
LIST_ORDER = ("i_max", "i_min", "p_max", "p_min")

DEFAULT_FRAME_RATE = 25.0  # D6: a stream that never signals a frame rate
OTHER_DEFAULT_FRAME_RATE = 30.0  # the other reading of D6 (S1's decoder)


def default_frame_rate() -> float:
    """The rate of a stream that never signals one (D6; 30 Hz under ``D6:default-30hz``)."""
    return OTHER_DEFAULT_FRAME_RATE if readings.active(readings.DEFAULT_30HZ) else DEFAULT_FRAME_RATE


def quant_div(q: int) -> int:
    """The divisor of the ranges (D4): fap_quant, or 1 when fap_quant = 0."""
    return q if q > 0 else 1


def _tdiv(a: int, q: int) -> int:
    """C-style truncating division."""
    return -((-a) // q) if a < 0 else a // q


def alphabet(lo_bound: int, hi_bound: int, q: int) -> tuple[int, int]:
    """Symbol range [min, max] for bounds in fap_quant = 1 units (D4)."""
    d = quant_div(q)
    return _tdiv(lo_bound, d), _tdiv(hi_bound, d)


def low_level_step(fap: int, q: int) -> int:
    """Quantiser step of low-level FAP ``fap`` (1-based): QP x fap_quant, 1 when fap_quant = 0."""
    return int(tables.quant_steps()[fap - 1]) * q if q > 0 else 1


def intensity_bound(q: int) -> int:
    """D5: viseme_blend / expression intensity alphabet 0..floor((63 + floor(q/2)) / q)
    (0..ceil(63/q) under the other reading ``D5:blend-ceil``)."""
    if readings.active(readings.BLEND_CEIL):
        return intensity_bound_ceil(q)
    d = quant_div(q)
    return (INTENSITY_MAX + d // 2) // d


def intensity_bound_ceil(q: int) -> int:
    """The other plausible reading of D5's blend/intensity alphabet: the smallest alphabet whose
    top level still reaches 63 after dequantisation, 0..ceil(63 / q). It agrees with
    :func:`intensity_bound` except where 63/q has a fractional part below one half."""
    d = quant_div(q)
    return -(-INTENSITY_MAX // d)


def d5_alphabet_differs(q: int) -> bool:
    """Whether the blend/intensity alphabet at fap_quant ``q`` depends on D5 (the two readings
    differ: q = 10, 12, 15, 19, 20, 26..31); elsewhere both give the same alphabet. Asked with
    no reading on (the checker)."""
    return intensity_bound(q) != intensity_bound_ceil(q)


def intensity_step(q: int) -> int:
    return quant_div(q)


def quantise(x: int, step: int) -> int:
    """Reference encoder quantiser (spec notes 3.4): dead zone of floor(step/2), round half up."""
    h = step // 2
    a = -x if x < 0 else x
    if a <= h:
        return 0
    lvl = (a + h) // step
    return -lvl if x < 0 else lvl


# ---------------------------------------------------------------------------- frame rate


@dataclass(frozen=True)
class FrameRateCode:
    frame_rate: int  # 8 bits
    seconds: int  # 4 bits (sixteenths)
    frequency_offset: bool  # x 1000/1001

    @property
    def rate(self) -> float:
        """D6: (frame_rate + seconds/16) x (1000/1001 if frequency_offset), real arithmetic."""
        r = self.frame_rate + self.seconds / 16.0
        return r * 1000.0 / 1001.0 if self.frequency_offset else r

    @property
    def exact(self) -> Fraction:
        r = Fraction(self.frame_rate) + Fraction(self.seconds, 16)
        return r * Fraction(1000, 1001) if self.frequency_offset else r


def frame_rate_code(rate: float | Fraction | str) -> FrameRateCode:
    """The frame-rate fields for a rate given as number, fraction or text ('29.97', '30000/1001')."""
    if isinstance(rate, str):
        rate = Fraction(rate.strip())
    exact = Fraction(rate).limit_denominator(1_000_000)
    for offset in (False, True):
        base = exact * Fraction(1001, 1000) if offset else exact
        sixteenths = base * 16
        cand = round(sixteenths)
        if abs(sixteenths - cand) <= Fraction(1, 10_000) and 0 < cand < 256 * 16:
            return FrameRateCode(cand // 16, cand % 16, offset)
    # approximate forms such as 29.97 = 30000/1001 rounded
    f = float(exact)
    for offset in (False, True):
        base = f * 1001 / 1000 if offset else f
        cand = round(base * 16)
        if 0 < cand < 256 * 16 and abs(cand / 16 - base) <= 5e-4 * base:
            return FrameRateCode(cand // 16, cand % 16, offset)
    raise ValueError(f"frame rate {float(exact):g} Hz is not codable as (0..255 + n/16) x (1 or 1000/1001)")


# ---------------------------------------------------------------------------- skip frames


def skip_chunks(total: int) -> list[int]:
    """4-bit chunks of number_of_frames_to_skip: 15 continues, the last chunk < 15."""
    return [15] * (total // 15) + [total % 15]


# ---------------------------------------------------------------------------- plane records


@dataclass
class PlaneInfo:
    """What the decoder read for one plane (for the checker, the trace and reports)."""

    index: int
    bit_offset: int  # first bit of the plane (of its start code when present)
    header_offset: int = 0  # first bit of is_intra
    end_offset: int = 0
    start_code: bool = False
    is_intra: bool = False
    object_mask: int = FAPS_MASK
    frame_rate: FrameRateCode | None = None
    time_code: tuple[int, int, int, int] | None = None  # hours, minutes, marker, seconds
    skip: int = 0
    fap_quant: int = 0
    group_types: tuple[int, ...] = ()
    coded: np.ndarray | None = None  # bool[68]
    gender: int = 0
    coding_type: int = CODING_ARITHMETIC
    coding_known: bool = False  # coding_type read (intra) or inherited (predicted): a plane an error cut
    # short may stop before it, and then says nothing of its coding mode
    new_lists: dict[str, dict[int, int]] = field(default_factory=dict)  # list name -> {fap: v}
    marker_offsets: list[tuple[int, int]] = field(default_factory=list)  # (bit offset, value)
    blocks: list[tuple[str, int, int]] = field(default_factory=list)  # (name, start bit, length)
    symbols: dict[int, int] = field(default_factory=dict)  # fap -> decoded symbol value (Q)
    frame_number: int = 0  # first frame of the plane (of the group in DCT mode)
    time_ms: float = 0.0
    segment_length: int = 1  # DCT mode: frames in this plane group
