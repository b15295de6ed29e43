"""Verb ``fbaconf fuzz``: fuzz a decoder under test, or fbaconf's own parsers; promote findings.

::

    fbaconf fuzz --decoder D.toml --seconds N [--seed S] [-j N] [-o DIR] [--target stream|scene]
                 [--spawn] [--coverage-every N] [--cluster local[:N]|tls://HOST:PORT]
    fbaconf fuzz --self [--seconds N] [--seed S] [-o DIR]
    fbaconf fuzz --decoder D.toml --replay FILE         # run one input, print its classification
    fbaconf fuzz --promote DIR [--data-dir PATH]         # findings -> regression suite cases
    fbaconf fuzz export DIR [--valid N] [--seed S]        # seeds + dictionary for libFuzzer/AFL++/OSS-Fuzz
    fbaconf fuzz minimise FILE --decoder D.toml [-o OUT]  # re-minimise a crash file (from any fuzzer)

Exit codes: 0 no findings (replay: the input behaves), 1 findings, 2 usage or setup error.
The stage's modules are listed in :mod:`fbaconf.fuzz`; see docs/fuzzing.md.
"""

from __future__ import annotations

import json
import shutil
import sys
import tempfile
from pathlib import Path

from fbaconf.isolation.bounds import add_ceiling_options, ceilings_from

from .inputs import InputKind


def register(sub) -> None:
    p = sub.add_parser(
        "fuzz",
        help="fuzz a decoder's (or fbaconf's own) bitstream and scene parsers",
        description="Structure-aware fuzzing: valid streams from the syntax model, field-aware and "
        "byte-level mutations of the conformance streams; crashes, hangs, memory "
        "blow-ups, unexpected exit codes and wrong output on valid input are "
        "deduplicated, minimised and written to DIR/findings/.",
    )
    p.add_argument(
        "export",
        nargs="?",
        choices=["export", "minimise"],
        metavar="export|minimise",
        help="'export DIR': write a seed corpus, an AFL++/libFuzzer dictionary and an OSS-Fuzz "
        "snippet for the fuzzers vendors run (see docs/fuzzing.md); 'minimise FILE': classify one input "
        "(a crash file of any fuzzer) with --decoder or --self and write the smallest input that does the "
        "same (same class and signature) to -o (default FILE.min.<ext>)",
    )
    p.add_argument(
        "export_dir",
        nargs="?",
        type=Path,
        metavar="DIR|FILE",
        help="(export) the folder to write; (minimise) the input",
    )
    p.add_argument(
        "--valid",
        type=int,
        default=64,
        metavar="N",
        help="(export) generated valid streams in the seed corpus (default 64)",
    )
    who = p.add_mutually_exclusive_group()
    who.add_argument("--decoder", help="decoder manifest .toml or bundled adapter name")
    who.add_argument(
        "--self",
        dest="self_",
        action="store_true",
        help="fuzz fbaconf's own decoder, checker and scene readers in-process",
    )
    who.add_argument(
        "--promote", type=Path, metavar="DIR", help="turn the findings of a fuzz run folder into regression suite cases"
    )
    p.add_argument("--seconds", type=float, default=60.0, help="fuzzing time budget (default 60)")
    p.add_argument("--seed", type=int, default=0, help="random seed: the same seed replays the same inputs")
    p.add_argument("-j", "--jobs", type=int, default=1, help="decoder processes in parallel (--decoder)")
    p.add_argument("-o", "--output", type=Path, help="run folder (default fbaconf-fuzz/<decoder|self>)")
    p.add_argument(
        "--target",
        type=InputKind,
        choices=(InputKind.STREAM, InputKind.SCENE, InputKind.TEXT),
        default=None,
        help="--decoder: fuzz the binary stream (default), the BT scene input (a fixed valid stream) "
        "or the .fap text (default for a player, a decoder that reads only .fap text)",
    )
    p.add_argument(
        "--timeout",
        type=float,
        default=None,
        help="cap the per-input timeout below the adapter's timeout_s (hangs are found faster)",
    )
    p.add_argument(
        "--expected-exit",
        default=None,
        help="exit codes that mean a clean reject (default: the manifest's reject_exit_codes; 0 and 69 "
        "are always expected)",
    )
    p.add_argument("--no-oracle", action="store_true", help="do not compare output on valid inputs")
    p.add_argument("--minimise-seconds", type=float, default=30.0, help="time budget per finding's minimisation")
    p.add_argument(
        "--minimise-tests", type=int, default=None, help="most inputs one minimisation runs (default: the fuzzer's)"
    )
    p.add_argument(
        "--seeds",
        type=Path,
        action="append",
        default=[],
        help="extra seed files or folders (*.fba) besides the conformance suites",
    )
    p.add_argument("--max-execs", type=int, default=None, help="stop after this many inputs")
    p.add_argument(
        "--cluster",
        metavar="local[:N]|tls://HOST:PORT",
        help="--decoder: run the campaign as shards on a Dask cluster (one per worker, corpus merged "
        "between rounds, findings deduplicated and minimised once)",
    )
    p.add_argument(
        "--spawn",
        action="store_true",
        help="--decoder: a fresh sandbox per input (slow, the strictest separation) instead of one "
        "sandbox per worker with a fork server, or the persistent protocol when the manifest has "
        "[commands] serve",
    )
    p.add_argument(
        "--coverage-every",
        type=int,
        default=8,
        metavar="N",
        help="--decoder: measure the syntax-model coverage of every N-th input (a reference decode, "
        "~1 ms each; default 8, 1 = every input), and of every input the oracle decoded anyway",
    )
    p.add_argument("--replay", type=Path, metavar="FILE", help="run one input and print its classification")
    p.add_argument("--data-dir", type=Path, help="(--promote) conformance data folder (default: the package's)")
    p.add_argument("--no-progress", action="store_true", help="no live status line")
    p.add_argument("--json", action="store_true", help="print the run summary as JSON")
    add_ceiling_options(p)
    p.set_defaults(func=cmd_fuzz)


def _extra_seeds(paths: list[Path]):
    from .inputs import Entry

    out = []
    for p in paths:
        files = sorted(p.rglob("*.fba")) if p.is_dir() else [p]
        for f in files:
            out.append(Entry(f.read_bytes(), origin=f"seed:{f}"))
    return out


def cmd_fuzz(args) -> int:
    args.minimise_file = None
    if args.export == "minimise":
        if args.export_dir is None or not (args.decoder or args.self_) or args.cluster or args.replay:
            usage = "fbaconf fuzz minimise FILE (--decoder D.toml | --self) [-o OUT]"
            print(f"fbaconf fuzz: error: usage: {usage}", file=sys.stderr)
            return 2
        if not args.export_dir.is_file():
            print(f"fbaconf fuzz: error: {args.export_dir}: no such file", file=sys.stderr)
            return 2
        args.minimise_file, args.minimise_out, args.output = args.export_dir, args.output, None
        args.export = None
    if args.export is not None:
        if args.export_dir is None or args.decoder or args.self_ or args.promote:
            print("fbaconf fuzz: error: usage: fbaconf fuzz export DIR [--valid N] [--seed S]", file=sys.stderr)
            return 2
        from .export import export

        doc = export(args.export_dir, n_valid=args.valid, seed=args.seed)
        print(
            json.dumps(doc, indent=1)
            if args.json
            else f"{doc['seeds']} seed streams ({doc['suite']} suite, {doc['prefixes']} prefixes, {doc['generated']} "
            f"generated): {doc['corpus']} to start from in corpus/, {doc['more']} in more/, "
            f"{doc['stress']} long ones in stress/; {doc['tokens']} dictionary tokens -> {doc['dir']}"
        )
        return 0
    if not (args.decoder or args.self_ or args.promote):
        print("fbaconf fuzz: error: one of --decoder, --self, --promote or 'export DIR' is required", file=sys.stderr)
        return 2
    if args.promote is not None:
        from .promote import promote

        added = promote(args.promote, args.data_dir, log=lambda s: print(s, file=sys.stderr))
        print(f"promoted {len(added)} finding(s) to the regression suite")
        for line in _after_promotion(added, args):
            print(line)
        if args.json:
            print(json.dumps(added, indent=1))
        return 0
    try:
        expected = (
            {int(x) for x in args.expected_exit.split(",") if x.strip()} if args.expected_exit is not None else None
        )
    except ValueError:
        print("fbaconf fuzz: error: --expected-exit must be a comma-separated list of integers", file=sys.stderr)
        return 2
    if args.self_:
        if args.cluster:
            print("fbaconf fuzz: error: --cluster fuzzes a decoder (--decoder), not fbaconf itself", file=sys.stderr)
            return 2
        return _self(args)
    if args.cluster:
        return _campaign(args, expected)
    return _decoder(args, expected)


def _campaign(args, expected: set[int] | None) -> int:
    from fbaconf.harness import cluster
    from fbaconf.harness.adapters import resolve

    from .campaign import ShardSpec, run_campaign

    ceilings = ceilings_from(args)
    adapter = resolve(args.decoder, ceilings=ceilings)  # a bad manifest fails here, not in every worker
    manifest = str(Path(args.decoder).resolve()) if Path(args.decoder).is_file() else args.decoder
    if args.replay is not None:
        print("fbaconf fuzz: error: --replay runs one input here; drop --cluster", file=sys.stderr)
        return 2
    kind = args.target or _default_kind(adapter)
    spec = ShardSpec(
        manifest,
        kind=kind,
        timeout_s=args.timeout,
        expected_exit=tuple(sorted(expected)) if expected is not None else None,
        oracle=not args.no_oracle,
        coverage_every=args.coverage_every,
        spawn=args.spawn,
        ceilings=ceilings,
    )
    out = (args.output or Path("fbaconf-fuzz") / adapter.name).resolve()
    out.mkdir(parents=True, exist_ok=True)
    log = (lambda m: None) if args.no_progress else (lambda m: print(m, file=sys.stderr, flush=True))
    with cluster.client(args.cluster) as c:
        workers = max(1, len(c.scheduler_info().get("workers", {})))
        camp, findings = run_campaign(
            c,
            spec,
            workers=workers,
            seconds=args.seconds,
            seed=args.seed,
            out=out,
            minimise_seconds=args.minimise_seconds,
            progress=log,
        )
    c_, n_ = len(camp.features & camp.universe), len(camp.universe)
    doc = {
        "format": "fbaconf.fuzz/1",
        "target": adapter.name,
        "seed": args.seed,
        "cluster": args.cluster,
        "workers": workers,
        "shards": camp.shards,
        "seconds": round(camp.wall_s, 2),
        "fuzz_seconds": round(camp.fuzz_seconds, 2),
        "execs": camp.execs,
        "execs_per_s": round(camp.execs / max(1e-9, camp.wall_s), 1),
        "findings": len(findings),
        "finding_hits": sum(f.hits for f in findings),
        "syntax_coverage": {
            "covered": c_,
            "total": n_,
            "features": sorted(camp.features),
            "missing": sorted(camp.universe - camp.features),
        },
        "corpus": len(camp.corpus),
        "decoder": {"name": adapter.name, "manifest": manifest, "mode": "campaign"},
        "finding_ids": [f.id for f in findings],
    }
    from fbaconf._atomic import atomic_write_text

    atomic_write_text(out / "fuzz.json", json.dumps(doc, indent=1) + "\n")
    if args.json:
        print(json.dumps(doc, indent=1))
    else:
        print(
            f"{doc['execs']} inputs in {doc['seconds']:.1f} s on {workers} worker(s) ({doc['execs_per_s']:,.0f} "
            f"execs/s), syntax coverage {c_}/{n_}, {len(findings)} finding(s) -> {out}"
        )
        for f in findings:
            ms = f.min_stats
            size = f"{ms.bytes_before} -> {ms.bytes_after} bytes" if ms else f"{len(f.original.data)} bytes"
            print(f"  {f.id}: {f.verdict.cls} ({f.verdict.signature}) x{f.hits}, {size}: {f.verdict.message[:120]}")
    return 1 if findings else 0


def _self(args) -> int:
    from .corpus import default_seeds, short_prefixes
    from .engine import FuzzConfig, Fuzzer
    from .findings import replay
    from .selftarget import SelfTarget

    S = InputKind
    kinds = (S.STREAM, S.STREAM, S.STREAM, S.SCENE, S.BIFS, S.TEXT)
    if args.target in (S.SCENE, S.TEXT) and args.replay is None:
        kinds = (args.target,)
    seeds = default_seeds() + _extra_seeds(args.seeds)
    short = short_prefixes(seeds)
    target = SelfTarget(scene_stream=short[0].data if short else seeds[0].data, checker_every=16)
    if args.replay is not None:
        kind = _kind_of(args.replay, args.target)
        v = replay(target, args.replay.read_bytes(), kind)
        return _print_replay(v, args)
    if args.minimise_file is not None:
        return _minimise_file(target, args, tests=5000)
    out = (args.output or Path("fbaconf-fuzz") / "self").resolve()
    fz = Fuzzer(
        target,
        seeds + short,
        FuzzConfig(
            seed=args.seed,
            seconds=args.seconds,
            jobs=1,
            out_dir=out,
            kinds=kinds,
            progress=False if args.no_progress else None,
            minimise_seconds=args.minimise_seconds,
            max_execs=args.max_execs,
            fresh_valid_share=0.003,
            prefer_short=0.9,
            minimise_tests=5000,
        ),
        decoder_info={"name": "fbaconf-self"},
    )
    if args.jobs and args.jobs > 1:
        print("fbaconf fuzz: --self runs in one process (-j ignored)", file=sys.stderr)
    fz.run()
    return _finish(fz, out, args)


def _default_kind(adapter) -> InputKind:
    """A player (reads only .fap text) is fuzzed through its text; everything else through the stream."""
    return InputKind.TEXT if "fba" not in adapter.inputs and "fap" in adapter.inputs else InputKind.STREAM


def _kind_of(path: Path, target: InputKind | None) -> InputKind:
    by_suffix = {".bt": InputKind.SCENE, ".bifs": InputKind.BIFS, ".fap": InputKind.TEXT}
    return by_suffix.get(path.suffix.lower(), InputKind.SCENE if target == InputKind.SCENE else InputKind.STREAM)


def _minimise_file(target, args, *, tests: int) -> int:
    """``fbaconf fuzz minimise FILE``: the input's verdict on a process of its own, then the same
    minimisation a finding of the fuzzer gets (:func:`findings.minimise_against`), so a crash file of
    AFL++ or libFuzzer ends with the signature and the minimal input ``fbaconf fuzz`` gives that bug."""
    from fbaconf._atomic import atomic_write_bytes

    from .findings import minimise_against

    path: Path = args.minimise_file
    kind = _kind_of(path, args.target)
    data = path.read_bytes()
    v = getattr(target, "alone", target.execute)(_entry(data, kind)).verdict
    if v is None:
        print("no finding: the input is handled cleanly (nothing to minimise)")
        return 0
    minimal, stats, mv = minimise_against(
        target, data, kind, v.key, seconds=args.minimise_seconds, tests=args.minimise_tests or tests
    )
    out = args.minimise_out or path.with_name(f"{path.stem}.min{path.suffix or '.fba'}")
    atomic_write_bytes(out, minimal)
    doc = {
        "class": v.cls,
        "signature": v.signature,
        "message": (mv or v).message,
        "bytes_before": stats.bytes_before,
        "bytes_after": stats.bytes_after,
        "tests": stats.tests,
        "seconds": round(stats.seconds, 2),
        "reproduced": stats.reproduced,
        "flaky": stats.flaky,
        "minimal": str(out),
    }
    if args.json:
        print(json.dumps(doc, indent=1))
    else:
        flaky = "  FLAKY: does not repeat on a fresh process" if stats.flaky else ""
        print(
            f"{v.cls} ({v.signature}): {stats.bytes_before} -> {stats.bytes_after} bytes "
            f"({stats.tests} tests, {stats.seconds:.1f} s) -> {out}{flaky}"
        )
    return 1


def _entry(data: bytes, kind: InputKind):
    from .inputs import Entry

    return Entry(data, kind=kind, origin="minimise")


def _print_replay(v, args) -> int:
    if args.json:
        print(
            json.dumps(
                None
                if v is None
                else {"class": v.cls, "signature": v.signature, "message": v.message, "detail": v.detail},
                indent=1,
                default=str,
            )
        )
    elif v is None:
        print("no finding: the input is handled cleanly")
    else:
        print(f"{v.cls} ({v.signature}): {v.message}")
    return 0 if v is None else 1


def _decoder(args, expected: set[int]) -> int:
    from fbaconf.harness.adapters import resolve
    from fbaconf.isolation import forkserver_build

    from .corpus import default_seeds
    from .engine import FuzzConfig, Fuzzer
    from .findings import replay
    from .targets import DecoderTarget

    adapter = resolve(args.decoder, ceilings=ceilings_from(args))
    if args.output is None:
        args.output = Path("fbaconf-fuzz") / adapter.name
    out: Path = args.output.resolve()
    if args.target is None:
        args.target = _default_kind(adapter)
    if args.minimise_file is None:
        out.mkdir(parents=True, exist_ok=True)
    # minimising one file writes no run folder: its work folder is a temporary one
    work = Path(tempfile.mkdtemp(prefix="fuzz-work-", dir=None if args.minimise_file is not None else out))
    target = None
    try:
        seeds = default_seeds() + _extra_seeds(args.seeds)
        scene_stream = None
        if args.target == InputKind.SCENE:
            scene_stream = next((s.data for s in seeds if s.origin.startswith("seed:simple-l1-core")), seeds[0].data)
        target = DecoderTarget(
            adapter,
            work,
            kind=args.target,
            timeout_s=args.timeout,
            expected_exit=expected,
            oracle=not args.no_oracle,
            scene_stream=scene_stream,
            fork_server=not args.spawn,
            persistent=not args.spawn,
        )
        if args.replay is not None:
            v = replay(target, args.replay.read_bytes(), args.target)
            return _print_replay(v, args)
        if args.minimise_file is not None:
            return _minimise_file(target, args, tests=600)
        info = {
            "name": adapter.name,
            "manifest": str(adapter.manifest_path) if adapter.manifest_path else None,
            "mode": "persistent" if target.persistent else "fork-server" if target.fork_server else "spawn",
            **({"fork_server": forkserver_build.server_kind()} if target.fork_server and not target.persistent else {}),
            "manifest_sha256": adapter.digest(),
            "limits": {
                "timeout_s": target.limits.timeout_s,
                "memory_mb": target.limits.memory_mb,
                "memory_kind": target.limits.memory_kind,
                "output_mb": target.limits.output_mb,
            },
        }
        fz = Fuzzer(
            target,
            seeds,
            FuzzConfig(
                seed=args.seed,
                seconds=args.seconds,
                jobs=args.jobs,
                out_dir=out,
                kinds=(args.target,),
                progress=False if args.no_progress else None,
                minimise_seconds=args.minimise_seconds,
                max_execs=args.max_execs,
                coverage_every=args.coverage_every,
            ),
            decoder_info=info,
        )
        fz.run()
        return _finish(fz, out, args)
    finally:
        if target is not None:
            target.close()
        shutil.rmtree(work, ignore_errors=True)


def _finish(fz, out: Path, args) -> int:
    from .findings import write_summary

    doc = write_summary(out, fz)
    if args.json:
        print(json.dumps(doc, indent=1))
    else:
        c = doc["syntax_coverage"]
        print(
            f"{doc['execs']} inputs in {doc['fuzz_seconds']:.1f} s ({doc['execs_per_s']:,.0f} execs/s), "
            f"syntax coverage {c['covered']}/{c['total']}, {doc['findings']} finding(s) -> {out}"
        )
        for f in fz.findings.values():
            ms = f.min_stats
            size = f"{ms.bytes_before} -> {ms.bytes_after} bytes" if ms else f"{len(f.original.data)} bytes"
            print(f"  {f.id}: {f.verdict.cls} ({f.verdict.signature}) x{f.hits}, {size}: {f.verdict.message[:120]}")
    return 1 if fz.findings else 0


def _after_promotion(added: list[dict], args) -> list[str]:
    """What to do after ``--promote``: build the suite (and goldens), check the decoder on it, commit."""
    if not added:
        return ["nothing new: every finding is already a regression case (or none is a stream)"]
    from .findings import load_findings
    from .promote import REGRESSION_SUITE

    decoders = sorted(
        {str((doc.get("decoder") or {}).get("manifest") or "") for _d, doc in load_findings(args.promote)} - {""}
    )
    data = f"{args.data_dir}/" if args.data_dir else "conformance/data/"
    out = [
        "next:",
        f"  1. fbaconf suites build {REGRESSION_SUITE} --goldens   # the new case(s) join the suite, with goldens",
        f"  2. fbaconf run --decoder {decoders[0] if decoders else 'D.toml'} --suite {REGRESSION_SUITE}"
        "   # fails on them until the decoder is fixed",
        f"  3. commit {data}regression.toml, {data}regression/, conformance/suites/{REGRESSION_SUITE}/ and golden/",
    ]
    if args.data_dir:
        out.insert(
            1,
            f"  (the cases went to {args.data_dir}; `suites build` reads the package's conformance/data: "
            "copy them there first)",
        )
    return out
