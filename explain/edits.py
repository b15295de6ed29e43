"""Edits of decoded frames that take one trigger out, shared by the ``.fap`` edits (rewritten by
fbaconf's writer, explain/triggers.py) and the stream edits (re-encoded, explain/streams.py)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from fbaconf.bitstreams.frames import FREE, RETAINED, SET, FapFrames

Change = Callable[[FapFrames], None]
DEFS = (3, 9)  # viseme_def, expression_def in HIGH_LEVEL_FIELDS


def drop(*faps: int) -> Change:
    """The FAPs ``faps`` (numbers from 1) never sent."""

    def change(fr: FapFrames) -> None:
        st = fr.status.copy()
        st[:, [f - 1 for f in faps]] = FREE
        fr.status = st

    return change


def rate25(fr: FapFrames) -> None:
    fr.frame_rate = 25.0


def no_defs(fr: FapFrames) -> None:
    h = fr.high.copy()
    h[:, list(DEFS)] = 0
    fr.high = h


def rows(fr: FapFrames) -> None:
    """Frames numbered 0..n-1 in their order."""
    fr.frame_number = np.arange(len(fr), dtype=np.int64)


def keep(fr: FapFrames) -> None:
    """Every held FAP sent again in every frame."""
    st = fr.status.copy()
    st[st == RETAINED] = SET
    fr.status = st


def nothing(fr: FapFrames) -> None:
    return None
