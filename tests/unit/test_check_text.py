"""`fbaconf check F.fap`: the ASCII .fap form checked against the text rules of its reader
(FAP-TEXT-* codes at line:column). Expected locations are counted by hand in the files written here."""

from __future__ import annotations

import json
import tomllib
from importlib import resources
from pathlib import Path

import jsonschema
import pytest
from hypothesis import given, settings, strategies as st

from fbaconf import rules as R
from fbaconf.bitstreams.faptext import check_fap_text, read_fap_text
from fbaconf.cli import main
from fbaconf.errors import TextFormatError

ROOT = Path(__file__).resolve().parents[2]


def mask(*set_faps, bad: dict[int, str] | None = None) -> str:
    m = ["1" if k + 1 in set_faps else "0" for k in range(68)]
    for fap, tok in (bad or {}).items():
        m[fap - 1] = tok
    return " ".join(m)


# line 1 "2.1 acceptance 25 4": the count token '4' is at column 19
# line 4: mask entry 4 (column 7) is '2'
# line 7 "2 30": FAP4's value is missing; the end of the file is just past '30' (column 5)
THREE_FAULTS = (
    "\n".join(
        [
            "2.1 acceptance 25 4",
            mask(3),
            "0 17",
            mask(3, bad={4: "2"}),
            "1 18",
            mask(3, 4),
            "2 30",
        ]
    )
    + "\n"
)


@pytest.fixture(scope="module")
def schema():
    text = resources.files("fbaconf.profiles").joinpath("data", "check-report.schema.json").read_text("utf-8")
    return json.loads(text)


def run(capsys, *args):
    rc = main(["check", *args])
    return rc, capsys.readouterr().out


def test_bad_mask_truncated_frame_and_wrong_count_each_with_line_column_and_code(tmp_path, schema, capsys):
    p = tmp_path / "three.fap"
    p.write_text(THREE_FAULTS)
    rc, out = run(capsys, str(p), "--json")
    assert rc == 1
    doc = json.loads(out)
    jsonschema.validate(doc, schema)
    got = {(i["code"], i["severity"], loc["line"], loc["column"]) for i in doc["issues"] for loc in i["locations"]}
    assert got == {("FAP-TEXT-013", "warning", 1, 19), ("FAP-TEXT-005", "error", 4, 7), ("FAP-TEXT-009", "error", 7, 5)}
    assert doc["counts"] == {"error": 2, "warning": 1, "info": 0}
    assert doc["summary"]["frames"] == 2 and doc["summary"]["frame_rate"] == 25
    rc, text = run(capsys, str(p))
    assert rc == 1
    assert "error: FAP-TEXT-005" in text and "at line 4:7" in text
    assert "error: FAP-TEXT-009" in text and "at line 7:5" in text
    assert "warning: FAP-TEXT-013" in text and "at line 1:19" in text


def test_clean_text_and_only_ignore(tmp_path, capsys):
    p = tmp_path / "ok.fap"
    p.write_text("2.1 ok 25 2\n" + mask(3) + "\n0 5\n" + mask() + "\n1\n")
    assert run(capsys, str(p))[0] == 0
    q = tmp_path / "three.fap"
    q.write_text(THREE_FAULTS)
    rc, out = run(capsys, str(q), "--json", "--ignore", "FAP-TEXT-005", "FAP-TEXT-009")
    assert rc == 0 and [i["code"] for i in json.loads(out)["issues"]] == ["FAP-TEXT-013"]


def test_header_error_and_claims_on_text(tmp_path, capsys):
    p = tmp_path / "h.fap"
    p.write_text("# a comment\n2.1 name fast 3\n")
    rc, out = run(capsys, str(p), "--json")
    assert rc == 1
    (issue,) = json.loads(out)["issues"]
    assert issue["code"] == "FAP-TEXT-001" and issue["locations"] == [{"line": 2, "column": 10}]
    assert run(capsys, str(p), "--claim", "simple@1")[0] == 2  # a claim is about the binary stream


def test_text_sniffed_without_the_suffix(tmp_path, capsys):
    p = tmp_path / "noext"
    p.write_text(THREE_FAULTS)
    rc, out = run(capsys, str(p))
    assert rc == 1 and "FAP-TEXT-005" in out


def test_every_invalid_text_case_is_reported_under_its_rule(capsys):
    spec = tomllib.loads((ROOT / "conformance" / "data" / "suites.toml").read_text("utf-8"))
    cases = [c for c in spec["case"] if c["suite"] == "simple-l1-text"]
    assert len([c for c in cases if c.get("expect")]) >= 3
    for c in cases:
        rc, out = run(capsys, str(ROOT / "conformance" / "data" / c["file"]), "--json")
        errors = {i["code"] for i in json.loads(out)["issues"] if i["severity"] == "error"}
        want = {R.RULES[r].code for r in c.get("expect", [])}
        assert errors == want, c["id"]
        assert rc == (1 if want else 0), c["id"]


def fap(count, *frames, head="2.1 x 25") -> str:
    return f"{head} {count}\n" + "".join(f"{m}\n{v}\n" for m, v in frames)


# one text per FAP-TEXT code that breaks exactly that rule (tests/unit/test_check_codes.py counts on it)
TEXT_CASES = {
    R.TEXT_HEADER: "2.1 x fast 0\n",
    R.TEXT_VERSION: fap(1, (mask(3), "0 5"), head="2.3 x 25"),
    R.TEXT_NAME: fap(1, (mask(3), "0 5"), head="2.1 a b 25"),
    R.TEXT_MASK_LENGTH: fap(1, (mask(3) + " 0", "0 5")),
    R.TEXT_MASK_VALUE: fap(1, (mask(bad={3: "2"}), "0")),
    R.TEXT_INTEGER: fap(1, (mask(3), "0 1.5")),
    R.TEXT_VALUE_RANGE: fap(1, (mask(3), "0 2147483648")),
    R.TEXT_HIGH_LEVEL_RANGE: fap(1, (mask(1), "0 15 0 0 0")),
    R.TEXT_TRUNCATED: fap(0, (mask(3), "0")),
    R.TEXT_FRAME_ORDER: fap(2, (mask(3), "1 5"), (mask(), "0")),
    R.TEXT_FRAME_DUPLICATE: fap(2, (mask(3), "0 5"), (mask(), "0")),
    R.TEXT_FRAME_BEYOND: fap(1, (mask(3), "5 5")),
    R.TEXT_FRAME_COUNT: fap(2, (mask(3), "0 5")),
    R.TEXT_MASK_SHORT: fap(2, (" ".join(mask(3).split()[:67]), "0 5"), (mask(3), "1 6")),
}


def test_every_text_code_has_a_case():
    assert set(TEXT_CASES) == {c for c in R.CODES if c.startswith("FAP-TEXT-")}


@pytest.mark.parametrize("code", sorted(TEXT_CASES))
def test_text_case_triggers_exactly_its_code(code, tmp_path, capsys):
    p = tmp_path / "case.fap"
    p.write_text(TEXT_CASES[code])
    rc, out = run(capsys, str(p), "--json")
    doc = json.loads(out)
    assert [i["code"] for i in doc["issues"]] == [code]
    assert rc == (1 if R.CODES[code].severity == "error" else 0)


def test_every_text_rule_has_a_code_of_its_severity():
    text_rules = [r for r in R.RULES.values() if r.stage == "fap-text"]
    assert len(text_rules) == 14  # the rules table of docs/fap-text.md
    for r in text_rules:
        assert r.code is not None and r.code.startswith("FAP-TEXT-") and R.CODES[r.code].severity == r.severity


TOKENS = st.sampled_from(["0", "1", "2", "-3", "x", "1.5", "#c", "\n", "\r\n", " ", "\t", "25", "2.1", "9" * 45])


@settings(max_examples=300, deadline=None)
@given(st.lists(TOKENS, max_size=400))
def test_the_check_agrees_with_the_reader(tokens):
    """For any text: check_fap_text never raises; where the reader reads the text, the check finds
    no error and the reader's warnings; where the reader refuses it, the check's first error is the
    reader's (the same rule at the same place)."""
    text = " ".join(tokens)
    found, _frames, _header = check_fap_text(text)
    errors = [w for w in found if R.RULES[w.rule].severity == "error"]
    try:
        _, _, warnings = read_fap_text(text)
    except TextFormatError as e:
        assert errors
        first = min(errors, key=lambda w: (w.line, w.column))
        assert (first.rule, first.line, first.column) == (e.rule, e.line, e.column)
    else:
        assert not errors
        assert sorted((w.rule, w.line, w.column) for w in warnings) == sorted((w.rule, w.line, w.column) for w in found)


def _file(n_frames: int, short_at: int | None = None) -> str:
    """A file of ``n_frames`` frames setting FAPs 3, 19 and 31; the mask of frame ``short_at`` one
    entry short (67 entries)."""
    lines = [f"2.1 cascade 25 {n_frames}"]
    for k in range(n_frames):
        m = mask(3, 19, 31).split()
        lines.append(" ".join(m[:67] if k == short_at else m))
        lines.append(f"{k} {10 + k} {20 + k} {30 + k}")
    return "\n".join(lines) + "\n"


def test_a_mask_line_one_entry_short_is_one_error_at_that_line(tmp_path, capsys):
    # frame 1's mask is line 4 (header, mask 0, values 0, mask 1): 67 tokens "0"/"1" of one char
    # and 66 spaces end at column 133; without the rule the frame number took the 68th entry and
    # every token after shifted (hundreds of findings)
    found, frames, _ = check_fap_text(_file(50, short_at=1))
    assert [(w.rule, w.line, w.column) for w in found] == [("fap-text-mask-short", 4, 134)]
    assert "67 entries" in found[0].message and "68 expected" in found[0].message
    assert frames is not None and len(frames) == 50 and frames.values[49, 30] == 30 + 49  # read on in step
    with pytest.raises(TextFormatError) as e:
        read_fap_text(_file(50, short_at=1))
    assert e.value.rule == "fap-text-mask-short" and e.value.line == 4
    p = tmp_path / "short.fap"
    p.write_text(_file(50, short_at=1))
    assert main(["check", str(p)]) == 1
    out = capsys.readouterr().out
    assert "FAP-TEXT-014" in out and "at line 4:134" in out and "1 error(s), 0 warning(s)" in out


def test_a_mask_wrapped_over_lines_is_still_read_as_tokens():
    m = mask(3, 19).split()
    text = "2.1 wrapped 25 1\n" + " ".join(m[:34]) + "\n" + " ".join(m[34:]) + "\n0 5 6\n"
    found, frames, _ = check_fap_text(text)
    assert found == [] and frames is not None and frames.values[0, 18] == 6


def test_a_frame_numbered_below_the_previous_is_out_of_order_even_when_repeated():
    text = "2.1 order 25 3\n" + "\n".join(f"{mask(3)}\n{fn} {fn}" for fn in (0, 1, 0)) + "\n"
    found, _, _ = check_fap_text(text)
    assert {w.rule for w in found} == {"fap-text-frame-order", "fap-text-frame-duplicate"}


def test_a_file_with_warnings_only_is_not_headed_clean(tmp_path, capsys):
    p = tmp_path / "order.fap"
    p.write_text("2.1 order 25 2\n" + "\n".join(f"{mask(3)}\n{fn} {fn}" for fn in (1, 0)) + "\n")
    assert main(["check", str(p)]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[0] == f"{p}: warnings" and "FAP-TEXT-010" in out
