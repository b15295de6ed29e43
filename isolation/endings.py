"""How a decoder process ended: one classifier for ``run``, ``certify`` and ``fuzz``.

Every finished invocation of a decoder under test becomes one :class:`Ending`:

=================  ====================================================================
``kind``           meaning
=================  ====================================================================
``setup``          the harness or the decoder's set-up failed, not the decoding: the
                   launcher could not start, the program cannot be executed, the sandbox
                   could not start it — known to the harness (its check before the start,
                   bubblewrap's status, the fork server's exec report), never read from the
                   decoder's output: a decoder printing "No such file or directory" ran —
                   or a runtime died reserving its address space under an address-space
                   limit (Go, JVM: the runtime's message and the fix are named).
                   Never a Pass, never the decoder's verdict on the stream.
``timeout``        killed at the wall-clock or CPU-time limit.
``memory``         over the memory limit.
``output-limit``   wrote more than the output limit.
``crash``          a signal, or a crash report on stderr whatever the exit code:
                   sanitizers (ASan/UBSan/MSan/TSan/LSan), Rust and Go panics, uncaught
                   Java/Python/.NET exceptions; ``report`` names the kind.
``not-supported``  exit 69.
``decoded``        exit 0 with no crash report.
``reject``         one of the decoder's documented reject exit codes
                   (manifest ``reject_exit_codes``, default 1 and 2).
``unexpected``     any other exit code; a persistent decoder's broken answer, or a reply
                   forged into the fork server's channel (``protocol-error``).
=================  ====================================================================

The run maps kinds to outcomes (``harness/compare/ladder.py``: ``outcome_for``), the fuzzer to
findings; both call :func:`classify`, so the same process ending is judged the same way everywhere.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Collection, Iterable
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING

from .process import MEMORY_TEXT, Note

if TYPE_CHECKING:
    from .process import ProcResult
    from .sandbox import Limits

EXIT_NOT_SUPPORTED = 69
DEFAULT_REJECT_EXIT_CODES = frozenset({1, 2})

_ASAN_FRAME = re.compile(r"^\s*#\d+ 0x[0-9a-f]+ in (\S+)", re.M)
_SANITIZER = re.compile(r"ERROR: (\w+Sanitizer): ([\w-]+)")
_UBSAN = re.compile(r"\S+:\d+:\d+: runtime error: ([^\n]+)")  # file:line:col: runtime error: …
_PY_FRAME = re.compile(r'^\s*File "([^"]+)", line (\d+), in (\S+)', re.M)
_GO_FRAME = re.compile(r"^(\S+\.\S+)\(.*\)$", re.M)
_GO_PANIC = re.compile(r"^(?:panic: |fatal error: )([^\n]*)", re.M)
_RUST_PANIC = re.compile(r"thread '[^']*' panicked at (?:'[^']*', )?([^\n:]+:\d+)")
_JAVA_EXC = re.compile(r"Exception in thread \"[^\"]*\" ([\w.$]+)")
_JAVA_FRAME = re.compile(r"^\s+at (\S+)\(", re.M)
_DOTNET_EXC = re.compile(r"Unhandled exception\. ([\w.]+)")
_BWRAP = re.compile(r"^bwrap: ([^\n]*)", re.M)
# A runtime that dies reserving address space at its start (under an address-space rlimit).
_RESERVE = re.compile(
    r"failed to reserve page summary memory|cannot reserve arena virtual address space|"
    r"runtime: cannot (?:re)?map pages|Could not reserve enough space for [\w ]+|"
    r"Error occurred during initialization of VM|Failed to reserve virtual memory"
)


@dataclass(frozen=True)
class CrashReport:
    """A crash report found on stderr: ``kind`` in words a vendor knows (addresses masked),
    ``signature`` a short hash of the top frames (deduplicates fuzz findings), ``line`` the
    report's first line as printed (the sanitizer's ``ERROR:`` line, ``panic: …``, the exception),
    ``where`` the innermost frame of the decoder's own code when the report names one."""

    kind: str
    signature: str
    line: str = ""
    where: str = ""


_HEX = re.compile(r"0x[0-9a-fA-F]+")


def _h(items: Iterable[str]) -> str:
    return hashlib.sha256("\n".join(items).encode()).hexdigest()[:10]


def _line_at(text: str, pos: int, *, join_next: bool = False) -> str:
    """The whole line of ``text`` holding position ``pos`` (with the next one when it ends in ``:``
    and ``join_next``: a Rust panic's message follows its location), at most 300 characters."""
    start = text.rfind("\n", 0, pos) + 1
    end = text.find("\n", pos)
    line = text[start : end if end >= 0 else len(text)].strip()
    if join_next and line.endswith(":") and end >= 0:
        nxt = text[end + 1 :].split("\n", 1)[0].strip()
        line = f"{line} {nxt}" if nxt else line
    return line[:300]


def _python_exception_line(text: str) -> str:
    """The exception line of the first Python traceback: the first unindented line after its frames."""
    after = text[text.index("Traceback (most recent call last)") :].splitlines()[1:]
    return next((ln.strip() for ln in after if ln.strip() and not ln[:1].isspace()), "")[:300]


def crash_report(text: str) -> CrashReport | None:
    """The crash report a process printed: sanitizer, Python traceback, Go/Rust panic, uncaught
    Java or .NET exception — or None."""
    m = _SANITIZER.search(text)
    if m or "UndefinedBehaviorSanitizer" in text or _UBSAN.search(text):
        frames = _ASAN_FRAME.findall(text)[:5]
        u = _UBSAN.search(text)
        if m:
            kind, at = f"{m.group(1)} {m.group(2)}", m.start()
        elif u:
            kind, at = f"UndefinedBehaviorSanitizer: {_HEX.sub('0x?', u.group(1))[:80]}", u.start()
        else:
            kind, at = "UndefinedBehaviorSanitizer", text.index("UndefinedBehaviorSanitizer")
        return CrashReport(kind, _h(frames or [kind]), _line_at(text, at), frames[0] if frames else "")
    m = _RUST_PANIC.search(text)
    if m:
        return CrashReport("Rust panic", _h([m.group(1)]), _line_at(text, m.start(), join_next=True), m.group(1))
    m = _GO_PANIC.search(text)
    if m and "goroutine" in text:
        frames = _GO_FRAME.findall(text)
        own = next((f for f in frames if not f.startswith("runtime.")), "")
        return CrashReport("Go panic", _h(frames[:5] or [m.group(1)]), _line_at(text, m.start()), own)
    m = _JAVA_EXC.search(text)
    if m:
        frames = _JAVA_FRAME.findall(text)
        return CrashReport(
            f"uncaught Java exception {m.group(1)}",
            _h(frames[:5] or [m.group(1)]),
            _line_at(text, m.start()),
            frames[0] if frames else "",
        )
    m = _DOTNET_EXC.search(text)
    if m:
        return CrashReport(f"unhandled .NET exception {m.group(1)}", _h([m.group(1)]), _line_at(text, m.start()))
    if "Traceback (most recent call last)" in text:
        found = _PY_FRAME.findall(text)
        frames = [f"{Path(f).name}:{ln}:{fn}" for f, ln, fn in found][-5:]
        line = _python_exception_line(text) or "?"
        exc = line.split(":")[0].strip()
        return CrashReport(f"uncaught Python exception {exc}", _h(frames + [exc]), line, found[-1][2] if found else "")
    return None


class EndingKind(StrEnum):
    """The fixed vocabulary of process endings (the table above)."""

    SETUP = "setup"
    TIMEOUT = "timeout"
    MEMORY = "memory"
    OUTPUT_LIMIT = "output-limit"
    CRASH = "crash"
    NOT_SUPPORTED = "not-supported"
    DECODED = "decoded"
    REJECT = "reject"
    UNEXPECTED = "unexpected"


@dataclass(frozen=True)
class Ending:
    kind: EndingKind
    message: str
    report: CrashReport | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", EndingKind(self.kind))  # a misspelt kind fails here

    @property
    def signature(self) -> str:
        """What identifies this ending for deduplication (fuzz findings)."""
        return f"{self.kind}:{self.report.kind}:{self.report.signature}" if self.report else self.kind


def _last_line(text: str) -> str:
    lines = [ln for ln in text.strip().splitlines() if ln.strip()]
    return f"; stderr: {lines[-1][:300]}" if lines else ""


def _setup(res: ProcResult, cmd: str, err: str) -> Ending | None:
    """The set-up failure the harness knows of (its notes), or None."""
    if Note.HARNESS_START_FAILED in res.notes:
        return Ending(EndingKind.SETUP, f"harness could not start the launcher: {err.strip()[:300]}")
    if Note.EXEC_FAILED in res.notes:
        return Ending(EndingKind.SETUP, (res.detail or err).strip()[:300] or f"cannot execute {cmd}")
    if Note.SANDBOX_FAILED in res.notes:  # bubblewrap never ran the program: its stderr is bubblewrap's own
        m = _BWRAP.search(err)
        what = m.group(1) if m else (_last_line(err)[len("; stderr: ") :] or "no message")
        if what.startswith("execvp "):
            prog, _, why = what[len("execvp ") :].partition(": ")
            return Ending(EndingKind.SETUP, f"sandbox: cannot execute {prog!r}: {why}")
        return Ending(EndingKind.SETUP, f"the sandbox (bubblewrap) could not start {cmd}: {what[:300]}")
    return None


def _reservation(res: ProcResult, limits: Limits, cmd: str, err: str) -> Ending | None:
    """A runtime that died reserving address space under the address-space rlimit: a set-up
    problem of the limits, named with the runtime's own line and the fix."""
    m = _RESERVE.search(err) if Note.AS_LIMIT in res.notes and res.returncode != 0 else None
    if m is None:
        return None
    line = next((ln.strip() for ln in err.splitlines() if m.group(0) in ln), m.group(0))[:200]
    return Ending(
        EndingKind.SETUP,
        f"{cmd}'s runtime could not reserve its address space under the "
        f"{limits.memory_mb} MB address-space limit: {line!r}. Not a verdict on the stream: the "
        f'limit is wrong for this runtime. Fix: memory_kind = "tree" in the manifest\'s [limits] '
        f"(the default: the limit holds for what the process tree uses, where cgroups are writable), "
        f'or "rss"',
    )


def classify(
    res: ProcResult,
    limits: Limits,
    reject_exit_codes: Collection[int] = DEFAULT_REJECT_EXIT_CODES,
    *,
    name: str | None = None,
) -> Ending:
    """One :class:`Ending` for a finished :class:`~fbaconf.isolation.sandbox.ProcResult`; its
    message names the decoder ``name`` (the manifest's) — "acme-java exited with code 1", not
    the runtime that ran it — or, without one, the program."""
    cmd = name or (Path(res.argv[0]).name if res.argv else "decoder")
    err = res.stderr_tail or ""
    rc = res.returncode
    known = _setup(res, cmd, err) or _reservation(res, limits, cmd, err)
    if known is not None:
        return known
    if res.timed_out:
        why = "CPU-time limit" if Note.CPU_LIMIT in res.notes else f"timeout of {limits.timeout_s:g} s"
        return Ending(EndingKind.TIMEOUT, f"{cmd} did not finish within the {why} (killed after {res.elapsed_s:.2f} s)")
    if res.memory_limit_hit and (rc != 0 or Note.TREE_MEMORY_LIMIT in res.notes):
        how = f"killed by {res.signal}" if res.signal else f"exit code {rc}"
        kind = (
            "whole-process-tree"
            if Note.TREE_MEMORY_LIMIT in res.notes
            else "resident-set"
            if limits.memory_kind == "rss"
            else "address-space"
        )
        peak = (
            f"its process tree's resident set sampled at {res.rss_sampled_mb:.0f} MB"
            if res.rss_sampled_mb
            else f"peak RSS {res.maxrss_mb:.0f} MB"
        )
        return Ending(
            EndingKind.MEMORY, f"{cmd} exceeded the {limits.memory_mb} MB {kind} memory limit ({how}; {peak})"
        )
    if Note.SUPERVISOR_LOST in res.notes:
        return Ending(
            EndingKind.UNEXPECTED,
            f"the fork server running {cmd} died during this input (the decoder "
            f"killed its parent process, or a process-tree limit did): its ending is unknown — "
            f"a decoder must not signal processes it did not start{_last_line(err)}",
        )
    if Note.PROTOCOL_ERROR in res.notes:
        return Ending(EndingKind.UNEXPECTED, f"{cmd}: {res.detail or 'protocol error'}{_last_line(err)}")
    if res.output_limit_hit:
        return Ending(
            EndingKind.OUTPUT_LIMIT,
            f"{cmd} wrote more than the {limits.output_mb} MB output limit "
            f"({res.output_bytes / 2**20:.0f} MB seen" + (f", killed by {res.signal})" if res.signal else ")"),
        )
    report = crash_report(err)
    # the crash report's own first line (sanitizer ERROR, panic, exception), not whatever stderr ended with
    said = f"; stderr: {report.line}" if report is not None and report.line else _last_line(err)
    where = f" in {report.where}" if report is not None and report.where else ""
    if (report is not None and any(t in report.line.lower() for t in MEMORY_TEXT)) or (
        res.signal == "SIGABRT" and any(t in err.lower() for t in MEMORY_TEXT)
    ):
        # the runtime's own out-of-memory report (MemoryError, std::bad_alloc, OutOfMemoryError, a Rust
        # allocation abort): an allocation the kernel refuses and one killed at the limit are the same
        # act, and which of the two the decoder meets — the lab's free memory decides — must not
        # change the verdict
        return Ending(EndingKind.MEMORY, f"{cmd} ran out of memory under the {limits.memory_mb} MB limit{said}")
    if res.signal:
        what = f" ({report.kind}{where})" if report else ""
        return Ending(EndingKind.CRASH, f"{cmd} crashed: killed by {res.signal}{what}{said}", report)
    if report is not None:
        return Ending(EndingKind.CRASH, f"{cmd} crashed: {report.kind}{where} (exit code {rc}){said}", report)
    if rc == EXIT_NOT_SUPPORTED:
        return Ending(EndingKind.NOT_SUPPORTED, f"{cmd} exited with code 69 (not supported){_last_line(err)}")
    if rc == 0:
        return Ending(EndingKind.DECODED, f"{cmd} exited 0")
    if rc in reject_exit_codes:
        return Ending(EndingKind.REJECT, f"{cmd} exited with code {rc}, a reject{_last_line(err)}")
    codes = ", ".join(map(str, sorted(reject_exit_codes)))
    return Ending(
        EndingKind.UNEXPECTED, f"{cmd} exited with code {rc}, not a documented reject code ({codes}){_last_line(err)}"
    )


def kept_stderr(err: str, ending: Ending) -> str:
    """The 2,000 characters of stderr a result keeps: from the crash report's first line when there is
    one (a sanitizer's report ends in a long legend that would push out the lines that matter),
    else the end."""
    line = ending.report.line if ending.report is not None else ""
    at = err.find(line) if line else -1
    if at >= 0:
        return err[err.rfind("\n", 0, at) + 1 :][:2000]
    return err[-2000:]
