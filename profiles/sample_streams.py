"""Streams for checker tests and the benchmark, made with the reference encoder.

``smooth_frames`` gives every coded low-level FAP a smooth random walk in units of its own
quantiser step, kept away from 0 and always moving, so that no intra or predicted
alphabet collapses to a single symbol (FAP-SEM-008) and unidirectional FAPs stay positive.
"""

from __future__ import annotations

import numpy as np

from fbaconf.bitstreams import tables
from fbaconf.bitstreams.arith import ZERO_RUN_LIMIT, ArithEncoder, make_model
from fbaconf.bitstreams.bitedit import end_stream, get_bits, splice
from fbaconf.bitstreams.bitio import BitWriter
from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.encoder import EncoderOptions, encode
from fbaconf.bitstreams.frames import SET, FapFrames


def smooth_frames(
    n: int, rate: float = 30.0, faps=range(3, 69), *, seed: int = 0, amplitude: int = 6, max_step: int = 2
) -> FapFrames:
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


def zero_heavy_plane(faps=range(3, 20)) -> bytes:
    """One intra plane whose FAPs sit at the top of wide explicit ranges (+-1860 steps): long
    zero runs, so its arithmetic block contains stuffing bits."""
    b = np.zeros((68, 4), dtype=np.int64)
    b[:] = (1860, -1860, 1860, -1860)
    f = FapFrames.empty(1, 30.0)
    for fap in faps:
        f.status[0, fap - 1] = SET
        f.values[0, fap - 1] = 1860 * int(tables.quant_steps()[fap - 1])
    return encode(f, EncoderOptions(bounds=b, plane_start_codes="none")).data


def stuffing_positions(data: bytes, start: int, length: int) -> list[int]:
    """Stream offsets of the stuffing bits inside an arithmetic block (after each zero run of
    ZERO_RUN_LIMIT), found independently of the decoder by scanning the bits."""
    out, zeros, pos = [], 0, start
    while pos < start + length:
        b = get_bits(data, pos, 1)
        pos += 1
        zeros = zeros + 1 if b == 0 else 0
        if zeros == ZERO_RUN_LIMIT:
            out.append(pos)
            pos += 1
            zeros = 0
    return out


def make_stream(
    n: int = 30,
    rate: float = 30.0,
    faps=range(3, 69),
    *,
    seed: int = 0,
    amplitude: int = 6,
    max_step: int = 2,
    **options,
) -> bytes:
    """Encoded bytes of :func:`smooth_frames` with EncoderOptions(**options)."""
    opts = EncoderOptions(**options)
    return encode(smooth_frames(n, rate, faps, seed=seed, amplitude=amplitude, max_step=max_step), opts).data


__all__ = ["make_stream", "smooth_frames", "stuffing_positions", "zero_heavy_plane"]


def value_overflow_stream(planes: int = 2260) -> bytes:
    """FAP 47 (tongue_roll, step 512), range 0..1860 steps: an intra plane at +1860 steps, then
    predicted planes each adding +1860 steps (the top symbol of the adaptive P model, coded
    with the codec's own arithmetic encoder, as an encoder would) until the value passes
    2^31 - 1: the value-overflow rule. The encoder itself refuses values beyond +-1860 steps,
    so the predicted planes are written here."""
    fap = 47
    bnd = np.zeros((68, 4), dtype=np.int64)
    bnd[fap - 1] = (1860, 0, 1860, 0)
    f = FapFrames.empty(1, 30.0)
    f.status[:, fap - 1] = SET
    f.values[0, fap - 1] = 1860 * 512
    e = encode(f, EncoderOptions(bounds=bnd, plane_start_codes="none")).data
    end = decode(e).planes[0].end_offset
    w = BitWriter()
    model = make_model(1861)
    for _ in range(planes):
        w.bit(0)  # is_intra
        w.write(1, 2)  # fba_object_mask 01
        w.bit(0)  # no skip
        enc = ArithEncoder(w)
        enc.encode(model, 1860)
        enc.flush()
    n = w.position
    return end_stream(splice((e, 0, end), (w.getvalue(), 0, n)), end + n)
