"""pytest plugin: gate a decoder's CI with ``pytest --fbaconf-decoder D.toml``.

Installed with fbaconf (entry point ``pytest11``); inactive unless ``--fbaconf-decoder`` is
given. Then every conformance case becomes one pytest item named
``fbaconf::<suite>/<case>``: Pass/QualityWarning pass (a QualityWarning also emits a
warning), NotSupported and cases outside the claim skip with the reason, and Fail /
Timeout / Crash / Error fail with the harness's message and first difference. Options:

  --fbaconf-decoder D.toml|NAME   decoder manifest or bundled adapter name
  --fbaconf-claim P@L             claim under test (default: the decoder's highest claim)
  --fbaconf-suite NAME            only this suite (repeatable)
  --fbaconf-baseline FILE         known failures/flakes: xfail instead of fail
  --fbaconf-out DIR               where case artefacts go (default: a temp folder)

Select cases with pytest's own ``-k``; parallelise with pytest-xdist if installed.
"""
from __future__ import annotations

import tempfile
import warnings
from pathlib import Path

import pytest


def pytest_addoption(parser) -> None:
    g = parser.getgroup("fbaconf", "fbaconf conformance cases")
    g.addoption("--fbaconf-decoder", default=None, help="decoder manifest .toml or bundled adapter name")
    g.addoption("--fbaconf-claim", default=None, help="profile@level under test")
    g.addoption("--fbaconf-suite", action="append", default=[], help="only this suite (repeatable)")
    g.addoption("--fbaconf-baseline", default=None, help="baseline file of known failures/flakes")
    g.addoption("--fbaconf-out", default=None, help="folder for artefacts of failing cases")


class FbaconfCaseWarning(UserWarning):
    """A case passed within tolerance but worse than the warn band (QualityWarning)."""


class FbaconfCaseFailure(Exception):
    pass


class _State:
    def __init__(self, config) -> None:
        from fbaconf.conformance.suite import load_suites
        from .adapters import resolve
        from .verbs import highest_claim
        self.adapter = resolve(config.getoption("fbaconf_decoder"))
        self.claim = config.getoption("fbaconf_claim") or highest_claim(self.adapter)
        names = config.getoption("fbaconf_suite") or None
        self.suites = load_suites(names=names)
        out = config.getoption("fbaconf_out")
        self.out = Path(out) if out else Path(tempfile.mkdtemp(prefix="fbaconf-pytest-"))
        self.baseline = {}
        if config.getoption("fbaconf_baseline"):
            from .baseline import load
            self.baseline = load(Path(config.getoption("fbaconf_baseline")))


class FbaconfItem(pytest.Item):
    def __init__(self, *, case, state, **kw) -> None:
        super().__init__(**kw)
        self.case = case
        self.state = state
        self.add_marker(pytest.mark.fbaconf)

    def runtest(self) -> None:
        from .results import Outcome
        from .runner import RunContext, required_for, run_case
        st = self.state
        if not required_for(st.claim, self.case):
            pytest.skip(f"outside the claim {st.claim} (case requires {self.case.claim})")
        work = st.out / "work"
        work.mkdir(parents=True, exist_ok=True)
        r = run_case(RunContext(st.adapter, st.claim, st.out, work_root=work), self.case)
        listed = st.baseline.get(r.case_id)
        if r.outcome == Outcome.NOT_SUPPORTED:
            pytest.skip(f"NotSupported: {r.message}")
        if r.outcome == Outcome.QUALITY_WARNING:
            warnings.warn(FbaconfCaseWarning(f"{r.case_id}: {r.message}"))
            return
        if r.outcome.failing:
            if listed == "Flake" or listed == r.outcome.value:
                pytest.xfail(f"baseline lists {r.case_id} as {listed}: {r.outcome.value}: {r.message}")
            raise FbaconfCaseFailure(r)

    def repr_failure(self, excinfo, style=None):
        if isinstance(excinfo.value, FbaconfCaseFailure):
            r = excinfo.value.args[0]
            lines = [f"{r.case_id}: {r.outcome.value}: {r.message}"]
            fd = r.first_difference
            if fd:
                lines.append(f"first difference: {fd}")
            if r.command:
                lines.append("command: " + " ".join(r.command))
            if r.stderr_tail.strip():
                lines.append("stderr (tail):\n" + r.stderr_tail.strip()[-1500:])
            return "\n".join(lines)
        return super().repr_failure(excinfo, style=style)

    def reportinfo(self):
        return self.case.suite_dir or Path("."), None, f"fbaconf {self.case.full_id}"


def pytest_configure(config) -> None:
    config.addinivalue_line("markers", "fbaconf: a conformance case run through the fbaconf harness")


def pytest_collection_modifyitems(session, config, items) -> None:
    if not config.getoption("fbaconf_decoder"):
        return
    state = _State(config)
    for s in state.suites:
        for c in s.cases:
            items.append(FbaconfItem.from_parent(session, name=f"fbaconf::{c.full_id}", case=c, state=state))
