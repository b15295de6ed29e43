"""Edits of a binary stream that take one trigger out: the stream the reference decodes, changed
and re-encoded by fbaconf's encoder (its defaults: fap_quant 1, intra planes where needed, plane
start codes at intra planes, no time codes, arithmetic coding). The edit for a coverage point is
chosen by the point's family. The re-encoding alone takes out many triggers of the coder and the
syntax (time codes, DCT, quantiser changes, most look-ahead stuffing) but not all: a stream keeps
its intra planes and its end code, the encoder chooses masks and lists of its own, and the skips
are in the frame numbers (renumbered for the skip points). explain makes no variant that still
has its point (``causes._variant``)."""

from __future__ import annotations

import numpy as np

from fbaconf.bitstreams.decoder import decode_frames
from fbaconf.bitstreams.encoder import encode
from fbaconf.bitstreams.encoder_options import EncoderOptions

from . import edits


def edit_for(point: str) -> tuple[str, edits.Change] | None:
    """(what the edit does, the change of the decoded frames) that takes ``point`` out of a stream,
    or None for a point no stream edit removes (claims, limits, scenes, models)."""
    family, _, rest = point.partition(".")
    if family == "fap" and rest.split(".")[0].isdigit():
        n = int(rest.split(".")[0])
        return f"without FAP {n}", edits.drop(n)
    if family in ("highlevel", "viseme", "expression"):
        return "without FAP 1/2 (no viseme, no expression)", edits.drop(1, 2)
    if family == "rate":
        return "at 25 Hz, one rate (re-encoded)", edits.rate25
    if family == "skip":
        return "frames numbered without gaps: no skips (re-encoded)", edits.rows
    if family in (
        "arith", "coding", "dct", "fap_quant", "lists", "mask", "plane", "retained", "status",
        "stream", "symbol", "timecode", "defaults", "diag",
    ):  # fmt: skip
        return "re-encoded by fbaconf's encoder with its defaults", edits.nothing
    return None


def stream_variant(data: bytes, change: edits.Change) -> bytes | None:
    """The stream decoded by the reference, changed, and re-encoded; None when it cannot be
    (an invalid stream, frames the encoder refuses)."""
    try:
        fr = decode_frames(data)
        change(fr)
        fr.time_ms = np.asarray(fr.frame_number, dtype=np.float64) * 1000.0 / fr.frame_rate
        return encode(fr, EncoderOptions()).data
    except Exception:  # noqa: BLE001 - a stream this edit cannot rewrite: no variant
        return None
