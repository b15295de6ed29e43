"""Tests for the ASCII .fap reader/writer (bitstreams/faptext.py)."""

from __future__ import annotations

import math
import random
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from fbaconf.bitstreams.faptext import (
    RULES,
    FapFileHeader,
    TextWarning,
    read_fap,
    read_fap_file,
    read_fap_text,
    write_fap,
    write_fap_file,
)
from fbaconf.bitstreams.frames import FREE, RETAINED, SET, FapFrames, first_difference
from fbaconf.errors import EncodeError, TextFormatError

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "fap"


def real_files() -> list[Path]:
    return sorted(DATA.glob("**/*.fap")) if DATA.is_dir() else []


def needs_data():
    if not real_files():
        pytest.skip(f"real .fap files not available under {DATA}")


# Frame counts from ../shared/data/fap/README.md (each equals the file's declared count).
EXPECTED_FRAMES = {
    "greta/AU_Interpolation_1111.fap": 1,
    "greta/AU_Interpolation_1140.fap": 1,
    "greta/AU_Interpolation_1175.fap": 1,
    "vreng/anger.fap": 23,
    "vreng/eyes.fap": 52,
    "vreng/fear.fap": 14,
    "vreng/jag.fap": 169,
    "vreng/joy.fap": 20,
    "vreng/sad.fap": 14,
    "vreng/surp.fap": 15,
    "xface/anger.fap": 108,
    "xface/beg.fap": 107,
    "xface/disgust.fap": 107,
    "xface/fear.fap": 107,
    "xface/happy-for.fap": 107,
    "xface/hate.fap": 107,
    "xface/joy.fap": 108,
    "xface/pride.fap": 107,
    "xface/test.fap": 43,
}
README_RANGES = {"xface": (43, 108), "vreng": (14, 169), "greta": (1, 1)}


def mask_line(faps=(), width=68, extra="") -> str:
    return " ".join("1" if i in faps else "0" for i in range(1, width + 1)) + extra


def col_of_entry(k: int) -> int:
    """Column of the k-th (1-based) entry of a mask_line()."""
    return 2 * k - 1


# ------------------------------------------------------------------------------- real files
@pytest.mark.external
def test_real_files_listed():
    needs_data()
    names = {p.relative_to(DATA).as_posix() for p in real_files()}
    assert names == set(EXPECTED_FRAMES)


@pytest.mark.external
@pytest.mark.parametrize("rel", sorted(EXPECTED_FRAMES))
def test_real_file_parses(rel):
    needs_data()
    path = DATA / rel
    if not path.exists():
        pytest.skip(f"{rel} absent")
    frames, header, warnings = read_fap_file(path)
    assert len(frames) == EXPECTED_FRAMES[rel] == header.declared_frames
    lo, hi = README_RANGES[rel.split("/")[0]]
    assert lo <= len(frames) <= hi
    assert frames.frame_rate == header.frame_rate
    assert not frames.is_intra.any() and (frames.bit_offset == -1).all()
    assert (frames.status[:, :2] == FREE).all()  # none of the real files uses FAP1/FAP2
    np.testing.assert_allclose(frames.time_ms, frames.frame_number * 1000.0 / header.frame_rate)
    if rel.startswith("greta/"):
        assert sorted((w.rule, w.line, w.column) for w in warnings) == [
            ("fap-text-mask-length", 2, 137),
            ("fap-text-name", 1, 5),
        ]
        assert header.name == rel.split("/")[1].replace("_", " ", 1)
        assert list(np.nonzero(frames.mask[0])[0] + 1) == [19, 20, 21, 22]  # the eyelid closures
        assert (frames.values[0] == 0).all() and frames.frame_number[0] == 0
    else:
        assert warnings == []
        # clean files: strict mode reads them identically
        strict, _, _ = read_fap_file(path, strict=True)
        assert first_difference(frames, strict) is None


@pytest.mark.external
def test_real_file_values():
    needs_data()
    jag, h, _ = read_fap_file(DATA / "vreng" / "jag.fap")
    assert (h.version, h.name, h.frame_rate, h.declared_frames) == ("2.0", "jag", 5.0, 169)
    assert list(jag.values[0, 2:8]) == [57, 26, -114, -36, -36, 63]
    assert list(jag.values[1, 2:6]) == [58, 28, -116, -36]
    assert jag.mask[0].sum() == 66 and not jag.mask[0, :2].any()
    assert list(jag.frame_number[:3]) == [0, 1, 2] and jag.frame_number[-1] == 168

    joy, h, _ = read_fap_file(DATA / "vreng" / "joy.fap")
    assert h.frame_rate == 10.0 and joy.frame_number[1] == 1
    assert {i + 1: int(v) for i, v in enumerate(joy.values[1]) if v} == {55: -19, 57: -19, 58: -19}
    assert list(np.nonzero(joy.mask[1])[0] + 1) == list(range(31, 39)) + list(range(51, 61))

    eyes, h, _ = read_fap_file(DATA / "vreng" / "eyes.fap")
    assert h.version == "2.0" and list(eyes.frame_number) == list(range(1, 53))
    assert list(np.nonzero(eyes.mask[0])[0] + 1) == list(range(19, 27))

    anger, h, _ = read_fap_file(DATA / "xface" / "anger.fap")  # CRLF, Windows path as name
    assert h.name == r"C:\Users\balci\Work\FACE\exml2fap\files\TempFile"
    assert list(anger.values[0, 2:6]) == [0, 10, 10, 0]
    assert list(anger.values[1, 2:6]) == [0, 8, 10, 1]
    assert anger.mask[0].sum() == 48


def test_read_fap_dispatch(tmp_path):
    text = "2.1 n 25 1\n" + mask_line({3}) + "\n0 7\n"
    p = tmp_path / "a.fap"
    p.write_text(text)
    for src in (text, text.encode(), p, str(p)):
        frames, header, warnings = read_fap(src)
        assert frames.values[0, 2] == 7 and warnings == []
    _, _, w = read_fap(text.replace("25 1", "25 2"), file="x.fap")
    assert str(w[0]).startswith("x.fap:1:10: ") and str(w[0]).endswith("[rule fap-text-frame-count]")
    with pytest.raises(TypeError):
        read_fap(12)


# ------------------------------------------------------------------------------- semantics
def test_retain_semantics_and_high_level():
    text = (
        "\n".join(
            [
                "2.2 synth 30 3",
                mask_line({1, 2, 5}),
                "0  3 7 40 1  2 50 4 10 1 0  -12",
                mask_line({6}),
                "1 99",
                mask_line({1, 5}),
                "2 0 0 0 0 8",
            ]
        )
        + "\n"
    )
    frames, header, warnings = read_fap_text(text)
    assert warnings == [] and header == FapFileHeader("2.2", "synth", 30.0, 3)
    assert list(frames.status[:, [0, 1, 4, 5, 6]].tolist()) == [
        [SET, SET, SET, FREE, FREE],
        [RETAINED, RETAINED, RETAINED, SET, FREE],
        [SET, RETAINED, SET, RETAINED, FREE],
    ]
    assert list(frames.values[:, 4]) == [-12, -12, 8]
    assert list(frames.values[:, 5]) == [0, 99, 99]
    assert (frames.values[:, :2] == 0).all()
    assert frames.high[0].tolist() == [3, 7, 40, 1, 2, 50, 4, 10, 1, 0]
    assert frames.high[1].tolist() == frames.high[0].tolist()
    assert frames.high[2].tolist() == [0, 0, 0, 0, 2, 50, 4, 10, 1, 0]
    np.testing.assert_allclose(frames.time_ms, [0, 1000 / 30, 2000 / 30])
    assert frames.frame_rate == 30.0


def test_whitespace_free_and_comments():
    text = (
        "# leading comment\r\n\r\n  2.1\tname  12.5 1  # trailing\r\n"
        + " ".join(["0"] * 30)
        + " # c 1 1 1\r\n"
        + "\t".join(["0"] * 30)
        + "\r\n"
        + "0 0 0 0 0 0 0 1\r"
        + "1\r\n# x\r\n-3 \r\n"
    )
    frames, header, warnings = read_fap_text(text)
    assert warnings == [] and header.frame_rate == 12.5 and header.name == "name"
    assert frames.values[0, 67] == -3 and frames.frame_number[0] == 1 and frames.mask[0].sum() == 1


# ------------------------------------------------------------------------------- rules
RULE_CASES = [
    # (rule, text, line, column, is_error)
    ("fap-text-header", "", 1, 1, True),
    ("fap-text-header", "# only a comment\n\n", 3, 1, True),
    ("fap-text-header", "# c\n  2.1 25\n", 2, 3, True),
    ("fap-text-header", "# c\n  2.1 a zz 3\n", 2, 9, True),
    ("fap-text-header", "2.1 a inf 3\n", 1, 7, True),
    ("fap-text-header", "2.1 a 0 3\n", 1, 7, True),
    ("fap-text-header", "2.1 a 25 -3\n", 1, 10, True),
    ("fap-text-header", "2.1 a 25 3.0\n", 1, 10, True),
    ("fap-text-header", "2.1 a 25 " + "9" * 200 + "\n", 1, 10, True),
    ("fap-text-version", "3.0 a 25 0\n", 1, 1, False),
    ("fap-text-name", "2.1 AU Interpolation.fap 25 0\n", 1, 5, False),
    ("fap-text-name", "2.1 25 0\n", 1, 5, False),
    ("fap-text-mask-length", "2.1 a 25 1\n" + mask_line({19}, 69) + "\n0 4\n", 2, 137, False),
    ("fap-text-mask-value", "2.1 a 25 1\n2 " + " ".join(["0"] * 67) + "\n0\n", 2, 1, True),
    ("fap-text-mask-value", "2.1 a 25 1\n" + mask_line()[:8] + "-1" + mask_line()[9:] + "\n0\n", 2, 9, True),
    ("fap-text-integer", "2.1 a 25 1\n" + mask_line({3}) + "\n0 1.5\n", 3, 3, True),
    ("fap-text-integer", "2.1 a 25 1\n" + mask_line()[:20] + "x" + mask_line()[21:] + "\n0\n", 2, 21, True),
    ("fap-text-integer", "2.1 a 25 1\n" + mask_line() + "\nzero\n", 3, 1, True),
    ("fap-text-value-range", "2.1 a 25 1\n" + mask_line({3}) + "\n-1 5\n", 3, 1, True),
    ("fap-text-value-range", "2.1 a 25 1\n" + mask_line({3}) + "\n0  2147483648\n", 3, 4, True),
    ("fap-text-value-range", "2.1 a 25 1\n" + mask_line({3}) + "\n0 " + "1" * 5000 + "\n", 3, 3, True),
    ("fap-text-high-level-range", "2.1 a 25 1\n" + mask_line({1}) + "\n0 15 0 0 0\n", 3, 3, False),
    ("fap-text-high-level-range", "2.1 a 25 1\n" + mask_line({2}) + "\n0 1 2 3 4 0 2\n", 3, 13, False),
    ("fap-text-truncated", "2.1 a 25 1\n" + mask_line({3, 4}) + "\n0 5\n", 3, 4, True),
    ("fap-text-truncated", "2.1 a 25 2\n" + mask_line({3}) + "\n0 5\n0 0 0 \n", 4, 6, True),
    ("fap-text-frame-order", "2.1 a 25 2\n" + mask_line() + "\n1\n" + mask_line() + "\n0\n", 5, 1, False),
    ("fap-text-frame-duplicate", "2.1 a 25 2\n" + mask_line() + "\n1\n" + mask_line() + "\n  1\n", 5, 3, False),
    ("fap-text-frame-beyond", "2.1 a 25 1\n" + mask_line() + "\n2\n", 3, 1, False),
    ("fap-text-frame-count", "2.1 a 25 2\n" + mask_line() + "\n1\n", 1, 10, False),
    ("fap-text-frame-count", "2.1 a 25 3\n", 1, 10, False),
    ("fap-text-mask-short", "2.1 a 25 1\n" + " ".join(["0"] * 67) + "\n0\n", 2, 134, True),
]


@pytest.mark.parametrize("rule,text,line,column,is_error", RULE_CASES)
def test_rule_location(rule, text, line, column, is_error):
    assert rule in RULES
    if is_error:
        with pytest.raises(TextFormatError) as ei:
            read_fap_text(text, file="t.fap")
        e = ei.value
        assert (e.rule, e.line, e.column) == (rule, line, column), str(e)
        assert str(e).startswith(f"t.fap: {line}:{column}: ")
    else:
        _, _, warnings = read_fap_text(text, file="t.fap")
        hits = [w for w in warnings if w.rule == rule]
        assert [(w.line, w.column) for w in hits] == [(line, column)], [str(w) for w in warnings]
        assert str(hits[0]).startswith(f"t.fap:{line}:{column}: ") and str(hits[0]).endswith(f"[rule {rule}]")
        with pytest.raises(TextFormatError) as ei:
            read_fap_text(text, strict=True)
        assert ei.value.rule in RULES


def test_every_rule_has_a_case():
    assert {c[0] for c in RULE_CASES} == set(RULES)
    assert all(r.startswith("fap-text-") and r == r.lower() for r in RULES)


def test_strict_reports_first_warning_location():
    text = "2.1 a 25 1\n" + mask_line({19}, 69) + "\n0 4\n"
    with pytest.raises(TextFormatError) as ei:
        read_fap_text(text, strict=True)
    assert (ei.value.rule, ei.value.line, ei.value.column) == ("fap-text-mask-length", 2, 137)
    frames, _, _ = read_fap_text(text)
    assert frames.values[0, 18] == 4 and frames.mask[0].sum() == 1


def test_69th_entry_one_is_not_the_quirk():
    # a 68-entry all-zero mask followed by frame number 1 on the same line is a normal frame
    text = "2.1 a 25 1\n" + mask_line() + " 1\n"
    frames, _, warnings = read_fap_text(text)
    assert warnings == [] and frames.frame_number.tolist() == [1]


def test_warning_cap():
    n = 120
    body = "".join(mask_line() + f"\n{n - k}\n" for k in range(n))
    _, _, warnings = read_fap_text(f"2.1 a 25 {n}\n" + body)
    order = [w for w in warnings if w.rule == "fap-text-frame-order"]
    assert len(order) == 51 and "further" in order[-1].message and "69 further" in order[-1].message


def test_huge_declared_count_does_not_allocate():
    text = "2.1 a 25 1000000000000000\n" + mask_line({3}) + "\n0 5\n"
    tracemalloc.start()
    try:
        frames, header, warnings = read_fap_text(text)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert header.declared_frames == 10**15 and len(frames) == 1
    assert [w.rule for w in warnings] == ["fap-text-frame-count"]
    assert peak < 5_000_000


# ------------------------------------------------------------------------------- writer
def test_write_format_and_file(tmp_path):
    frames = FapFrames.empty(2, frame_rate=29.97)
    frames.status[0, [0, 4]] = SET
    frames.high[0] = [1, 2, 3, 0, 0, 0, 0, 0, 0, 0]
    frames.values[0, 4] = -7
    frames.status[1, [0, 4]] = RETAINED
    frames.high[1] = frames.high[0]
    frames.values[1, 4] = -7
    text = write_fap(frames, name="x")
    lines = text.split("\n")
    assert lines[0] == "2.1 x 29.97 2"
    assert lines[1].split() == ["1", "0", "0", "0", "1"] + ["0"] * 63
    assert lines[2] == "0 1 2 3 0 -7" and lines[4] == "1" and text.endswith("\n")
    p = tmp_path / "sub" / "o.fap"
    write_fap_file(p, frames, name="x", version="2.2")
    back, header, warnings = read_fap_file(p)
    assert warnings == [] and header.version == "2.2" and first_difference(frames, back) is None
    assert write_fap(FapFrames.empty(0, 10.0)).split("\n")[0] == "2.1 fbaconf 10 0"


@pytest.mark.parametrize("kw", [{"name": "a b"}, {"name": ""}, {"name": "a#b"}, {"version": "2 .1"}])
def test_write_rejects_bad_header_words(kw):
    with pytest.raises(EncodeError):
        write_fap(FapFrames.empty(1), **kw)


def test_write_rejects_bad_rate_and_frame_numbers():
    f = FapFrames.empty(1)
    f.frame_rate = float("nan")
    with pytest.raises(EncodeError):
        write_fap(f)
    f = FapFrames.empty(2)
    f.frame_number[1] = -1
    with pytest.raises(EncodeError):
        write_fap(f)


# ------------------------------------------------------------------------------- round trip
RATES = [25.0, 30.0, 29.97, 10.0, 2.0, 12.5, 23.976]
HIGH_RANGES = [(0, 14), (0, 14), (0, 63), (0, 1), (0, 6), (0, 63), (0, 6), (0, 63), (0, 1), (0, 1)]


def make_frames(n: int, rate: float, density: float, seed: int, first: int) -> FapFrames:
    """Random FapFrames with .fap semantics (mask = SET, unmasked retained when set before)."""
    rng = np.random.default_rng(seed)
    f = FapFrames.empty(n, frame_rate=rate)
    last_v = np.zeros(68, np.int32)
    last_h = np.zeros(10, np.int32)
    ever = np.zeros(68, bool)
    fn = first
    for k in range(n):
        mask = rng.random(68) < density
        v = last_v.copy()
        v[2:][mask[2:]] = rng.integers(-5000, 5001, mask[2:].sum())
        h = last_h.copy()
        new_h = np.array([rng.integers(lo, hi + 1) for lo, hi in HIGH_RANGES], np.int32)
        if mask[0]:
            h[:4] = new_h[:4]
        if mask[1]:
            h[4:] = new_h[4:]
        ever |= mask
        f.status[k] = np.where(mask, SET, np.where(ever, RETAINED, FREE))
        f.values[k] = v
        f.high[k] = h
        f.frame_number[k] = fn
        fn += int(rng.integers(1, 4))
        last_v, last_h = v, h
    f.time_ms[:] = f.frame_number * 1000.0 / rate
    return f


frames_strategy = st.builds(
    make_frames,
    n=st.integers(0, 8),
    rate=st.sampled_from(RATES),
    density=st.sampled_from([0.0, 0.05, 0.3, 0.9, 1.0]),
    seed=st.integers(0, 2**32 - 1),
    first=st.integers(0, 3),
)


def check_same(frames: FapFrames, back: FapFrames, warnings) -> None:
    assert first_difference(frames, back) is None, first_difference(frames, back)
    np.testing.assert_array_equal(frames.status, back.status)
    assert back.frame_rate == frames.frame_rate
    np.testing.assert_allclose(back.time_ms, frames.time_ms)
    rules = {w.rule for w in warnings}
    assert rules <= {"fap-text-frame-beyond"}  # sparse numbering can exceed the declared count
    if len(frames) == 0 or frames.frame_number[-1] <= len(frames):
        assert not rules


@settings(max_examples=60, deadline=None)
@given(frames=frames_strategy)
def test_round_trip(frames):
    text = write_fap(frames, name="rt")
    back, header, warnings = read_fap_text(text)
    assert header.declared_frames == len(frames) and header.name == "rt"
    check_same(frames, back, warnings)


def perturb(text: str, rnd: random.Random) -> str:
    """Re-space a written .fap text: random blanks/tabs, wrapped lines (never joined), blank
    and comment lines, trailing comments, CRLF / CR / LF endings."""
    out: list[str] = []
    junk = "0123456789 -x#\t"
    if rnd.random() < 0.5:
        out.append("# " + "".join(rnd.choice(junk) for _ in range(rnd.randint(0, 20))))
    for i, line in enumerate(text.split("\n")[:-1]):
        toks = line.split(" ")
        pieces = [rnd.choice(["", " ", "\t", "  "]) + toks[0]]
        for t in toks[1:]:
            if i > 0 and rnd.random() < 0.1:
                sep = rnd.choice([" ", ""]) + "\n" + rnd.choice(["", "\t", " "])
            else:
                sep = rnd.choice([" ", "\t", "  ", " \t "])
            pieces.append(sep + t)
        line = "".join(pieces)
        if rnd.random() < 0.3:
            line += rnd.choice([" ", ""]) + "#" + "".join(rnd.choice(junk) for _ in range(rnd.randint(0, 12)))
        out.extend(line.split("\n"))
        if rnd.random() < 0.1:
            out.append(rnd.choice(["", "   ", "# comment 1 2 3", "\t#"]))
    eol = rnd.choice(["\n", "\r\n", "\r", None])
    if eol is None:
        return "".join(ln + rnd.choice(["\n", "\r\n"]) for ln in out)
    return eol.join(out) + (eol if rnd.random() < 0.8 else "")


@settings(max_examples=60, deadline=None)
@given(frames=frames_strategy, seed=st.integers(0, 2**32 - 1))
def test_round_trip_perturbed(frames, seed):
    text = perturb(write_fap(frames, name="rt"), random.Random(seed))
    back, header, warnings = read_fap_text(text)
    assert header.name == "rt"
    check_same(frames, back, warnings)


# ------------------------------------------------------------------------------- robustness
def read_or_error(text: str):
    """Read ``text`` leniently and strictly: each ends in a result or a TextFormatError, and
    strict succeeds exactly when lenient succeeds without warnings (with the same frames)."""
    try:
        strict = read_fap_text(text, strict=True)[0]
    except TextFormatError as e:
        assert e.rule in RULES and e.line >= 1 and e.column >= 1
        strict = None
    try:
        frames, header, warnings = read_fap_text(text)
    except TextFormatError as e:
        assert e.rule in RULES and e.line >= 1 and e.column >= 1
        assert strict is None
        return None
    assert (strict is not None) == (warnings == [])
    if strict is not None:
        assert first_difference(frames, strict) is None
    assert isinstance(header, FapFileHeader) and all(isinstance(w, TextWarning) for w in warnings)
    assert all(w.rule in RULES for w in warnings)
    assert len(frames.values) == len(frames.frame_number) == len(frames.status)
    assert math.isfinite(frames.frame_rate) and frames.frame_rate > 0
    return frames


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.text(max_size=400))
def test_random_text(text):
    read_or_error(text)


@settings(max_examples=100, deadline=None)
@given(st.binary(max_size=400), st.sampled_from(["latin-1", "utf-8"]))
def test_random_bytes(data, enc):
    read_or_error(data.decode(enc, errors="replace"))
    try:  # the bytes source of read_fap: a result or TextFormatError, nothing else
        read_fap(data)
    except TextFormatError:
        pass


TOKENS = [
    "0",
    "1",
    "0",
    "1",
    "2",
    "-1",
    "x",
    "1.5",
    "#",
    "\n",
    "\r\n",
    "\r",
    " ",
    "\t",
    "99999999999",
    "2.1",
    "25",
    "a b",
]


@settings(max_examples=150, deadline=None)
@given(
    head=st.sampled_from(["2.1 a 25 3\n", "2.0 a b 10 1\n", "2.2 x 0.5 999999999999999\n", ""]),
    toks=st.lists(st.sampled_from(TOKENS), max_size=400),
)
def test_random_token_soup(head, toks):
    read_or_error(head + " ".join(toks))


@settings(max_examples=150, deadline=None)
@given(
    head=st.sampled_from(["2.1 a 25 3\n", "2.1 AU x 25 1\n"]),
    nmasks=st.integers(1, 3),
    width=st.sampled_from([67, 68, 69]),
    bits=st.lists(st.sampled_from(["0", "0", "0", "1"]), min_size=210, max_size=210),
    tail=st.lists(st.sampled_from(["0", "1", "-7", "12", "\n", "x"]), max_size=80),
)
def test_near_valid_frames(head, nmasks, width, bits, tail):
    parts = []
    for m in range(nmasks):
        parts.append(" ".join(bits[m * 70 : m * 70 + width]) + "\n" + " ".join(tail[m * 20 : (m + 1) * 20]) + "\n")
    read_or_error(head + "".join(parts))


def mutate(text: str, rnd: random.Random) -> str:
    for _ in range(rnd.randint(1, 4)):
        if not text:
            break
        op = rnd.randrange(7)
        i = rnd.randrange(len(text))
        j = min(len(text), i + rnd.randint(1, 40))
        if op == 0:
            text = text[:i] + text[j:]
        elif op == 1:
            text = (
                text[:i] + "".join(rnd.choice("01-9#x. \t\n\r\x00\u00e9") for _ in range(rnd.randint(1, 6))) + text[i:]
            )
        elif op == 2:
            text = text[:i]
        elif op == 3:
            text = text[:i] + text[i:j] + text[i:]
        elif op == 4:
            text = text[:i] + rnd.choice("0123456789") + text[i + 1 :]
        elif op == 5:
            lines = text.split("\n")
            rnd.shuffle(lines)
            text = "\n".join(lines)
        else:
            text = text.replace(" ", rnd.choice(["", "\n", "  "]), rnd.randint(1, 5))
    return text


@pytest.mark.external
@settings(max_examples=120, deadline=None)
@given(idx=st.integers(0, 10**6), seed=st.integers(0, 2**32 - 1))
def test_mutated_real_files(idx, seed):
    files = real_files()
    if not files:
        pytest.skip("real .fap files not available")
    text = files[idx % len(files)].read_bytes().decode("utf-8", errors="replace")
    read_or_error(mutate(text, random.Random(seed)))


def test_large_input_reads_every_frame_in_bounded_memory():
    # 500 frames of all-masked data (under tracemalloc, which slows Python several times): every
    # frame read, memory a small multiple of the text's size
    frames = make_frames(500, 25.0, 1.0, 1, 0)
    text = write_fap(frames)
    tracemalloc.start()
    try:
        back, _, warnings = read_fap_text(text)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    check_same(frames, back, warnings)
    assert peak < 20 * len(text) + 5_000_000
