"""Hand-made frame recipes: valid streams whose content no ``content = {...}`` table expresses,
each aimed at a rule an independent mutant showed the suite did not exercise
(``mutation/data/mutants-independent.md``). ``special = "<name>"`` in ``suites.toml``.

Each recipe builds its FAP frames by hand and encodes them with the reference encoder; the
recipe asserts the property it exists for (a bit pattern, a mask type), so an encoder change
that loses it fails the build instead of silently weakening the case.
"""

from __future__ import annotations

import numpy as np

from fbaconf.bitstreams import tables
from fbaconf.bitstreams.bitedit import end_stream, splice
from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.encoder import EncoderOptions, encode
from fbaconf.bitstreams.frames import HIGH_LEVEL_FIELDS, RETAINED, SET, FapFrames
from fbaconf.bitstreams.synth import synthetic_sequence
from fbaconf.conformance.suite import SuiteError
from fbaconf.profiles.sample_streams import stuffing_positions


def _encode(frames, **options) -> bytes:
    return encode(frames, EncoderOptions(**options)).data


def _need(ok: bool, name: str, what: str) -> None:
    if not ok:
        raise SuiteError(f"special stream {name!r} lost its property: {what}", rule="suite-spec")


def mask_00_after_set() -> bytes:
    """Group 2 (FAPs 3-18) and the visemes set, then a segment (frames 10-19) where group 2 has
    mask type 00 and FAP 1 mask type 01: their FAPs are RETAINED (D3: uncoded after being set),
    viseme values held; coded again from frame 20."""
    n = 30
    fr = synthetic_sequence(n, 25.0, seed=4, visemes=True, expressions=True)
    fr.status[10:20, 2:18] = RETAINED
    fr.status[10:20, 0] = RETAINED
    gt = np.full((n, 10), 3)
    gt[10:20, 1] = 0
    gt[10:20, 0] = 1
    data = _encode(fr, fap_quant=1, group_types=gt)
    out = decode(data).frames
    _need(
        bool((out.status[10:20, 2:18] == RETAINED).all() and (out.status[10:20, 0] == RETAINED).all()),
        "mask-00-after-set",
        "group 2 and FAP 1 RETAINED in frames 10-19",
    )
    return data


def extreme_steps() -> bytes:
    """Every low-level FAP jumps between 0 and its largest value (1860 x its quantiser step) at
    fap_quant 3: the arithmetic output has long zero runs, stuffing bits close together."""
    qp = tables.quant_steps()
    fr = FapFrames.empty(40, 25.0)
    for f in range(3, 69):
        fr.values[:, f - 1] = (1860 * qp[f - 1]) * ((np.arange(40) % 4) == 1)
    fr.status[:, 2:] = SET
    data = _encode(fr, fap_quant=3, plane_start_codes="none", intra_period=8)
    n = sum(len(stuffing_positions(data, s, ln)) for p in decode(data).planes for _n, s, ln in p.blocks)
    _need(n >= 4, "extreme-steps", f"at least 4 stuffing bits (found {n})")
    return data


def high_level_only() -> bytes:
    """Visemes and expressions only, no low-level FAP coded: the low-level block is empty but
    still there (its flush bits), 60 frames at fap_quant 2."""
    fr = synthetic_sequence(60, 25.0, seed=14, faps=[])
    _need(not fr.status[:, 2:].any(), "high-level-only", "no low-level FAP")
    return _encode(fr, fap_quant=2, intra_period=25)


def skips_14_15() -> bytes:
    """Skips of exactly 14, 15, 29 and 30 frames: chunk values 14 (ends a chain) and 15
    (continues it), and chains of two chunks."""
    fr = synthetic_sequence(5, 25.0, seed=13)
    fr.frame_number = np.array([0, 15, 31, 61, 92])
    fr.time_ms = fr.frame_number * 40.0
    data = _encode(fr, fap_quant=2)
    _need([p.skip for p in decode(data).planes] == [0, 14, 15, 29, 30], "skips-14-15", "skips 14, 15, 29, 30")
    return data


def lists_persist_unmasked() -> bytes:
    """Range lists persist for FAPs a later list does not carry (D4): FAP 18 gets a list in
    segment 1, is not coded in segment 2 (which sends a list for FAP 4 only), and is coded
    again without a list in segment 3, still under its segment-1 range."""
    fr = FapFrames.empty(15, 25.0)
    fr.status[:, 3] = SET
    fr.values[:, 3] = 20
    fr.values[5:10, 3] = 2200
    fr.status[0:5, 17] = SET
    fr.values[0:5, 17] = 1000
    fr.status[5:10, 17] = RETAINED
    fr.status[10:15, 17] = SET
    fr.values[10:15, 17] = [900, 950, 1000, 980, 1010]
    return _encode(fr, fap_quant=1, ranges="persist")


def dct_stuffing() -> bytes:
    """DCT mode, FAPs 66-68 at -524,284: DC codes with long zero runs, so the payload has
    stuffing bits and ends in 20+ zeros (the end stuffing, D9)."""
    fr = FapFrames.empty(20, 25.0)
    for f in (66, 67, 68):
        fr.status[:, f - 1] = SET
        fr.values[:, f - 1] = -524284
    fr.values[16:, 65] = 1000
    return _encode(fr, coding="dct", fap_quant=12)


def dct_header_zeros() -> bytes:
    """DCT mode: a predicted plane group after a 15-frame skip (header zeros) whose DC
    difference code starts with 14 zeros: the zero run counts across header and payload (D9)."""
    fr = FapFrames.empty(7, 25.0)
    fr.frame_number = np.array([0, 1, 2, 3, 19, 35, 36])
    fr.time_ms = fr.frame_number * 40.0
    fr.status[:, 13] = SET
    fr.values[:, 13] = [0, 0, 0, 0, 40000, 0, 5]
    return _encode(fr, coding="dct", fap_quant=12, plane_start_codes="none")


def block_end_stuffing() -> bytes:
    """A low-level block whose last bit completes a run of 22 zeros: the stuffing bit after
    it belongs to the block (D7), not to the next field. Symbol values found by search."""
    seq = [(15, 901), (16, 694), (24, 1440), (30, 1679), (2, 119), (5, 396), (26, 2269)]
    qp = tables.quant_steps()
    fr = FapFrames.empty(3, 25.0)
    b = np.tile(np.array([1860, -1860, 1860, -1860]), (68, 1))
    for f, (code, s) in zip(range(3, 10), seq):
        fr.status[:, f - 1] = SET
        fr.values[:, f - 1] = (s - 60 * code) * qp[f - 1]
        b[f - 1, 0], b[f - 1, 1] = code * 60, -code * 60
    fr.values[1, 2] += 8
    fr.values[2, 3] -= 4
    data = _encode(fr, fap_quant=1, bounds=b, plane_start_codes="all")
    at_end = [
        (s, ln)
        for p in decode(data).planes
        for _n, s, ln in p.blocks
        if stuffing_positions(data, s, ln) and stuffing_positions(data, s, ln)[-1] == s + ln - 1
    ]
    _need(bool(at_end), "block-end-stuffing", "a block whose last bit is a stuffing bit")
    return data


def halving_random() -> bytes:
    """16,500 planes after one intra plane at fap_quant 12, FAPs 4 and 6 uniformly random:
    FAP 4's predicted alphabet has 31 symbols (a small model), FAP 6's 311 (a large one), so
    both kinds of model reach the total 16,383 and are halved (spec notes 3.2), then code a few
    hundred symbols more with the halved frequencies."""
    rng = np.random.default_rng(7)
    n, q = 16500, 12
    qp = tables.quant_steps()
    fr = FapFrames.empty(n, 25.0)
    b = np.tile(np.array([1860, -1860, 1860, -1860]), (68, 1))
    b[3, 2:] = (180, -180)  # FAP 4: predicted symbols -15..15 at fap_quant 12
    for f, amp in ((4, 7), (6, 77)):  # differences stay inside the predicted alphabets
        fr.status[:, f - 1] = SET
        fr.values[:, f - 1] = rng.integers(-amp, amp + 1, n) * qp[f - 1] * q
    return _encode(fr, fap_quant=q, bounds=b, plane_start_codes="none", intra_period=n)


def high_level_held() -> bytes:
    """FAPs 1 and 2 coded with viseme_def and init_face set in frames 0-5, then RETAINED under
    mask type 01 through later intra planes: every field of both is held (D3), the flags too."""
    fr = synthetic_sequence(16, 25.0, seed=54, visemes=True, expressions=True, faps=[3, 4])
    for name in ("viseme_def", "init_face"):
        fr.high[:, HIGH_LEVEL_FIELDS.index(name)] = 1
    fr.status[6:, 0:2] = RETAINED
    data = _encode(fr, fap_quant=2, partial_mask_type=1, intra_period=4)
    out = decode(data).frames
    _need(bool((out.status[6:, 0:2] == RETAINED).all()), "high-level-held", "FAPs 1 and 2 RETAINED from frame 6")
    return data


def blend_64() -> bytes:
    """viseme_blend and both intensities at 63, fap_quant 2, with D5's whole alphabet: the intra
    level 32 dequantises to 64 (D5 allows it), which a decoder outputs as is, never clamped."""
    fr = synthetic_sequence(6, 25.0, seed=56, visemes=True, expressions=True, faps=[3, 4])
    for name in ("viseme_blend", "expression_intensity1", "expression_intensity2"):
        fr.high[:, HIGH_LEVEL_FIELDS.index(name)] = 63
    data = _encode(fr, fap_quant=2, full_intensity_alphabet=True)
    out = decode(data).frames
    _need(int(out.high[0, HIGH_LEVEL_FIELDS.index("viseme_blend")]) == 64, "blend-64", "viseme_blend 64 in frame 0")
    return data


def pred_beyond_intra_range() -> bytes:
    """The range rule (D4): predicted planes take FAP 4 above and FAP 19 below the values their
    intra alphabets code (i_max / i_min list value 1: levels -60..60 at fap_quant 1), by
    differences inside the predicted alphabet (+40 and -30 levels a plane; lists of 600). Valid:
    decoded as previous + difference (notes §3.4), as S1's encoder writes such planes and its
    decoder adds without a check. fbaconf's encoder sizes the intra range to every value of the
    segment, so the stream is spliced: the intra plane of one encoding (narrow intra lists) and
    the predicted planes of another (wide intra lists, the same predicted lists, the same values):
    the predicted planes decode alike after either intra plane, their models and alphabets
    starting afresh from the same predicted lists."""
    n = 8
    qp = tables.quant_steps()
    fr = FapFrames.empty(n, 25.0)
    k = np.arange(n)
    for f, levels in ((4, 60 + 40 * k), (19, -60 - 30 * k)):
        fr.status[:, f - 1] = SET
        fr.values[:, f - 1] = levels * qp[f - 1]
    narrow = np.tile(np.array([1860, -1860, 600, -600]), (68, 1))
    narrow[[3, 18], :2] = (60, -60)
    wide = narrow.copy()
    wide[[3, 18], :2] = (1860, -1860)
    a = _encode(fr.select(slice(0, 1)), fap_quant=1, bounds=narrow, plane_start_codes="none")
    b = _encode(fr, fap_quant=1, bounds=wide, plane_start_codes="none")
    pa, pb = decode(a).planes, decode(b).planes
    _need(pb[0].is_intra and not any(p.is_intra for p in pb[1:]), "pred-beyond-intra-range", "one intra plane in B")
    joined = splice((a, 0, pa[0].end_offset), (b, pb[1].bit_offset, pb[-1].end_offset))
    data = end_stream(joined, pa[0].end_offset + pb[-1].end_offset - pb[1].bit_offset)
    out = decode(data).frames
    _need(
        bool((out.values[:, 3] == fr.values[:, 3]).all() and (out.values[:, 18] == fr.values[:, 18]).all()),
        "pred-beyond-intra-range",
        "the spliced stream decodes to the encoded values",
    )
    _need(
        int(out.values[-1, 3]) > 60 * qp[3] and int(out.values[-1, 18]) < -60 * qp[18],
        "pred-beyond-intra-range",
        "FAPs 4 and 19 end outside their intra ranges",
    )
    return data


RECIPES = {
    "blend-64": blend_64,
    "high-level-held": high_level_held,
    "mask-00-after-set": mask_00_after_set,
    "extreme-steps": extreme_steps,
    "high-level-only": high_level_only,
    "skips-14-15": skips_14_15,
    "lists-persist-unmasked": lists_persist_unmasked,
    "dct-stuffing": dct_stuffing,
    "dct-header-zeros": dct_header_zeros,
    "block-end-stuffing": block_end_stuffing,
    "halving-random": halving_random,
    "pred-beyond-intra-range": pred_beyond_intra_range,
}
