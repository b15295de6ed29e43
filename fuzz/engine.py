"""The fuzzing loop: batches of reproducible inputs, the corpus grown by new syntax features, findings
deduplicated and minimised."""

from __future__ import annotations

import collections
import hashlib
import random
import sys
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

from fbaconf.errors import FbaconfInputError
from fbaconf.scenes import bifs, bt

from . import cmutator
from .choosers import RandomChooser
from .corpus import scene_seeds
from .features_ahead import FeaturesAhead
from .findings import Finding, minimise_against, write_finding
from .fresh import FreshStreams, helper_worthwhile, input_rng
from .inputs import STRESS_BYTES, Entry, InputKind, gen_valid
from .model import SCENE_FEATURES, STREAM_FEATURES, features_of, parsed
from .mutators import BYTE_MUTATORS, draw, mutate_stream
from .scenes import gen_scene, mutate_scene, scene_features
from .selftarget import SelfTarget
from .targets import HANG_CONFIRM_FACTOR, ExecResult, FuzzSetupError, Run, Verdict
from .text import mutate_text, text_seeds


@dataclass
class Stats:
    execs: int = 0
    started: float = field(default_factory=time.perf_counter)
    findings: int = 0
    hits: int = 0
    features: set[str] = field(default_factory=set)
    universe: tuple[str, ...] = STREAM_FEATURES
    corpus: int = 0
    minimise_s: float = 0.0
    by_origin: dict[str, int] = field(default_factory=dict)
    measured: int = 0  # inputs whose syntax-model coverage was measured (every coverage_every-th)
    slow_not_hung: int = 0  # timeouts that finished alone with more time: the machine's load, no finding

    @property
    def elapsed(self) -> float:
        return time.perf_counter() - self.started

    cpu_started: float = field(default_factory=time.process_time)

    @property
    def rate(self) -> float:
        return self.execs / max(1e-9, self.elapsed - self.minimise_s)

    @property
    def cpu_s(self) -> float:
        return time.process_time() - self.cpu_started

    def coverage(self) -> tuple[int, int]:
        u = set(self.universe)
        return len(self.features & u), len(u)

    def line(self) -> str:
        c, n = self.coverage()
        return (
            f"[{self.elapsed:6.1f}s] execs {self.execs} ({self.rate:,.0f}/s)  findings {self.findings}"
            f" ({self.hits} hits)  syntax coverage {c}/{n} ({100.0 * c / max(1, n):.0f}%)  corpus {self.corpus}"
        )


class Progress:
    def __init__(self, enabled: bool | None, stream=None) -> None:
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty() if enabled is None else enabled
        self.enabled = enabled is not False
        self.last = 0.0

    def update(self, stats: Stats, force: bool = False) -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        every = 0.25 if self.tty else 10.0
        if not force and now - self.last < every:
            return
        self.last = now
        if self.tty:
            self.stream.write("\r" + stats.line() + "\x1b[K")
        else:
            self.stream.write(stats.line() + "\n")
        self.stream.flush()

    def message(self, text: str) -> None:
        if not self.enabled:
            return
        self.stream.write(("\r\x1b[K" if self.tty else "") + text + "\n")
        self.stream.flush()

    def close(self, stats: Stats) -> None:
        if self.enabled:
            self.update(stats, force=True)
            if self.tty:
                self.stream.write("\n")
                self.stream.flush()


@dataclass
class FuzzConfig:
    """How a fuzz run goes: its seed and budget (``seconds``, ``max_execs``), parallelism, the
    input kinds, the corpus and valid-stream policy, minimisation, and where findings go."""

    seed: int = 0
    seconds: float = 60.0
    jobs: int = 1
    out_dir: Path | None = None
    kind: InputKind = InputKind.STREAM
    kinds: tuple[InputKind, ...] | None = None
    progress: bool | None = None
    max_execs: int | None = None
    max_corpus: int = 400
    valid_pool: int = 24  # fresh valid streams made up front
    fresh_valid_share: float = 0.04  # share of inputs that are a fresh valid stream
    fresh_helper: bool = True  # encode them ahead in a helper process (when a CPU is free: fuzz.fresh)
    features_helper: bool = True  # measure coverage ahead in a helper process (likewise: fuzz.features_ahead)
    prefer_short: float = 0.5
    run_seeds_first: int = 64
    coverage_every: int = 1  # measure syntax-model coverage on every n-th input
    minimise_seconds: float = 30.0
    minimise_tests: int = 600
    minimise_findings: bool = True  # a campaign's shards leave it to the coordinator


class Fuzzer:
    """The loop: generate a batch of inputs (pure function of seed and index), run it (``jobs`` in
    parallel), then, in input order, record coverage, grow the corpus and handle findings
    (dedup, minimise, write)."""

    def __init__(
        self,
        target,
        seeds: list[Entry],
        config: FuzzConfig | None = None,
        *,
        scene_seeds_: list[Entry] | None = None,
        decoder_info: dict | None = None,
        stop_on: Callable[[Finding], bool] | None = None,
    ) -> None:
        c = config or FuzzConfig()
        seed, seconds, jobs, out_dir, kind, kinds = c.seed, c.seconds, c.jobs, c.out_dir, c.kind, c.kinds
        progress, valid_pool, fresh_valid_share, prefer_short = (
            c.progress,
            c.valid_pool,
            c.fresh_valid_share,
            c.prefer_short,
        )
        run_seeds_first, minimise_seconds, minimise_tests, max_execs = (
            c.run_seeds_first,
            c.minimise_seconds,
            c.minimise_tests,
            c.max_execs,
        )
        max_corpus, coverage_every, minimise_findings = c.max_corpus, c.coverage_every, c.minimise_findings
        if not seeds and kind == InputKind.STREAM and InputKind.STREAM in (kinds or (kind,)):
            raise FuzzSetupError("no seed streams (build the suites: fbaconf suites build)")
        self.target = target
        self.seed = int(seed)
        self.seconds = float(seconds)
        self.jobs = max(1, int(jobs))
        self.out_dir = Path(out_dir) if out_dir else None
        self.kinds = kinds or (kind,)
        self.corpus: dict[InputKind, list[Entry]] = {
            InputKind.STREAM: list(seeds),
            InputKind.SCENE: list(scene_seeds_ or []),
            InputKind.BIFS: [],
            InputKind.TEXT: [],
        }
        if InputKind.TEXT in self.kinds:
            self.corpus[InputKind.TEXT] = text_seeds()
            if not self.corpus[InputKind.TEXT]:
                raise FuzzSetupError("no .fap seeds (build the suites: fbaconf suites build)")
        if InputKind.SCENE in self.kinds and not self.corpus[InputKind.SCENE]:
            self.corpus[InputKind.SCENE] = scene_seeds()
        if InputKind.BIFS in self.kinds:
            self.corpus[InputKind.BIFS] = _bifs_seeds(self.corpus[InputKind.SCENE])
        self.fresh_valid_share = fresh_valid_share
        self.prefer_short = prefer_short
        self.run_seeds_first = run_seeds_first
        ch = RandomChooser(random.Random(self.seed))
        self.valid_pool = [gen_valid(ch) for _ in range(valid_pool)] if InputKind.STREAM in self.kinds else []
        self.progress = Progress(progress)
        self.minimise_seconds = minimise_seconds
        self.minimise_tests = minimise_tests
        self.max_execs = max_execs
        self.stop_on = stop_on
        self.stopped = False
        self.max_corpus = max_corpus
        # Syntax-model coverage of what a decoder under test was sent costs a reference decode
        # per input (~1 ms): measured on every input, or on every n-th (``--coverage-every``).
        self.coverage_every = max(1, int(coverage_every))
        self.minimise_findings = minimise_findings  # a campaign's shards leave it to the coordinator
        self.new_corpus: list[Entry] = []  # what this run added to the corpus (merged across shards)
        self.findings: dict[str, Finding] = {}
        self.stats = Stats(
            universe=tuple(
                u
                for k in self.kinds
                for u in (STREAM_FEATURES if k == InputKind.STREAM else SCENE_FEATURES if k == InputKind.SCENE else ())
            )
        )
        self.decoder_info = decoder_info or {}
        self.stats.corpus = sum(len(v) for v in self.corpus.values())
        # the seeds run as they are before any mutation: the first run_seeds_first, and every long
        # stream among the rest (_parent seldom mutates one: it is reached here)
        seeds = self.corpus.get(InputKind.STREAM, [])
        self.seeds_first = [i for i, e in enumerate(seeds) if i < self.run_seeds_first or len(e.data) > STRESS_BYTES]
        # the helper lives as long as a run (make_input outside one makes its streams itself)
        self.fresh = FreshStreams(self.seed, self._fresh_wanted, helper=False)
        self.fresh_helper = c.fresh_helper and helper_worthwhile(self.jobs, self.max_execs)
        self.features = FeaturesAhead(helper=False)
        self.features_helper = c.features_helper and helper_worthwhile(self.jobs, self.max_execs)

    # ---------------------------------------------------------------- generation
    def make_input(self, index: int, corpus_size: int | None = None) -> Entry:
        """Input ``index`` of this seed. The corpus only grows (between batches, in input order),
        so the input depends on the seed, the index and the corpus size then (recorded in each
        finding as ``corpus_size``; pass it to regenerate an input after the run)."""
        kind = self.kinds[index % len(self.kinds)]
        n = len(self.corpus[kind]) if corpus_size is None else corpus_size
        e = self._make_input(index, kind, self.corpus[kind][:n])
        e.corpus_size, e.index = n, index
        return e

    def _make_input(self, index: int, kind: InputKind, corpus: list[Entry]) -> Entry:
        rng = input_rng(self.seed, index)
        if kind == InputKind.STREAM:
            if index < len(self.seeds_first) and self.seeds_first[index] < len(corpus):  # the seeds first
                e = corpus[self.seeds_first[index]]
                return Entry(e.data, origin=e.origin, valid=e.valid, recon=e.recon, model=e.model)
            r = rng.random()
            if r < self.fresh_valid_share:  # a new valid stream (slow to encode: rare, made ahead)
                return self.fresh.take(index)
            if r < 0.06 and self.valid_pool:  # a generated valid stream as it is (round-trip oracle)
                e = self.valid_pool[rng.randrange(len(self.valid_pool))]
                return Entry(e.data, origin=e.origin, valid=True, recon=e.recon, model=e.model)
            if r < 0.12 and self.valid_pool:
                e = self.valid_pool[rng.randrange(len(self.valid_pool))]
            else:
                e = self._parent(rng, corpus)
            data, how = mutate_stream(rng, e, corpus)
            return Entry(data, origin=f"mutate:{how}<-{e.origin}")
        if kind == InputKind.SCENE:
            if rng.random() < 0.1 or not corpus:
                return gen_scene(RandomChooser(rng))
            e = corpus[rng.randrange(len(corpus))]
            data, how = mutate_scene(rng, e, corpus)
            return Entry(data, kind=InputKind.SCENE, origin=f"mutate:{how}<-{e.origin}")
        if kind == InputKind.TEXT:
            e = corpus[rng.randrange(len(corpus))]
            data, how = mutate_text(rng, e, corpus)
            return Entry(data, kind=InputKind.TEXT, origin=f"mutate:{how}<-{e.origin}")
        e = corpus[rng.randrange(len(corpus))] if corpus else Entry(b"", kind=InputKind.BIFS)
        name = rng.choice(list(BYTE_MUTATORS))
        return Entry(BYTE_MUTATORS[name](rng, e.data, corpus), kind=InputKind.BIFS, origin=f"mutate:{name}<-{e.origin}")

    def _fresh_wanted(self, index: int) -> bool:
        """Whether input ``index`` will be a fresh valid stream (_make_input's first draw)."""
        return (
            self.kinds[index % len(self.kinds)] == InputKind.STREAM
            and index >= len(self.seeds_first)
            and input_rng(self.seed, index).random() < self.fresh_valid_share
        )

    def _parent(self, rng: random.Random, corpus: list[Entry]) -> Entry:
        """The corpus entry to mutate: the shorter of two with ``prefer_short`` (a tournament),
        drawn as :func:`mutators.draw` draws (stress streams last)."""

        def tournament(rng: random.Random, corpus: list[Entry]) -> Entry:
            e = corpus[rng.randrange(len(corpus))]
            if rng.random() < self.prefer_short:
                e2 = corpus[rng.randrange(len(corpus))]
                e = e if len(e.data) <= len(e2.data) else e2
            return e

        e = draw(rng, corpus, tournament)
        assert e is not None  # noqa: S101 - the corpus is never empty here
        return e

    # ---------------------------------------------------------------- loop
    def run(self) -> Stats:
        st = self.stats
        st.started = time.perf_counter()
        st.cpu_started = time.process_time()
        deadline = st.started + self.seconds
        self.fresh.helper = self.fresh_helper
        self.features.helper = self.features_helper
        try:
            if self.jobs == 1:
                self._run_pipelined(deadline)
            else:
                self._run_batches(deadline)
        finally:
            self.fresh.close()
            self.features.close()
            close = getattr(self.target, "close", None)
            if close is not None:
                close()
        self.progress.close(st)
        return st

    def _more(self, index: int, deadline: float) -> bool:
        return (
            time.perf_counter() < deadline and not self.stopped and (self.max_execs is None or index < self.max_execs)
        )

    def _run_pipelined(self, deadline: float) -> None:
        """One decoder at a time, overlapped with the loop's own work: targets with ``start``
        and a ``depth`` (a fork server, a persistent decoder) get up to ``depth`` inputs queued,
        each starting the moment the one before ends, while this thread judges and records the
        oldest and makes the next — a slow input to make (a fresh valid stream) leaves the
        decoder the queue to run. Inputs are recorded in input order; input k + depth - 1 is
        made before input k is recorded (its ``corpus_size`` says which corpus it was made
        from, so a run is replayable as ever)."""
        start = getattr(self.target, "start", None) or (lambda inp: Run.done(self.target.execute(inp)))
        depth = max(2, int(getattr(self.target, "depth", 2)))
        queue: collections.deque = collections.deque()  # (index, input, run), oldest first
        index = 0
        while True:
            while len(queue) < depth and self._more(index, deadline):
                inp = self.make_input(index)
                if self._measured_unparsed(index, inp):
                    self.features.ask(index, inp.data)  # parsed by the helper while the decoder runs
                queue.append((index, inp, start(inp)))
                index += 1
            if not queue:
                return
            k, cur, run = queue.popleft()
            out = run.result()
            if out.verdict is not None:
                for _k, _inp, later in queue:
                    later.result()  # a finding's minimisation needs the decoder to itself
            self._record(k, cur, out, deadline)
            self.progress.update(self.stats)
            if self.stopped:
                for _k, _inp, later in queue:
                    later.result()  # started, never recorded: the run stops here
                return

    def _run_batches(self, deadline: float) -> None:
        index = 0
        batch = 4 * self.jobs
        with ThreadPoolExecutor(self.jobs) as pool:
            while self._more(index, deadline):
                n = batch if self.max_execs is None else min(batch, self.max_execs - index)
                inputs = [self.make_input(index + k) for k in range(n)]
                outs = list(pool.map(self.target.execute, inputs))
                for k, (inp, out) in enumerate(zip(inputs, outs)):
                    self._record(index + k, inp, out, deadline)
                index += n
                self.progress.update(self.stats)

    def _measured_unparsed(self, index: int, inp: Entry) -> bool:
        """Whether input ``index`` will have its coverage measured by a parse of its own (unless
        the oracle parses it first: :meth:`_record`)."""
        return (
            inp.kind == InputKind.STREAM
            and inp.model is None
            and index % self.coverage_every == 0
            and not isinstance(self.target, SelfTarget)
        )

    def _record(self, index: int, inp: Entry, out: ExecResult, deadline: float) -> None:
        st = self.stats
        st.execs += 1
        feats = out.features
        measure = (
            not feats
            and not isinstance(self.target, SelfTarget)
            and (
                index % self.coverage_every == 0
                or inp.model is not None
                or (inp.kind == InputKind.STREAM and parsed(inp.data))
            )
        )  # the oracle's parse: free
        if measure and inp.kind == InputKind.STREAM:  # coverage of the syntax model by what we sent the decoder
            if inp.model is not None:
                feats = inp.model.features
            elif parsed(inp.data):
                feats = features_of(inp.data)
            else:
                feats = self.features.take(index, inp.data)
        elif measure and inp.kind == InputKind.SCENE:
            feats = _scene_feats_of(inp)
        if measure:
            st.measured += 1
        new = feats - st.features
        if new:
            st.features |= new
            pool = self.corpus[inp.kind]
            if len(inp.data) <= 4096 and len(pool) < self.max_corpus and out.verdict is None:
                e = Entry(inp.data, kind=inp.kind, origin=f"corpus#{index}", valid=inp.valid, recon=inp.recon)
                pool.append(e)
                self.new_corpus.append(e)
                st.corpus += 1
        if out.verdict is not None:
            self._finding(index, inp, out.verdict, deadline)
        for e, v in getattr(self.target, "take_late", list)():  # found on a later input, filed under its own
            self._finding(e.index if e.index is not None else index, e, v, deadline)

    def _finding(self, index: int, inp: Entry, v: Verdict, deadline: float) -> None:
        st = self.stats
        f = self.findings.get(v.key)
        still_hangs = getattr(self.target, "still_hangs", None)
        if f is None and v.cls == "hang" and still_hangs is not None and not still_hangs(inp):
            st.slow_not_hung += 1  # slowed past the limit by the machine, not hung: no finding
            self.progress.message(
                f"input #{index} timed out, then finished alone with {HANG_CONFIRM_FACTOR:g} times the "
                "timeout: the machine's load, not a hang of the decoder's"
            )
            return
        st.hits += 1
        if f is not None:
            f.hits += 1
            return
        fid = f"{v.cls}-{hashlib.sha256(v.key.encode()).hexdigest()[:8]}"
        f = Finding(fid, v, inp, index, st.elapsed)
        self.findings[v.key] = f
        st.findings += 1
        self.progress.message(
            f"finding {fid}: {v.cls} ({v.signature}): {v.message[:160]} — input #{index}, "
            f"{len(inp.data)} bytes, {inp.origin[:80]}"
        )
        if self.minimise_findings:
            t0 = time.perf_counter()
            self._minimise(f, deadline)
            st.minimise_s += time.perf_counter() - t0
        if self.out_dir is not None:
            write_finding(self.out_dir, f, self)
        if self.stop_on is not None and self.stop_on(f):
            self.stopped = True

    def _minimise(self, f: Finding, deadline: float) -> None:
        budget = max(min(self.minimise_seconds, deadline - time.perf_counter()), min(10.0, self.minimise_seconds))
        f.minimal, f.min_stats, v = minimise_against(
            self.target, f.original.data, f.original.kind, f.verdict.key, seconds=budget, tests=self.minimise_tests
        )
        f.min_verdict = v or f.verdict
        self.progress.message(
            f"  minimised {f.id}: {f.min_stats.bytes_before} -> {f.min_stats.bytes_after} bytes "
            f"({f.min_stats.tests} tests, {f.min_stats.seconds:.1f} s)"
            + ("  FLAKY: does not repeat on a fresh process" if f.min_stats.flaky else "")
        )

    def summary(self) -> dict:
        st = self.stats
        c, n = st.coverage()
        return {
            "format": "fbaconf.fuzz/1",
            "target": getattr(self.target, "name", "?"),
            "seed": self.seed,
            "seconds": round(st.elapsed, 2),
            "fuzz_seconds": round(st.elapsed - st.minimise_s, 2),
            "execs": st.execs,
            "execs_per_s": round(st.rate, 1),
            "jobs": self.jobs,
            "cpu_seconds": round(st.cpu_s, 2),
            "execs_per_cpu_s": round(st.execs / max(1e-9, st.cpu_s), 1),
            "findings": st.findings,
            "finding_hits": st.hits,
            "timeouts_not_confirmed": st.slow_not_hung,
            "syntax_coverage": {
                "covered": c,
                "total": n,
                "features": sorted(st.features),
                "measured_inputs": st.measured,
                "coverage_every": self.coverage_every,
                "missing": sorted(set(st.universe) - st.features),
            },
            "corpus": st.corpus,
            # which structure-aware mutator made the streams: the C one (fba_mutator.c) or the Python one
            "stream_mutator": "C" if cmutator.library() is not None else "Python",
            "decoder": self.decoder_info,
            "finding_ids": [f.id for f in self.findings.values()],
        }


def _scene_feats_of(inp: Entry) -> set[str]:
    text = inp.data.decode("utf-8", "replace")
    try:
        scene = bt.parse(text)
    except FbaconfInputError as e:
        return {f"rule:{getattr(e, 'rule', '?')}"}
    return scene_features(scene, None, text)


def _bifs_seeds(scenes: list[Entry]) -> list[Entry]:
    out = []
    for e in scenes:
        try:
            out.append(
                Entry(bifs.encode(bt.parse(e.data.decode("utf-8"))), kind=InputKind.BIFS, origin=f"bifs({e.origin})")
            )
        except Exception:  # noqa: BLE001, S112 - scenes the BIFS encoder does not cover
            continue
    return out
