"""Checker diagnostics: the Diagnostic record, its location, folding and selection.

The codes themselves (severity, clause, description) live in the one rule registry,
:mod:`fbaconf.rules`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from fbaconf.rules import CODES, SEVERITIES


# ---------------------------------------------------------------------------- records
@dataclass(frozen=True)
class Location:
    bit_offset: int | None = None
    plane: int | None = None
    frame: int | None = None
    fap: int | None = None
    node_path: str | None = None
    time_ms: float | None = None
    line: int | None = None  # text input (.fap): 1-based line and column (characters)
    column: int | None = None

    @property
    def byte_offset(self) -> int | None:
        return None if self.bit_offset is None else self.bit_offset // 8

    def to_dict(self) -> dict:
        d: dict = {}
        if self.bit_offset is not None:
            d["byte_offset"] = self.bit_offset // 8
            d["bit"] = self.bit_offset % 8
            d["bit_offset"] = self.bit_offset
        for k in ("plane", "frame", "fap", "node_path"):
            v = getattr(self, k)
            if v is not None:
                d[k] = v
        if self.time_ms is not None:
            d["time_ms"] = round(float(self.time_ms), 3)
        if self.line is not None:
            d["line"] = self.line
            d["column"] = self.column if self.column is not None else 1
        return d

    def __str__(self) -> str:
        parts = []
        if self.line is not None:
            parts.append(f"line {self.line}:{self.column if self.column is not None else 1}")
        if self.bit_offset is not None:
            parts.append(f"byte {self.bit_offset // 8} bit {self.bit_offset % 8}")
        if self.plane is not None:
            parts.append(f"plane {self.plane}")
        if self.frame is not None:
            parts.append(f"frame {self.frame}")
        if self.fap is not None:
            parts.append(f"FAP {self.fap}")
        if self.node_path:
            parts.append(self.node_path)
        return ", ".join(parts) or "stream"

    def sort_key(self) -> tuple:
        return (
            self.bit_offset if self.bit_offset is not None else 1 << 62,
            self.line or 0,
            self.column or 0,
            self.node_path or "",
        )


@dataclass(frozen=True)
class Diagnostic:
    code: str
    severity: str
    message: str
    clause: str
    location: Location = field(default_factory=Location)

    def to_dict(self) -> dict:
        return {
            "code": self.code,
            "severity": self.severity,
            "message": self.message,
            "clause": self.clause,
            "location": self.location.to_dict(),
        }

    def __str__(self) -> str:
        return f"{self.severity}: {self.code} at {self.location}: {self.message} [{self.clause}]"


def diag(
    code: str,
    message: str,
    *,
    bit_offset: int | None = None,
    plane: int | None = None,
    frame: int | None = None,
    fap: int | None = None,
    node_path: str | None = None,
    time_ms: float | None = None,
) -> Diagnostic:
    """A diagnostic for a registered code (severity and clause come from the registry)."""
    info = CODES[code]
    return Diagnostic(
        code,
        info.severity,
        message,
        info.clause,
        Location(None if bit_offset is None else int(bit_offset), plane, frame, fap, node_path, time_ms),
    )


def text_diag(code: str, message: str, line: int, column: int) -> Diagnostic:
    """A diagnostic of a text input (.fap) at line:column."""
    info = CODES[code]
    return Diagnostic(code, info.severity, message, info.clause, Location(line=line, column=column))


@dataclass
class Issue:
    """Repeated diagnostics of one code folded: the first message, a count and the first locations."""

    code: str
    severity: str
    clause: str
    message: str
    count: int
    locations: list[Location]

    def to_dict(self) -> dict:
        return {
            "code": self.code,
            "severity": self.severity,
            "clause": self.clause,
            "message": self.message,
            "count": self.count,
            "locations": [loc.to_dict() for loc in self.locations],
            "omitted_locations": self.count - len(self.locations),
        }


def fold(diags: list[Diagnostic], first: int = 5) -> list[Issue]:
    """Fold diagnostics by code, in order of first occurrence: count + the first ``first`` locations."""
    out: dict[str, Issue] = {}
    for d in diags:
        it = out.get(d.code)
        if it is None:
            out[d.code] = Issue(d.code, d.severity, d.clause, d.message, 1, [d.location])
        else:
            it.count += 1
            if len(it.locations) < first:
                it.locations.append(d.location)
    return list(out.values())


def select(diags: list[Diagnostic], only: list[str] | None = None, ignore: list[str] | None = None) -> list[Diagnostic]:
    """Keep the codes in ``only`` (all when empty) and drop those in ``ignore``. A pattern ending
    in '*' matches a prefix (``FAP-DECISION-*``)."""

    def match(code: str, pats) -> bool:
        return any(code == p or (p.endswith("*") and code.startswith(p[:-1])) for p in pats)

    out = diags
    if only:
        out = [d for d in out if match(d.code, only)]
    if ignore:
        out = [d for d in out if not match(d.code, ignore)]
    return out


def counts(diags) -> dict[str, int]:
    c = {s: 0 for s in SEVERITIES}
    for d in diags:
        c[d.severity] += getattr(d, "count", 1)
    return c


__all__ = ["Diagnostic", "Issue", "Location", "counts", "diag", "fold", "select", "text_diag"]
