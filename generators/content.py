"""Suite content: procedural FAP sequences from a case's content spec, and the encoder options of a case."""
from __future__ import annotations

from fractions import Fraction

import numpy as np

from fbaconf.bitstreams import tables
from fbaconf.bitstreams.encoder import EncoderOptions
from fbaconf.bitstreams.frames import FREE, HIGH_LEVEL_FIELDS
from fbaconf.bitstreams.synth import synthetic_sequence


def make_content(c: dict):
    """Procedural FapFrames for a case's ``content`` table."""
    frames = synthetic_sequence(int(c.get("frames", 30)), float(c.get("rate", 25.0)),
                                visemes=bool(c.get("visemes", True)), expressions=bool(c.get("expressions", True)),
                                faps=c.get("faps"), seed=int(c.get("seed", 0)))
    scale = float(c.get("scale", 1.0))
    if scale != 1.0:
        frames.values[:] = np.round(frames.values * scale).astype(np.int32)
    if c.get("negate"):
        qs = tables.quant_steps()
        for fap in c["negate"]:  # strictly negative: -(|v| + 40 steps), beyond any quantiser's dead zone
            j = int(fap) - 1
            frames.values[:, j] = -(np.abs(frames.values[:, j]) + 40 * int(qs[j]))
    for name, v in c.get("set_high", {}).items():
        col = HIGH_LEVEL_FIELDS.index(name)
        frames.high[:, col] = np.resize(np.asarray(v, dtype=np.int32), len(frames))
    for fap, v in c.get("set_values", {}).items():
        frames.values[:, int(fap) - 1] = np.resize(np.asarray(v, dtype=np.int32), len(frames))
        frames.status[:, int(fap) - 1] = 1
    start = int(c.get("start_frame", 0))
    if start:  # the content begins later in the stream's timeline (skip chain + time codes past a minute)
        frames.frame_number = frames.frame_number + start
        frames.time_ms = frames.frame_number * 1000.0 / frames.frame_rate
    k = int(c.get("sparse", 0))
    if k > 1:
        # FAP f is coded only in frames where (frame + f) % k == 0, always in frame 0
        n = len(frames)
        rows = np.arange(n)[:, None]
        cols = np.arange(frames.values.shape[1])[None, :]
        drop = ((rows + cols) % k != 0) & (rows > 0)
        frames.status[:, 2:][drop[:, 2:]] = FREE
    for fap, (a, b) in c.get("free_after", {}).items():  # FAP coded only in frames [a, b)
        j = int(fap) - 1
        keep = np.zeros(len(frames), bool)
        keep[int(a):int(b)] = True
        frames.status[~keep, j] = FREE
    ext = [int(f) for f in c.get("extremes", [])]
    if ext:  # values at the ends of the widest range (+-1860 steps): 0, +M, 0, -M ... (alternating phase)
        qs = tables.quant_steps()
        pat = np.array([1, 0, -1, 0])
        for i, f in enumerate(ext):
            m = 1860 * int(qs[f - 1])
            frames.values[:, f - 1] = m * np.resize(np.roll(pat, i), len(frames))
            frames.status[:, f - 1] = 1
    drops = c.get("drop", [])  # [[first, count], ...]: frames left out -> skip_frames
    if drops:
        keep = np.ones(len(frames), bool)
        for a, n in drops:
            keep[int(a):int(a) + int(n)] = False
        frames = frames.select(np.nonzero(keep)[0])
    return frames


def encoder_options(o: dict, n_frames: int):
    o = dict(o)
    cpf = o.pop("coding_per_frame", None)
    if isinstance(cpf, str) and cpf.startswith("alternate:"):
        run = int(cpf.split(":")[1])
        o["coding_per_frame"] = ["arithmetic" if (k // run) % 2 == 0 else "dct" for k in range(n_frames)]
    if isinstance(o.get("frame_rate"), str) and "/" in o["frame_rate"]:
        o["frame_rate"] = Fraction(o["frame_rate"])
    qpf = o.get("fap_quant_per_frame")
    if isinstance(qpf, str):  # "1:10,2:10" = ten frames at 1, ten at 2
        q = []
        for part in qpf.split(","):
            v, n = part.split(":")
            q += [int(v)] * int(n)
        o["fap_quant_per_frame"] = np.array((q * n_frames)[:n_frames])
    b = o.get("bounds")
    if isinstance(b, str):  # "wide": every list value 31 (+-1860), "wide:<fap>,<fap>": only those FAPs
        arr = tables.default_bounds().copy()
        faps = range(3, 69) if b == "wide" else [int(x) for x in b.split(":", 1)[1].split(",")]
        for f in faps:
            arr[f - 1] = (1860, -1860, 1860, -1860)
        o["bounds"] = arr
    return EncoderOptions(**o)
