"""What the issue-37 cases rest on, and that they hold what they claim.

``harness.provisional.rests_on`` derives a case's provisional decisions from the checker's
diagnostics on its streams. Expected here, by hand: blend/intensity content at quantisers where
both readings of D5's alphabet (0..floor((63 + floor(q/2))/q) and 0..ceil(63/q)) agree rests on
no decision, also across fap_quant changes; content at one quantiser of each class where they
differ rests on D5; a predicted value outside the range its intra alphabet codes rests on D4
(decided valid); an error that is one whatever the D5 reading (a select outside 0..14 / 0..6,
a blend outside 0..63 at fap_quant 1, a 0 marker bit) rests on none.
"""

from __future__ import annotations

import pytest

from fbaconf.bitstreams.decoder import decode
from fbaconf.conformance.provisional import rests_on
from fbaconf.conformance.suite import load_suites

CASES = {c.full_id: c for s in load_suites() for c in s.cases}

EXPECTED = {
    "simple-l1-core/high-level-quant-change": [],
    "simple-l1-core/high-level-quant-d5": ["D5"],
    "simple-l1-core/pred-beyond-intra-range": ["D4"],
    "simple-l1-core/arith-q8-visemes-expressions": [],  # fap_quant 8: 0..8 under both readings
    "simple-l1-core/high-level-q0": [],  # fap_quant 0 from the start: 0..63 under every reading
    "simple-l1-core/blend-64": [],  # fap_quant 2: 0..32 under both readings
    "simple-l1-error/viseme-select-range": [],
    "simple-l1-error/expression-select-range": [],
    "simple-l1-error/blend-range": [],
    "simple-l1-error/list-marker-i-max": [],
    "simple-l1-error/list-marker-i-min": [],
    "simple-l1-error/list-marker-p-max": [],
    "simple-l1-error/list-marker-p-min": [],
    "simple-l2-stress/four-faces": [],  # fap_quant 2
}


@pytest.mark.parametrize("case_id", sorted(EXPECTED))
def test_what_the_case_rests_on(case_id):
    assert rests_on(CASES[case_id]) == EXPECTED[case_id]


# The top of the blend/intensity alphabet times the quantiser, worked out by hand (q = 0: no
# quantisation, 0..63): D5's floor((63 + floor(q/2))/q) x q. Agreeing quantisers: 4: 16 x 4 = 64,
# 13: 5 x 13 = 65, 2: 32 x 2 = 64, 22: 3 x 22 = 66, 7: 9 x 7 = 63, 17: 4 x 17 = 68, 1: 63.
# Differing ones (D5 / other reading): 10: 6 x 10 = 60 / 70, 12: 5 x 12 = 60 / 72, 15: 4 x 15 =
# 60 / 75, 19: 3 x 19 = 57 / 76, 20: 3 x 20 = 60 / 80, 26: 2 x 26 = 52 / 78, 31: 2 x 31 = 62 / 93.
TOPS = {
    "high-level-quant-change": {0: 63, 4: 64, 13: 65, 2: 64, 22: 66, 7: 63, 17: 68, 1: 63},
    "high-level-quant-d5": {10: 60, 12: 60, 15: 60, 19: 57, 20: 60, 26: 52, 31: 62},
}


@pytest.mark.parametrize("case_id", sorted(TOPS))
def test_blends_reach_both_ends_of_every_alphabet(case_id):
    """Each segment's intra plane codes the top symbol of the blend and both intensities, and its
    predicted planes the largest differences both ways (to 0 and back to the top)."""
    fr = decode(CASES[f"simple-l1-core/{case_id}"].input_path("fba").read_bytes()).frames
    quants = [int(q) for q in fr.fap_quant]
    assert list(dict.fromkeys(quants)) == list(TOPS[case_id])
    for q, top in TOPS[case_id].items():
        rows = [k for k, x in enumerate(quants) if x == q]
        assert fr.is_intra[rows[0]] and not fr.is_intra[rows[1:]].any()
        for col in (2, 5, 7):  # viseme_blend, expression_intensity1, expression_intensity2
            seg = fr.high[rows, col].tolist()
            assert seg[0] == top and 0 in seg[1:] and any(a == 0 and b == top for a, b in zip(seg, seg[1:])), (
                q,
                col,
                seg,
            )
