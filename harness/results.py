"""Per-case results of a harness run, and the run record that reports are made from.

A :class:`CaseResult` is written (one JSON line) the moment it is known, so an interrupted
run loses nothing and ``--resume`` skips cases already recorded. A :class:`RunRecord`
is what every report (terminal, JSON, JUnit XML, HTML) and the certificate are built from.

Outcome classes (architecture "Results"): Pass, Fail, QualityWarning, NotSupported,
Timeout, Crash, Error, Skipped. Only ``Pass``/``QualityWarning`` satisfy a case the claim
requires: a required case that is NotSupported fails the claim too (a claim means all of
it). NotSupported outside the claim is informative.
"""

from __future__ import annotations

import json
import os
import threading
from collections.abc import Iterable, Iterator
from dataclasses import asdict, dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any


class Outcome(StrEnum):
    PASS = "Pass"  # noqa: S105 - an outcome, not a password
    FAIL = "Fail"
    QUALITY_WARNING = "QualityWarning"
    NOT_SUPPORTED = "NotSupported"
    TIMEOUT = "Timeout"
    CRASH = "Crash"
    ERROR = "Error"
    SKIPPED = "Skipped"

    @property
    def ok(self) -> bool:
        """True when this outcome does not fail a required case."""
        return self in (Outcome.PASS, Outcome.QUALITY_WARNING)

    @property
    def failing(self) -> bool:
        """True for outcomes that mean the decoder misbehaved or the case could not run."""
        return self in (Outcome.FAIL, Outcome.TIMEOUT, Outcome.CRASH, Outcome.ERROR)


# Order used in summaries (worst first).
OUTCOME_ORDER = (
    Outcome.CRASH,
    Outcome.TIMEOUT,
    Outcome.FAIL,
    Outcome.ERROR,
    Outcome.QUALITY_WARNING,
    Outcome.NOT_SUPPORTED,
    Outcome.SKIPPED,
    Outcome.PASS,
)


@dataclass
class StageResult:
    """One rung of the comparison ladder for one case (``faps``, ``vertices``, ``images``, ``process``).

    ``first_difference`` names where the decoder first departs from the golden output, e.g.
    ``{"frame": 12, "fap": 31, "name": "raise_l_i_eyebrow", "expected": 120, "got": 121}`` or
    ``{"frame": 3, "vertex": 88, "part": "skin", "expected": [..], "got": [..], "distance": 0.02}``
    or ``{"frame": 0, "pixel": [x, y], "expected": [r,g,b], "got": [r,g,b]}``.
    ``metrics`` holds the numbers (max/rms error, PSNR, ΔE mean/p95, failing pixel share...);
    ``series`` per-frame error curves for the HTML plots (name -> list of floats);
    ``artefacts`` paths (relative to the run's output folder) of expected/got/diff images.
    """

    stage: str
    outcome: Outcome
    message: str = ""
    first_difference: dict[str, Any] | None = None
    metrics: dict[str, float] = field(default_factory=dict)
    series: dict[str, list[float]] = field(default_factory=dict)
    artefacts: dict[str, str] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["outcome"] = self.outcome.value
        return d

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> StageResult:
        d = dict(d)
        d["outcome"] = Outcome(d["outcome"])
        return cls(**d)


@dataclass
class CaseResult:
    """The verdict for one test case against one decoder."""

    case_id: str  # "<suite>/<case>"
    suite: str
    claim: str  # the profile@level the case belongs to, e.g. "simple@1"
    outcome: Outcome
    message: str = ""
    required: bool = True  # required by the claim under test (False: optional tool / informative)
    stages: list[StageResult] = field(default_factory=list)
    duration_s: float = 0.0
    command: list[str] | None = None  # argv actually run (for reproduction)
    exit_code: int | None = None
    signal: str | None = None
    stderr_tail: str = ""
    crash_kind: str | None = None  # the crash report found (sanitizer, panic, uncaught exception), if any
    baseline: str | None = None  # "known-failure", "flake", "fixed" (listed failing, passes now), "new"
    rests_on: list[str] = field(default_factory=list)  # provisional decisions the expected output rests on (D3-D8)
    kind: str = "decode"  # the case's kind: decode, multi or error (an invalid stream)
    tools: list[str] = field(default_factory=list)  # the coding tools the case's streams use
    ending: str | None = None  # how the decoder's process ended (isolation.endings.EndingKind), when it ran
    reading: str | None = None  # the declared other reading the case was judged by (a provisional difference)
    other_reading: str | None = None  # an undeclared other reading the decoder's result equals (a hint, no excuse)

    @property
    def first_difference(self) -> dict[str, Any] | None:
        for s in self.stages:
            if s.first_difference:
                return s.first_difference
        return None

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["outcome"] = self.outcome.value
        d["stages"] = [s.to_json() for s in self.stages]
        return d

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> CaseResult:
        d = dict(d)
        d["outcome"] = Outcome(d["outcome"])
        d["stages"] = [StageResult.from_json(s) for s in d.get("stages", [])]
        return cls(**d)


@dataclass
class SpeedResult:
    """Measured per-frame cost of one operation (decode or render) against a level minimum, and
    whether the machine gave the decoder its CPU meanwhile (harness/speed/measure.py, harness/speed/load.py)."""

    operation: str  # "decode" | "render"
    claim: str
    per_frame_s: float
    startup_s: float
    rate_fps: float  # 1 / per_frame_s (x faces where the level counts all faces together)
    required_fps: float
    passed: bool  # True only for verdict "pass"
    provenance: str  # provenance of the level minimum (seed / iso-via-implementation / provisional)
    samples: list[dict[str, Any]] = field(default_factory=list)  # {"frames": n, "seconds": t, "cpu_s", ...} per run
    fit_r2: float = 0.0
    message: str = ""
    verdict: str = ""  # "pass" | "fail" | "inconclusive" (the rate missed on a busy machine); default: by passed
    reason: str = ""  # the verdict in words, with the numbers
    cpu_s: float | None = None  # the decoder's CPU time over the timed runs
    wall_s: float | None = None  # the timed runs' time
    stall_s: float | None = None  # time it (or any task: stall_source "machine PSI") waited for a CPU
    stall_source: str = ""
    others_share: float | None = None  # share of the CPUs other processes used during the runs
    others_share_between: float | None = None  # ... and between them
    load: float | None = None  # the highest 1-minute load average seen
    cpus: int | None = None  # CPUs usable
    uncontended_fps: float | None = None  # the rate without the wait other processes explain

    def __post_init__(self) -> None:
        if not self.verdict:  # a result made (or written) before verdicts: by whether it passed
            self.verdict = "pass" if self.passed else "fail"

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> SpeedResult:
        return cls(**d)


@dataclass
class RunRecord:
    """Everything a report needs: who ran what, on what, and the verdicts."""

    decoder: dict[str, Any]  # {"name", "manifest_sha256", "kind", "claims", "inputs", "outputs"}
    claim: str | None
    suites: list[dict[str, Any]]  # [{"name", "version", "sha256", "cases"}]
    system: dict[str, Any]
    results: list[CaseResult] = field(default_factory=list)
    speed: list[SpeedResult] = field(default_factory=list)
    started: str = ""
    finished: str = ""
    duration_s: float = 0.0
    provisional: list[str] = field(default_factory=list)  # statements of provisional rules/limits
    missing: list[str] = field(default_factory=list)  # required cases the decoder could not take, by reason
    baseline_summary: str = ""  # "N new, N known, N fixed, N flaky" when a baseline/flakes/retries applied
    exit_code: int = 0
    # required cases judged by a declared other reading ({"case_id", "rests_on", "reading"}); they fail the
    # claim only under --strict (harness/verdict.py)
    provisional_differences: list[dict[str, Any]] = field(default_factory=list)
    strict: bool = False
    verdict: dict[str, Any] = field(
        default_factory=dict
    )  # the claim's verdict: words, tools and decisions (verdict.py)

    def counts(self, results: Iterable[CaseResult] | None = None) -> dict[str, int]:
        c = {o.value: 0 for o in OUTCOME_ORDER}
        for r in self.results if results is None else results:
            c[r.outcome.value] += 1
        return c

    def to_json(self) -> dict[str, Any]:
        return {
            "format": "fbaconf.run/1",
            "decoder": self.decoder,
            "claim": self.claim,
            "suites": self.suites,
            "system": self.system,
            "started": self.started,
            "finished": self.finished,
            "duration_s": self.duration_s,
            "counts": self.counts(),
            "exit_code": self.exit_code,
            "provisional": self.provisional,
            "missing": self.missing,
            "baseline_summary": self.baseline_summary,
            "provisional_differences": self.provisional_differences,
            "strict": self.strict,
            "verdict": self.verdict,
            "results": [r.to_json() for r in self.results],
            "speed": [s.to_json() for s in self.speed],
        }

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> RunRecord:
        return cls(
            decoder=d["decoder"],
            claim=d.get("claim"),
            suites=d.get("suites", []),
            system=d.get("system", {}),
            results=[CaseResult.from_json(r) for r in d.get("results", [])],
            speed=[SpeedResult.from_json(s) for s in d.get("speed", [])],
            started=d.get("started", ""),
            finished=d.get("finished", ""),
            duration_s=d.get("duration_s", 0.0),
            provisional=d.get("provisional", []),
            missing=d.get("missing", []),
            baseline_summary=d.get("baseline_summary", ""),
            exit_code=d.get("exit_code", 0),
            provisional_differences=d.get("provisional_differences", []),
            strict=d.get("strict", False),
            verdict=d.get("verdict", {}),
        )


_APPEND_LOCK = threading.Lock()


class ResultLog:
    """Append-only JSON-lines log of case results: written and flushed per case (``--resume``).

    A line cut short by an interruption is ignored on reading (the case simply runs again).
    """

    def __init__(self, path: Path) -> None:
        self.path = Path(path)

    def read(self) -> dict[str, CaseResult]:
        done: dict[str, CaseResult] = {}
        if not self.path.is_file():
            return done
        with open(self.path, encoding="utf-8") as f:
            for line in f:
                try:
                    r = CaseResult.from_json(json.loads(line))
                except (ValueError, KeyError, TypeError):
                    continue
                done[r.case_id] = r
        return done

    def append(self, result: CaseResult) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        data = (json.dumps(result.to_json(), sort_keys=True) + "\n").encode("utf-8")
        # one appender at a time (the runner's threads finish cases together): checking the last
        # byte and writing must not interleave with another line's write, which left blank and
        # spliced lines when a long line went out in several writes
        with _APPEND_LOCK:
            fd = os.open(self.path, os.O_RDWR | os.O_APPEND | os.O_CREAT, 0o644)
            try:
                end = os.lseek(fd, 0, os.SEEK_END)
                if end and os.pread(fd, 1, end - 1) != b"\n":  # a line cut short by an interruption
                    data = b"\n" + data  # must not swallow the next record
                while data:
                    data = data[os.write(fd, data) :]
                os.fsync(fd)
            finally:
                os.close(fd)

    def __iter__(self) -> Iterator[CaseResult]:
        return iter(self.read().values())
