"""An in-process decoder is called one way (PythonAdapter.execute) and its ending judged by the one
classifier, in run, the speed phase and fuzz alike: an uncaught exception was a Crash in run and a
Fail in speed; a typed input error is a reject everywhere."""

from __future__ import annotations

from pathlib import Path

from fbaconf.conformance.suite import load_suites
from fbaconf.errors import FbaconfInputError
from fbaconf.fuzz.inputs import Entry
from fbaconf.fuzz.targets import DecoderTarget
from fbaconf.harness.adapters import Job, PythonAdapter
from fbaconf.harness.results import Outcome
from fbaconf.harness.runner import run_cases
from fbaconf.harness.speed import measure as speed


class Raises(PythonAdapter):
    """A decoder with a bug: it raises on every stream."""

    name, claims, inputs, outputs, faps_format = "raises", ["simple@1"], ["fba"], ["faps"], "npz"

    def run(self, job: Job) -> None:
        raise IndexError("plane table")


class Rejects(Raises):
    def run(self, job: Job) -> None:
        raise FbaconfInputError("bad marker", rule="marker")


def _one_case():
    (s,) = load_suites(names=["simple-l1-core"])
    return [next(c for c in s.cases if c.id == "arith-q1-all-faps")]


def test_an_exception_is_a_crash_in_run_speed_and_fuzz(tmp_path):
    (r,) = run_cases(Raises(), _one_case(), claim="simple@1", out_dir=tmp_path / "run", jobs=1, progress=False)
    assert r.outcome == Outcome.CRASH and "IndexError" in r.message and r.crash_kind
    (s,) = [x for x in speed.measure_claim(Raises(), "simple@1", lengths=[2, 4], repeats=1) if x is not None]
    assert s.verdict == "fail" and "Crash" in s.message and "IndexError" in s.message, s.message
    target = DecoderTarget(Raises(), tmp_path / "fuzz", timeout_s=5.0)
    data = _one_case()[0].input_path("fba").read_bytes()
    v = target.execute(Entry(data)).verdict
    assert v is not None and v.cls == "crash" and "IndexError" in v.message


def test_a_typed_input_error_is_a_reject_in_all_three(tmp_path):
    (r,) = run_cases(Rejects(), _one_case(), claim="simple@1", out_dir=tmp_path / "run", jobs=1, progress=False)
    assert r.outcome == Outcome.FAIL and r.ending == "reject" and "valid stream was rejected" in r.message
    (s,) = [x for x in speed.measure_claim(Rejects(), "simple@1", lengths=[2, 4], repeats=1) if x is not None]
    assert s.verdict == "fail" and "rejected" in s.message, s.message
    target = DecoderTarget(Rejects(), Path(tmp_path) / "fuzz", timeout_s=5.0, oracle=False)
    data = _one_case()[0].input_path("fba").read_bytes()
    assert target.execute(Entry(data)).verdict is None  # a valid stream rejected: fuzz looks for crashes only
