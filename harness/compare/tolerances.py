"""Tolerances of the comparison ladder: harness/data/tolerances.toml (every number with its reason) and
a case's overrides."""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import Field, asdict, dataclass, fields
from functools import lru_cache
from importlib import resources
from typing import TYPE_CHECKING, Any, ClassVar, Self

from .base import ToleranceError


@lru_cache(maxsize=1)
def _tolerance_file() -> dict[str, Any]:
    text = resources.files("fbaconf.harness").joinpath("data", "tolerances.toml").read_text("utf-8")
    return tomllib.loads(text)


def load_tolerances() -> dict[str, Any]:
    """The parsed default tolerance file (a fresh copy): ``{"vertices": {...}, "images": {...}}``."""
    return {k: dict(v) for k, v in _tolerance_file().items()}


def _check_number(cls_name: str, key: str, v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise ToleranceError(f"{cls_name}.{key} must be a number, not {type(v).__name__}", rule="tolerance-type")
    x = float(v)
    if math.isnan(x) or x < 0:
        raise ToleranceError(f"{cls_name}.{key} must be >= 0 (got {x})", rule="tolerance-value")
    return x


class _Tolerances:
    if TYPE_CHECKING:  # what the dataclass subclasses have: fields() and asdict() take them
        __dataclass_fields__: ClassVar[dict[str, Field[Any]]]

    _section = ""
    _order: tuple[tuple[str, str], ...] = ()  # (warn key, fail key) pairs that must be ordered

    @classmethod
    def defaults(cls) -> Self:
        return cls.from_dict(None, None)

    @classmethod
    def from_dict(
        cls, defaults: _Tolerances | Mapping[str, Any] | None = None, overrides: Mapping[str, Any] | None = None
    ) -> Self:
        """Tolerances from ``defaults`` (an instance, a dict, or None for the data file)
        with the keys of ``overrides`` replacing them. Unknown keys, non-numbers, negative
        or NaN values and a warn limit above its fail limit raise :class:`ToleranceError`."""
        names = [f.name for f in fields(cls)]
        if defaults is None:
            base = dict(_tolerance_file().get(cls._section, {}))
        elif isinstance(defaults, cls):
            base = asdict(defaults)
        elif isinstance(defaults, Mapping):
            base = dict(defaults)
        else:
            raise ToleranceError(
                f"{cls.__name__} defaults must be a {cls.__name__}, a table or None", rule="tolerance-type"
            )
        if overrides is not None and not isinstance(overrides, Mapping):
            raise ToleranceError(f"{cls.__name__} overrides must be a table", rule="tolerance-type")
        merged = {**base, **dict(overrides or {})}
        unknown = sorted(set(merged) - set(names))
        if unknown:
            raise ToleranceError(
                f"unknown {cls.__name__} key(s) {', '.join(map(str, unknown))} (known: {', '.join(names)})",
                rule="tolerance-key",
            )
        missing = [n for n in names if n not in merged]
        if missing:
            raise ToleranceError(f"{cls.__name__} misses {', '.join(missing)}", rule="tolerance-key")
        vals = {n: _check_number(cls.__name__, n, merged[n]) for n in names}
        for w, f in cls._order:
            if vals[w] > vals[f]:
                raise ToleranceError(
                    f"{cls.__name__}: {w} ({vals[w]}) is above {f} ({vals[f]})", rule="tolerance-order"
                )
        return cls(**vals)

    def to_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in asdict(self).items()}


@dataclass(frozen=True)
class VertexTolerances(_Tolerances):
    """Vertex comparison limits in scene units: per-frame maximum euclidean error of any
    vertex and per-frame RMS over all vertices."""

    max_tol: float
    rms_tol: float
    _section = "vertices"


@dataclass(frozen=True)
class ImageTolerances(_Tolerances):
    """Image comparison limits (harness/data/tolerances.toml says why each): per-pixel
    ``abs_tol`` + ``contrast_k`` x local contrast on sRGB-encoded values in [0, 1], the number
    of violating pixels a frame may have (``fail_pixels`` or ``fail_percent`` % of its pixels,
    whichever is more), pixels with local contrast above ``edge_contrast`` are edges, and
    CIEDE2000 limits on the interior and the whole image."""

    abs_tol: float
    contrast_k: float
    edge_contrast: float
    fail_pixels: float
    fail_percent: float
    interior_deltae_warn_mean: float
    interior_deltae_fail_mean: float
    interior_deltae_fail_p99: float
    deltae_fail_mean: float
    _section = "images"
    _order = (("interior_deltae_warn_mean", "interior_deltae_fail_mean"),)
