"""pytest plugin: gate a decoder's CI with ``pytest --fbaconf-decoder D.toml``.

Installed with fbaconf (entry point ``pytest11``); inactive unless ``--fbaconf-decoder`` is
given. Then every conformance case becomes one pytest item with the node id
``fbaconf::<suite>/<case>``, and nothing else is collected unless paths are named on the
command line — not the project's own tests, nor those of an fbaconf checkout beside them
(``./fbaconf``, as the GitHub Actions example has it). Pass/QualityWarning pass (a
QualityWarning also emits a warning), cases outside the claim skip with the reason, a required
case the decoder cannot take (NotSupported) fails — a claim means all of it — and Fail /
Timeout / Crash / Error fail with the harness's message and first difference. Node ids can
be pasted back as arguments (``pytest --fbaconf-decoder D.toml fbaconf::simple-l1-core/dct-q4``),
and ``--lf`` / ``--ff`` work as usual.

With a baseline (``fbaconf run``'s file, harness/baseline.py) a case failing as listed is an
xfail naming its line, one listed ``Flake`` (or matching ``--fbaconf-flakes``) is re-run and
an xfail if it keeps failing, a listed case that passes now fails ("fixed": remove the line)
unless ``--fbaconf-allow-fixed``, and anything else that fails is new and fails. A provisional
difference (conformance/provisional.py) is an xfail unless ``--fbaconf-strict``, as in ``fbaconf run``.
The run ends with ``fbaconf: N new, N known, N fixed, N flaky`` and the new failures by name,
before pytest's own failure sections (with ``--junitxml``, the file's ``baseline`` property). Options:

  --fbaconf-decoder D.toml|NAME   decoder manifest or bundled adapter name
  --fbaconf-claim P@L             claim under test (default: the decoder's highest claim)
  --fbaconf-suite NAME            only this suite (repeatable)
  --fbaconf-baseline FILE         known failures/flakes (checked before anything runs)
  --fbaconf-flakes FILE           regular expressions of flaky case ids
  --fbaconf-retries N             re-run a failing case up to N times (a pass on a re-run: flaky)
  --fbaconf-allow-fixed           a listed case that passes now does not fail
  --fbaconf-strict                provisional differences fail
  --fbaconf-out DIR               where case artefacts go (default: a temp folder)
  --fbaconf-keep-workdirs         keep the case folders: a failure's reproduce line runs as printed

Select cases with pytest's own ``-k`` or by node id; parallelise with pytest-xdist if installed.
"""

from __future__ import annotations

import fnmatch
import inspect
import tempfile
import warnings
from collections.abc import Generator, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

from fbaconf.conformance.provisional import open_decisions
from fbaconf.conformance.suite import Case, load_suites
from fbaconf.errors import FbaconfInputError

from . import baseline as bl
from .adapters import resolve
from .preflight import preflight
from .reports.common import clean_text, format_difference, reproduce_line
from .results import CaseResult, Outcome
from .runner import RunContext, run_case
from .selection import required_for
from .usage import check_suites, resolve_claim

if TYPE_CHECKING:
    from _pytest._code.code import TerminalRepr, TracebackStyle

PREFIX = "fbaconf::"
_PROPERTY = "fbaconf"  # user property of each item: new, known, fixed, flaky, provisional, pass


def pytest_addoption(parser: pytest.Parser) -> None:
    g = parser.getgroup("fbaconf", "fbaconf conformance cases")
    g.addoption("--fbaconf-decoder", default=None, help="decoder manifest .toml or bundled adapter name")
    g.addoption("--fbaconf-claim", default=None, help="profile@level under test")
    g.addoption("--fbaconf-suite", action="append", default=[], help="only this suite (repeatable)")
    g.addoption("--fbaconf-baseline", default=None, help="baseline file of known failures/flakes")
    g.addoption("--fbaconf-flakes", default=None, help="file of regular expressions of flaky case ids")
    g.addoption("--fbaconf-retries", type=int, default=0, help="re-run a failing case up to N times (default 0)")
    g.addoption(
        "--fbaconf-allow-fixed",
        action="store_true",
        default=False,
        help="a case the baseline lists as failing that passes now does not fail",
    )
    g.addoption(
        "--fbaconf-strict",
        action="store_true",
        default=False,
        help="a failing case that rests on a provisional decision fails (default: xfail)",
    )
    g.addoption("--fbaconf-out", default=None, help="folder for artefacts of failing cases")
    g.addoption(
        "--fbaconf-keep-workdirs",
        action="store_true",
        default=False,
        help="keep each case's work folder (under the --fbaconf-out folder), so its command can be rerun",
    )


class FbaconfCaseWarning(UserWarning):
    """A case passed within tolerance but worse than the warn band (QualityWarning), or only on a re-run."""


class FbaconfCaseFailure(Exception):
    pass


class _State:
    """The session's decoder, claim, suites and baseline, all checked in ``pytest_configure``."""

    def __init__(self, config: pytest.Config) -> None:
        self.adapter = resolve(config.getoption("fbaconf_decoder"))
        self.claim = resolve_claim(config.getoption("fbaconf_claim"), self.adapter)
        names = config.getoption("fbaconf_suite") or []
        suites = load_suites()
        check_suites(suites, names)
        self.suites = [s for s in suites if not names or s.name in names]
        out = config.getoption("fbaconf_out")
        self.out = Path(out).resolve() if out else Path(tempfile.mkdtemp(prefix="fbaconf-pytest-"))
        b, f = config.getoption("fbaconf_baseline"), config.getoption("fbaconf_flakes")
        self.baseline_path = b
        self.baseline = bl.load(Path(b)) if b else None
        self.flakes = bl.load_flakes(Path(f)) if f else None
        self.retries = config.getoption("fbaconf_retries")
        if self.retries < 0:
            raise FbaconfInputError("--fbaconf-retries must be >= 0", rule="usage")
        self.allow_fixed = config.getoption("fbaconf_allow_fixed")
        self.strict = config.getoption("fbaconf_strict")
        self.keep = config.getoption("fbaconf_keep_workdirs")
        preflight(self.adapter)  # the program exists and is executable, the sandbox view is sound

    def flaky(self, case_id: str) -> bool:
        entry = (self.baseline or {}).get(case_id)
        return (entry is not None and entry.outcome == bl.FLAKE) or any(p.search(case_id) for p in self.flakes or [])


class FbaconfItem(pytest.Item):
    def __init__(self, *, case: Case, state: _State, **kw: Any) -> None:
        super().__init__(**kw)
        self.case = case
        self.state = state
        self.add_marker(pytest.mark.fbaconf)

    def _run(self) -> CaseResult:
        st = self.state
        work = st.out / "work"
        work.mkdir(parents=True, exist_ok=True)
        return run_case(RunContext(st.adapter, st.claim, st.out, keep_workdirs=st.keep, work_root=work), self.case)

    def runtest(self) -> None:
        st = self.state
        if not required_for(st.claim, self.case, st.adapter):
            pytest.skip(f"outside the claim {st.claim} (case requires {self.case.claim})")
        r = self._run()
        retries = max(st.retries, 1 if st.flaky(r.case_id) else 0) if r.outcome.failing else 0
        for attempt in range(1, retries + 1):  # as `fbaconf run --retries`: a pass on a re-run is a flake
            if self._run().outcome.ok:
                r.baseline = "flake"
                r.message = f"{bl.RETRY_PASSED} {attempt}; first run: {r.message}"
                break
        if r.reading and r.outcome.ok:
            self.user_properties.append((_PROPERTY, "provisional"))
            if st.strict:
                pytest.fail(
                    f"provisional difference (judged by the declared reading {r.reading}; --fbaconf-strict "
                    f"fails it): {clean_text(r.message)}",
                    pytrace=False,
                )
        opened = sorted(set(r.rests_on) & set(open_decisions()))
        if not st.strict and opened and r.outcome.value in ("Fail", "NotSupported"):
            self.user_properties.append((_PROPERTY, "unverified"))
            pytest.xfail(
                f"rests on the open decision {', '.join(opened)}: the claim names its tool unverified when "
                f"none of the tool's cases passes (--fbaconf-strict fails it): {r.outcome.value}: "
                f"{clean_text(r.message)}"
            )
        summary = bl.classify([r], st.baseline, st.flakes)
        self._judge(r, summary)

    def _judge(self, r: CaseResult, summary: bl.Summary) -> None:
        st = self.state
        if summary.flaky:
            self.user_properties.append((_PROPERTY, "flaky"))
            if r.outcome.ok or r.message.startswith(bl.RETRY_PASSED):
                warnings.warn(FbaconfCaseWarning(f"{r.case_id}: {clean_text(r.message)}"), stacklevel=1)
                return
            pytest.xfail(f"flaky (listed as a flake): {r.outcome.value}: {clean_text(r.message)}")
        if summary.known:
            entry = (st.baseline or {})[r.case_id]
            self.user_properties.append((_PROPERTY, "known"))
            pytest.xfail(
                f"known failure (baseline: {r.case_id},{entry.text()}): {r.outcome.value}: {clean_text(r.message)}"
            )
        if summary.fixed:
            self.user_properties.append((_PROPERTY, "fixed"))
            if st.allow_fixed:
                return
            entry = (st.baseline or {})[r.case_id]
            raise FbaconfCaseFailure(
                r,
                f"fixed: {r.case_id} passes now, but {st.baseline_path} lists it as "
                f"{entry.text()}: remove its line (or --fbaconf-allow-fixed)",
            )
        if summary.new:
            self.user_properties.append((_PROPERTY, "new"))
            raise FbaconfCaseFailure(r, None)
        self.user_properties.append((_PROPERTY, "pass"))
        if r.outcome == Outcome.QUALITY_WARNING:
            warnings.warn(FbaconfCaseWarning(f"{r.case_id}: {clean_text(r.message)}"), stacklevel=1)

    def repr_failure(
        self, excinfo: pytest.ExceptionInfo[BaseException], style: TracebackStyle | None = None
    ) -> str | TerminalRepr:
        if isinstance(excinfo.value, FbaconfCaseFailure):
            r, headline = excinfo.value.args
            if headline:
                return clean_text(headline)
            lines = [f"{r.case_id}: {r.outcome.value}: {r.message}"]
            fd = r.first_difference
            if fd and format_difference(fd) not in r.message:
                lines.append(f"first difference: {format_difference(fd)}")
            if r.command:
                lines.append("reproduce: " + reproduce_line(r, "--fbaconf-keep-workdirs"))
            if r.stderr_tail.strip():
                lines.append("stderr (tail):\n" + r.stderr_tail.strip()[-1500:])
            return clean_text("\n".join(lines))
        return super().repr_failure(excinfo, style=style)

    def reportinfo(self) -> tuple[Path, int | None, str]:
        return self.path, None, f"{PREFIX}{self.case.full_id}"


class FbaconfCollector(pytest.Collector):
    """The node ``fbaconf``: its children are the conformance cases."""

    def __init__(self, *, state: _State, selected: list[str], **kw: Any) -> None:
        super().__init__(**kw)
        self.state = state
        self.selected = selected

    def collect(self) -> Iterator[FbaconfItem]:
        for s in self.state.suites:
            for c in s.cases:
                if self.selected and not any(fnmatch.fnmatchcase(c.full_id, g) for g in self.selected):
                    continue
                yield FbaconfItem.from_parent(self, name=c.full_id, case=c, state=self.state)


# ------------------------------------------------------------------ confining collection


def _selected(config: pytest.Config) -> list[str]:
    return list(getattr(config.option, "fbaconf_selected", None) or [])


@pytest.hookimpl(tryfirst=True)
def pytest_load_initial_conftests(early_config: pytest.Config, parser: pytest.Parser, args: list[str]) -> None:
    """Node ids pasted back (``fbaconf::suite/case``) select cases; they are no paths. Taken out of
    the arguments before pytest looks for conftest files under them — with fbaconf checked out
    at ``./fbaconf`` it would load fbaconf's own ``tests/conftest.py`` — and the rootdir and ini
    file decided again from the paths named: pytest takes every argument that names a file for
    one, the manifest after ``--fbaconf-decoder`` too, and a rootdir there printed the node ids as
    ``../../the/manifest/folder/fbaconf::suite/case``, which do not paste back."""
    ns = early_config.known_args_namespace
    if not getattr(ns, "fbaconf_decoder", None):
        return
    given = [str(a) for a in (getattr(ns, "file_or_dir", None) or [])]
    picked = [a for a in given if a.startswith(PREFIX)]
    if picked:
        early_config.option.fbaconf_selected = [a[len(PREFIX) :] for a in picked]  # an option: xdist workers get it
        ns.file_or_dir = [a for a in given if a not in picked]
        args[:] = [a for a in args if a not in picked]
    _reroot(early_config, ns.file_or_dir)


def _reroot(config: pytest.Config, paths: list[str]) -> None:
    """pytest chose the rootdir and ini file from the arguments before this plugin could take the
    node ids out: with a folder named ``fbaconf`` here, from that folder (fbaconf's own
    pyproject.toml). Decide them again from the remaining arguments (pytest's own function);
    where pytest's internals differ from the ones known here, leave them."""
    try:
        from _pytest.config.findpaths import determine_setup  # noqa: PLC0415 (pytest's internal, optional)

        params = inspect.signature(determine_setup).parameters
        ns = config.known_args_namespace
        kw = {
            "inifile": ns.inifilename,
            "args": paths,
            "rootdir_cmd_arg": ns.rootdir or None,
            "invocation_dir": config.invocation_params.dir,
            "override_ini": ns.override_ini,
        }
        got = determine_setup(**{k: v for k, v in kw.items() if k in params})
        rootpath, inipath, inicfg = got[0], got[1], got[2]
        if (rootpath, inipath) == (config.rootpath, config.inipath):
            return
        old_cut = {str(config.inipath.parent) if config.inipath else None, str(config.rootpath)}
        cache = config._inicache
        config._rootpath, config._inipath, config._inicfg = rootpath, inipath, inicfg
        cache.clear()
        config._parser.extra_info.update(rootdir=str(rootpath), inifile=str(inipath))
        if ns.confcutdir in old_cut:
            ns.confcutdir = str(inipath.parent if inipath else rootpath)
    except (ImportError, AttributeError, TypeError, ValueError):
        return


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "fbaconf: a conformance case run through the fbaconf harness")
    if not config.getoption("fbaconf_decoder"):
        return
    try:  # every input is checked now: a bad manifest, claim, suite or baseline stops pytest at once
        config.stash[_STATE] = _State(config)
    except FbaconfInputError as e:
        raise pytest.UsageError(f"fbaconf: {e}") from None


_STATE = pytest.StashKey[_State]()


def _confined(config: pytest.Config) -> bool:
    """Collect the conformance cases only: no path was named (the default arguments, testpaths or
    the current folder would collect whatever tests lie around, fbaconf's own included)."""
    return bool(config.getoption("fbaconf_decoder")) and config.args_source != pytest.Config.ArgsSource.ARGS


def pytest_ignore_collect(collection_path: Path, config: pytest.Config) -> bool | None:
    if _confined(config):
        return True
    return None


def pytest_report_header(config: pytest.Config) -> list[str] | None:
    st = config.stash.get(_STATE, None)
    if st is None:
        return None
    return [
        f"fbaconf: decoder {st.adapter.name}, claim {st.claim}"
        + (f", baseline {st.baseline_path} ({len(st.baseline)} line(s))" if st.baseline is not None else "")
    ]


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(session: pytest.Session, config: pytest.Config, items: list[pytest.Item]) -> None:
    """Add the cases (before ``--lf``/``--ff`` and ``-k`` look at the items)."""
    st = config.stash.get(_STATE, None)
    if st is None:
        return
    node = FbaconfCollector.from_parent(
        session,
        name="fbaconf",
        nodeid="fbaconf",
        path=Path(config.invocation_params.dir),
        state=st,
        selected=_selected(config),
    )
    added = list(node.collect())
    items.extend(added)
    # Count them as collected (the terminal's "collected N items").
    config.hook.pytest_collectreport(
        report=pytest.CollectReport(node.nodeid, "passed", None, list[pytest.Item | pytest.Collector](added))
    )


@pytest.hookimpl(wrapper=True, tryfirst=True)
def pytest_terminal_summary(
    terminalreporter: pytest.TerminalReporter, exitstatus: int, config: pytest.Config
) -> Generator[None, object, object]:
    """``fbaconf: N new, N known, N fixed, N flaky`` and the new and fixed cases by name, before
    pytest's own failure sections."""
    if config.stash.get(_STATE, None) is not None:
        _baseline_summary(terminalreporter)
    return (yield)


def _seen(tr: pytest.TerminalReporter) -> dict[str, str]:
    """Each item's class against the baseline (new, known, fixed, flaky, provisional, pass), from its reports."""
    return {
        rep.nodeid: v
        for reports in tr.stats.values()
        for rep in reports
        for name, v in getattr(rep, "user_properties", None) or []
        if name == _PROPERTY
    }


def _line(seen: dict[str, str]) -> str:
    count = {k: sum(1 for v in seen.values() if v == k) for k in ("new", "known", "fixed", "flaky", "provisional")}
    line = f"{count['new']} new, {count['known']} known, {count['fixed']} fixed, {count['flaky']} flaky"
    return line + (f" ({count['provisional']} provisional difference(s): xfail)" if count["provisional"] else "")


def _baseline_summary(tr: pytest.TerminalReporter) -> None:
    seen = _seen(tr)
    if not seen:
        return
    tr.write_sep("=", "fbaconf baseline", bold=True)
    tr.write_line(f"fbaconf: {_line(seen)}")
    for what in ("new", "fixed"):
        for nodeid in sorted(n for n, v in seen.items() if v == what):
            tr.write_line(f"  {what.upper():5}  {nodeid}", red=True)


@pytest.hookimpl(tryfirst=True)
def pytest_sessionfinish(session: pytest.Session) -> None:
    """With ``--junitxml``, the line is the JUnit file's ``baseline`` property, as in ``fbaconf run``'s."""
    config = session.config
    tr = config.pluginmanager.get_plugin("terminalreporter")
    if config.stash.get(_STATE, None) is None or tr is None:
        return
    try:
        from _pytest.junitxml import xml_key  # noqa: PLC0415 (pytest's internal: the file's global properties)
    except ImportError:
        return
    xml, seen = config.stash.get(xml_key, None), _seen(tr)
    if xml is not None and seen:
        xml.add_global_property("baseline", _line(seen))
