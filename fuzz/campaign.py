"""Fuzzing campaigns on a Dask cluster: ``fbaconf fuzz --decoder D.toml --cluster local[:N]``
or ``--cluster tcp://HOST:PORT`` (the cluster set-up of :mod:`fbaconf.harness.cluster`).

A campaign runs in rounds. Each round is one task per worker, a *shard*: an ordinary
one-at-a-time :class:`~fbaconf.fuzz.engine.Fuzzer` in the worker (its own seed, its own fork
server and folders on the worker) seeded with the suites plus the corpus merged from every
shard so far, that reports its findings unminimised, its new corpus entries, its coverage and
its execs. This process merges them as they arrive: findings deduplicated by class and
signature across shards (hits summed), the corpus merged and handed to the next round, the
coverage united. At the end each distinct finding is minimised once, as a task, and written
like a local run's. A worker lost mid-round loses nothing: Dask reruns its shard elsewhere,
and a shard is a pure function of its seed, so the rerun finds what the lost one would have.
"""
from __future__ import annotations

import hashlib
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

from fbaconf.harness.adapters import resolve

from .corpus import default_seeds
from .engine import FuzzConfig, Fuzzer
from .findings import Finding, write_finding
from .inputs import Entry
from .minimise import MinimiseStats, minimise
from .targets import DecoderTarget, Verdict

ROUND_S = 30.0  # a shard's length: corpus merged between rounds
MAX_MERGED = 2000


@dataclass
class ShardSpec:
    manifest: str
    kind: str = "stream"
    timeout_s: float | None = None
    expected_exit: tuple[int, ...] | None = None
    oracle: bool = True
    coverage_every: int = 8
    spawn: bool = False


def _target(spec: ShardSpec, work: Path):
    return DecoderTarget(resolve(spec.manifest), work, kind=spec.kind, timeout_s=spec.timeout_s,
                         expected_exit=spec.expected_exit, oracle=spec.oracle,
                         fork_server=not spec.spawn, persistent=not spec.spawn)


def run_shard(spec: ShardSpec, seed: int, seconds: float, merged: list[bytes]) -> dict:
    """One shard, in a worker: fuzz for ``seconds`` and report (no minimisation, no files)."""
    work = Path(tempfile.mkdtemp(prefix="fbaconf-shard-"))
    try:
        target = _target(spec, work)
        seeds = default_seeds() + [Entry(b, origin=f"merged#{i}") for i, b in enumerate(merged)]
        fz = Fuzzer(target, seeds,
                    FuzzConfig(seed=seed, seconds=seconds, jobs=1, progress=False, kinds=(spec.kind,),
                               coverage_every=spec.coverage_every, minimise_findings=False))
        fz.run()
        st = fz.stats
        return {"seed": seed, "execs": st.execs, "fuzz_seconds": st.elapsed - st.minimise_s,
                "features": sorted(st.features), "universe": list(st.universe),
                "corpus": [e.data for e in fz.new_corpus],
                "findings": [{"key": f.verdict.key, "cls": f.verdict.cls, "signature": f.verdict.signature,
                              "message": f.verdict.message, "detail": f.verdict.detail, "data": f.original.data,
                              "kind": f.original.kind, "origin": f.original.origin, "index": f.index,
                              "corpus_size": f.original.corpus_size, "hits": f.hits, "seed": seed,
                              "found_at_s": f.found_at_s}
                             for f in fz.findings.values()]}
    finally:
        shutil.rmtree(work, ignore_errors=True)


def minimise_task(spec: ShardSpec, data: bytes, kind: str, key: str, seconds: float, tests: int) -> dict:
    """Minimise one finding in a worker: the smallest input with the same class and signature."""
    work = Path(tempfile.mkdtemp(prefix="fbaconf-min-"))
    target = _target(spec, work)
    last = {}
    try:
        def test(cand: bytes) -> bool:
            v = target.execute(Entry(cand, kind=kind, origin="minimise")).verdict
            if v is not None and v.key == key:
                last["v"] = v
                return True
            return False
        minimal, stats = minimise(data, test, max_tests=tests, max_seconds=seconds)
        v = last.get("v")
        return {"minimal": minimal, "tests": stats.tests, "seconds": stats.seconds,
                "message": v.message if v else None, "detail": v.detail if v else None}
    finally:
        target.close()
        shutil.rmtree(work, ignore_errors=True)


@dataclass
class Campaign:
    """What the coordinator has merged so far."""
    execs: int = 0
    fuzz_seconds: float = 0.0
    shards: int = 0
    features: set[str] = field(default_factory=set)
    universe: set[str] = field(default_factory=set)
    corpus: dict[str, bytes] = field(default_factory=dict)
    findings: dict[str, dict] = field(default_factory=dict)

    def merge(self, r: dict) -> list[dict]:
        """Merge one shard's report; returns the findings new to the campaign."""
        self.shards += 1
        self.execs += r["execs"]
        self.fuzz_seconds += r["fuzz_seconds"]
        self.features |= set(r["features"])
        self.universe |= set(r["universe"])
        for b in r["corpus"]:
            if len(self.corpus) < MAX_MERGED:
                self.corpus.setdefault(hashlib.sha1(b).hexdigest(), b)
        new = []
        for f in r["findings"]:
            have = self.findings.get(f["key"])
            if have is None:
                self.findings[f["key"]] = dict(f, shards=1)
                new.append(f)
            else:
                have["hits"] += f["hits"]
                have["shards"] += 1
                if len(f["data"]) < len(have["data"]):  # keep the smaller original
                    have.update(data=f["data"], seed=f["seed"], index=f["index"], corpus_size=f["corpus_size"],
                                origin=f["origin"])
        return new


def run_campaign(c, spec: ShardSpec, *, workers: int, seconds: float, seed: int, out: Path,  # noqa: PLR0913
                 minimise_seconds: float, progress=print, round_s: float = ROUND_S) -> tuple[Campaign, list]:
    """Rounds of one shard per worker until ``seconds`` have passed; then each distinct finding
    minimised once and written to ``out/findings``. Returns the campaign and its Findings."""
    from distributed import as_completed  # noqa: PLC0415 (Dask: optional (the cluster extra))
    camp = Campaign()
    t0 = time.perf_counter()
    rnd = 0
    while True:
        left = seconds - (time.perf_counter() - t0)
        if left <= 1.0 and rnd > 0:
            break
        length = max(1.0, min(round_s, left))
        merged = list(camp.corpus.values())
        futs = [c.submit(run_shard, spec, seed * 1_000_003 + rnd * 1009 + i, length, merged,
                         key=f"fbaconf-shard-{seed}-{rnd}-{i}", pure=False, retries=3)
                for i in range(workers)]
        for _fut, r in as_completed(futs, with_results=True):
            for f in camp.merge(r):
                progress(f"finding {f['cls']} ({f['signature']}) in shard seed {f['seed']}: {f['message'][:120]}")
        rnd += 1
        progress(f"[{time.perf_counter() - t0:6.1f}s] round {rnd}: {camp.execs} execs, "
                 f"{len(camp.findings)} finding(s), corpus +{len(camp.corpus)}")
    wall = time.perf_counter() - t0
    # each distinct finding minimised once, on the cluster
    mins = {k: c.submit(minimise_task, spec, f["data"], f["kind"], k, minimise_seconds, 600,
                        key=f"fbaconf-min-{seed}-{hashlib.sha1(k.encode()).hexdigest()[:12]}", pure=False, retries=2)
            for k, f in camp.findings.items()}
    findings = _write(camp, {k: fut.result() for k, fut in mins.items()}, spec, out)
    camp.wall_s = wall
    return camp, findings


def _write(camp: Campaign, mins: dict, spec: ShardSpec, out: Path) -> list:
    out.mkdir(parents=True, exist_ok=True)
    local = _target(spec, Path(tempfile.mkdtemp(prefix="fbaconf-campaign-", dir=out)))
    info = {"name": local.adapter.name, "manifest": str(local.adapter.manifest_path or spec.manifest),
            "mode": "campaign"}
    written = []
    try:
        for k, f in camp.findings.items():
            v = Verdict(f["cls"], f["signature"], f["message"], f["detail"])
            e = Entry(f["data"], kind=f["kind"], origin=f["origin"])
            e.corpus_size = f["corpus_size"]
            fid = f"{f['cls']}-{hashlib.sha256(k.encode()).hexdigest()[:8]}"
            fd = Finding(fid, v, e, f["index"], f["found_at_s"], hits=f["hits"])
            m = mins.get(k) or {}
            if m.get("minimal") is not None:
                fd.minimal = m["minimal"]
                fd.min_stats = MinimiseStats(bytes_before=len(f["data"]), bytes_after=len(m["minimal"]),
                                             tests=m["tests"], seconds=m["seconds"])
                if m.get("message"):
                    fd.min_verdict = Verdict(f["cls"], f["signature"], m["message"], m["detail"] or {})
            write_finding(out, fd, SimpleNamespace(target=local, decoder_info=info, seed=f["seed"]))
            written.append(fd)
    finally:
        local.close()
        shutil.rmtree(local.work_root, ignore_errors=True)
    return written
