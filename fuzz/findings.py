"""Findings on disk (input, minimised input, reproduce script, JSON) and their replay."""

from __future__ import annotations

import hashlib
import json
import os
import shlex
from dataclasses import dataclass
from pathlib import Path

from fbaconf._atomic import atomic_write_bytes, atomic_write_text
from fbaconf.harness.adapters import Job

from .inputs import Entry, InputKind
from .minimise import MinimiseStats, minimise
from .selftarget import SelfTarget
from .targets import DecoderTarget, FuzzSetupError, Verdict


@dataclass
class Finding:
    id: str
    verdict: Verdict
    original: Entry
    index: int  # input index (with the seed, regenerates the original)
    found_at_s: float
    hits: int = 1
    minimal: bytes | None = None
    min_stats: MinimiseStats | None = None
    min_verdict: Verdict | None = None
    path: Path | None = None


def write_finding(out_dir: Path, f: Finding, fz) -> Path:  # fz: the engine.Fuzzer that found it
    d = Path(out_dir) / "findings" / f.id
    d.mkdir(parents=True, exist_ok=True)
    ext = {InputKind.SCENE: "bt", InputKind.BIFS: "bifs", InputKind.TEXT: "fap"}.get(f.original.kind, "fba")
    atomic_write_bytes(d / f"original.{ext}", f.original.data)
    minimal = f.minimal if f.minimal is not None else f.original.data
    atomic_write_bytes(d / f"minimal.{ext}", minimal)
    target = fz.target
    info = fz.decoder_info
    replay = ["fbaconf", "fuzz"] + (
        ["--self"]
        if isinstance(target, SelfTarget)
        else ["--decoder", str(info.get("manifest") or info.get("name", "?"))]
    )
    if f.original.kind != InputKind.STREAM:
        replay += ["--target", f.original.kind]
    replay += ["--replay", str((d / f"minimal.{ext}").resolve())]
    command = None
    if isinstance(target, DecoderTarget) and target.is_command:
        wd = "/tmp/fbaconf-repro"  # noqa: S108 - the reproduce script runs the decoder in a fixed folder it creates
        values = {
            "input": str((d / f"minimal.{ext}").resolve()),
            "fba": str((d / f"minimal.{ext}").resolve()),
            "faps_out": f"{wd}/faps.{'fap' if target.adapter.faps_format == 'fap' else 'npz'}",
            "vertices_out": f"{wd}/vertices.npz",
            "images_dir": f"{wd}/images",
            "faps_out_dir": f"{wd}/faces",
        }
        if f.original.kind == InputKind.SCENE:
            values.update(
                scene=values["input"],
                scene_bt=values["input"],
                input=str((d / "stream.fba").resolve()),
                fba=str((d / "stream.fba").resolve()),
            )
            atomic_write_bytes(d / "stream.fba", target.scene_stream or b"")
        try:
            command = target.adapter.argv("decode", Job(Path(wd), values))
        except KeyError:
            command = None
        lim = target.limits
        script = [
            "#!/bin/sh",
            f"# reproduce finding {f.id}: {f.verdict.cls} ({f.verdict.signature})",
            f"# limits: timeout {lim.timeout_s:g} s, memory {lim.memory_mb} MB ({lim.memory_kind}), "
            f"output {lim.output_mb} MB",
            f"mkdir -p {wd}/images {wd}/faces",
        ]
        if lim.memory_kind == "address-space" and lim.memory_mb:
            script.append(f"ulimit -v {lim.memory_mb * 1024}")
        if command:
            envs = " ".join(f"{k}={shlex.quote(v)}" for k, v in target.adapter.env.items())
            script.append(f"{envs + ' ' if envs else ''}timeout {lim.timeout_s:g} {shlex.join(command)}")
            script.append('echo "exit status: $?"')
        atomic_write_text(d / "reproduce.sh", "\n".join(script) + "\n")
        os.chmod(d / "reproduce.sh", 0o755)  # noqa: S103 - an executable script, as its name says
    mv = f.min_verdict or f.verdict
    doc = {
        "format": "fbaconf.fuzz-finding/1",
        "id": f.id,
        "class": f.verdict.cls,
        "signature": f.verdict.signature,
        "message": f.verdict.message,
        "minimal_message": mv.message,
        "target": getattr(target, "name", "?"),
        "input_kind": f.original.kind,
        "decoder": info,
        "seed": fz.seed,
        "input_index": f.index,
        "corpus_size": f.original.corpus_size,
        "origin": f.original.origin,
        "input_valid": bool(f.original.valid),
        "found_at_s": round(f.found_at_s, 2),
        "hits": f.hits,
        "original": {
            "file": f"original.{ext}",
            "bytes": len(f.original.data),
            "sha256": hashlib.sha256(f.original.data).hexdigest(),
        },
        "minimal": {"file": f"minimal.{ext}", "bytes": len(minimal), "sha256": hashlib.sha256(minimal).hexdigest()},
        "minimisation": (
            {
                "tests": f.min_stats.tests,
                "seconds": round(f.min_stats.seconds, 2),
                "reproduced": f.min_stats.reproduced,
                "flaky": f.min_stats.flaky,
            }
            if f.min_stats
            else None
        ),
        # a finding whose input does not do it again on a fresh process, or that no input did alone
        "flaky": bool((f.min_stats and f.min_stats.flaky) or (f.verdict.detail or {}).get("flaky")),
        "detail": {k: v for k, v in (mv.detail or {}).items()},
        "reproduce": {
            "fbaconf": shlex.join(replay),
            "command": command,
            "regenerate": f"input #{f.index} of seed {fz.seed} (corpus size {f.original.corpus_size})",
        },
    }
    atomic_write_text(d / "finding.json", json.dumps(doc, indent=1, default=str) + "\n")
    f.path = d
    return d


def write_summary(out_dir: Path, fz) -> dict:
    doc = fz.summary()
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    atomic_write_text(Path(out_dir) / "fuzz.json", json.dumps(doc, indent=1) + "\n")
    return doc


def load_findings(fuzz_dir: Path) -> list[tuple[Path, dict]]:
    out = []
    for p in sorted((Path(fuzz_dir) / "findings").glob("*/finding.json")):
        try:
            doc = json.loads(p.read_text("utf-8"))
        except (OSError, ValueError) as e:
            raise FuzzSetupError(f"unreadable finding {p}: {e}") from None
        if not isinstance(doc, dict):
            raise FuzzSetupError(f"unreadable finding {p}: not a JSON object")
        out.append((p.parent, doc))
    return out


def minimise_against(
    target, data: bytes, kind: InputKind, key: str, *, seconds: float, tests: int
) -> tuple[bytes, MinimiseStats, Verdict | None]:
    """The smallest input found on which ``target`` gives a verdict of ``key`` (class and
    signature), the statistics, and the minimal input's verdict: prefixes at plane boundaries
    (the syntax model's, for a stream), then bytes, then bits; checked on a process of its own at
    both ends (``alone``), every other test through the target's fast path (``settled``). The
    fuzzer's findings and ``fbaconf fuzz minimise`` are minimised by this one function, so a bug
    gets one signature and one minimal input whichever found it."""
    last: dict[str, Verdict | None] = {}
    settled = getattr(target, "settled", target.execute)  # its ending bound to it (targets.py)
    alone = getattr(target, "alone", target.execute)  # a process of its own: the two checks

    def test(cand: bytes, run=settled) -> bool:
        out = run(Entry(cand, kind=kind, origin="minimise"))
        ok = out.verdict is not None and out.verdict.key == key
        if ok:
            last["v"] = out.verdict
        return ok

    bounds = None
    if kind == InputKind.STREAM:
        try:
            bounds = Entry(data, kind=kind).get_model().boundaries()
        except Exception:  # noqa: BLE001 - an input the syntax model cannot walk is minimised by bytes only
            bounds = None
    minimal, stats = minimise(
        data, test, max_tests=tests, max_seconds=seconds, boundaries=bounds, check=lambda c: test(c, alone)
    )
    return minimal, stats, last.get("v")


def replay(target, data: bytes, kind: InputKind = InputKind.STREAM) -> Verdict | None:
    """The verdict of ``target`` on ``data``, on a process of its own (``alone``: through
    ``serve``, a fresh process whose exit is awaited). A replay is a run of its own: the fork
    server or persistent decoder it starts is stopped when it ends (``target.close``)."""
    try:
        return getattr(target, "alone", target.execute)(Entry(data, kind=kind, origin="replay")).verdict
    finally:
        close = getattr(target, "close", None)
        if close is not None:
            close()
