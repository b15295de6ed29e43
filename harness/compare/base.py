"""What every comparison stage shares: limits on untrusted outputs, the error types, the worst-of outcome."""

from __future__ import annotations

from collections.abc import Iterable

from fbaconf.errors import FbaconfInputError
from fbaconf.harness.results import OUTCOME_ORDER, Outcome

DEFAULT_MAX_BYTES = 256 * 1024 * 1024  # cap of one output file, and of the decompressed arrays read from it
MAX_NPZ_MEMBERS = 64
DEFAULT_MAX_PIXELS = 64 * 1024 * 1024  # cap of width x height x channels of one image
PSNR_CAP = 100.0  # PSNR of identical images is infinite; recorded as this (JSON has no infinity)

FAPFRAMES_FORMAT = "fbaconf.FapFrames/1"
_INT32 = (-(2**31), 2**31 - 1)


class OutputError(FbaconfInputError):
    """A decoder's output file cannot be used: unreadable, too large, wrong arrays, shapes,
    dtypes or non-finite values. ``file`` names it; ``rule`` says which check failed."""

    rule = "output"


class ToleranceError(FbaconfInputError, ValueError):
    """A tolerance table (data file or a case's overrides) is invalid."""

    rule = "tolerance"


def worst(outcomes: Iterable[Outcome]) -> Outcome:
    """The worst of some stage outcomes, in ``results.OUTCOME_ORDER`` (Crash > Timeout >
    Fail > Error > QualityWarning > NotSupported > Skipped > Pass). No outcomes: Pass."""
    rank = {o: i for i, o in enumerate(OUTCOME_ORDER)}
    best = Outcome.PASS
    for o in outcomes:
        o = Outcome(o)
        if rank[o] < rank[best]:
            best = o
    return best
