"""Which quirks of a .fap player explain each case it fails (how docs/third-party.md's tables were made).

    python examples/third-party/attribute.py MANIFEST.toml RUN.json [CASE_ID ...]

RUN.json is the ``fbaconf run --json`` report of the player. For every case it failed (or crashed
on), the script rewrites the case's ``.fap`` with fbaconf's writer — which already removes every
*text-form* trigger: comments, CR/CRLF, wrapped lines, 69-entry masks, header names with spaces,
a wrong frame count — and then with each combination of the edits below, smallest first, and runs
the player's command on each variant (directly, not in the sandbox: use it on programs you built
yourself). The first combination whose variant passes is printed: ``()`` means the text form alone
failed the case; ``('rate',)`` that an integer rate is all it needed; ``other`` that no
combination passes; ``None`` that the case is invalid (no variant: the player accepted an invalid
file). Expected = fbaconf's reading of the variant, judged as the harness judges a player.

Edits (each removes one trigger): ``keep`` every held FAP written in every frame; ``rate`` a 25 Hz
header; ``high`` no FAP 1/2; ``rows`` frames numbered 0..n-1 in file order; ``lips`` no inner/outer
lip pair of Xface's ``adjustFAPs``.
"""
from __future__ import annotations

import itertools
import json
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

import numpy as np

from fbaconf.bitstreams.faptext import read_fap_file, write_fap
from fbaconf.bitstreams.frames import FREE, SET
from fbaconf.conformance.suite import suites_root
from fbaconf.harness.compare.faps import compare_faps
from fbaconf.harness.compare.loaders import load_output_faps

LIP_PAIRS = [(52, 5), (58, 11), (57, 10), (51, 4), (56, 9), (55, 8), (53, 6), (54, 7), (59, 12), (60, 13)]


def _keep(fr):
    st = fr.status.copy()
    st[st != FREE] = SET
    fr.status = st


def _rate(fr):
    fr.frame_rate = 25.0


def _high(fr):
    st = fr.status.copy()
    st[:, 0:2] = FREE
    fr.status = st


def _rows(fr):
    fr.frame_number = np.arange(len(fr), dtype=np.int64)


def _lips(fr):
    st = fr.status.copy()
    for a, b in LIP_PAIRS:
        st[:, [a - 1, b - 1]] = FREE
    fr.status = st


EDITS = {"keep": _keep, "rate": _rate, "high": _high, "rows": _rows, "lips": _lips}


def judge(manifest: Path, fap: Path) -> tuple[str, str]:
    """Run the player's decode command on ``fap``; the outcome as the harness gives it for a text case."""
    m = tomllib.loads(manifest.read_text())
    with tempfile.TemporaryDirectory() as t:
        out = Path(t) / "out.fap"
        argv = [a.replace("{input}", str(fap)).replace("{faps_out}", str(out)) for a in m["commands"]["decode"]]
        try:
            r = subprocess.run(argv, capture_output=True, text=True, timeout=60)
        except subprocess.TimeoutExpired:
            return "Timeout", ""
        if r.returncode < 0:
            return "Crash", f"signal {-r.returncode}"
        if r.returncode != 0:
            return "Reject", r.stderr.strip()[-120:]
        try:
            got = load_output_faps(out)
        except Exception as e:  # noqa: BLE001 - the player's output, whatever it is
            return "Fail", str(e)[:160]
        res = compare_faps(read_fap_file(fap)[0], got, text_output=True, player=True)
        return res.outcome.value, res.message[:160]


def attribute(manifest: Path, case_id: str, work: Path):
    suite, case = case_id.split("/")
    src = suites_root() / suite / f"{case}.fap"
    try:
        read_fap_file(src, strict=False)
    except Exception:  # noqa: BLE001 - an invalid case: nothing to rewrite
        return None
    for k in range(len(EDITS) + 1):
        for combo in itertools.combinations(EDITS, k):
            fr = read_fap_file(src)[0]
            for e in combo:
                EDITS[e](fr)
            fr.time_ms = fr.frame_number * 1000.0 / fr.frame_rate
            v = work / f"{case}-{'+'.join(combo) or 'plain'}.fap"
            v.write_text(write_fap(fr, name="variant"))
            if judge(manifest, v)[0] == "Pass":
                return combo
    return "other"


def main(argv: list[str]) -> int:
    if len(argv) < 2:
        print(__doc__, file=sys.stderr)
        return 2
    manifest, run = Path(argv[0]), json.loads(Path(argv[1]).read_text())
    only = set(argv[2:])
    with tempfile.TemporaryDirectory() as t:
        for r in run["results"]:
            if r["outcome"] in ("Fail", "Crash") and (not only or r["case_id"] in only):
                print(f"{r['outcome']:5} {r['case_id']} -> {attribute(manifest, r['case_id'], Path(t))}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
