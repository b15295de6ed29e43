"""Preparing an encoder's input: resampling to another frame rate, the group mask types the
encoder derives (D3), and the checks on what it is given."""

from __future__ import annotations

import numpy as np

from fbaconf.errors import EncodeError

from . import tables
from .frames import FREE, HIGH_LEVEL_FIELDS, SET, FapFrames
from .syntax import (
    EXPRESSION_SELECT_MAX,
    INTENSITY_MAX,
    MASK_ALL,
    MASK_INTERPOLATE,
    MASK_NONE,
    MASK_RETAIN,
    VISEME_SELECT_MAX,
)
from .tables import NUM_FAPS


def resample(frames: FapFrames, rate: float) -> FapFrames:
    """Temporal subsampling to ``rate``: output frame j (time j/rate) is the latest input frame
    at or before that time, kept as it is (its coded FAPs stay coded)."""
    if len(frames) == 0:
        return frames.copy()
    t_in = frames.frame_number / frames.frame_rate
    t_end = t_in[-1]
    n_out = int(np.floor(t_end * rate + 1e-9)) + 1
    t_out = np.arange(n_out) / rate
    idx = np.searchsorted(t_in, t_out + 1e-9, side="right") - 1
    keep = idx >= 0
    idx, jn = idx[keep], np.arange(n_out)[keep]
    out = frames.select(idx)
    out.frame_number = jn.astype(np.int64)
    out.frame_rate = float(rate)
    out.time_ms = jn * 1000.0 / rate
    return out


def _derive_group_types(frames: FapFrames, partial: int | None) -> np.ndarray:
    n = len(frames)
    types = np.zeros((n, 10), dtype=np.int64)
    coded = frames.status == SET
    ever = np.zeros(NUM_FAPS, dtype=bool)
    for k in range(n):
        for gi, g in enumerate(tables.groups()):
            sl = slice(g.first_fap - 1, g.last_fap)
            c = coded[k, sl]
            if c.all():
                t = MASK_ALL
            else:
                freed = ((frames.status[k, sl] == FREE) & ever[sl] & ~c).any()
                if c.any():
                    t = partial if partial is not None else (MASK_INTERPOLATE if freed else MASK_RETAIN)
                else:
                    t = MASK_INTERPOLATE if freed else MASK_NONE
            types[k, gi] = t
        ever |= coded[k]
    return types


def _check_input(frames: FapFrames) -> None:
    fn = frames.frame_number
    if len(fn) and fn[0] < 0:
        raise EncodeError("frame numbers must be >= 0", rule="frame-order", frame=0, value=int(fn[0]))
    bad = np.nonzero(np.diff(fn) <= 0)[0]
    if len(bad):
        k = int(bad[0]) + 1
        raise EncodeError(
            f"frame numbers must increase (frame {int(fn[k - 1])} is followed by {int(fn[k])})",
            rule="frame-order",
            frame=k,
            value=int(fn[k]),
        )
    limits = {
        "viseme_select1": VISEME_SELECT_MAX,
        "viseme_select2": VISEME_SELECT_MAX,
        "viseme_blend": INTENSITY_MAX,
        "viseme_def": 1,
        "expression_select1": EXPRESSION_SELECT_MAX,
        "expression_intensity1": INTENSITY_MAX,
        "expression_select2": EXPRESSION_SELECT_MAX,
        "expression_intensity2": INTENSITY_MAX,
        "init_face": 1,
        "expression_def": 1,
    }
    for j, name in enumerate(HIGH_LEVEL_FIELDS):
        fap = 1 if j < 4 else 2
        col = frames.high[:, j]
        live = frames.status[:, fap - 1] == SET
        bad = np.nonzero(live & ((col < 0) | (col > limits[name])))[0]
        if len(bad):
            k = int(bad[0])
            raise EncodeError(
                f"{name} = {int(col[k])} outside 0..{limits[name]}",
                rule="high-level-range",
                frame=k,
                fap=fap,
                value=int(col[k]),
            )
