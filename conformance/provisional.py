"""What a case's expected result rests on: the provisional decisions another reading would change.

The ISO/IEC 14496 text was not available to fbaconf: some expected results follow readings
fbaconf had to decide (``conformance/data/provisional.toml``, D1-D8). A case *rests on* a decision
when a known other reading changes its result:

* **D3-D7** — an other reading of ``bitstreams/data/readings.toml`` (each seen in a public
  source) decodes the case's streams differently: the goldens hold what it gives
  (``golden/<suite>/<case>/readings/<slug>/``, written by ``fbaconf golden regenerate``), so this
  is read from them, never guessed;
* an *open* decision (``open = true`` in provisional.toml: **D8**, the DCT segment mode, whose
  tables are fbaconf's own and for which no other reading is known) — every case whose streams
  use its tool.

A decision no case's result depends on under any known reading (D1, D2, D6's frame rate 0, the
viseme/expression select ranges) is no excuse for anything: what the verdict makes of these is
:mod:`fbaconf.harness.verdict`.
"""

from __future__ import annotations

import functools
import tomllib
from importlib import resources
from pathlib import Path

from fbaconf.bitstreams import readings
from fbaconf.profiles.model import Claim, load_profiles

from .golden import reading_goldens
from .suite import Case


@functools.lru_cache(maxsize=1)
def decisions() -> dict[str, dict]:
    """The provisional rules, by id (``conformance/data/provisional.toml``)."""
    data = tomllib.loads(resources.files("fbaconf.conformance").joinpath("data/provisional.toml").read_text("utf-8"))
    return {r["id"]: r for r in data["rule"]}


def open_decisions() -> dict[str, str]:
    """Decisions no other reading is known for, by id, with the tool whose cases rest on them."""
    return {d: r["tool"] for d, r in decisions().items() if r.get("open")}


def rests_on(case: Case, golden: Path | None = None) -> list[str]:
    """The provisional decisions ``case``'s expected result rests on (sorted ids, e.g.
    ``["D7", "D8"]``): those of the other readings its goldens hold, and the open decisions of
    its tools."""
    out = {readings.get(r).decision for r in reading_goldens(case, golden)}
    out |= {d for d, tool in open_decisions().items() if tool in case.tools}
    return sorted(out)


def readings_for(case: Case, declared, golden: Path | None = None) -> dict[str, Path]:
    """The other readings ``declared`` by a decoder that change ``case``'s result, with the
    folders of what they give."""
    return {r: p for r, p in reading_goldens(case, golden).items() if r in set(declared)}


def statements(claim: str | None) -> list[str]:
    """What a verdict rests on that the public sources leave open (data: conformance/data/provisional.toml
    and the provenance of each level limit)."""
    out = [f"{r['id']}: {r['text']} ({r['where']})" for r in decisions().values()]
    ps = load_profiles()
    if claim:
        c = Claim.parse(claim, ps)
        for lim in ps.limits_for(c):
            if lim.provenance == "provisional" and c.level in lim.values:
                out.append(
                    f"level limit {lim.id} = {lim.value(c.level):g} {lim.unit} at {claim} "
                    f"({lim.description}) is provisional"
                )
    return out
