"""Minimisation of a finding's input (ddmin over bytes, then bits), checked: a minimised input
is reported only once it has done again, on a fresh run, what it was kept for."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

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
            cand = units[:i] + units[i + chunk :]
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
    reproduced: bool | None = None  # the input returned did it again when re-run at the end
    flaky: bool = False  # a re-run of the original or the minimal input did not do it again


def minimise(
    data: bytes,
    test: Callable[[bytes], bool],
    *,
    max_tests: int = 600,
    max_seconds: float = 30.0,
    boundaries: list[int] | None = None,
    bits: bool = True,
    check: Callable[[bytes], bool] | None = None,
) -> tuple[bytes, MinimiseStats]:
    """The smallest input found that still passes ``test`` (same classification): prefixes at
    plane boundaries, then ddmin on bytes, then on bits (inputs up to 512 bytes).

    Checked at both ends, outside the cache, so a finding that does not repeat is never reported
    as a minimal input: the original is run first — if it does not do it again, nothing is
    minimised (``flaky``); the minimal input is run again last — if it does not, the original is
    returned instead (``flaky``, and ``reproduced`` says whether the original did). The two
    checks run ``check`` when given (a decoder process of the input's own:
    ``DecoderTarget.alone``), ``test`` otherwise."""
    t0 = time.perf_counter()
    stats = MinimiseStats(bytes_before=len(data))
    cache: dict[bytes, bool] = {data: True}

    def budget() -> bool:
        return stats.tests < max_tests and time.perf_counter() - t0 < max_seconds

    def fresh(cand: bytes) -> bool:
        stats.tests += 1
        return bool((check or test)(cand))

    def t(cand: bytes) -> bool:
        if cand not in cache:
            stats.tests += 1
            cache[cand] = bool(test(cand))
        return cache[cand]

    def done(best: bytes, reproduced: bool) -> tuple[bytes, MinimiseStats]:
        stats.reproduced = reproduced
        stats.seconds = time.perf_counter() - t0
        stats.bytes_after = len(best)
        return best, stats

    if not fresh(data):
        stats.flaky = True
        return done(data, False)
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
    if best == data or fresh(best):
        return done(best, True)
    stats.flaky = True  # the minimisation rested on results that do not repeat
    return done(data, fresh(data))
