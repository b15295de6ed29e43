"""pytest plugin: gate a decoder's CI with ``pytest --fbaconf-decoder D.toml``.

Installed with fbaconf (entry point ``pytest11``); inactive unless ``--fbaconf-decoder`` is
given. Then every conformance case becomes one pytest item with the node id
``fbaconf::<suite>/<case>``: Pass/QualityWarning pass (a QualityWarning also emits a
warning), cases outside the claim skip with the reason, a required case the decoder cannot
take (NotSupported) fails — a claim means all of it — and Fail / Timeout / Crash / Error fail
with the harness's message and first difference. Node ids can be pasted back as arguments
(``pytest --fbaconf-decoder D.toml fbaconf::simple-l1-core/dct-q4``), and ``--lf`` / ``--ff``
work as usual. Options:

  --fbaconf-decoder D.toml|NAME   decoder manifest or bundled adapter name
  --fbaconf-claim P@L             claim under test (default: the decoder's highest claim)
  --fbaconf-suite NAME            only this suite (repeatable)
  --fbaconf-baseline FILE         known failures/flakes: xfail instead of fail
  --fbaconf-out DIR               where case artefacts go (default: a temp folder)

Select cases with pytest's own ``-k`` or by node id; parallelise with pytest-xdist if installed.
"""
from __future__ import annotations

import fnmatch
import tempfile
import warnings
from pathlib import Path

import pytest

from fbaconf.conformance.suite import load_suites

from .adapters import resolve
from .baseline import load
from .results import Outcome
from .runner import RunContext, run_case
from .selection import required_for
from .session import resolve_claim

PREFIX = "fbaconf::"


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
        self.adapter = resolve(config.getoption("fbaconf_decoder"))
        self.claim = resolve_claim(config.getoption("fbaconf_claim"), self.adapter)
        names = config.getoption("fbaconf_suite") or None
        self.suites = load_suites(names=names)
        out = config.getoption("fbaconf_out")
        self.out = Path(out).resolve() if out else Path(tempfile.mkdtemp(prefix="fbaconf-pytest-"))
        self.baseline = {}
        if config.getoption("fbaconf_baseline"):
            self.baseline = load(Path(config.getoption("fbaconf_baseline")))


class FbaconfItem(pytest.Item):
    def __init__(self, *, case, state, **kw) -> None:
        super().__init__(**kw)
        self.case = case
        self.state = state
        self.add_marker(pytest.mark.fbaconf)

    def runtest(self) -> None:
        st = self.state
        if not required_for(st.claim, self.case, st.adapter):
            pytest.skip(f"outside the claim {st.claim} (case requires {self.case.claim})")
        work = st.out / "work"
        work.mkdir(parents=True, exist_ok=True)
        r = run_case(RunContext(st.adapter, st.claim, st.out, work_root=work), self.case)
        listed = st.baseline.get(r.case_id)
        if r.outcome == Outcome.NOT_SUPPORTED:
            raise FbaconfCaseFailure(r)  # required (checked above): the claim needs it
        if r.outcome == Outcome.QUALITY_WARNING:
            warnings.warn(FbaconfCaseWarning(f"{r.case_id}: {r.message}"), stacklevel=1)
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
        return self.path, None, f"{PREFIX}{self.case.full_id}"


class FbaconfCollector(pytest.Collector):
    """The node ``fbaconf``: its children are the conformance cases."""

    def __init__(self, *, state, selected, **kw) -> None:
        super().__init__(**kw)
        self.state = state
        self.selected = selected

    def collect(self):
        for s in self.state.suites:
            for c in s.cases:
                if self.selected and not any(fnmatch.fnmatchcase(c.full_id, g) for g in self.selected):
                    continue
                yield FbaconfItem.from_parent(self, name=c.full_id, case=c, state=self.state)


def pytest_configure(config) -> None:
    config.addinivalue_line("markers", "fbaconf: a conformance case run through the fbaconf harness")
    # Node ids pasted back as arguments select cases; they are not paths for pytest to collect.
    picked = [a[len(PREFIX):] for a in config.args if a.startswith(PREFIX)]
    config.stash[_SELECTED] = picked
    if picked:
        config.args[:] = [a for a in config.args if not a.startswith(PREFIX)] or [str(config.invocation_params.dir)]


_SELECTED = pytest.StashKey[list]()


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(session, config, items) -> None:
    """Add the cases (before ``--lf``/``--ff`` and ``-k`` look at the items)."""
    if not config.getoption("fbaconf_decoder"):
        return
    picked = config.stash.get(_SELECTED, [])
    if picked:  # only the named cases: drop whatever else the (replacement) path collected
        for it in list(items):
            config.hook.pytest_deselected(items=[it])
        items.clear()
    node = FbaconfCollector.from_parent(session, name="fbaconf", nodeid="fbaconf",
                                        path=Path(config.invocation_params.dir),
                                        state=_State(config), selected=picked)
    added = list(node.collect())
    items.extend(added)
    # Count them as collected (the terminal's "collected N items").
    config.hook.pytest_collectreport(report=pytest.CollectReport(node.nodeid, "passed", None, added))
