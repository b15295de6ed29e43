"""Streams for checker tests and the benchmark, made with the reference encoder.

``smooth_frames`` gives every coded low-level FAP a smooth random walk in units of its own
quantiser step, kept away from 0 and always moving, so that no intra or predicted
alphabet collapses to a single symbol (FAP-SEM-008) and unidirectional FAPs stay positive.
"""
from __future__ import annotations

import numpy as np

from fbaconf.bitstreams import tables
from fbaconf.bitstreams.encoder import EncoderOptions, encode
from fbaconf.bitstreams.frames import SET, FapFrames


def smooth_frames(n: int, rate: float = 30.0, faps=range(3, 69), *, seed: int = 0, amplitude: int = 6,
                  max_step: int = 2) -> FapFrames:
    """n frames at ``rate`` Hz, the given low-level FAPs coded in every frame."""
    rng = np.random.default_rng(seed)
    f = FapFrames.empty(n, rate)
    faps = [int(x) for x in faps]
    qp = tables.quant_steps()
    k = np.arange(n)
    for j, fap in enumerate(faps):
        walk = np.cumsum(rng.integers(-max_step, max_step + 1, size=n))
        walk = np.clip(walk, -amplitude, amplitude)
        # a slow sine keeps the FAP moving in both directions in every segment
        sine = np.round(amplitude * np.sin(2 * np.pi * k / 8.0 + j))
        level = 2 * amplitude + 1 + np.clip(walk + sine, -2 * amplitude, 2 * amplitude)
        f.values[:, fap - 1] = (level * qp[fap - 1]).astype(np.int32)
        f.status[:, fap - 1] = SET
    return f


def make_stream(n: int = 30, rate: float = 30.0, faps=range(3, 69), *, seed: int = 0, amplitude: int = 6,
                max_step: int = 2, **options) -> bytes:
    """Encoded bytes of :func:`smooth_frames` with EncoderOptions(**options)."""
    opts = EncoderOptions(**options)
    return encode(smooth_frames(n, rate, faps, seed=seed, amplitude=amplitude, max_step=max_step), opts).data


__all__ = ["make_stream", "smooth_frames"]
