"""Procedural FAP sequences written by the project (no third-party data).

Speech-like mouth and jaw motion, eye blinks, gaze shifts, head movement, eyebrow
raises, cheeks, tongue, nose and ears — every one of the 66 low-level FAPs moves — plus
visemes and expressions when asked. Pure functions of (frame index, rate): the same
arguments give the same sequence on every platform (values are rounded from float64
expressions with no data-dependent branching).
"""

from __future__ import annotations

import numpy as np

from . import tables
from .frames import SET, FapFrames


def _amplitude(fap: int) -> float:
    """A plausible peak amplitude (FAPU/AU) per FAP, a fraction of its default intra range."""
    f = tables.fap_table()[fap - 1]
    return 0.45 * f.intra_range * f.quant_step


def synthetic_sequence(
    n_frames: int,
    rate: float = 25.0,
    *,
    visemes: bool = True,
    expressions: bool = True,
    faps: list[int] | None = None,
    seed: int = 0,
) -> FapFrames:
    """A FAP sequence of ``n_frames`` frames at ``rate`` Hz with every requested FAP coded in
    every frame. ``seed`` shifts the phases (different but equally deterministic content)."""
    t = np.arange(n_frames, dtype=np.float64) / rate
    out = FapFrames.empty(n_frames, frame_rate=rate)
    chosen = list(range(3, 69)) if faps is None else [f for f in faps if 3 <= f <= 68]
    phase = 0.37 * seed
    # shared drivers
    speech = np.maximum(0.0, np.sin(2 * np.pi * 3.1 * t + phase)) * (0.6 + 0.4 * np.sin(2 * np.pi * 0.23 * t))
    blink_period = 3.3
    blink = np.exp(np.maximum(-60.0, -((((t + phase) % blink_period) - 0.15) ** 2) / (2 * 0.05**2)))
    gaze = np.sin(2 * np.pi * 0.17 * t + phase)
    brow = np.maximum(0.0, np.sin(2 * np.pi * 0.11 * t + 1.3 + phase)) ** 2
    for fap in chosen:
        info = tables.fap_table()[fap - 1]
        amp = _amplitude(fap)
        g = info.group
        if g == 2 or g == 8:
            x = speech * (1.0 if fap in (3, 4, 5, 51, 52) else 0.5) + 0.2 * np.sin(2 * np.pi * 0.7 * t + fap)
        elif fap in (19, 20):
            x = blink
        elif fap in (21, 22):
            x = 0.5 * blink
        elif fap in (23, 24, 25, 26):
            x = gaze if fap in (23, 24) else 0.5 * np.sin(2 * np.pi * 0.13 * t + phase)
        elif g == 3:
            x = 0.3 * np.sin(2 * np.pi * 0.09 * t + fap)
        elif g == 4:
            x = brow * (1.0 if fap <= 36 else -0.4)
        elif g == 7:
            x = 0.35 * np.sin(2 * np.pi * (0.05 + 0.02 * (fap - 48)) * t + fap + phase)
        else:
            x = 0.4 * np.sin(2 * np.pi * (0.1 + 0.01 * fap) * t + fap + phase)
        if info.direction == "U":
            x = np.abs(x)
        out.values[:, fap - 1] = np.rint(amp * x).astype(np.int32)
        out.status[:, fap - 1] = SET
    if visemes:
        # one viseme per ~120 ms, cross-fading into the next
        slot = np.floor(t / 0.12).astype(np.int64)
        frac = t / 0.12 - slot
        v1 = 1 + (slot * 5 + seed) % 14
        v2 = 1 + ((slot + 1) * 5 + seed) % 14
        out.status[:, 0] = SET
        out.hl("viseme_select1")[:] = v1
        out.hl("viseme_select2")[:] = v2
        out.hl("viseme_blend")[:] = np.rint(63 * (1.0 - frac)).astype(np.int32)
        out.hl("viseme_def")[:] = 0
    if expressions:
        slot = np.floor(t / 2.0).astype(np.int64)
        out.status[:, 1] = SET
        out.hl("expression_select1")[:] = 1 + (slot + seed) % 6
        out.hl("expression_intensity1")[:] = np.rint(63 * np.abs(np.sin(np.pi * t / 2.0))).astype(np.int32)
        out.hl("expression_select2")[:] = 1 + (slot + 3 + seed) % 6
        out.hl("expression_intensity2")[:] = np.rint(20 * np.abs(np.cos(np.pi * t / 2.0))).astype(np.int32)
        out.hl("init_face")[:] = 0
        out.hl("expression_def")[:] = 0
    return out
