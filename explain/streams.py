"""Edits of a binary stream that take one trigger out: the stream the reference decodes, changed
and re-encoded by fbaconf's encoder. The edit for a coverage point is chosen by the point's
family, and so is how the stream is coded again:

* an edit of the content or the timing (a FAP dropped, FAP 1/2 dropped, the rate set to 25 Hz, the
  frames renumbered without skips, lists only where a value needs one) codes the rest as the
  original was coded (:func:`as_coded`: its quantiser and coding mode per frame, intra planes,
  mask types, start codes, time codes, gender, end code), so that the variant differs from the
  case in the edit and little else;
* the points of the coding itself (the coder, masks, quantisers, DCT, start and end codes, time
  codes...) are taken out by coding the stream again with the encoder's defaults (fap_quant 1,
  intra planes where needed, plane start codes at intra planes, no time codes, arithmetic coding,
  tight lists in every intra plane), which changes much of the coding at once.

Neither always takes its point out (a stream keeps its intra planes; the encoder's own choices can
make a point again), and an edit takes out more than its point: explain makes no variant that still
has its point and names what else its variant lacks (``causes._variant``)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from fbaconf.bitstreams.decoder import DecodeResult, decode
from fbaconf.bitstreams.encoder import encode
from fbaconf.bitstreams.encoder_options import EncoderOptions
from fbaconf.bitstreams.frames import FapFrames
from fbaconf.bitstreams.syntax import CODING_DCT, LIST_ORDER, PlaneInfo

from . import edits

# how the edited frames are coded again: from the original's decoding and the edited frames
Coding = Callable[[DecodeResult, FapFrames], EncoderOptions]


def as_coded(orig: DecodeResult, fr: FapFrames) -> EncoderOptions:
    """Options that code ``fr`` (the original's frames, edited row for row) as ``orig`` was coded."""
    planes = orig.planes
    of = orig.frames
    by_offset = {p.bit_offset: p for p in planes}
    rows = [by_offset.get(int(b)) for b in of.bit_offset]
    numbers = fr.frame_number.tolist()
    dct = bool((of.coding_type == CODING_DCT).any())
    types: list[tuple[int, ...]] = []
    last: tuple[int, ...] = (3,) * 10
    for p in rows:
        if p is not None and p.is_intra and len(p.group_types) == 10:
            last = p.group_types
        types.append(last)
    return EncoderOptions(
        fap_quant_per_frame=np.asarray(of.fap_quant, dtype=np.int64),
        coding_per_frame=[int(c) for c in of.coding_type] if dct else None,
        intra_at=frozenset(n for n, p in zip(numbers, rows) if p is not None and p.is_intra and not dct),
        plane_start_codes="none",
        start_codes_before=frozenset(n for n, p in zip(numbers, rows) if p is not None and p.start_code),
        time_codes=any(p.time_code is not None for p in planes),
        ranges=_ranges(planes),
        group_types=np.asarray(types, dtype=np.int64),
        gender=int(of.gender),
        end_code=orig.end_code is not None,
    )


def _ranges(planes: list[PlaneInfo]) -> str:
    """The encoder's range mode a stream was coded in: every intra plane of the arithmetic mode
    sending all four lists is "auto" (tight lists each time); lists only where a value needed one
    (or a quantiser changed) is "persist"."""
    intra = [p for p in planes if p.is_intra and p.coding_type != CODING_DCT]
    return "auto" if intra and all(len(p.new_lists) == len(LIST_ORDER) for p in intra) else "persist"


def _defaults(orig: DecodeResult, fr: FapFrames) -> EncoderOptions:
    return EncoderOptions()


def _default_ranges(orig: DecodeResult, fr: FapFrames) -> EncoderOptions:
    return replace(as_coded(orig, fr), ranges="persist")


def edit_for(point: str) -> tuple[str, edits.Change, Coding] | None:
    """(what the edit does, the change of the decoded frames, how they are coded again) that takes
    ``point`` out of a stream, or None for a point no stream edit removes (claims, limits, scenes,
    models)."""
    family, _, rest = point.partition(".")
    if family == "fap" and rest.split(".")[0].isdigit():
        n = int(rest.split(".")[0])
        return f"without FAP {n}", edits.drop(n), as_coded
    if family in ("highlevel", "viseme", "expression"):
        return "without FAP 1/2 (no viseme, no expression)", edits.drop(1, 2), as_coded
    if family == "rate":
        return "at 25 Hz, one rate", edits.rate25, as_coded
    if family == "skip":
        return "frames numbered without gaps: no skips", edits.rows, as_coded
    if family == "lists":
        return "lists only where a value needs one (the default ranges)", edits.nothing, _default_ranges
    if family in (
        "arith", "coding", "dct", "fap_quant", "mask", "plane", "retained", "status",
        "stream", "symbol", "timecode", "defaults", "diag",
    ):  # fmt: skip
        return "re-encoded by fbaconf's encoder with its defaults", edits.nothing, _defaults
    return None


def stream_variant(data: bytes, change: edits.Change, coding: Coding = _defaults) -> bytes | None:
    """The stream decoded by the reference, changed, and coded again as ``coding`` says (where the
    encoder refuses that, the edited mask types give way to the encoder's own); None when it
    cannot be (an invalid stream, frames the encoder refuses)."""
    try:
        orig = decode(data)
        fr = orig.frames.copy()
        change(fr)
        fr.time_ms = np.asarray(fr.frame_number, dtype=np.float64) * 1000.0 / fr.frame_rate
        opts = coding(orig, fr)
    except Exception:  # noqa: BLE001 - a stream this edit cannot rewrite: no variant
        return None
    for o in (opts, replace(opts, group_types=None)):  # a dropped FAP contradicts "all coded"
        try:
            return encode(fr, o).data
        except Exception:  # noqa: BLE001,S112 - the next, looser options
            continue
    return None
