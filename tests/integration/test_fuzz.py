"""The fuzzer: syntax model, generators and mutators, minimiser, classification, and
acceptance: three planted-bug decoders (an out-of-bounds write on a large skip chain in C, a
hang on a zero frame rate, an allocation from an unchecked time code) are each found,
classified and minimised from the conformance seed corpus; our own parsers give no finding;
a promoted finding fails the buggy decoder and passes the reference.

The acceptance runs here are bounded by input counts (deterministic for a seed) rather than
wall time, so they take a few seconds each on a loaded machine; the full 60-s runs are in
docs/fuzzing.md.
"""

from __future__ import annotations

import dataclasses
import json
import random
import shutil
import subprocess
import textwrap
import time
import tomllib
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from fbaconf.bitstreams import bitedit
from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.encoder import EncoderOptions, encode
from fbaconf.bitstreams.synth import synthetic_sequence
from fbaconf.cli import main
from fbaconf.conformance.suite import Case
from fbaconf.errors import BitstreamError, FbaconfInputError
from fbaconf.fuzz import model, strategies
from fbaconf.fuzz.atheris_entry import fuzz_one_input
from fbaconf.fuzz.corpus import default_seeds, short_prefixes
from fbaconf.fuzz.engine import FuzzConfig, Fuzzer
from fbaconf.fuzz.features_ahead import FeaturesAhead
from fbaconf.fuzz.findings import replay, write_summary
from fbaconf.fuzz.inputs import Entry, InputKind
from fbaconf.fuzz.minimise import minimise
from fbaconf.fuzz.model import features_of, stream_model
from fbaconf.fuzz.mutators import FIELD_MUTATORS, m_skip_chain, m_zero_frame_rate, mutate_stream
from fbaconf.fuzz.promote import REGRESSION_SUITE, promote
from fbaconf.fuzz.selftarget import SelfTarget
from fbaconf.fuzz.targets import DecoderTarget, ExecResult, stack_hash
from fbaconf.harness.adapters import load_manifest, resolve
from fbaconf.harness.compare import compare_faps
from fbaconf.harness.results import Outcome
from fbaconf.harness.runner import run_cases
from fbaconf.profiles.checker import check_stream
from fbaconf.scenes import bt

HERE = Path(__file__).resolve().parents[1] / "fuzz_decoders"
SET = settings(max_examples=8, deadline=None, suppress_health_check=list(HealthCheck))


@pytest.fixture(scope="module")
def seeds() -> list[Entry]:
    return default_seeds()


# ------------------------------------------------------------------ bits and syntax model


@SET
@given(st.binary(min_size=1, max_size=40), st.integers(0, 10**6), st.integers(1, 20), st.integers(0, 2**20))
def test_bit_helpers_match_a_text_oracle(data, at, n, value):
    """The integer bit helpers against the obvious '0'/'1' string implementation."""
    bits = "".join(f"{b:08b}" for b in data)

    def pack(s: str) -> bytes:
        s += "0" * (-len(s) % 8)
        return bytes(int(s[i : i + 8], 2) for i in range(0, len(s), 8))

    nb = len(data) * 8
    at = at % nb
    value &= (1 << n) - 1
    v = format(value, f"0{n}b")
    assert bitedit.insert_bits(data, at, value, n) == pack(bits[:at] + v + bits[at:])
    assert bitedit.remove_bits(data, at, n) == pack(bits[:at] + bits[at + n :])
    assert bitedit.truncate_bits(data, at) == pack(bits[:at])
    if at + n <= nb:
        assert bitedit.set_bits(data, at, n, value) == pack(bits[:at] + v + bits[at + n :])
        assert bitedit.get_bits(data, at, n) == int(bits[at : at + n], 2)


def test_syntax_model_locates_header_fields():
    fr = synthetic_sequence(4, 25.0, faps=[3, 4, 19])
    fr.frame_number[:] = [0, 1, 40, 41]  # a skip chain of 38 frames before the third plane
    data = encode(fr, EncoderOptions(time_codes=True, plane_start_codes="all")).data
    m = stream_model(data)
    assert m.error_rule is None and len(m.planes) == 4
    (rate,) = m.fields_named("frame_rate")
    assert rate.value == 25 and bitedit.get_bits(data, rate.offset, 8) == 25
    chunks = [f for f in m.fields_named("number_of_frames_to_skip") if f.plane == 2]
    assert [c.value for c in chunks] == [15, 15, 8]
    assert len(m.fields_named("plane_start_code")) == 4
    assert len(m.fields_named("list_value")) == sum(len(v) for p in m.planes for v in p.new_lists.values())
    assert {"plane:skip-chain", "plane:time-code", "plane:start-code", "stream:end-code"} <= m.features
    # the zero-frame-rate and skip-chain mutators hit exactly those fields
    rng = random.Random(3)
    z = m_zero_frame_rate(random.Random(0), Entry(data), [])
    with pytest.raises(BitstreamError) as e:
        decode(z)
    assert e.value.rule == "frame-rate-zero"
    long = m_skip_chain(rng, Entry(data), [])
    assert max(p.skip for p in stream_model(long).planes) >= 15


def test_every_mutator_yields_typed_errors_only(seeds):
    corpus = seeds[:6]
    rng = random.Random(8)
    names = set()
    for i in range(240):
        e = corpus[i % len(corpus)]
        data, how = mutate_stream(rng, e, corpus, native=False)
        names.update(how.split("+"))
        try:
            decode(data)
        except BitstreamError as err:
            assert err.rule != "internal", (how, err)
    assert set(FIELD_MUTATORS) <= names


@SET
@given(strategies.valid_entries())
def test_generated_streams_are_valid_and_round_trip(e):
    got = decode(e.data).frames
    assert compare_faps(e.recon, got, text_output=False).outcome.ok


@SET
@given(strategies.valid_streams())
def test_valid_streams_pass_the_checker(data):
    """The public bytes strategy: every stream starts with the face object start code (spec
    notes: 0x000001BA) and the checker finds no error in it."""
    assert data[:4] == bytes.fromhex("000001BA")
    assert [d.code for d in check_stream(data) if d.severity == "error"] == []


@SET
@given(strategies.near_valid_streams())
def test_near_valid_streams_only_typed_errors(data):
    target = SelfTarget(checker_every=1)
    assert target.execute(Entry(data)).verdict is None


@SET
@given(strategies.bt_scenes(mutated=True))
def test_scene_reader_typed_errors_only(text):
    try:
        bt.parse(text)
    except FbaconfInputError:
        pass


def test_bt_integer_with_leading_zero():
    """Found by `fbaconf fuzz --self`: '01' escaped the BT reader as a ValueError."""
    n = bt.parse("Face { fit FIT { FAPs [01 -007 0x1F] } }").nodes[0].fields["fit"].fields["FAPs"]
    assert list(n) == [1, -7, 31]


# ------------------------------------------------------------------ minimiser, classification


def test_minimise_finds_the_trigger():
    data = bytes(range(200)) + b"\xde\xad" + bytes(100)
    best, stats = minimise(data, lambda d: b"\xde\xad" in d, max_tests=2000)
    assert best == b"\xde\xad" and stats.tests < 400


def test_stack_hash_kinds():
    asan = (
        "==1==ERROR: AddressSanitizer: heap-buffer-overflow on address 0x1\n"
        "    #0 0x4005 in plane /src/dec.c:40\n    #1 0x4006 in main /src/dec.c:80\n"
    )
    py = 'Traceback (most recent call last):\n  File "/x/dec.py", line 3, in f\n    g()\nIndexError: list index'
    assert stack_hash(asan)[0] == "AddressSanitizer heap-buffer-overflow"
    assert stack_hash(py)[0] == "uncaught Python exception IndexError"
    assert stack_hash(asan)[1] != stack_hash(asan.replace("plane", "other"))[1]
    assert stack_hash("just an error message") is None


def test_self_fuzz_no_findings_and_entry(tmp_path, seeds):
    target = SelfTarget(checker_every=8, scene_stream=seeds[0].data)
    fz = Fuzzer(
        target,
        seeds + short_prefixes(seeds[:4]),
        FuzzConfig(
            seed=5,
            seconds=60,
            max_execs=400,
            kinds=("stream", "stream", "scene", "bifs"),
            progress=False,
            out_dir=tmp_path,
        ),
    )
    st_ = fz.run()
    assert st_.execs == 400 and not fz.findings, [f.verdict.message for f in fz.findings.values()]
    doc = write_summary(tmp_path, fz)
    assert doc["syntax_coverage"]["covered"] > 30
    rng = random.Random(1)
    for sel in range(8):
        fuzz_one_input(bytes([sel]) + bytes(rng.randrange(256) for _ in range(40)))
    fuzz_one_input(bytes([0]) + seeds[0].data)


def test_same_seed_same_inputs(seeds):
    a = Fuzzer(SelfTarget(), seeds, FuzzConfig(seed=11, progress=False, valid_pool=2))
    b = Fuzzer(SelfTarget(), seeds, FuzzConfig(seed=11, progress=False, valid_pool=2))
    assert [a.make_input(i).data for i in range(60, 90)] == [b.make_input(i).data for i in range(60, 90)]


def test_fresh_streams_from_the_helper_are_the_loops_own(seeds):
    """The helper process encodes the run's fresh valid streams ahead of the loop: every one it
    hands over is the stream the loop makes itself for that input (a run replays with or without
    it), and a helper that dies leaves the loop to make them, the same again."""
    with_helper = Fuzzer(SelfTarget(), seeds, FuzzConfig(seed=3, progress=False, valid_pool=2, fresh_helper=True))
    alone = Fuzzer(SelfTarget(), seeds, FuzzConfig(seed=3, progress=False, valid_pool=2, fresh_helper=False))
    fresh = [i for i in range(600) if with_helper._fresh_wanted(i)]
    assert len(fresh) > 10  # ~4 % of the inputs after the seeds
    fs = with_helper.fresh
    fs.helper = True  # whatever this machine's CPUs: the helper is what is tested
    try:
        got = {}
        for i in fresh[:-6]:
            e = fs.take(i)
            got[i] = e.data
            while fs.proc is not None and fs.queue and fs.queue[0] <= i + 40:  # let it run ahead
                fs._drain(1.0)
        assert fs.proc is not None, "the helper did not start"
        from_helper = len(fs.ready)
        assert from_helper > 0, "nothing made ahead"
        fs.proc.kill()
        fs.proc.wait()
        for i in fresh[-6:]:
            got[i] = fs.take(i).data
        assert fs.proc is None  # a dead helper is noticed and let go
    finally:
        fs.close()
    assert got == {i: alone.make_input(i).data for i in fresh}


def test_the_fresh_stream_helper_lives_as_long_as_the_run(seeds):
    """The helper starts with a run and is gone (killed and reaped) when it ends; inputs made
    outside a run (a finding regenerated) start none."""
    config = FuzzConfig(seed=2, seconds=120, max_execs=150, progress=False, valid_pool=2, run_seeds_first=0)
    fz = Fuzzer(SelfTarget(), seeds, config)
    fz.fresh_helper = True  # whatever this machine's CPUs and the run's length
    assert sum(map(fz._fresh_wanted, range(150))) >= 3  # the run has fresh streams to make
    pids: list[int] = []
    record = fz._record

    def watching(i, inp, out, dl):
        if fz.fresh.proc is not None and not pids:
            pids.append(fz.fresh.proc.pid)
        return record(i, inp, out, dl)

    fz._record = watching
    fz.run()
    assert pids, "the helper never ran: the test would prove nothing"
    assert not Path(f"/proc/{pids[0]}").exists()
    for i in range(fz.stats.execs, fz.stats.execs + 200):
        fz.make_input(i)
    assert fz.fresh.proc is None


class _Accepts:
    """A decoder target that accepts every input after half a millisecond (the loop measures the
    coverage of what it sends, unlike --self's)."""

    name = "accepts"

    def execute(self, inp):
        time.sleep(0.0005)
        return ExecResult(None)


def test_coverage_from_the_helper_is_the_loops_own(seeds):
    """The coverage of the inputs the loop parses for it alone is measured ahead by a helper
    process: the same features input for input, so the same corpus and run with or without it
    (and the helper is gone once the run ends)."""
    runs = {}
    for helper in (True, False):
        # both runs start alike: no seed's model and no reference parse at hand from earlier tests
        model._PARSES.clear()
        fresh_seeds = [dataclasses.replace(e, model=None) for e in seeds]
        config = FuzzConfig(seed=5, max_execs=1600, progress=False, valid_pool=2, coverage_every=4)
        fz = Fuzzer(_Accepts(), fresh_seeds, config)
        fz.features_helper = helper  # whatever this machine's CPUs: the helper is what is tested
        taken = fz.features.take
        pids: list[int] = []

        def watching(index, data, taken=taken, fz=fz, pids=pids):
            if fz.features.proc is not None and not pids:
                pids.append(fz.features.proc.pid)
            return taken(index, data)

        fz.features.take = watching
        fz.run()
        runs[helper] = (fz.stats.features, fz.stats.measured, [e.data for e in fz.corpus[InputKind.STREAM]])
        if helper:
            assert pids and fz.features.from_helper > 50, "the helper measured nothing: the test would prove nothing"
            assert not Path(f"/proc/{pids[0]}").exists()
        else:
            assert fz.features.from_helper == 0
    assert runs[True] == runs[False]


def test_a_dead_coverage_helper_leaves_the_loop_to_parse(seeds):
    """Killed mid-run, the helper is let go and the loop parses the inputs itself: the same
    features as a parse here gives."""
    fa = FeaturesAhead(helper=True)
    data = [e.data for e in seeds if len(e.data) < 4096][:40]
    try:
        for i, d in enumerate(data[:20]):
            fa.ask(i, d)
        assert fa.proc is not None, "the helper did not start"
        got = [fa.take(i, d) for i, d in enumerate(data[:20])]
        fa.proc.kill()
        fa.proc.wait()
        for i, d in enumerate(data[20:], start=20):
            fa.ask(i, d)
            got.append(fa.take(i, d))
        assert fa.proc is None
    finally:
        fa.close()
    assert got == [features_of(d) for d in data]


# ------------------------------------------------------------------ planted-bug decoders


def _planted(name: str, tmp_path: Path):
    if name == "skipchain":
        if shutil.which("gcc") is None:
            pytest.skip("gcc not available")
        exe = tmp_path / "skipchain"
        subprocess.run(["gcc", "-O1", "-o", str(exe), str(HERE / "skipchain.c")], check=True)
        (tmp_path / "skipchain.toml").write_text(
            'name = "planted-skipchain"\nclaims = ["simple@1"]\ninputs = ["fba"]\noutputs = ["faps"]\n'
            'faps_format = "fap"\n[commands]\ndecode = ["{manifest_dir}/skipchain", "{input}", "{faps_out}"]\n'
            "[limits]\ntimeout_s = 2\nmemory_mb = 256\noutput_mb = 16\n"
        )
        return load_manifest(tmp_path / "skipchain.toml")
    return load_manifest(HERE / f"{name}.toml")


def _fuzz_planted(
    name: str, tmp_path: Path, seeds, max_execs: int, cls: str | None = None, jobs: int = 2, serve: bool = False
):
    adapter = _planted(name, tmp_path)
    if serve:  # the same program through the persistent protocol (skipchain --serve)
        p = Path(adapter.manifest_path)
        p.write_text(p.read_text().replace("[limits]", 'serve = ["{manifest_dir}/skipchain", "--serve"]\n[limits]'))
        adapter = load_manifest(p)
    out = tmp_path / "out"
    target = DecoderTarget(adapter, tmp_path / "work", timeout_s=1.0)
    assert target.persistent == serve
    fz = Fuzzer(
        target,
        seeds,
        FuzzConfig(
            seed=1,
            seconds=120,
            jobs=jobs,
            out_dir=out,
            progress=False,
            max_execs=max_execs,
            # a budget of tests, not seconds: the machine's load must not decide whether a finding
            # gets shorter (the seconds only stop a decoder that hangs on every candidate)
            minimise_tests=40,
            minimise_seconds=120,
            run_seeds_first=0,
            valid_pool=4,
        ),
        decoder_info={"name": adapter.name, "manifest": str(adapter.manifest_path)},
        stop_on=lambda f: f.verdict.cls == cls,
    )
    fz.run()
    write_summary(out, fz)
    return fz, target, out


# input budgets: the run stops at the first finding of the class (typically within 30 inputs). A
# zero frame rate (hangdec) is about 3 % of the inputs: 300 leave a miss at about 1e-4
PLANTED = [
    ("skipchain", "crash", "SIGSEGV", 300),
    ("hangdec", "hang", "timeout", 300),
    ("allocdec", "memory", "memory-limit", 300),
]


@pytest.fixture(scope="module")
def skipchain_run(tmp_path_factory, seeds):
    tmp = tmp_path_factory.mktemp("skipchain")
    return _fuzz_planted("skipchain", tmp, seeds, 300, "crash") + (tmp,)


def test_a_decoder_slowed_past_its_timeout_is_not_a_hang(tmp_path, seeds):
    """A timeout is confirmed before it becomes a finding: the input alone, with four times the
    limit. A decoder that takes 0.8 s under a 0.5 s limit (as a loaded machine makes a fast one)
    finishes then — no finding, counted as the machine's; hangdec, which loops forever, is still
    found (test_planted_bug_found_classified_minimised)."""
    (tmp_path / "slow.py").write_text("import sys, time\ntime.sleep(0.8)\nsys.exit(1)\n")
    (tmp_path / "slow.toml").write_text(
        'name = "slow"\nclaims = ["simple@1"]\ninputs = ["fba"]\noutputs = ["faps"]\nfaps_format = "fap"\n'
        "reject_exit_codes = [1]\n[commands]\n"
        'decode = ["{python}", "-I", "-S", "{manifest_dir}/slow.py", "{input}", "{faps_out}"]\n'
        "[limits]\ntimeout_s = 0.5\nmemory_mb = 256\noutput_mb = 16\n"
    )
    target = DecoderTarget(load_manifest(tmp_path / "slow.toml"), tmp_path / "work")
    fz = Fuzzer(target, seeds[:2], FuzzConfig(seed=1, seconds=60, jobs=1, progress=False, max_execs=2))
    fz.run()
    assert not fz.findings and fz.stats.slow_not_hung == 2


@pytest.mark.parametrize("name,cls,sig,execs", PLANTED[1:])
def test_planted_bug_found_classified_minimised(name, cls, sig, execs, tmp_path, seeds):
    fz, target, out = _fuzz_planted(name, tmp_path, seeds, execs, cls)
    _check_planted(fz, target, out, cls, sig)


def test_planted_skipchain_crash(skipchain_run):
    fz, target, out, _tmp = skipchain_run
    _check_planted(fz, target, out, "crash", "SIGSEGV")


def test_planted_skipchain_crash_persistent(tmp_path, seeds):
    """The same planted crash through the persistent protocol, one input at a time: found,
    attributed to the input that killed the process, minimised (each minimisation test
    restarts the server after the crash) and replayable."""
    fz, target, out = _fuzz_planted("skipchain", tmp_path, seeds, 300, "crash", jobs=1, serve=True)
    _check_planted(fz, target, out, "crash", "SIGSEGV")


def test_one_at_a_time_runs_replay_exactly(tmp_path, seeds):
    """One decoder at a time, inputs are queued to the fork server ``depth`` deep while the loop
    makes the next ones; the corpus still grows in input order, so two runs of one seed record
    the same inputs, grow the same corpus and find the same findings at the same inputs."""
    runs = []
    for k in range(2):
        (tmp_path / f"r{k}").mkdir()
        adapter = _planted("skipchain", tmp_path / f"r{k}")
        target = DecoderTarget(adapter, tmp_path / f"w{k}", timeout_s=1.0)
        assert target.depth > 2
        recorded = []
        fz = Fuzzer(
            target,
            seeds,
            FuzzConfig(
                seed=5,
                seconds=120,
                progress=False,
                max_execs=160,
                minimise_findings=False,
                run_seeds_first=0,
                valid_pool=4,
            ),
        )
        record = fz._record
        fz._record = lambda i, inp, out, dl: (recorded.append((i, inp.data)), record(i, inp, out, dl))
        fz.run()
        assert [i for i, _d in recorded] == list(range(160))  # each input recorded once, in order
        runs.append(
            (recorded, [e.data for e in fz.new_corpus], sorted((f.index, f.verdict.key) for f in fz.findings.values()))
        )
    assert runs[0] == runs[1]
    assert runs[0][1] and runs[0][2]  # the corpus grew and the planted crash was found


def _check_planted(fz, target, out: Path, cls: str, sig: str):
    found = [f for f in fz.findings.values() if f.verdict.cls == cls and f.verdict.signature == sig]
    assert found, {f.id: f.verdict.message for f in fz.findings.values()}
    f = found[0]
    assert f.minimal is not None and len(f.minimal) < len(f.original.data)
    doc = json.loads((f.path / "finding.json").read_text())
    assert doc["class"] == cls and doc["minimal"]["bytes"] == len(f.minimal)
    assert (f.path / "original.fba").read_bytes() == f.original.data
    assert "--replay" in doc["reproduce"]["fbaconf"] and doc["reproduce"]["command"]
    assert replay(target, f.minimal).key == f.verdict.key  # the minimal input reproduces it
    assert fz.make_input(f.index, f.original.corpus_size).data == f.original.data  # seed + index regenerate it
    assert json.loads((out / "fuzz.json").read_text())["findings"] == len(fz.findings)


def test_promoted_finding_fails_buggy_decoder_passes_reference(skipchain_run, tmp_path):
    fz, target, out, tmp = skipchain_run
    data_dir = tmp_path / "data"
    added = promote(out, data_dir, log=lambda s: None)
    crash = [c for c in added if "crash" in c["id"]]
    assert crash
    spec = tomllib.loads((data_dir / "regression.toml").read_text())
    assert spec["suite"][0]["name"] == REGRESSION_SUITE
    c = next(x for x in spec["case"] if x["id"] == crash[0]["id"])
    data = (data_dir / c["file"]).read_bytes()
    assert c["generator"] == "file"
    assert promote(out, data_dir, log=lambda s: None) == []  # idempotent
    if crash[0]["valid"]:
        # a valid stream that crashes the decoder (a skip chain the reference decodes): a decode case,
        # whose golden `fbaconf golden regenerate` makes from the reference's output
        assert "expect" not in c
        assert replay(target, data).cls == "crash"
        decode(data)  # the reference accepts it
        # the error-case path with the same crash behind an invalid end: the last byte cut (the
        # stream ends inside its last block; the decoder crashes on the first plane's header)
        data = data[:-1]
        expect = sorted({d.code for d in check_stream(data, claim="simple@1") if d.severity == "error"})
        assert expect and replay(target, data).cls == "crash"
    else:
        expect = c["expect"]
        assert isinstance(expect, list) and expect
    # the case as build.py makes it (generator = "file" with expect: an error case)
    suite_dir = tmp_path / "suite"
    suite_dir.mkdir()
    (suite_dir / f"{c['id']}.fba").write_bytes(data)
    case = Case(
        id=c["id"],
        suite=REGRESSION_SUITE,
        claim="simple@1",
        group="error",
        kind="error",
        inputs={"fba": f"{c['id']}.fba"},
        expect={"diagnostics": expect},
        suite_dir=suite_dir,
    )
    bad = run_cases(target.adapter, [case], claim="simple@1", out_dir=tmp_path / "run-bad", jobs=1, progress=False)
    ref = run_cases(
        resolve("reference-inprocess"), [case], claim="simple@1", out_dir=tmp_path / "run-ref", jobs=1, progress=False
    )
    assert bad[0].outcome == Outcome.CRASH, bad[0].message
    assert ref[0].outcome == Outcome.PASS, ref[0].message


def test_cli(tmp_path):
    assert (
        main(["fuzz", "--self", "--seconds", "30", "--max-execs", "60", "-o", str(tmp_path / "s"), "--no-progress"])
        == 0
    )
    doc = json.loads((tmp_path / "s" / "fuzz.json").read_text())
    assert doc["execs"] == 60 and doc["findings"] == 0
    assert main(["fuzz", "--promote", str(tmp_path / "s"), "--data-dir", str(tmp_path / "d")]) == 2
    (tmp_path / "x.bt").write_text("Face { fit FIT { FAPs [01] } }")
    assert main(["fuzz", "--self", "--replay", str(tmp_path / "x.bt")]) == 0


def test_relative_work_folder_gives_no_bogus_finding(tmp_path, monkeypatch, seeds):
    """A relative -o used to make every command decoder miss its input (a bogus finding)."""
    monkeypatch.chdir(tmp_path)
    with DecoderTarget(resolve("reference"), Path("rel-work")) as target:  # its server stops at the end
        assert target.execute(seeds[0]).verdict is None


def test_text_fuzzing_finds_a_players_crash_and_a_copier(tmp_path):
    """Players (decoders that read only .fap text) are fuzzed with .fap text: a player that
    dies on a comment line is a crash finding; one that copies its input is wrong output."""
    crashy = tmp_path / "crashy.py"
    crashy.write_text(
        textwrap.dedent("""\
        import sys
        import numpy as np
        from fbaconf.bitstreams.faptext import read_fap_file, write_fap_file
        from fbaconf.bitstreams.frames import RETAINED, SET
        if b"#" in open(sys.argv[1], "rb").read():
            raise RuntimeError("comment lines are not handled")
        f = read_fap_file(sys.argv[1])[0]
        f.status[:] = np.where(f.status == RETAINED, SET, f.status)
        write_fap_file(sys.argv[2], f)
        """)
    )
    for name, argv, cls in (
        ("crashy", f'"{{python}}", "{crashy}", "{{input}}", "{{faps_out}}"', "crash"),
        ("copier", '"/bin/cp", "{input}", "{faps_out}"', "wrong-output"),
    ):
        m = tmp_path / f"{name}.toml"
        m.write_text(
            f'name = "{name}"\nclaims = ["simple@1"]\ninputs = ["fap"]\noutputs = ["faps"]\n'
            f'faps_format = "fap"\n[commands]\ndecode = [{argv}]\n'
        )
        target = DecoderTarget(load_manifest(m), tmp_path / f"w-{name}", kind="text")
        fz = Fuzzer(
            target,
            [],
            FuzzConfig(
                seed=3,
                seconds=60,
                max_execs=300,
                kinds=("text",),
                progress=False,
                out_dir=tmp_path / f"o-{name}",
                minimise_seconds=2,
            ),
            stop_on=lambda f: True,
        )
        fz.run()
        assert any(f.verdict.cls == cls for f in fz.findings.values()), (
            name,
            [f.verdict.cls for f in fz.findings.values()],
        )
