"""`fbaconf run` and `certify` say in one line whether decoders are isolated on this machine —
bubblewrap present, missing, or switched off; an in-process adapter says so too."""

from __future__ import annotations

import pytest

from fbaconf.harness import adapters
from fbaconf.harness.preflight import preflight
from fbaconf.isolation import sandbox
from fbaconf.isolation.report import report


@pytest.mark.parametrize(
    "have,env,words",
    [
        ("bwrap", None, "decoders run in a bubblewrap sandbox on this machine"),
        ("none", None, "bubblewrap (bwrap) is not available: decoders run UNISOLATED"),
        ("none", "none", "bubblewrap (bwrap) is switched off (FBACONF_SANDBOX=none): decoders run UNISOLATED"),
    ],
)
def test_one_line_says_whether_decoders_are_isolated(monkeypatch, capsys, have, env, words):
    monkeypatch.setattr(sandbox, "isolation", lambda: have)
    if env:
        monkeypatch.setenv("FBACONF_SANDBOX", env)
    else:
        monkeypatch.delenv("FBACONF_SANDBOX", raising=False)
    ref = adapters.resolve("reference")  # a command decoder (the bundled reference program)
    line = report(ref).notice()
    assert line.startswith("fbaconf: isolation: ") and words in line and "\n" not in line
    inproc = report(adapters.resolve("reference-inprocess")).notice()
    assert "reference-inprocess runs inside fbaconf (no sandbox applies)" in inproc and words in inproc
    preflight(adapters.resolve("reference-inprocess"))  # what run and certify print first
    assert capsys.readouterr().err.strip() == inproc
