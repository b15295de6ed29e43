"""Targets and verdicts: the decoder under test (through the harness's sandbox and its one classifier
of process endings) and fbaconf itself (--self)."""

from __future__ import annotations

import contextlib
import dataclasses
import os
import tempfile
import threading
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from fbaconf.bitstreams.faptext import read_fap_text
from fbaconf.errors import FbaconfInputError
from fbaconf.harness import compare as cmp
from fbaconf.harness.adapters import CommandAdapter, Job
from fbaconf.harness.runner import hidden_from_decoders
from fbaconf.isolation import endings, sandbox
from fbaconf.isolation.endings import crash_report
from fbaconf.isolation.forkclient import ForkServer
from fbaconf.isolation.persistent import FLAKY, PersistentDecoder
from fbaconf.isolation.process import Note
from fbaconf.isolation.sandbox import Limits
from fbaconf.profiles.checker import check_stream
from fbaconf.safefs import Tree, empty_tree, remove_tree

from .inputs import Entry, InputKind
from .model import reference_parse

HANG_CONFIRM_FACTOR = 4.0  # a timeout is a hang when the input also outlasts this many times the limit alone


@dataclass
class Verdict:
    cls: str
    signature: str  # dedup key within the class (signal + stack hash, or behaviour)
    message: str
    detail: dict = field(default_factory=dict)

    @property
    def key(self) -> str:
        return f"{self.cls}:{self.signature}"


class FuzzSetupError(FbaconfInputError):
    """The fuzz run cannot start or continue (decoder not runnable, no seeds...)."""

    rule = "fuzz-setup"


def stack_hash(text: str) -> tuple[str, str] | None:
    """(kind, short hash) of the crash report a decoder printed — the harness's one crash
    classifier (:func:`fbaconf.isolation.endings.crash_report`)."""
    r = crash_report(text)
    return (r.kind, r.signature) if r else None


@dataclass
class ExecResult:
    verdict: Verdict | None
    features: set[str] = field(default_factory=set)


PIPELINE_DEPTH = 8  # case folders per worker of a fork server or persistent decoder

# what a case folder keeps between inputs: its input folder as it is, its output folders emptied
# (the layout a run's case folder has, whether or not the decoder's command names them)
_CASE_TREE: Tree = {"in": None, "out": {"images": {}, "faces": {}}, "tmp": {}}


@dataclass
class _Slot:
    """One of a worker's case folders."""

    job: object
    input: Path
    folder: str  # the case folder (its tree: _CASE_TREE)
    input_fd: int | None = None
    input_len: int = 0


@dataclass
class _Worker:
    """One worker thread's case folders (used in turn) and fork server or persistent decoder."""

    root: Path
    slots: list = field(default_factory=list)
    turn: int = 0
    server: object = None
    argv: list = field(default_factory=list)


class Run:
    """An input under way: ``wait()`` until the decoder ended, ``result()`` its ExecResult."""

    def __init__(self, wait, judge) -> None:
        self._wait, self._judge, self._out = wait, judge, None

    @classmethod
    def done(cls, out: ExecResult) -> Run:
        return cls(lambda: None, lambda: out)

    def wait(self) -> None:
        self._wait()

    def result(self) -> ExecResult:
        if self._out is None:
            self._wait()
            self._out = self._judge()
        return self._out


class DecoderTarget:
    """A decoder adapter under its limits (command manifests through the sandbox; in-process
    Python adapters called directly)."""

    def __init__(  # noqa: PLR0913 - keyword options of a target
        self,
        adapter,
        work_root: Path,
        *,
        kind: InputKind = InputKind.STREAM,
        timeout_s: float | None = None,
        expected_exit: Iterable[int] | None = None,
        oracle: bool = True,
        scene_stream: bytes | None = None,
        fork_server: bool = True,
        persistent: bool = True,
    ) -> None:
        self.adapter = adapter
        self.kind = kind
        self.work_root = Path(work_root).resolve()  # decoders run in their own folders: absolute paths
        self.work_root.mkdir(parents=True, exist_ok=True)
        lim = adapter.limits
        self.limits = (
            lim
            if timeout_s is None
            else Limits(min(lim.timeout_s, timeout_s), lim.memory_mb, lim.memory_kind, lim.output_mb, lim.processes)
        )
        # The decoder's documented reject codes (manifest reject_exit_codes), unless overridden;
        # 0 (decoded) and 69 (not supported) are always expected endings.
        self.reject_exit_codes = (
            frozenset(expected_exit) - {0, 69}
            if expected_exit is not None
            else frozenset(getattr(adapter, "reject_exit_codes", (1, 2)))
        )
        self.oracle = oracle and kind in (InputKind.STREAM, InputKind.TEXT) and "faps" in adapter.outputs
        self.is_command = isinstance(adapter, CommandAdapter)
        self.scene_stream = scene_stream
        # Command decoders run through one fork server per worker thread (isolation/forkclient.py):
        # one sandbox per worker, a fork + exec per input, the worker's folder reused.
        self.fork_server = fork_server and self.is_command
        # A manifest with [commands] serve gets its inputs through the persistent protocol
        # (isolation/persistent.py) unless told otherwise.
        self.persistent = persistent and self.is_command and "serve" in adapter.commands
        if self.persistent and kind == InputKind.SCENE:
            raise FuzzSetupError(
                "the persistent protocol carries streams and .fap text, not scenes: fuzz scenes with --spawn"
            )
        # Inputs a worker may have under way (queued to its server, running, or being judged):
        # a queue of a few absorbs the loop's slow inputs (a fresh valid stream takes ~8 ms
        # to encode) while the decoder keeps running; the spawning path runs one at a time.
        self.depth = PIPELINE_DEPTH if (self.fork_server or self.persistent) else 1
        self._local = threading.local()
        self._workers: list = []
        self._workers_lock = threading.Lock()
        self._late: list[tuple[Entry, Verdict]] = []  # take_late
        self._clean: bytes | None = None  # the shortest input answered cleanly (settled's follower)
        self._probed = False
        if kind == InputKind.STREAM and "fba" not in adapter.inputs:
            raise FuzzSetupError(
                f"decoder {adapter.name} does not accept binary streams (inputs: {', '.join(adapter.inputs)})"
            )
        if kind == InputKind.TEXT and "fap" not in adapter.inputs:
            raise FuzzSetupError(f"decoder {adapter.name} accepts no .fap text (inputs: {', '.join(adapter.inputs)})")
        if kind == InputKind.SCENE and InputKind.SCENE.value not in adapter.inputs:
            raise FuzzSetupError(f"decoder {adapter.name} accepts no BT scene (inputs: {', '.join(adapter.inputs)})")

    @property
    def name(self) -> str:
        return self.adapter.name

    def ext(self) -> str:
        return "bt" if self.kind == InputKind.SCENE else "fba"

    # ---------------------------------------------------------------- job
    def _job(self, data: bytes, workdir: Path):
        """The decoder's files for one input in ``workdir``: ``in/`` (the input, rewritten in
        place: a reused worker folder keeps the folder the sandbox binds read-only) and an
        empty ``out/``."""
        ind, outd = workdir / "in", workdir / "out"
        ind.mkdir(parents=True, exist_ok=True)
        for p in workdir.iterdir():  # what the previous input left behind
            if p.name != "in":
                remove_tree(p)
        outd.mkdir()
        values: dict[str, str] = {}
        if self.kind == InputKind.SCENE:
            sp = ind / "input.bt"
            sp.write_bytes(data)
            fp = ind / "stream.fba"
            fp.write_bytes(self.scene_stream or b"")
            values.update(scene=str(sp), scene_bt=str(sp), fba=str(fp), input=str(fp))
        elif self.kind == InputKind.TEXT:
            fp = ind / "input.fap"
            fp.write_bytes(data)
            values.update(fap=str(fp), input=str(fp))
        else:
            fp = ind / "input.fba"
            fp.write_bytes(data)
            values.update(fba=str(fp), input=str(fp))
        ext = "fap" if self.adapter.faps_format == "fap" else "npz"
        values.update(
            faps_out=str(outd / f"faps.{ext}"),
            vertices_out=str(outd / "vertices.npz"),
            images_dir=str(outd / "images"),
            faps_out_dir=str(outd / "faces"),
        )
        (outd / "images").mkdir()
        (outd / "faces").mkdir()
        return Job(workdir=workdir, values=values, frames=0)

    def _worker(self) -> _Worker:
        """This thread's worker: ``depth`` case folders used in turn (inputs queued and running
        in some while an earlier input's outputs are judged from another), reused input after
        input, and (command decoders) its fork server or persistent decoder."""
        w = getattr(self._local, "worker", None)
        if w is None:
            root = Path(tempfile.mkdtemp(prefix="w-", dir=self.work_root))
            w = self._local.worker = _Worker(root)
            for i in range(self.depth):
                job = self._job(b"", root / f"case{i}")
                d = job.workdir
                w.slots.append(
                    _Slot(
                        job,
                        Path(job.values["input"] if self.kind != InputKind.SCENE else job.values["scene"]),
                        str(d),
                    )
                )
            with self._workers_lock:
                self._workers.append(w)
        return w

    def _reuse(self, slot: _Slot, data: bytes, write_input: bool = True):
        """The slot's job for the next input: the input rewritten in place (through a
        descriptor kept open), the outputs and everything else an earlier input left removed."""
        empty_tree(slot.folder, _CASE_TREE)
        if write_input:
            if slot.input_fd is None:
                slot.input_fd = os.open(slot.input, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_CLOEXEC, 0o644)
            os.pwrite(slot.input_fd, data, 0)
            if len(data) < slot.input_len:
                os.ftruncate(slot.input_fd, len(data))
            slot.input_len = len(data)
        return slot.job

    def _view(self, w: _Worker, argv: list[str]):
        """The sandbox view of a worker: the decoder's own view of case folder 0, plus the others."""
        view = self.adapter.sandbox_view(argv, w.slots[0].job.workdir, hidden=hidden_from_decoders())
        for slot in w.slots[1:]:
            view.writable.append(slot.job.workdir)
            view.read_only_inside.append(slot.job.workdir / "in")
        return view

    def close(self) -> None:
        """Stop every worker's fork server (they restart on the next input)."""
        with self._workers_lock:
            workers, self._workers = self._workers, []
        for w in workers:
            if w.server is not None:
                w.server.close()
                w.server = None
            for slot in w.slots:
                if slot.input_fd is not None:
                    os.close(slot.input_fd)
                    slot.input_fd = None
        self._local = threading.local()

    def __enter__(self) -> DecoderTarget:
        return self

    def __exit__(self, *exc) -> None:
        """A target used on its own (``with DecoderTarget(...) as t``) stops its servers at the end."""
        self.close()

    def argv_for(self, job) -> list[str]:
        try:
            return self.adapter.argv("decode", job)
        except KeyError as e:
            raise FuzzSetupError(f"[commands] decode needs {{{e.args[0]}}}, which a fuzz input does not have") from None

    def execute(self, inp: Entry) -> ExecResult:
        return self.start(inp).result()

    def start(self, inp: Entry) -> Run:
        """Start running ``inp``: ``result()`` on the :class:`Run` judges it. Through a fork
        server or a persistent decoder the decoder runs while the caller works, and an input
        started while another runs is queued behind it (one decoder at a time, no gap); at
        most ``depth`` inputs of a worker are under way (its case folders)."""
        if self.persistent or self.fork_server:
            w = self._worker()
            k, w.turn = w.turn, (w.turn + 1) % len(w.slots)
            slot = w.slots[k]
            job = self._reuse(slot, inp.data, write_input=not self.persistent)  # persistent: on stdin
            if w.server is None and self.persistent:
                self._serve(w)
            elif w.server is None:
                w.argv = [self.argv_for(s.job) for s in w.slots]  # a slot's paths never change
                w.server = ForkServer(
                    w.root,
                    self._view(w, w.argv[0]),
                    self.limits,
                    env=self.adapter.env,
                    sum_outputs_every=16,
                    slots=len(w.slots),
                )
            if self.persistent:
                pending = w.server.start(inp.data, job.values["faps_out"])
                pending.on_late = lambda res, inp=inp, job=job: self._late_ending(inp, job, res)
            else:
                pending = w.server.start(w.argv[k], job.workdir, slot=k)
            return Run(pending.wait, lambda: self._clean_if(inp, ExecResult(self._judge(inp, job, pending.result()))))
        with self._own_folder(inp.data) as job:
            if self.is_command:
                out = ExecResult(self._judge(inp, job, self._sandboxed(job, self.limits)))
            else:
                out = ExecResult(self._run_python(inp, job))
        return Run.done(out)

    @contextlib.contextmanager
    def _own_folder(self, data: bytes) -> Iterator[Job]:
        """A job for ``data`` in a fresh case folder, removed afterwards."""
        workdir = Path(tempfile.mkdtemp(prefix="x-", dir=self.work_root))
        try:
            yield self._job(data, workdir)
        finally:
            try:
                remove_tree(workdir)
            except OSError:
                pass

    def _sandboxed(self, job: Job, limits: Limits):
        """The decoder's command on ``job`` in a sandbox of its own under ``limits``."""
        argv = self.argv_for(job)
        view = self.adapter.sandbox_view(argv, job.workdir, hidden=hidden_from_decoders())
        return sandbox.run(argv, job.workdir, limits, env=self.adapter.env, view=view)

    def _clean_if(self, inp: Entry, out: ExecResult) -> ExecResult:
        """``out`` as it is; a clean input of 4 KB at most, shorter than the last, is kept as
        :meth:`settled`'s follower."""
        if (
            self.persistent
            and out.verdict is None
            and len(inp.data) <= 4096
            and (self._clean is None or len(inp.data) < len(self._clean))
        ):
            self._clean = inp.data
        return out

    def _serve(self, w: _Worker) -> None:
        """The worker's persistent decoder (``[commands] serve``), started at its first input."""
        w.argv = [self.adapter.argv("serve", w.slots[0].job)]
        w.server = PersistentDecoder(
            w.argv[0], w.root, w.slots[0].job.workdir, self._view(w, w.argv[0]), self.limits, env=self.adapter.env
        )

    def still_hangs(self, inp: Entry, factor: float = HANG_CONFIRM_FACTOR) -> bool:
        """Whether ``inp`` times out again on a process and sandbox of its own given ``factor``
        times the timeout. A decoder that the machine's load (other work, the fuzzer's own) slowed
        past its limit finishes then: the lab's, not a finding of the decoder's. One that loops or
        waits forever does not."""
        if not self.is_command:
            return True
        longer = dataclasses.replace(self.limits, timeout_s=self.limits.timeout_s * factor)
        with self._own_folder(inp.data) as job:
            res = self._sandboxed(job, longer)
        return endings.classify(res, longer, self.reject_exit_codes, name=self.adapter.name).kind == "timeout"

    def alone(self, inp: Entry) -> ExecResult:
        """``inp`` on a decoder process of its own, whose whole life is this input's: how a
        finding is minimised, its minimal input checked and replayed. Through ``serve`` that is a
        fresh process given this one input, its exit awaited (an answer sent before the decoding
        ended cannot hide a crash that follows it); otherwise every input is a process of its
        own already."""
        if not self.persistent:
            return self.execute(inp)
        w = self._worker()
        if w.server is None:
            self._serve(w)
        w.server.drain()  # the case folders are free
        k, w.turn = w.turn, (w.turn + 1) % len(w.slots)
        job = self._reuse(w.slots[k], inp.data, write_input=False)
        return ExecResult(self._judge(inp, job, w.server.alone(inp.data, job.values["faps_out"])))

    def settled(self, inp: Entry) -> ExecResult:
        """``inp``'s verdict once the decoder has answered a request after it — how each input
        of a minimisation is judged. Through ``serve``, ``inp`` goes to the worker's process
        followed by an input it handled cleanly before (the follower): ``inp``'s result is held
        until the follower is answered, so an ending that comes after ``inp``'s answer is
        confirmed and filed under ``inp`` (isolation/persistent.py), at the cost of one more
        round trip, not of a process per input. Without a known clean follower, or without
        ``serve``, as :meth:`alone` / :meth:`execute`."""
        if not self.persistent:
            return self.execute(inp)
        follower = self._follower()
        if follower is None:
            return self.alone(inp)
        w = self._worker()
        if w.server is None:
            self._serve(w)
        w.server.drain()
        jobs = []
        for data in (inp.data, follower):
            k, w.turn = w.turn, (w.turn + 1) % len(w.slots)
            jobs.append(self._reuse(w.slots[k], data, write_input=False))
        first = w.server.start(inp.data, jobs[0].values["faps_out"])
        after = w.server.start(follower, jobs[1].values["faps_out"])
        res = first.result()
        after.result()  # the follower's own ending is not this input's finding
        return ExecResult(self._judge(inp, jobs[0], res))

    def _follower(self) -> bytes | None:
        """An input this decoder answered cleanly (no finding): the shortest of those it was
        given, else the empty input if it handles that cleanly alone, else None."""
        if self._clean is None and not self._probed:
            self._probed = True
            if self.alone(Entry(b"", kind=self.kind, origin="follower")).verdict is None:
                self._clean = b""
        return self._clean

    def _late_ending(self, inp: Entry, job, res) -> None:
        """An ending found to be ``inp``'s after its result was given out (one input at a time:
        the persistent decoder confirmed it on a later input, isolation/persistent.py)."""
        v = self._judge(inp, job, res)
        if v is not None:
            with self._workers_lock:
                self._late.append((inp, v))

    def take_late(self) -> list[tuple[Entry, Verdict]]:
        """The findings of inputs already judged clean that a later input showed to be theirs
        (the fuzzer files them under those inputs)."""
        with self._workers_lock:
            out, self._late = self._late, []
        return out

    def _judge(self, inp: Entry, job, res) -> Verdict | None:
        """The finding (or None) for one finished decoder process."""
        ending = endings.classify(res, self.limits, self.reject_exit_codes, name=self.adapter.name)
        if ending.kind == "setup":  # the harness's own knowledge (endings.py), never the decoder's words
            raise FuzzSetupError(f"cannot run the decoder: {ending.message}")
        detail = {
            "exit_code": res.returncode,
            "signal": res.signal,
            "elapsed_s": round(res.elapsed_s, 3),
            **({"notes": list(res.notes)} if res.notes else {}),
            **({"harness": res.detail} if res.detail else {}),
            "maxrss_mb": round(res.maxrss_mb, 1),
            "stderr_tail": res.stderr_tail[-1500:],
        }
        v = self.verdict_for(ending, inp, job, detail)
        if v is not None and FLAKY in res.notes:  # no input reproduces it alone: its own key, said so
            v = Verdict(v.cls, f"flaky:{v.signature}", f"{v.message} {res.detail}", {**v.detail, "flaky": True})
        return v

    def verdict_for(self, ending, inp: Entry, job, detail: dict) -> Verdict | None:
        """The finding (or None) for one process ending — the run's classifier
        (:mod:`fbaconf.isolation.endings`), so fuzz and run judge an ending the same way."""
        k = ending.kind
        rep = ending.report
        if k == "timeout":
            return Verdict("hang", "timeout", ending.message, detail)
        if k == "memory":
            return Verdict("memory", "memory-limit", ending.message, detail)
        if k == "output-limit":
            return Verdict("output-blowup", "output-limit", ending.message, detail)
        if k == "crash":
            sig = ":".join(
                x for x in (detail.get("signal") or "", rep.kind if rep else "", rep.signature if rep else "") if x
            )
            return Verdict("crash", sig or "crash", ending.message, {**detail, "crash_kind": rep.kind if rep else None})
        if k == "unexpected":
            rc, notes = detail.get("exit_code"), detail.get("notes", ())
            sig = (
                "fork-server-killed"
                if Note.SUPERVISOR_LOST in notes
                else "protocol-error"
                if Note.PROTOCOL_ERROR in notes
                else f"exit-{rc}"
            )
            return Verdict("unexpected-exit", sig, ending.message, detail)
        rc = {"decoded": 0, "not-supported": 69}.get(k, detail.get("exit_code"))
        return self._oracle(inp, job, rc, detail)

    def _run_python(self, inp: Entry, job) -> Verdict | None:
        """An in-process decoder, called the one way run and speed call it
        (:meth:`fbaconf.harness.adapters.PythonAdapter.execute`) and judged as a process ending."""
        ex = self.adapter.execute(job)
        if ex.ending.kind == "setup":
            raise FuzzSetupError(f"cannot run the decoder: {ex.ending.message}")
        return self.verdict_for(
            ex.ending,
            inp,
            job,
            {"exit_code": ex.exit_code, "elapsed_s": round(ex.elapsed_s, 3), "stderr_tail": ex.stderr_tail[-1500:]},
        )

    def _oracle(self, inp: Entry, job, rc: int, detail: dict) -> Verdict | None:
        if rc == 69:
            return None
        if rc == 0 and self.kind == InputKind.STREAM:
            rule = reference_rejection(inp)
            if rule is not None:  # as in the run's error cases: decoding garbage silently is a defect
                return Verdict(
                    "accepted-invalid",
                    f"rule:{rule}",
                    f"exit code 0 on a stream the reference rejects "
                    f"(rule {rule}): decoded an invalid stream without complaint",
                    detail,
                )
        if not self.oracle:
            return None
        # the reference's frames first; whether the stream's reading is decision-free (a second,
        # slower parse by the checker) is asked only when there is a finding to report
        expected = reference_text(inp) if self.kind == InputKind.TEXT else reference_frames(inp)
        if expected is None:
            return None
        v = self._output_verdict(expected, job, rc, detail)
        if v is not None and self.kind == InputKind.STREAM and not decision_free(inp):
            return None
        return v

    def _output_verdict(self, expected, job, rc: int, detail: dict) -> Verdict | None:
        """The finding (or None) of a decoder's ending and FAP output on an oracle input."""
        if rc != 0:
            return Verdict("wrong-output", "rejected-valid", f"rejected a valid stream (exit code {rc})", detail)
        path = job.path("faps_out")
        if path is None or not path.is_file():
            return Verdict("wrong-output", "no-output", "exit code 0 but no FAP output for a valid stream", detail)
        try:
            got = cmp.load_output_faps(path)
        except cmp.OutputError as e:
            return Verdict("wrong-output", "unreadable-output", f"unreadable FAP output: {e}", detail)
        r = cmp.compare_faps(
            expected,
            got,
            text_output=path.suffix.lower() == ".fap" or self.kind == InputKind.TEXT,
            player=self.kind == InputKind.TEXT,
        )
        if r.outcome.ok:
            return None
        what = (r.first_difference or {}).get("what", "value")
        return Verdict("wrong-output", f"differs:{what}", r.message, {**detail, "first_difference": r.first_difference})


def reference_text(inp: Entry):
    """What a player must make of ``inp`` (.fap text): the frames fbaconf's reader reads from
    it without any warning, or None when the text is invalid or relies on a lenient reading
    (then only crashes, hangs and blow-ups are findings)."""
    try:
        frames, _header, warnings = read_fap_text(inp.data.decode("utf-8"), strict=True)
    except (FbaconfInputError, UnicodeDecodeError):
        return None
    return frames if not warnings and len(frames) else None


def _reference_decode(data: bytes):
    """(frames, None) or (None, rule): the reference decoder's reading of ``data``, parsed once
    per input for the oracle and the coverage features together (fuzz.model.reference_parse)."""
    _planes, frames, rule, _code, _end = reference_parse(data)
    return (None, rule) if rule is not None else (frames, None)


def reference_rejection(inp: Entry) -> str | None:
    """The rule the reference decoder rejects ``inp`` with, or None when it decodes it."""
    if inp.valid:
        return None
    return _reference_decode(inp.data)[1]


def reference_frames(inp: Entry):
    """The reference FapFrames of ``inp`` when it is an oracle candidate (generated valid, or
    decoded by the reference into at least one frame), else None."""
    frames, rule = _reference_decode(inp.data)
    if rule is not None or (not inp.valid and len(frames) == 0):
        return None  # no plane: nothing to compare, and rejecting it is no defect
    return frames


def decision_free(inp: Entry) -> bool:
    """Whether the reference's reading of ``inp`` is normative: generated valid, or no error and
    no decision-dependent (FAP-DECISION-*) diagnostic from the checker."""
    if inp.valid:
        return True
    return not any(d.severity == "error" or d.code.startswith("FAP-DECISION") for d in check_stream(inp.data))
