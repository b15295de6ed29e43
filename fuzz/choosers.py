"""Choosers: where random decisions come from (a seeded RNG, or hypothesis' draw)."""

from __future__ import annotations

import random


class Chooser:
    """Source of choices: :class:`RandomChooser` (the fuzz loop) or :class:`DrawChooser` (hypothesis)."""

    def int(self, lo: int, hi: int) -> int:  # pragma: no cover - interface
        raise NotImplementedError

    def choice(self, seq):
        return seq[self.int(0, len(seq) - 1)]

    def bool(self, p: float = 0.5) -> bool:
        return self.int(0, 999) < int(p * 1000)

    def float(self, lo: float, hi: float) -> float:
        return lo + (hi - lo) * self.int(0, 10**6) / 10**6


class RandomChooser(Chooser):
    def __init__(self, rng: random.Random) -> None:
        self.rng = rng

    def int(self, lo: int, hi: int) -> int:
        return self.rng.randint(lo, hi)


class DrawChooser(Chooser):
    def __init__(self, draw) -> None:
        from hypothesis import strategies as st  # noqa: PLC0415 (test-only dependency)

        self.draw, self.st = draw, st

    def int(self, lo: int, hi: int) -> int:
        return self.draw(self.st.integers(lo, hi))
