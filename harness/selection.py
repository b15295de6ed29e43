"""Which cases a decoder must pass, and which it can take.

* :func:`claim_covers` — the claim policy: a claim covers every case of its profile (and the
  profiles it includes) at its level or below;
* :func:`required_for` — whether a claim requires a case of a given decoder (player cases
  only for players);
* :func:`capability` — why a decoder cannot take a case (NotSupported before anything runs);
* :func:`select_cases` — the cases a ``run``/``certify`` takes from the suites.
"""

from __future__ import annotations

import fnmatch
from typing import Protocol

from fbaconf.conformance.suite import Case, CaseKind, Suite
from fbaconf.profiles.model import Claim, load_profiles

from .adapters import Adapter


def claim_covers(claimed: str, case_claim: str) -> bool:
    """A decoder claiming ``claimed`` must pass cases of ``case_claim``: the case's profile is
    the claimed one or included in it, and the case's level is at most the claimed level."""
    ps = load_profiles()
    a, b = Claim.parse(claimed, ps), Claim.parse(case_claim, ps)
    return ps.profile_includes(a.profile, b.profile) and b.level <= a.level


INFORMATIVE_GROUPS = ("text",)  # player cases (.fap text): no MPEG-4 profile claim requires them


class MaybePlayer(Protocol):
    """All the claim rules ask of a decoder: whether it reads only the .fap text."""

    @property
    def is_player(self) -> bool: ...


def required_for(claim: str | None, case: Case, adapter: MaybePlayer) -> bool:
    """Whether a claim requires ``case`` of ``adapter``: the case's profile and level are
    covered, and — unless the program is a player (it reads only .fap text) — it is not a
    player case (an MPEG-4 profile claim is about the binary stream; docs/harness.md).
    The one rule ``run``, ``certify``, the pytest plugin and the case selection share."""
    if claim is not None and case.group in INFORMATIVE_GROUPS and not adapter.is_player:
        return False
    return claim is None or claim_covers(claim, case.claim)


def capability(adapter: Adapter, case: Case) -> str | None:
    """Why ``adapter`` cannot run ``case`` (-> NotSupported), or None when it can."""
    if not any(claim_covers(c, case.claim) for c in adapter.claims):
        return f"case requires {case.claim}, outside the decoder's claims ({', '.join(adapter.claims)})"
    if adapter.tools is not None:
        missing = [t for t in case.tools if t not in adapter.tools]
        if missing:
            return f"case uses tool(s) {', '.join(missing)} the decoder does not declare"
    if case.kind == CaseKind.MULTI:
        if not case.inputs.get("faces"):
            return "multi-face case without face streams"
        if not adapter.supports_multi:
            return "case decodes several faces at once; the decoder has no decode_multi command"
        if "fba" not in adapter.inputs:
            return "multi-face cases are binary streams; the decoder does not accept fba"
    else:
        if not (
            ("fba" in adapter.inputs and case.inputs.get("fba")) or ("fap" in adapter.inputs and case.inputs.get("fap"))
        ):
            forms = [k for k in ("fba", "fap") if case.inputs.get(k)]
            return f"case comes as {'/'.join(forms) or 'nothing'}; the decoder accepts {'/'.join(adapter.inputs)}"
        if case.inputs.get("scene") or case.inputs.get("bifs"):
            if not (
                ("scene" in adapter.inputs and case.inputs.get("scene"))
                or ("bifs" in adapter.inputs and case.inputs.get("bifs"))
            ):
                return "case carries a scene (FDP/FIT/FaceDefTables/model); the decoder accepts no scene input"
    if case.kind != CaseKind.ERROR and case.stages and not set(case.stages) & set(adapter.outputs):
        return f"case compares {', '.join(case.stages)}; the decoder outputs {', '.join(adapter.outputs)}"
    return None


def select_cases(
    suites: list[Suite],
    claim: str | None,
    suite_names: list[str],
    case_globs: list[str],
    only_required: bool,
    adapter: Adapter,
) -> list[Case]:
    """The cases of ``suites`` named by ``suite_names``/``case_globs`` (all when empty); with
    ``only_required``, just those the claim requires of ``adapter``."""
    cases = []
    for s in suites:
        if suite_names and s.name not in suite_names:
            continue
        for c in s.cases:
            if case_globs and not any(fnmatch.fnmatch(c.id, g) or fnmatch.fnmatch(c.full_id, g) for g in case_globs):
                continue
            if only_required and not required_for(claim, c, adapter):
                continue
            cases.append(c)
    return cases
