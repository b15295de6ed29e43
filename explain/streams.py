"""Edits of a binary stream that take one trigger out: the stream the reference decodes, changed
and re-encoded by fbaconf's encoder (its defaults: fap_quant 1, intra planes where needed, plane
start codes at intra planes, no time codes, arithmetic coding). The edit for a coverage point is
chosen by the point's family. The re-encoding alone takes out many triggers of the coder and the
syntax (time codes, DCT, quantiser changes, most look-ahead stuffing) but not all: a stream keeps
its intra planes and its end code, the encoder chooses masks of its own and by default sends
tight lists in every intra plane (the list points are re-encoded under the default ranges
instead), and the skips are in the frame numbers (renumbered for the skip points). explain makes
no variant that still has its point (``causes._variant``)."""

from __future__ import annotations

import numpy as np

from fbaconf.bitstreams.decoder import decode_frames
from fbaconf.bitstreams.encoder import encode
from fbaconf.bitstreams.encoder_options import EncoderOptions

from . import edits


def edit_for(point: str) -> tuple[str, edits.Change, EncoderOptions] | None:
    """(what the edit does, the change of the decoded frames, the encoder's options) that takes
    ``point`` out of a stream, or None for a point no stream edit removes (claims, limits, scenes,
    models)."""
    family, _, rest = point.partition(".")
    defaults = EncoderOptions()
    if family == "fap" and rest.split(".")[0].isdigit():
        n = int(rest.split(".")[0])
        return f"without FAP {n}", edits.drop(n), defaults
    if family in ("highlevel", "viseme", "expression"):
        return "without FAP 1/2 (no viseme, no expression)", edits.drop(1, 2), defaults
    if family == "rate":
        return "at 25 Hz, one rate (re-encoded)", edits.rate25, defaults
    if family == "skip":
        return "frames numbered without gaps: no skips (re-encoded)", edits.rows, defaults
    if family == "lists":  # the encoder's own default sends tight lists in every intra plane
        return (
            "re-encoded under the default ranges: lists only where a value needs one",
            edits.nothing,
            EncoderOptions(ranges="persist"),
        )
    if family in (
        "arith", "coding", "dct", "fap_quant", "mask", "plane", "retained", "status",
        "stream", "symbol", "timecode", "defaults", "diag",
    ):  # fmt: skip
        return "re-encoded by fbaconf's encoder with its defaults", edits.nothing, defaults
    return None


def stream_variant(data: bytes, change: edits.Change, options: EncoderOptions | None = None) -> bytes | None:
    """The stream decoded by the reference, changed, and re-encoded (with ``options``, default the
    encoder's defaults); None when it cannot be (an invalid stream, frames the encoder refuses)."""
    try:
        fr = decode_frames(data)
        change(fr)
        fr.time_ms = np.asarray(fr.frame_number, dtype=np.float64) * 1000.0 / fr.frame_rate
        return encode(fr, options or EncoderOptions()).data
    except Exception:  # noqa: BLE001 - a stream this edit cannot rewrite: no variant
        return None
