"""The encoder's plan of a sequence: where intra planes go, the closed-loop reconstruction and
every plane's symbols (the ranges the encoder keeps its values in, decision D4)."""

from __future__ import annotations

import numpy as np

from .encoder_options import EncoderOptions
from .frames import HIGH_LEVEL_FIELDS, SET, FapFrames
from .syntax import (
    INTENSITY_MAX,
    intensity_step,
    low_level_step,
    quant_div,
    quantise,
)
from .tables import MAX_RANGE, NUM_FAPS, RANGE_DELTA


class Plan:
    """Intra placement, closed-loop reconstruction and the symbols of every plane."""

    def __init__(
        self, frames: FapFrames, opts: EncoderOptions, quants: np.ndarray, types: np.ndarray, forced: set[int]
    ) -> None:
        n = len(frames)
        coded = frames.status == SET
        self.coded = coded
        self.full_alphabet = opts.full_intensity_alphabet
        self.intra = np.zeros(n, dtype=bool)
        for k in range(n):
            if k == 0 or k in forced:
                self.intra[k] = True
            elif (coded[k] != coded[k - 1]).any() or (types[k] != types[k - 1]).any() or quants[k] != quants[k - 1]:
                self.intra[k] = True
        if opts.intra_period > 0:
            last = 0
            for k in range(n):
                if self.intra[k]:
                    last = k
                elif k - last >= opts.intra_period:
                    self.intra[k] = True
                    last = k
        # closed loop
        vals = frames.values.astype(np.int64)
        high = frames.high.astype(np.int64)
        self.sym = np.zeros((n, NUM_FAPS), dtype=np.int64)  # low-level symbol value Q (intra: level, P: delta)
        self.hsym = np.zeros((n, len(HIGH_LEVEL_FIELDS)), dtype=np.int64)
        self.recon = np.zeros((n, NUM_FAPS), dtype=np.int64)
        self.rhigh = np.zeros((n, len(HIGH_LEVEL_FIELDS)), dtype=np.int64)
        cur = np.zeros(NUM_FAPS, dtype=np.int64)
        hcur = np.zeros(len(HIGH_LEVEL_FIELDS), dtype=np.int64)
        steps_by_q: dict[int, np.ndarray] = {}
        for k in range(n):
            q = int(quants[k])
            steps = steps_by_q.get(q)
            if steps is None:
                steps = steps_by_q[q] = np.array(
                    [1, 1] + [low_level_step(f, q) for f in range(3, NUM_FAPS + 1)], dtype=np.int64
                )
            c = coded[k]
            idx = np.nonzero(c[2:])[0] + 2
            if self.intra[k]:
                target = vals[k, idx]
            else:
                target = vals[k, idx] - cur[idx]
            st = steps[idx]
            h = st // 2
            a = np.abs(target)
            lvl = np.where(a <= h, 0, (a + h) // st) * np.sign(target)
            self.sym[k, idx] = lvl
            cur[idx] = (0 if self.intra[k] else cur[idx]) + lvl * st
            istep = intensity_step(q)
            if c[0]:
                for j in (0, 1):
                    self.hsym[k, j] = high[k, j] if self.intra[k] else high[k, j] - hcur[j]
                    hcur[j] = high[k, j]
                self._intensity(k, 2, high, hcur, istep)
                hcur[3] = high[k, 3]
            if c[1]:
                for j in (4, 6):
                    self.hsym[k, j] = high[k, j] if self.intra[k] else high[k, j] - hcur[j]
                    hcur[j] = high[k, j]
                for j in (5, 7):
                    self._intensity(k, j, high, hcur, istep)
                hcur[8] = high[k, 8]
                hcur[9] = high[k, 9]
            self.recon[k] = cur
            self.rhigh[k] = hcur
        # needed bounds per segment, in fap_quant = 1 units: (i_max, i_min, p_max, p_min)
        self.segments: list[tuple[int, int]] = []
        starts = list(np.nonzero(self.intra)[0]) + [n]
        for a, b in zip(starts[:-1], starts[1:]):
            self.segments.append((int(a), int(b)))
        self.need = {}
        self.p_overflow: list[int] = []
        self.levels = np.zeros((n, NUM_FAPS), dtype=np.int64)  # reconstructed value / step
        for k in range(n):
            self.levels[k] = self.recon[k] // steps_by_q[int(quants[k])]
        for a, b in self.segments:
            d = quant_div(int(quants[a]))
            # the intra range covers every value of the segment, also those reached by prediction:
            # a predicted value outside it is valid (D4's range rule) but warned (FAP-DECISION-008),
            # and the encoder keeps its streams off that reading
            lv = np.where(coded[a:b], self.levels[a:b], 0)
            need = np.zeros((NUM_FAPS, 4), dtype=np.int64)
            need[:, 0] = np.maximum(lv.max(axis=0), 0) * d
            need[:, 1] = np.minimum(lv.min(axis=0), 0) * d
            if b > a + 1:
                ps = self.sym[a + 1 : b]
                need[:, 2] = np.maximum(ps.max(axis=0), 0) * d
                need[:, 3] = np.minimum(ps.min(axis=0), 0) * d
                over = (np.abs(ps) * d > MAX_RANGE) & coded[a + 1 : b]
                rows = np.nonzero(over.any(axis=1))[0]
                if len(rows):
                    self.p_overflow.append(a + 1 + int(rows[0]))
            self.need[a] = need

    def _intensity(self, k: int, j: int, high, hcur, istep: int) -> None:
        """Quantise a blend/intensity closed-loop, keeping the reconstruction inside 0..63.

        D5's alphabet allows floor((63 + floor(q/2)) / q) x q, which can exceed 63 (64 at
        q = 2); a decoder must output it, but this encoder produces it only with
        ``full_intensity_alphabet``: otherwise the level is lowered to the largest multiple of
        q <= 63 instead (error < q there, else <= q/2)."""
        base = 0 if self.intra[k] else int(hcur[j])
        level = quantise(int(high[k, j]) - base, istep)
        r = base + level * istep
        if r > INTENSITY_MAX and not self.full_alphabet:
            level = (INTENSITY_MAX - base) // istep
        elif r < 0:
            level = -(base // istep)
        self.hsym[k, j] = level
        hcur[j] = base + level * istep


def bound_code(v: int) -> int:
    """Smallest 5-bit list value whose bound (x 60) covers magnitude v."""
    return -(-abs(int(v)) // RANGE_DELTA)


MAX_EMULATION_FIXES = 64
