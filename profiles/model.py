"""Profiles and levels, loaded from the one data file ``data/profiles.toml``.

Nothing here hard-codes a limit: every number (and its provenance and unit) comes from the
data file, so a normative correction is a data change only. The loader validates the file
(unknown tools, include cycles, missing levels, provenance values) and raises
``ProfileDataError`` naming the offending entry.

A :class:`Claim` is ``profile@level`` (``simple@1``, ``Calibration@L2``). Claims order by
(profile rank, level): for a given stream the admissible claims form an upper set in both
axes (profiles are nested, level limits grow with the level), so the first admissible claim
in that order is the unique smallest one (``--smallest-claim``).
"""

from __future__ import annotations

import difflib
import tomllib
from dataclasses import dataclass, field
from functools import lru_cache, total_ordering
from importlib import resources
from pathlib import Path

PROVENANCES = ("seed", "iso-via-implementation", "provisional")
LIMIT_KINDS = ("max", "min")
LIMIT_BOUNDS = ("stream", "scene", "decoder")
TOOL_SOURCES = ("stream", "scene")


class ProfileDataError(ValueError):
    """The profiles data file is malformed."""


@dataclass(frozen=True)
class Tool:
    id: str
    description: str
    source: str  # stream | scene


@dataclass(frozen=True)
class Indication:
    code: int
    name: str
    provenance: str
    private: bool = False


@dataclass(frozen=True)
class Limit:
    id: str
    description: str
    unit: str
    kind: str  # max | min
    applies_from: str  # lowest profile id the limit applies to
    bounds: str  # stream | scene | decoder
    provenance: str
    values: dict[int, float]  # level -> value

    def value(self, level: int) -> float:
        return self.values[level]


@dataclass(frozen=True)
class Profile:
    id: str
    name: str
    rank: int
    includes: tuple[str, ...]
    own_tools: tuple[str, ...]
    tools: frozenset[str]  # own + included, transitively
    provenance: str
    indication: dict[int, Indication] = field(default_factory=dict)
    ancestors: frozenset[str] = frozenset()  # profiles included, transitively (not self)


@dataclass(frozen=True)
class ProfileSet:
    tools: dict[str, Tool]
    profiles: dict[str, Profile]
    levels: tuple[int, ...]
    limits: dict[str, Limit]
    source: str

    def profile(self, name: str) -> Profile:
        key = name.strip().lower()
        for p in self.profiles.values():
            if p.id == key or p.name.lower() == key:
                return p
        raise KeyError(name)

    def profile_includes(self, profile: str, other: str) -> bool:
        """True when ``profile`` is ``other`` or includes it."""
        p = self.profiles[profile]
        return other == p.id or other in p.ancestors

    def limits_for(self, claim: Claim) -> list[Limit]:
        """The limits that apply to a claim (applies_from included in the claimed profile)."""
        return [lim for lim in self.limits.values() if self.profile_includes(claim.profile, lim.applies_from)]

    def claims(self) -> list[Claim]:
        out = [Claim(p.id, lv, p.rank) for p in self.profiles.values() for lv in self.levels]
        return sorted(out)

    def claim(self, text: str) -> Claim:
        return Claim.parse(text, self)


@total_ordering
@dataclass(frozen=True)
class Claim:
    profile: str  # profile id
    level: int
    rank: int = 0

    @classmethod
    def parse(cls, text: str, profiles: ProfileSet | None = None) -> Claim:
        """``simple@1`` / ``Simple@L2`` / ``calibration@l1`` -> Claim (ValueError when unknown)."""
        ps = profiles or load_profiles()
        if not isinstance(text, str) or text.count("@") != 1:
            raise ValueError(f"claim {text!r} must be PROFILE@LEVEL, e.g. simple@1")
        pname, lv = text.split("@")
        try:
            prof = ps.profile(pname)
        except KeyError:
            close = difflib.get_close_matches(pname.strip().lower(), list(ps.profiles), n=1)
            hint = f"did you mean {close[0]}@{lv.strip() or 1}? " if close else ""
            raise ValueError(f"unknown profile {pname!r} ({hint}known: {', '.join(ps.profiles)})") from None
        lv = lv.strip()
        if lv[:1] in ("L", "l"):
            lv = lv[1:]
        if not lv.isdigit() or int(lv) not in ps.levels:
            raise ValueError(f"unknown level {lv!r} (known: {', '.join(map(str, ps.levels))})")
        return cls(prof.id, int(lv), prof.rank)

    def __lt__(self, other: Claim) -> bool:
        return (self.rank, self.level, self.profile) < (other.rank, other.level, other.profile)

    def __str__(self) -> str:
        return f"{self.profile}@{self.level}"


def _err(src: str, msg: str) -> ProfileDataError:
    return ProfileDataError(f"{src}: {msg}")


def parse_profiles(text: str, source: str = "<profiles>") -> ProfileSet:
    """Parse and validate profile data (TOML text)."""
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise _err(source, f"not valid TOML: {e}") from None
    if raw.get("format") != "fbaconf.profiles/1":
        raise _err(source, "format must be 'fbaconf.profiles/1'")
    tools = _parse_tools(raw.get("tools", {}), source)
    levels = tuple(int(x) for x in raw.get("levels", {}).get("numbers", ()))
    if not levels or list(levels) != sorted(set(levels)):
        raise _err(source, "levels.numbers must be a non-empty increasing list")
    profiles = _parse_profile_table(raw.get("profiles", {}), tools, levels, source)
    limits = {lid: _parse_limit(lid, lim, profiles, levels, source) for lid, lim in raw.get("limits", {}).items()}
    return ProfileSet(tools, profiles, levels, limits, source)


def _parse_tools(raw: dict, source: str) -> dict[str, Tool]:
    tools: dict[str, Tool] = {}
    for tid, t in raw.items():
        if t.get("source") not in TOOL_SOURCES:
            raise _err(source, f"tools.{tid}.source must be one of {TOOL_SOURCES}")
        tools[tid] = Tool(tid, str(t.get("description", "")), t["source"])
    return tools


def _parse_profile_table(
    rawp: dict, tools: dict[str, Tool], levels: tuple[int, ...], source: str
) -> dict[str, Profile]:
    """The ``[profiles]`` table: references checked, includes closed (no cycle), ranks ordered."""
    if not rawp:
        raise _err(source, "no profiles")
    for pid, p in rawp.items():
        for t in p.get("tools", []):
            if t not in tools:
                raise _err(source, f"profiles.{pid}: unknown tool {t!r}")
        for inc in p.get("includes", []):
            if inc not in rawp:
                raise _err(source, f"profiles.{pid}: includes unknown profile {inc!r}")
        if p.get("provenance") not in PROVENANCES:
            raise _err(source, f"profiles.{pid}.provenance must be one of {PROVENANCES}")

    def closure(pid: str, stack: tuple[str, ...]) -> set[str]:
        if pid in stack:
            raise _err(source, f"profile include cycle: {' -> '.join(stack + (pid,))}")
        out: set[str] = set()
        for inc in rawp[pid].get("includes", []):
            out.add(inc)
            out |= closure(inc, stack + (pid,))
        return out

    profiles: dict[str, Profile] = {}
    for pid, p in rawp.items():
        anc = closure(pid, ())
        all_tools = set(p.get("tools", []))
        for a in anc:
            all_tools |= set(rawp[a].get("tools", []))
        rank = p.get("rank")
        if not isinstance(rank, int):
            raise _err(source, f"profiles.{pid}.rank must be an integer")
        profiles[pid] = Profile(
            pid,
            str(p.get("name", pid)),
            rank,
            tuple(p.get("includes", [])),
            tuple(p.get("tools", [])),
            frozenset(all_tools),
            p["provenance"],
            _parse_indications(pid, p.get("indication", {}), levels, source),
            frozenset(anc),
        )
    for pid, p in profiles.items():
        for a in p.ancestors:
            if profiles[a].rank >= p.rank:
                raise _err(source, f"profile {pid} includes {a} so its rank must be larger")
    if len({p.rank for p in profiles.values()}) != len(profiles):
        raise _err(source, "profile ranks must be distinct")
    return profiles


def _parse_indications(pid: str, raw: dict, levels: tuple[int, ...], source: str) -> dict[int, Indication]:
    ind: dict[int, Indication] = {}
    for lv, v in raw.items():
        if int(lv) not in levels:
            raise _err(source, f"profiles.{pid}.indication: unknown level {lv}")
        if v.get("provenance") not in PROVENANCES:
            raise _err(source, f"profiles.{pid}.indication.{lv}.provenance must be one of {PROVENANCES}")
        ind[int(lv)] = Indication(
            int(v["code"]), str(v.get("name", "")), v["provenance"], bool(v.get("private", False))
        )
    return ind


def _parse_limit(lid: str, lim: dict, profiles: dict[str, Profile], levels: tuple[int, ...], source: str) -> Limit:
    where = f"limits.{lid}"
    for key in ("description", "unit", "kind", "applies_from", "bounds", "provenance", "values"):
        if key not in lim:
            raise _err(source, f"{where}: missing {key}")
    for key, allowed in (("kind", LIMIT_KINDS), ("bounds", LIMIT_BOUNDS), ("provenance", PROVENANCES)):
        if lim[key] not in allowed:
            raise _err(source, f"{where}.{key} must be one of {allowed}")
    if lim["applies_from"] not in profiles:
        raise _err(source, f"{where}.applies_from: unknown profile {lim['applies_from']!r}")
    vals = {int(k): v for k, v in lim["values"].items()}
    if set(vals) != set(levels):
        raise _err(source, f"{where}.values must give a value for every level {levels}")
    for lv, v in vals.items():
        if not isinstance(v, (int, float)) or isinstance(v, bool) or v < 0:
            raise _err(source, f"{where}.values.{lv} must be a non-negative number")
    ordered = [vals[lv] for lv in levels]
    if lim["kind"] == "max" and ordered != sorted(ordered):
        raise _err(source, f"{where}: a max limit must not decrease with the level")
    return Limit(
        lid, lim["description"], lim["unit"], lim["kind"], lim["applies_from"], lim["bounds"], lim["provenance"], vals
    )


@lru_cache(maxsize=1)
def _default_text() -> str:
    return resources.files("fbaconf.profiles").joinpath("data", "profiles.toml").read_text("utf-8")


def load_profiles(path: str | Path | None = None) -> ProfileSet:
    """The suite's profile data (``data/profiles.toml``), or another file with the same schema."""
    if path is None:
        return _load_default()
    p = Path(path)
    return parse_profiles(p.read_text("utf-8"), str(p))


@lru_cache(maxsize=1)
def _load_default() -> ProfileSet:
    return parse_profiles(_default_text(), "profiles/data/profiles.toml")


__all__ = [
    "Claim",
    "Limit",
    "Profile",
    "ProfileDataError",
    "ProfileSet",
    "Tool",
    "load_profiles",
    "parse_profiles",
    "PROVENANCES",
]
