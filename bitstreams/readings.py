"""The other readings of fbaconf's provisional decisions, and the switch that turns one on.

fbaconf decodes by its decisions (spec notes D1-D10). Where a public source shows another
plausible reading, ``data/readings.toml`` lists it and the reference implements it beside the
decision, off unless :func:`using` turns it on:

* ``D3:type10-keeps`` — :meth:`fbaconf.bitstreams.decoder._Decoder._mask_state`;
* ``D4:keep-scaling`` — :meth:`fbaconf.bitstreams.decoder._Decoder.intra_header`;
* ``D4:defaults-unrounded`` — :func:`fbaconf.bitstreams.tables.default_bounds`;
* ``D4:value-range-enforced`` — :meth:`fbaconf.bitstreams.decoder._Decoder.payload` (pure-Python path);
* ``D5:blend-ceil`` — :func:`fbaconf.bitstreams.syntax.intensity_bound`;
* ``D6:default-30hz`` — :func:`fbaconf.bitstreams.syntax.default_frame_rate`;
* ``D7:rewind-14`` — :meth:`fbaconf.bitstreams.arith.ArithDecoder.finish` (pure-Python path).

The switch is process-wide: it exists so that ``fbaconf golden regenerate`` can write, beside
each case's goldens, what another reading gives (and the reference decoder program can decode by
one, ``--reading``). Nothing turns a reading on while a harness decodes for a verdict.
"""

from __future__ import annotations

import contextlib
import functools
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass
from importlib import resources

from fbaconf.errors import FbaconfInputError


class ReadingError(FbaconfInputError):
    rule = "reading"


@dataclass(frozen=True)
class Reading:
    id: str  # "D7:rewind-14": what a manifest declares
    decision: str  # "D7"
    text: str
    source: str
    warning: str  # the checker code that flags a stream whose decoding this reading can change
    pure: bool = False  # needs the pure-Python arithmetic decoder

    @property
    def slug(self) -> str:
        """The reading's folder name under a case's goldens (``D7-rewind-14``)."""
        return self.id.replace(":", "-")


@functools.lru_cache(maxsize=1)
def catalogue() -> dict[str, Reading]:
    """Every listed reading, by id (``data/readings.toml``)."""
    data = tomllib.loads(resources.files("fbaconf.bitstreams").joinpath("data/readings.toml").read_text("utf-8"))
    out = {}
    for r in data["reading"]:
        out[r["id"]] = Reading(
            id=r["id"],
            decision=r["decision"],
            text=r["text"],
            source=r["source"],
            warning=r["warning"],
            pure=bool(r.get("pure", False)),
        )
    return out


def by_slug(slug: str) -> Reading | None:
    return next((r for r in catalogue().values() if r.slug == slug), None)


def get(reading_id: str) -> Reading:
    """The reading ``reading_id``; :class:`ReadingError` naming the known ones otherwise."""
    r = catalogue().get(reading_id)
    if r is None:
        raise ReadingError(f"no reading {reading_id!r} (known: {', '.join(catalogue())})")
    return r


# The ids the decision points ask for (each listed in data/readings.toml).
TYPE10_KEEPS = "D3:type10-keeps"
KEEP_SCALING = "D4:keep-scaling"
DEFAULTS_UNROUNDED = "D4:defaults-unrounded"
VALUE_RANGE = "D4:value-range-enforced"
BLEND_CEIL = "D5:blend-ceil"
DEFAULT_30HZ = "D6:default-30hz"
REWIND_14 = "D7:rewind-14"

_active: frozenset[str] = frozenset()


def active(reading_id: str) -> bool:
    """Whether ``reading_id`` is on in this process (decision points ask this)."""
    return reading_id in _active


def pure_required() -> bool:
    """Whether an active reading needs the pure-Python arithmetic decoder."""
    return any(catalogue()[r].pure for r in _active)


@contextlib.contextmanager
def using(*reading_ids: str) -> Iterator[None]:
    """Decode by ``reading_ids`` (as well as any already on) inside the block (process-wide; not for
    concurrent decoding)."""
    global _active
    for r in reading_ids:
        get(r)
    old = _active
    _active = old | frozenset(reading_ids)
    try:
        yield
    finally:
        _active = old
