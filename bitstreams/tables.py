"""The FAP tables, loaded once from the versioned data files in ``data/``.

Nothing here hard-codes a table value: every number comes from a CSV file that names
its provenance, so a normative correction is a data change only.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources

import numpy as np

from . import readings

NUM_FAPS = 68
NUM_GROUPS = 10
RANGE_DELTA = 60  # unit of the new min/max lists (spec notes 1.4)
MAX_RANGE_CODE = 31  # 5-bit list values
MAX_RANGE = MAX_RANGE_CODE * RANGE_DELTA  # 1860


def _rows(name: str) -> list[dict[str, str]]:
    text = resources.files("fbaconf.bitstreams").joinpath("data", name).read_text("utf-8")
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.startswith("#")]
    return list(csv.DictReader(lines))


@dataclass(frozen=True)
class FapInfo:
    number: int
    name: str
    bifs_name: str
    fapu: str  # '' for FAP 1/2
    direction: str  # 'U', 'B' or ''
    positive_motion: str
    group: int
    feature_points: tuple[str, ...]
    quant_step: int
    intra_range: int  # default +- bound (fap_quant = 1 units), 0 for FAP 1/2
    pred_range: int
    provenance: str


@dataclass(frozen=True)
class GroupInfo:
    group: int
    first_fap: int
    last_fap: int
    size: int
    description: str

    @property
    def faps(self) -> range:
        return range(self.first_fap, self.last_fap + 1)


@dataclass(frozen=True)
class FapuInfo:
    fapu: str
    description: str
    point_a: str
    point_b: str
    axis: str
    divisor: float
    unit_value: float | None
    provenance: str


@lru_cache(maxsize=1)
def fap_table() -> tuple[FapInfo, ...]:
    out = []
    for r in _rows("fap_table.csv"):
        out.append(
            FapInfo(
                number=int(r["number"]),
                name=r["name"],
                bifs_name=r["bifs_name"],
                fapu=r["fapu"],
                direction=r["direction"],
                positive_motion=r["positive_motion"],
                group=int(r["group"]),
                feature_points=tuple(p for p in r["feature_point"].split(";") if p),
                quant_step=int(r["quant_step"]),
                intra_range=int(r["intra_range"] or 0),
                pred_range=int(r["pred_range"] or 0),
                provenance=r["provenance"],
            )
        )
    if [f.number for f in out] != list(range(1, NUM_FAPS + 1)):
        raise RuntimeError("fap_table.csv must list FAPs 1..68 in order")
    return tuple(out)


@lru_cache(maxsize=1)
def groups() -> tuple[GroupInfo, ...]:
    out = tuple(
        GroupInfo(int(r["group"]), int(r["first_fap"]), int(r["last_fap"]), int(r["size"]), r["description"])
        for r in _rows("groups.csv")
    )
    table = fap_table()
    for g in out:
        if g.size != g.last_fap - g.first_fap + 1 or any(table[n - 1].group != g.group for n in g.faps):
            raise RuntimeError(f"groups.csv disagrees with fap_table.csv for group {g.group}")
    if len(out) != NUM_GROUPS:
        raise RuntimeError("groups.csv must list 10 groups")
    return out


@lru_cache(maxsize=1)
def fapu_table() -> dict[str, FapuInfo]:
    out = {}
    for r in _rows("fapu.csv"):
        out[r["fapu"]] = FapuInfo(
            r["fapu"],
            r["description"],
            r["point_a"],
            r["point_b"],
            r["axis"],
            float(r["divisor"] or 0),
            float(r["unit_value"]) if r["unit_value"] else None,
            r["provenance"],
        )
    return out


@lru_cache(maxsize=1)
def visemes() -> tuple[tuple[int, str, str], ...]:
    return tuple((int(r["number"]), r["phonemes"], r["example"]) for r in _rows("visemes.csv"))


@lru_cache(maxsize=1)
def expressions() -> tuple[tuple[int, str], ...]:
    return tuple((int(r["number"]), r["name"]) for r in _rows("expressions.csv"))


def round_up_range(v: int) -> int:
    """Round a default bound away from zero to a multiple of RANGE_DELTA (decision D4)."""
    return -(-v // RANGE_DELTA) * RANGE_DELTA


@lru_cache(maxsize=1)
def quant_steps() -> np.ndarray:
    """int64[68]: default quantiser step QP per FAP (index = FAP number - 1)."""
    return np.array([f.quant_step for f in fap_table()], dtype=np.int64)


def default_bounds() -> np.ndarray:
    """int64[68, 4]: initial (i_max, i_min, p_max, p_min) in fap_quant = 1 units (decision D4;
    the table's values as listed under the other reading ``D4:defaults-unrounded``).

    Rows 0 and 1 (FAP 1/2) are unused (their alphabets are fixed by decision D5)."""
    return _default_bounds(readings.active(readings.DEFAULTS_UNROUNDED))


@lru_cache(maxsize=2)
def _default_bounds(unrounded: bool) -> np.ndarray:
    rnd = (lambda v: v) if unrounded else round_up_range
    b = np.zeros((NUM_FAPS, 4), dtype=np.int64)
    for f in fap_table()[2:]:
        i, p = rnd(f.intra_range), rnd(f.pred_range)
        b[f.number - 1] = (i, -i, p, -p)
    return b


def group_of_fap() -> np.ndarray:
    return np.array([f.group for f in fap_table()], dtype=np.int64)


def fap_by_name(name: str) -> FapInfo:
    for f in fap_table():
        if f.name == name or f.bifs_name == name:
            return f
    raise KeyError(name)


# Left/right pairs of low-level FAPs (same name with l <-> r). Derived from the table's names.
@lru_cache(maxsize=1)
def left_right_pairs() -> tuple[tuple[int, int], ...]:
    names = {f.name: f.number for f in fap_table()}
    pairs = []
    for f in fap_table():
        parts = f.name.split("_")
        swap = {"l": "r", "lm": "rm"}
        if any(p in swap for p in parts):
            other = "_".join(swap.get(p, p) for p in parts)
            if other in names:
                pairs.append((f.number, names[other]))
    return tuple(pairs)
