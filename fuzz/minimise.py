"""Minimisation of a finding's input (ddmin over bytes, then bits)."""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable

from fbaconf.bitstreams.bitedit import from_bits, to_bits, truncate_bits


def ddmin(units: list, test: Callable[[list], bool], *, budget: Callable[[], bool]) -> list:
    """Delta debugging (complement removal, Zeller & Hildebrandt) of ``units`` keeping ``test`` true."""
    n = 2
    while len(units) >= 2 and budget():
        chunk = math.ceil(len(units) / n)
        reduced = False
        # try removing chunks from the end first: truncations are the commonest reduction
        for i in reversed(range(0, len(units), chunk)):
            if not budget():
                break
            cand = units[:i] + units[i + chunk:]
            if cand and test(cand):
                units = cand
                n = max(n - 1, 2)
                reduced = True
                break
        if not reduced:
            if n >= len(units):
                break
            n = min(len(units), n * 2)
    return units


@dataclass
class MinimiseStats:
    tests: int = 0
    seconds: float = 0.0
    bytes_before: int = 0
    bytes_after: int = 0


def minimise(data: bytes, test: Callable[[bytes], bool], *, max_tests: int = 600, max_seconds: float = 30.0,
             boundaries: list[int] | None = None, bits: bool = True) -> tuple[bytes, MinimiseStats]:
    """The smallest input found that still passes ``test`` (same classification): prefixes at
    plane boundaries, then ddmin on bytes, then on bits (inputs up to 512 bytes)."""
    t0 = time.perf_counter()
    stats = MinimiseStats(bytes_before=len(data))
    cache: dict[bytes, bool] = {data: True}

    def budget() -> bool:
        return stats.tests < max_tests and time.perf_counter() - t0 < max_seconds

    def t(cand: bytes) -> bool:
        if cand in cache:
            return cache[cand]
        stats.tests += 1
        ok = bool(test(cand))
        cache[cand] = ok
        return ok

    best = data
    for b in sorted(set(boundaries or [])):  # shortest plane-boundary prefix first
        if not budget():
            break
        cand = truncate_bits(best, b)
        if len(cand) < len(best) and t(cand):
            best = cand
            break
    if budget():
        best = bytes(ddmin(list(best), lambda u: t(bytes(u)), budget=budget))
    if bits and len(best) <= 512 and budget():
        bl = ddmin(list(to_bits(best)), lambda u: t(from_bits("".join(u))), budget=budget)
        cand = from_bits("".join(bl))
        if len(cand) <= len(best) and t(cand):
            best = cand
    stats.seconds = time.perf_counter() - t0
    stats.bytes_after = len(best)
    return best, stats
