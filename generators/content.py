"""Suite content: procedural FAP sequences from a case's content spec, and the encoder options of a case."""

from __future__ import annotations

from fractions import Fraction

import numpy as np

from fbaconf.bitstreams import tables
from fbaconf.bitstreams.encoder import EncoderOptions
from fbaconf.bitstreams.frames import FREE, HIGH_LEVEL_FIELDS, SET, FapFrames
from fbaconf.bitstreams.synth import synthetic_sequence


def sweep_content(groups: list[list[int]], scale: dict, rate: float = 25.0):
    """FapFrames that show every FAP in turn: frame 0 neutral (nothing sent), then one
    frame per group of ``groups``. A group's low-level FAPs (negative = the negative direction)
    take ``scale[fap]`` (else ``scale["default"]``) times their default intra range, in whole
    quantiser steps; every other low-level FAP is sent as 0 from the first low-level group on.
    FAP 1 / 2 in a group: viseme 10 / expression 1 (joy) at full weight, with the low-level FAPs
    unsent (FREE) in that frame so that the high-level table drives them — so a group holding 1 or
    2 must come before any low-level group. Each FAP is pushed far enough in its frame that a
    player ignoring it moves the part by several pixels in some scenario (the amplitudes are
    measured: ``python tests/suites/image_variants.py --drop``)."""
    out = FapFrames.empty(len(groups) + 1, frame_rate=rate)
    ft = tables.fap_table()
    low_started = False
    for k, group in enumerate(groups, 1):
        if any(abs(s) >= 3 for s in group):
            low_started = True
        if low_started:
            out.status[k, 2:] = SET
        for s in group:
            fap = abs(int(s))
            if fap == 1:
                out.status[k, 0] = SET
                for name, v in (("viseme_select1", 10), ("viseme_select2", 1), ("viseme_blend", 63)):
                    out.hl(name)[k] = v
            elif fap == 2:
                out.status[k, 1] = SET
                for name, v in (
                    ("expression_select1", 1),
                    ("expression_intensity1", 63),
                    ("expression_select2", 1),
                    ("expression_intensity2", 0),
                ):
                    out.hl(name)[k] = v
            else:
                f = ft[fap - 1]
                steps = int(round(float(scale.get(str(fap), scale["default"])) * f.intra_range))
                out.values[k, fap - 1] = (1 if int(s) > 0 else -1) * steps * int(f.quant_step)
    return out


def make_content(c: dict):
    """Procedural FapFrames for a case's ``content`` table."""
    if "sweep" in c:
        return sweep_content(c["sweep"], c.get("sweep_scale", {"default": 0.2}), float(c.get("rate", 25.0)))
    frames = synthetic_sequence(
        int(c.get("frames", 30)),
        float(c.get("rate", 25.0)),
        visemes=bool(c.get("visemes", True)),
        expressions=bool(c.get("expressions", True)),
        faps=c.get("faps"),
        seed=int(c.get("seed", 0)),
    )
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
        keep[int(a) : int(b)] = True
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
            keep[int(a) : int(a) + int(n)] = False
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
