"""A failure's cause comes no later than its first divergence.

A decoder reads a stream in order and writes each frame from what it has read so far, so the
stream points a case first hits after the frame where the decoder's output first left the
expected one did not make that frame wrong: a stream that fails at frame 2 does not fail because
of its end code, or of a mask change at frame 9. The spectrum takes such points out of that
case's features (they stay in its passing-case counts, where they are evidence as any other).

Only a first difference that names an output frame of the FAP sequence localises: the FAP
comparisons' and the vertices' (one posed face per FAP frame). A rejection, a crash or a header
difference (the frame rate) says nothing of where in the stream the decoder went wrong, and a
case of several streams has no one stream to cut: those cases keep all their features.
"""

from __future__ import annotations

import functools
from pathlib import Path

from fbaconf.conformance.coverage import stream_points, stream_points_through
from fbaconf.conformance.suite import Case, CaseKind
from fbaconf.harness.results import CaseResult


def _frame_stage(stage: str) -> bool:
    return stage in ("faps", "effective_faps", "vertices") or stage.startswith("vertices[")


def first_frame(r: CaseResult) -> int | None:
    """The output frame (0-based) of ``r``'s first difference, when its first differing stage
    compares frames of the FAP sequence."""
    for s in r.stages:
        fd = s.first_difference
        if fd:
            frame = fd.get("frame")
            ok = _frame_stage(s.stage) and isinstance(frame, int) and not isinstance(frame, bool)
            return frame if ok else None
    return None


def after_divergence(case: Case | None, r: CaseResult) -> frozenset[str]:
    """The stream points ``case`` first hits after the frame where ``r``'s output first differs
    (empty when the difference names no frame or the case is not one stream)."""
    row = first_frame(r)
    if row is None or case is None or case.kind != CaseKind.DECODE:
        return frozenset()
    fba = case.input_path("fba")
    if fba is None or not fba.is_file():
        return frozenset()
    st = fba.stat()
    return _after(str(fba), st.st_mtime_ns, st.st_size, row)


@functools.lru_cache(maxsize=1024)
def _after(path: str, _mtime_ns: int, _size: int, row: int) -> frozenset[str]:
    data = Path(path).read_bytes()
    through = stream_points_through(data, row)
    return frozenset() if through is None else frozenset(stream_points(data) - through)
