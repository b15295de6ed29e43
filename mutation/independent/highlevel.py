"""Independent mutants: highlevel (see the package docstring).

High-level FAPs as the bitstream decoder turns them into state (spec notes §1.3, §2.3, D5):
viseme_select / viseme_blend, expression_select / intensities and their quantiser step,
viseme_def / init_face / expression_def, holding of the high-level values across planes,
and the SET / RETAINED / FREE status derivation of decision D3. Written from the spec notes
and the reference source only; each is one plausible misreading.
"""

from __future__ import annotations

from fbaconf.bitstreams import decoder
from fbaconf.mutation.core import Mutant

DEC = "fbaconf.bitstreams.decoder:_Decoder"


def _m(name, where, description, old, new, rule, **kw) -> Mutant:
    return Mutant(
        name=name,
        where=where,
        description=description,
        old=old,
        new=new,
        pure_decoder=True,
        family="independent",
        rule=rule,
        **kw,
    )


def _patch_intensity_step_q0() -> None:
    """Intensities multiplied by fap_quant itself, also when fap_quant = 0 (so they decode as 0)."""
    decoder.intensity_step = lambda q: q


_VIS_INTRA = """ib = intensity_bound(q)
        istep = intensity_step(q)
        if intra:
            s1 = """
_EXP_INTRA = """ib = intensity_bound(q)
        istep = intensity_step(q)
        if intra:
            e1 = """

MUTANTS_LIST: list[Mutant] = [
    # ------------------------------------------------------------------ dequantisation (D5, §3.4)
    _m(
        "ind-hl-intra-blend-step-missing",
        f"{DEC}.payload",
        "an intra viseme_blend is not multiplied by fap_quant (the predicted difference is)",
        "hl[0], hl[1], hl[2] = s1, s2, b * istep",
        "hl[0], hl[1], hl[2] = s1, s2, b",
        "D5 / §3.4 viseme_blend step = fap_quant",
    ),
    _m(
        "ind-hl-intra-intensity2-step-missing",
        f"{DEC}.payload",
        "an intra expression_intensity2 is not multiplied by fap_quant (intensity1 is)",
        "hl[4], hl[5], hl[6], hl[7] = e1, i1 * istep, e2, i2 * istep",
        "hl[4], hl[5], hl[6], hl[7] = e1, i1 * istep, e2, i2",
        "D5 / §3.4 intensity step = fap_quant",
    ),
    Mutant(
        name="ind-hl-intensity-step-q0-zero",
        where="fbaconf.bitstreams.decoder:intensity_step",
        description="blend / intensities are multiplied by fap_quant even when it is 0 (all decode as 0)",
        patch=_patch_intensity_step_q0,
        pure_decoder=True,
        family="independent",
        rule="D5 dequantised by q (none when fap_quant = 0)",
    ),
    _m(
        "ind-hl-blend-bound-undivided",
        f"{DEC}.payload",
        "viseme_blend alphabet 0..63 whatever fap_quant (S1 encoder bug), values still multiplied by q",
        _VIS_INTRA,
        _VIS_INTRA.replace("ib = intensity_bound(q)", "ib = 63"),
        "D5 blend alphabet /q",
    ),
    _m(
        "ind-hl-intensity-bound-undivided",
        f"{DEC}.payload",
        "expression intensity alphabets 0..63 whatever fap_quant (S1 encoder bug), values still multiplied by q",
        _EXP_INTRA,
        _EXP_INTRA.replace("ib = intensity_bound(q)", "ib = 63"),
        "D5 intensity alphabet /q",
    ),
    _m(
        "ind-hl-intra-blend-clamped-63",
        f"{DEC}.payload",
        "an intra viseme_blend is clamped to 63 after dequantisation (q = 2 can give 64)",
        "hl[0], hl[1], hl[2] = s1, s2, b * istep",
        "hl[0], hl[1], hl[2] = s1, s2, min(63, b * istep)",
        "D5 alphabet 0..floor((63 + floor(q/2))/q), x q",
    ),
    # ------------------------------------------------------------------ selects (D5, §1.3)
    _m(
        "ind-hl-viseme-select-14-rejected",
        f"{DEC}.payload",
        "viseme_select 14 (U) is rejected as out of range (range check < 14)",
        "if not 0 <= hl[k] <= mx:",
        "if not 0 <= hl[k] < mx:",
        "D5 viseme_select 0..14",
    ),
    _m(
        "ind-hl-expression-select-6-rejected",
        f"{DEC}.payload",
        "expression_select 6 (surprise) is rejected as out of range (range check < 6)",
        "if not 0 <= hl[k] <= EXPRESSION_SELECT_MAX:",
        "if not 0 <= hl[k] < EXPRESSION_SELECT_MAX:",
        "D5 expression_select 0..6",
    ),
    _m(
        "ind-hl-p-viseme-select-absolute",
        f"{DEC}.payload",
        "in predicted planes the decoded viseme_select symbols are taken as values, not differences",
        "hl[0] += d1\n            hl[1] += d2",
        "hl[0] = d1\n            hl[1] = d2",
        "§3.4 selects: intra direct, P = previous + diff",
    ),
    _m(
        "ind-hl-p-expression-order",
        f"{DEC}.payload",
        "predicted expression block read as select1, select2, intensity1, intensity2 (intra order kept)",
        """hl[5] += (dec.decode(self._p_model("ei1", -ib, ib)) - ib) * istep
            hl[6] += dec.decode(self._p_model("es2", -E, E)) - E""",
        """hl[6] += dec.decode(self._p_model("es2", -E, E)) - E
            hl[5] += (dec.decode(self._p_model("ei1", -ib, ib)) - ib) * istep""",
        "§1.3 expression block order",
    ),
    # ------------------------------------------------------------------ flags held across planes
    _m(
        "ind-hl-viseme-def-one-shot",
        f"{DEC}.payload",
        "viseme_def is treated as a one-plane flag: reset to 0 in every plane that does not code FAP 1",
        "hl = self.high\n",
        "hl = self.high\n    hl[3] = 0\n",
        "§1.3 / D3 FAP 1 fields held (RETAINED)",
    ),
    _m(
        "ind-hl-init-face-one-shot",
        f"{DEC}.payload",
        "init_face is treated as a one-plane event: reset to 0 in every plane that does not code FAP 2",
        "hl = self.high\n",
        "hl = self.high\n    hl[8] = 0\n",
        "§1.3 / D3 FAP 2 fields held (RETAINED)",
    ),
    # ------------------------------------------------------------------ status derivation (D3)
    _m(
        "ind-hl-unsent-always-retained",
        f"{DEC}._mask_state",
        "a FAP not coded under mask type 00/01 is RETAINED even if it was never set (0 taken as its value)",
        "(types_arr == MASK_INTERPOLATE) | ~self.ever_set",
        "(types_arr == MASK_INTERPOLATE)",
        "D3 RETAINED only if ever set, else FREE",
    ),
    _m(
        "ind-hl-type10-retained",
        f"{DEC}._mask_state",
        "mask type 10 treated like 01 (as S1 does): an unsent FAP is RETAINED when ever set",
        "(types_arr == MASK_INTERPOLATE) | ~self.ever_set",
        "~self.ever_set",
        "D3 type 10: unsent FAPs FREE",
    ),
    _m(
        "ind-hl-ever-set-two-segments",
        f"{DEC}._mask_state",
        "'ever set' remembers only the previous intra segment: a FAP unsent for two segments becomes FREE",
        "self.ever_set |= coded",
        "self.ever_set = getattr(self, '_prev_coded', coded) | coded\n    self._prev_coded = coded",
        "D3 RETAINED if it was ever set",
    ),
    _m(
        "ind-hl-high-level-never-retained",
        f"{DEC}._mask_state",
        "FAP 1 / FAP 2 not coded are always FREE (high-level FAPs never held), low-level FAPs per D3",
        "self.status_template = tmpl.astype(np.uint8)",
        "tmpl[:2] = np.where(coded[:2], SET, FREE)\n    self.status_template = tmpl.astype(np.uint8)",
        "D3 applies to FAP 1 / 2 as well",
    ),
]
