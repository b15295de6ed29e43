"""Fuzzing campaigns on a Dask cluster: ``fbaconf fuzz --decoder D.toml --cluster local[:N]``
or ``--cluster tls://HOST:PORT`` (the cluster set-up of :mod:`fbaconf.harness.cluster`).

A campaign runs in rounds. Each round is one task per worker, a *shard*: an ordinary
one-at-a-time :class:`~fbaconf.fuzz.engine.Fuzzer` in the worker (its own seed, its own fork
server and folders on the worker) seeded with the suites plus the corpus merged from every
shard so far, that reports its findings unminimised, its new corpus entries, its coverage and
its execs. This process merges them as they arrive: findings deduplicated by class and
signature across shards (hits summed), the corpus merged and handed to the next round, the
coverage united. At the end each distinct finding is minimised once, as a task, and written
like a local run's. A worker lost mid-round loses nothing: Dask reruns its shard elsewhere,
and a shard is a pure function of its seed, so the rerun finds what the lost one would have.

The cluster is the harness's (mutual TLS, :mod:`fbaconf.harness.cluster`); task keys are
random, and a shard's or a minimisation's report travels as JSON text (inputs as base64),
parsed and checked as plain data here before it is merged (:func:`shard_report`).
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import json
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

from fbaconf.harness.adapters import resolve
from fbaconf.harness.cluster import ClusterError, from_data, task_key
from fbaconf.isolation.bounds import DEFAULT_CEILINGS, Ceilings

from .corpus import default_seeds
from .engine import FuzzConfig, Fuzzer
from .findings import Finding, minimise_against, write_finding
from .inputs import Entry, InputKind
from .minimise import MinimiseStats
from .targets import DecoderTarget, Verdict

ROUND_S = 30.0  # a shard's length: corpus merged between rounds
MAX_MERGED = 2000


@dataclass
class ShardSpec:
    manifest: str
    kind: InputKind = InputKind.STREAM
    timeout_s: float | None = None
    expected_exit: tuple[int, ...] | None = None
    oracle: bool = True
    coverage_every: int = 8
    spawn: bool = False
    # the lab's ceilings (--max-timeout-s...): every worker reads the manifest under the same ones
    ceilings: Ceilings = DEFAULT_CEILINGS


def _target(spec: ShardSpec, work: Path):
    return DecoderTarget(
        resolve(spec.manifest, ceilings=spec.ceilings),
        work,
        kind=spec.kind,
        timeout_s=spec.timeout_s,
        expected_exit=spec.expected_exit,
        oracle=spec.oracle,
        fork_server=not spec.spawn,
        persistent=not spec.spawn,
    )


def _b64(data: bytes) -> str:
    return base64.b64encode(data).decode("ascii")


def _unb64(text, what: str) -> bytes:
    if not isinstance(text, str):
        raise ClusterError(f"{what} from the cluster is not base64 text")
    try:
        return base64.b64decode(text.encode("ascii"), validate=True)
    except (binascii.Error, UnicodeEncodeError):
        raise ClusterError(f"{what} from the cluster is not base64 text") from None


def _json(doc: dict) -> str:
    """A worker's report as JSON text (numbers that numpy made become plain ones)."""
    return json.dumps(
        doc, default=lambda o: o.item() if hasattr(o, "item") else o.tolist() if hasattr(o, "tolist") else str(o)
    )


def run_shard(spec: ShardSpec, seed: int, seconds: float, merged: list[bytes]) -> str:
    """One shard, in a worker: fuzz for ``seconds`` and report (no minimisation, no files),
    as JSON text (:func:`shard_report` reads it)."""
    work = Path(tempfile.mkdtemp(prefix="fbaconf-shard-"))
    try:
        target = _target(spec, work)
        seeds = default_seeds() + [Entry(b, origin=f"merged#{i}") for i, b in enumerate(merged)]
        fz = Fuzzer(
            target,
            seeds,
            FuzzConfig(
                seed=seed,
                seconds=seconds,
                jobs=1,
                progress=False,
                kinds=(spec.kind,),
                coverage_every=spec.coverage_every,
                minimise_findings=False,
                fresh_helper=False,  # the shards have every CPU already
                features_helper=False,
            ),
        )
        fz.run()
        st = fz.stats
        return _json(
            {
                "seed": seed,
                "execs": st.execs,
                "fuzz_seconds": st.elapsed - st.minimise_s,
                "features": sorted(st.features),
                "universe": list(st.universe),
                "corpus": [_b64(e.data) for e in fz.new_corpus],
                "findings": [
                    {
                        "key": f.verdict.key,
                        "cls": f.verdict.cls,
                        "signature": f.verdict.signature,
                        "message": f.verdict.message,
                        "detail": f.verdict.detail,
                        "data": _b64(f.original.data),
                        "kind": f.original.kind,
                        "origin": f.original.origin,
                        "index": f.index,
                        "corpus_size": f.original.corpus_size,
                        "hits": f.hits,
                        "seed": seed,
                        "found_at_s": f.found_at_s,
                    }
                    for f in fz.findings.values()
                ],
            }
        )
    finally:
        shutil.rmtree(work, ignore_errors=True)


_SHARD_FIELDS = {
    "seed": int,
    "execs": int,
    "fuzz_seconds": (int, float),
    "features": list,
    "universe": list,
    "corpus": list,
    "findings": list,
}
_FINDING_FIELDS = {
    "key": str,
    "cls": str,
    "signature": str,
    "message": str,
    "detail": dict,
    "data": str,
    "kind": str,
    "origin": str,
    "index": int,
    "corpus_size": (int, type(None)),
    "hits": int,
    "seed": int,
    "found_at_s": (int, float),
}


def _fields(d: dict, want: dict, what: str) -> None:
    for k, t in want.items():
        kinds = t if isinstance(t, tuple) else (t,)
        if k not in d or (isinstance(d[k], bool) and bool not in kinds) or not isinstance(d[k], t):
            raise ClusterError(f"{what} from the cluster lacks {k!r} or holds the wrong kind of value there")


def shard_report(text) -> dict:
    """A shard's JSON report, checked (plain data, the fields merged and their kinds) and with
    its inputs decoded; ClusterError for anything else."""
    r = from_data(text, "shard report")
    _fields(r, _SHARD_FIELDS, "a shard report")
    if not all(isinstance(x, str) for x in r["features"] + r["universe"]):
        raise ClusterError("a shard report's features are not names")
    r["corpus"] = [_unb64(b, "a corpus entry") for b in r["corpus"]]
    for f in r["findings"]:
        if not isinstance(f, dict):
            raise ClusterError("a shard report's finding is not a table")
        _fields(f, _FINDING_FIELDS, "a shard report's finding")
        f["data"] = _unb64(f["data"], "a finding's input")
    return r


def minimise_task(spec: ShardSpec, data: bytes, kind: InputKind, key: str, seconds: float, tests: int) -> str:
    """Minimise one finding in a worker: the smallest input with the same class and signature
    (JSON text, read by :func:`minimise_report`)."""
    work = Path(tempfile.mkdtemp(prefix="fbaconf-min-"))
    target = _target(spec, work)
    try:
        minimal, stats, v = minimise_against(target, data, kind, key, seconds=seconds, tests=tests)
        return _json(
            {
                "minimal": _b64(minimal),
                "tests": stats.tests,
                "seconds": stats.seconds,
                "reproduced": stats.reproduced,
                "flaky": stats.flaky,
                "message": v.message if v else None,
                "detail": v.detail if v else None,
            }
        )
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
                self.corpus.setdefault(hashlib.sha1(b, usedforsecurity=False).hexdigest(), b)
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
                    have.update(
                        data=f["data"],
                        seed=f["seed"],
                        index=f["index"],
                        corpus_size=f["corpus_size"],
                        origin=f["origin"],
                    )
        return new


def minimise_report(text) -> dict:
    """A minimisation's JSON report, checked, its input decoded."""
    m = from_data(text, "minimisation report")
    _fields(
        m,
        {
            "minimal": str,
            "tests": int,
            "seconds": (int, float),
            "reproduced": (bool, type(None)),
            "flaky": bool,
            "message": (str, type(None)),
            "detail": (dict, type(None)),
        },
        "a minimisation report",
    )
    m["minimal"] = _unb64(m["minimal"], "a minimised input")
    return m


def run_campaign(  # noqa: PLR0913 - one shard's whole configuration, sent to a worker as arguments
    c,
    spec: ShardSpec,
    *,
    workers: int,
    seconds: float,
    seed: int,
    out: Path,
    minimise_seconds: float,
    progress=print,
    round_s: float = ROUND_S,
) -> tuple[Campaign, list]:
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
        futs = [
            c.submit(
                run_shard,
                spec,
                seed * 1_000_003 + rnd * 1009 + i,
                length,
                merged,
                key=task_key("shard"),
                pure=False,
                retries=3,
            )
            for i in range(workers)
        ]
        for _fut, r in as_completed(futs, with_results=True):
            for f in camp.merge(shard_report(r)):
                progress(f"finding {f['cls']} ({f['signature']}) in shard seed {f['seed']}: {f['message'][:120]}")
        rnd += 1
        progress(
            f"[{time.perf_counter() - t0:6.1f}s] round {rnd}: {camp.execs} execs, "
            f"{len(camp.findings)} finding(s), corpus +{len(camp.corpus)}"
        )
    wall = time.perf_counter() - t0
    # each distinct finding minimised once, on the cluster
    mins = {
        k: c.submit(
            minimise_task,
            spec,
            f["data"],
            f["kind"],
            k,
            minimise_seconds,
            600,
            key=task_key("min"),
            pure=False,
            retries=2,
        )
        for k, f in camp.findings.items()
    }
    findings = _write(camp, {k: minimise_report(fut.result()) for k, fut in mins.items()}, spec, out)
    camp.wall_s = wall
    return camp, findings


def _write(camp: Campaign, mins: dict, spec: ShardSpec, out: Path) -> list:
    out.mkdir(parents=True, exist_ok=True)
    local = _target(spec, Path(tempfile.mkdtemp(prefix="fbaconf-campaign-", dir=out)))
    info = {
        "name": local.adapter.name,
        "manifest": str(local.adapter.manifest_path or spec.manifest),
        "mode": "campaign",
    }
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
                fd.min_stats = MinimiseStats(
                    bytes_before=len(f["data"]),
                    bytes_after=len(m["minimal"]),
                    tests=m["tests"],
                    seconds=m["seconds"],
                    reproduced=m["reproduced"],
                    flaky=m["flaky"],
                )
                if m.get("message"):
                    fd.min_verdict = Verdict(f["cls"], f["signature"], m["message"], m["detail"] or {})
            write_finding(out, fd, SimpleNamespace(target=local, decoder_info=info, seed=f["seed"]))
            written.append(fd)
    finally:
        local.close()
        shutil.rmtree(local.work_root, ignore_errors=True)
    return written
