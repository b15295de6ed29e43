"""What the reference encoder is asked (:class:`EncoderOptions`) and what it gives back
(:class:`EncodeResult`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from fractions import Fraction

import numpy as np

from fbaconf.errors import EncodeError

from .frames import FapFrames
from .syntax import (
    MASK_INTERPOLATE,
    MASK_RETAIN,
)

PLANE_START_CODE_MODES = ("none", "intra", "all")
CODING_MODES = ("arithmetic", "dct")  # coding_type 0 and 1
RANGE_MODES = ("auto", "persist")


@dataclass
class EncoderOptions:
    fap_quant: int = 1  # 0 = no quantisation, 1..31 scale the default steps
    intra_period: int = 0  # 0 = intra planes only where needed; N = at least every N planes
    frame_rate: float | str | Fraction | None = None  # output rate; None = the input's
    time_codes: bool = False  # write a time code in every intra plane
    plane_start_codes: str = "intra"  # none | intra | all
    ranges: str = "auto"  # auto: tight lists in every intra plane; persist: defaults, lists when needed
    bounds: np.ndarray | None = None  # explicit int[68, 4] (i_max, i_min, p_max, p_min), fap_quant=1 units
    partial_mask_type: int | None = None  # force 1 or 2 for partially coded groups
    group_types: np.ndarray | None = None  # explicit int[n, 10] mask types (frames after resampling)
    fap_quant_per_frame: np.ndarray | None = None  # int[n]; changes force an intra plane
    gender: int = 0
    coding: str = "arithmetic"  # arithmetic | dct (DCT: fap_quant is the scaling index 0..31, dct.py)
    end_code: bool = True
    coding_per_frame: np.ndarray | list | None = None  # per frame 'arithmetic'/'dct' (or 0/1); a change
    # starts an intra plane in the other mode (overrides ``coding``)
    start_codes_before: frozenset = frozenset()  # frame numbers whose plane gets a plane start code
    intra_at: frozenset = frozenset()  # frame numbers coded as intra planes (frame-based mode)
    full_intensity_alphabet: bool = False  # blend/intensity levels up to D5's alphabet end, even past
    # 63 (64 at fap_quant 2): a value a decoder must output; off, the level is lowered to stay <= 63
    widen_at: frozenset = frozenset()  # (frame number, n): that intra plane's range lists n codes wider
    # (both set by encode() itself where needed to prevent start-code emulation, D9)

    def validate(self) -> None:
        if not 0 <= self.fap_quant <= 31:
            raise EncodeError(f"fap_quant {self.fap_quant} outside 0..31", rule="option")
        if self.intra_period < 0:
            raise EncodeError("intra period must be >= 0", rule="option")
        if self.plane_start_codes not in PLANE_START_CODE_MODES:
            raise EncodeError(f"plane_start_codes must be one of {PLANE_START_CODE_MODES}", rule="option")
        if self.ranges not in RANGE_MODES:
            raise EncodeError(f"ranges must be one of {RANGE_MODES}", rule="option")
        if self.partial_mask_type not in (None, MASK_RETAIN, MASK_INTERPOLATE):
            raise EncodeError("partial_mask_type must be 1 or 2", rule="option")
        if self.gender not in (0, 1):
            raise EncodeError("gender must be 0 or 1", rule="option")
        if self.coding not in CODING_MODES:
            raise EncodeError("coding must be 'arithmetic' or 'dct'", rule="option")


@dataclass
class EncodeResult:
    data: bytes
    recon: FapFrames  # the encoder's own reconstruction (what a conformant decoder outputs)
    intra_frames: list[int]
    plane_offsets: list[int]
    start_codes: list[int] = field(default_factory=list)  # byte offsets of the start codes written
