"""``fbaconf explain`` on decoders whose faults are known because they were planted: the text
player of tests/players/quirky.py (five quirks, each named in its docstring with the input
feature that triggers it) and a player whose ending on some inputs is random (undefined
behaviour). The expected causes and cases come from what was planted, not from explain."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from fbaconf.cli import main

from lib.manifests import python_decoder, write_manifest
from lib.sandbox import needs_sandbox

PLAYER = Path(__file__).resolve().parents[1] / "players" / "quirky.py"
TEXT = "simple-l1-text/"
# each planted quirk (tests/players/quirky.py) -> the feature that triggers it -> the cases that have it
PLANTED = {
    "content.rate-fractional": {"rate-fractional"},  # 1. integer rate
    "content.head-rotation": {"header-2-2"},  # 2. FAPs 48-50 scaled
    "content.numbered-from-nonzero": {"numbered-from-one", "mask-69-tokens-last-1"},  # 3. numbered from one
    "text.crlf": {"comments-crlf"},  # 4. CRLF breaks values
    "content.viseme_def": {"viseme-def"},  # 5. viseme_def dropped
}


def _player(tmp_path: Path) -> Path:
    return write_manifest(
        tmp_path / "quirky.toml",
        ["{python}", str(PLAYER), "{input}", "{faps_out}"],
        name="quirky",
        inputs=("fap",),
        limits="timeout_s = 30",
    )


def _explain(capsys: pytest.CaptureFixture[str], *argv: str) -> str:
    capsys.readouterr()
    assert main(["explain", *argv]) == 0
    return capsys.readouterr().out


def test_five_planted_quirks_are_five_confirmed_causes_covering_every_failure(tmp_path, capsys):
    needs_sandbox()
    run = tmp_path / "run"
    main(["run", "--decoder", str(_player(tmp_path)), "--suite", "simple-l1-text", "-o", str(run), "-j", "2"])
    doc = json.loads(_explain(capsys, str(run), "--json", "--keep", str(tmp_path / "inputs")))
    failing = {c for cases in PLANTED.values() for c in cases}
    assert doc["failing"] == len(failing)
    causes = {c["feature"]: c for c in doc["causes"]}
    assert set(causes) == set(PLANTED), doc["headline"]
    for feature, cases in PLANTED.items():
        c = causes[feature]
        assert {x.removeprefix(TEXT) for x in c["cases"]} == cases
        assert c["confirmed"] and c["confirmed"]["outcome"] == "Pass", c
        assert Path(c["confirmed"]["input"]).is_file()  # the smallest confirming input, kept
    assert doc["headline"] == f"5 causes explain {len(failing)} of {len(failing)} failures"
    assert 0 < doc["runs"] <= doc["bound"]
    html = tmp_path / "html"
    _explain(capsys, str(run), "--no-confirm", "--html", str(html))
    page = (html / "index.html").read_text()
    assert "Root causes" in page and "CRLF line ends" in page


def test_a_run_without_failures_is_one_line(tmp_path, capsys):
    needs_sandbox()
    run = tmp_path / "run"
    main(["run", "--decoder", str(_player(tmp_path)), "--case", "simple-l1-text/rate-30", "-o", str(run)])
    out = _explain(capsys, str(run))
    assert out.count("\n") == 1 and "no failures" in out


RANDOM_ON_COMMENTS = """\
import random
from fbaconf.reference.pipeline import reference_outputs
IN, OUT = sys.argv[1], sys.argv[2]
if b"#" in open(IN, "rb").read():  # planted: an ending that is not a function of the input
    if random.SystemRandom().random() < 0.5:
        os.kill(os.getpid(), signal.SIGSEGV)
    sys.exit(1)
try:
    reference_outputs(IN, faps_out=OUT, player_state=True)
except Exception:  # an invalid file: rejected
    sys.exit(1)
"""


def test_undefined_behaviour_is_its_own_cause(tmp_path, capsys):
    needs_sandbox()
    m = python_decoder(tmp_path, "coin", RANDOM_ON_COMMENTS, inputs=("fap",), limits="timeout_s = 30")
    run = tmp_path / "run"
    main(["run", "--decoder", str(m), "--suite", "simple-l1-text", "-o", str(run), "-j", "2"])
    doc = json.loads(_explain(capsys, str(run), "--json"))
    with_comments = {"comment-between-frames", "comments-crlf", "header-no-name"}
    causes = {c["feature"]: c for c in doc["causes"]}
    # three cases, five runs each, a fair coin: all fifteen alike has odds 2^-12
    assert "undefined-behaviour" in causes, doc["headline"]
    ub = {x.removeprefix(TEXT) for x in causes["undefined-behaviour"]["cases"]}
    assert ub and ub <= with_comments
    rest = {x.removeprefix(TEXT) for f, c in causes.items() if f != "undefined-behaviour" for x in c["cases"]}
    assert ub | rest == with_comments
