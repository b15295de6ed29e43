"""Fuzz inputs: the :class:`Entry` type (an input and where it came from) and valid face-object
streams made from scratch through the reference encoder (:func:`gen_valid`)."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import numpy as np

from fbaconf.bitstreams.encoder import EncoderOptions, encode
from fbaconf.bitstreams.frames import FREE
from fbaconf.bitstreams.synth import synthetic_sequence
from fbaconf.errors import FbaconfInputError

from .choosers import Chooser
from .model import StreamModel, stream_model

RATES = (25.0, 30.0, 15.0, 12.5, 10.0, 60.0, 7.5, 24.0, 30000 / 1001, 50.0)

# A stream over this many bytes is thousands of frames (the suites' stress streams): each input made
# from one costs a decoder seconds under ASan and fbaconf's judge (a reference decode for the oracle
# and the coverage) hundreds of times a typical seed. Such seeds are run as they are, kept out of
# the export's default seeds (stress/), out of the parents fbaconf's own loop mutates and out of
# the partners it splices and crosses them with.
STRESS_BYTES = 8192


class InputKind(StrEnum):
    """What an input is: a face-object stream, a BT scene (text), a binary BIFS scene, or
    ``.fap`` text."""

    STREAM = "stream"
    SCENE = "scene"
    BIFS = "bifs"
    TEXT = "text"


@dataclass
class Entry:
    """A corpus entry / an input: bytes (stream, BIFS) or text encoded UTF-8 (scene, .fap)."""

    data: bytes
    kind: InputKind = InputKind.STREAM
    origin: str = "seed"
    valid: bool | None = None  # True: generated valid stream (reference output = recon)
    recon: Any = None  # encoder reconstruction for generated streams (round-trip oracle)
    model: StreamModel | None = None
    corpus_size: int | None = None  # size of the corpus it was made from (regeneration)
    index: int | None = None  # its input number in the run that made it

    def __post_init__(self) -> None:
        self.kind = InputKind(self.kind)

    def get_model(self) -> StreamModel:
        if self.model is None:
            self.model = stream_model(self.data)
        return self.model


def gen_valid(ch: Chooser) -> Entry:
    """A valid stream from random procedural content and random encoder options."""
    n = ch.choice((1, 2, 3, 4, 6, 8, 12)) if ch.bool(0.9) else ch.int(16, 40)
    rate = ch.choice(RATES)
    if ch.bool(0.3):
        faps = None
    else:
        faps = sorted({ch.int(3, 68) for _ in range(ch.int(1, 12))})
    frames = synthetic_sequence(n, rate, visemes=ch.bool(0.4), expressions=ch.bool(0.4), faps=faps, seed=ch.int(0, 50))
    if n > 1 and ch.bool(0.3):  # sparse coding: masks, retained/free FAPs
        k = ch.int(2, 4)
        for row in range(1, n):
            for col in range(2, 68):
                if (row + col) % k:
                    frames.status[row, col] = FREE
    if n > 1 and ch.bool(0.25):  # skipped frames
        gaps = [0] + [ch.choice((1, 1, 1, 2, 5, 16, 40)) for _ in range(n - 1)]
        frames.frame_number[:] = np.cumsum(gaps)
        frames.time_ms[:] = frames.frame_number * 1000.0 / rate
    coding = "dct" if ch.bool(0.15) else "arithmetic"
    opts = EncoderOptions(
        fap_quant=ch.choice((0, 1, 1, 2, 4, 8, 16, 31)),
        intra_period=ch.choice((0, 0, 1, 2, 5)),
        time_codes=ch.bool(0.3),
        plane_start_codes=ch.choice(("none", "intra", "all")),
        ranges=ch.choice(("auto", "persist")),
        partial_mask_type=ch.choice((None, 1, 2)),
        gender=ch.int(0, 1),
        coding=coding,
        end_code=ch.bool(0.85),
        frame_rate=None if ch.bool(0.8) else ch.choice(("30000/1001", 12.5, 25)),
    )
    if coding == "arithmetic" and n >= 4 and ch.bool(0.1):
        run = ch.int(1, 3)
        opts.coding_per_frame = ["arithmetic" if (k // run) % 2 == 0 else "dct" for k in range(n)]
    try:
        res = encode(frames, opts)
    except FbaconfInputError:
        res = encode(synthetic_sequence(2, 25.0, visemes=False, expressions=False, faps=[3, 19]), EncoderOptions())
        return Entry(res.data, origin="generate:valid(fallback)", valid=True, recon=res.recon)
    return Entry(res.data, origin=f"generate:valid(n={n},q={opts.fap_quant},{coding})", valid=True, recon=res.recon)
