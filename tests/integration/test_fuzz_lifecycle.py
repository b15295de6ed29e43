"""Every fork server and persistent decoder a fuzz run starts is stopped when the run ends, in
this process too: the processes are counted on the machine, by the test's own
folder in their command lines (the server's copy under the work folder, the decoder's path),
after a run, after a replay, after a target used on its own, and after a cluster campaign
(tests/integration/test_cluster.py counts those)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from fbaconf.fuzz.corpus import default_seeds
from fbaconf.fuzz.engine import FuzzConfig, Fuzzer
from fbaconf.fuzz.findings import replay
from fbaconf.fuzz.targets import DecoderTarget
from fbaconf.harness.adapters import load_manifest

from lib.procs import alive

HERE = Path(__file__).resolve().parents[1] / "fuzz_decoders"


def skipchain(tmp_path: Path, serve: bool):
    if shutil.which("gcc") is None:
        pytest.skip("gcc not available")
    subprocess.run(["gcc", "-O1", "-o", str(tmp_path / "skipchain"), str(HERE / "skipchain.c")], check=True)
    m = tmp_path / "skipchain.toml"
    m.write_text(
        'name = "planted-skipchain"\nclaims = ["simple@1"]\ninputs = ["fba"]\noutputs = ["faps"]\n'
        'faps_format = "fap"\n[commands]\ndecode = ["{manifest_dir}/skipchain", "{input}", "{faps_out}"]\n'
        + ('serve = ["{manifest_dir}/skipchain", "--serve"]\n' if serve else "")
        + "[limits]\ntimeout_s = 2\nmemory_mb = 256\noutput_mb = 16\n"
    )
    return load_manifest(m)


@pytest.mark.parametrize("mode", ["fork-server", "persistent"])
def test_a_fuzz_run_a_replay_and_a_lone_target_leave_no_server(tmp_path, mode):
    tag = str(tmp_path)
    adapter = skipchain(tmp_path, serve=mode == "persistent")
    target = DecoderTarget(adapter, tmp_path / "work", timeout_s=1.0)
    assert (target.persistent, target.fork_server) == (mode == "persistent", True)
    during = []
    fz = Fuzzer(
        target,
        default_seeds(),
        FuzzConfig(
            seed=1,
            seconds=120,
            jobs=2 if mode == "fork-server" else 1,
            progress=False,
            max_execs=300,
            minimise_seconds=2,
            run_seeds_first=0,
            valid_pool=4,
        ),
        stop_on=lambda f: f.verdict.cls == "crash",
    )
    record = fz._record

    def counting(i, inp, out, dl):
        if i == 3:
            during.append(len(alive(tag)))
        return record(i, inp, out, dl)

    fz._record = counting
    fz.run()
    assert during and during[0] >= 1, "no server was running during the run: the test would prove nothing"
    assert alive(tag) == []  # the run stopped its servers (and the crashed ones' replacements)
    crash = next(f for f in fz.findings.values() if f.verdict.cls == "crash")
    assert replay(target, crash.minimal).key == crash.verdict.key
    assert alive(tag) == []  # a replay is a run of its own
    with DecoderTarget(adapter, tmp_path / "lone", timeout_s=1.0) as lone:
        assert lone.execute(default_seeds()[0]).verdict is None
        assert alive(tag)
    assert alive(tag) == []  # a target used on its own stops its server when its block ends
