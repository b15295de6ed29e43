"""Cases as Dask tasks: the same verdicts as the local pool, and a worker lost
mid-run loses no case."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import threading
from pathlib import Path

import pytest

from fbaconf.conformance.suite import load_suites
from fbaconf.errors import FbaconfInputError
from fbaconf.fuzz import campaign
from fbaconf.fuzz.campaign import ShardSpec, run_campaign
from fbaconf.harness import adapters, cluster
from fbaconf.harness.results import ResultLog
from fbaconf.harness.runner import run_cases
from fbaconf.isolation.bounds import Ceilings

from lib.manifests import python_decoder
from lib.procs import alive

# Dask (distributed) is the optional extra fbaconf[cluster]; the test extras install it, so a
# missing Dask fails these tests (harness.cluster names the extra) rather than skipping them.


def some_cases(n: int):
    (s,) = load_suites(names=["simple-l1-core"])
    (e,) = load_suites(names=["simple-l1-error"])
    return s.cases[:n] + e.cases[:3]


def slow_manifest(tmp_path: Path) -> Path:
    script = tmp_path / "slow.py"
    script.write_text(
        "import sys, time\ntime.sleep(0.4)\n"
        "from fbaconf.reference.pipeline import reference_outputs\n"
        "try:\n    reference_outputs(sys.argv[1], faps_out=sys.argv[2])\n"
        "except Exception as e:\n    print(e, file=sys.stderr); sys.exit(1)\n"
    )
    m = tmp_path / "slow.toml"
    m.write_text(
        'name = "slow"\nclaims = ["simple@1"]\ninputs = ["fba"]\noutputs = ["faps"]\nfaps_format = "npz"\n'
        f'[commands]\ndecode = ["{{python}}", "{script}", "{{input}}", "{{faps_out}}"]\n'
    )
    return m


@pytest.mark.parametrize(
    "spec,expected",
    [
        ("local", ("local", os.cpu_count() or 1)),
        ("local:3", ("local", 3)),
        ("tcp://10.1.2.3:8786", ("tls", "tls://10.1.2.3:8786")),
        ("tls://10.1.2.3:8786", ("tls", "tls://10.1.2.3:8786")),
    ],
)
def test_cluster_specs(spec, expected):
    assert cluster.parse(spec) == expected


@pytest.mark.parametrize("spec", ["locl:2", "local:0", "http://x:1", ""])
def test_bad_cluster_specs(spec):
    with pytest.raises(cluster.ClusterError):
        cluster.parse(spec)


def _children() -> list[int]:
    me = os.getpid()
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
                if int(fields[1]) == me:
                    out.append(int(d.name))
            except (OSError, IndexError, ValueError):
                pass
    return out


def _workers() -> list[int]:
    """The cluster's workers: children forked from this process (harness/cluster/local.py), so
    their command line is this one's."""
    me = Path("/proc/self/cmdline").read_bytes()
    out = []
    for p in _children():
        try:
            if Path(f"/proc/{p}/cmdline").read_bytes() == me:
                out.append(p)
        except OSError:
            pass
    return out


def test_cluster_verdicts_equal_the_pool_and_a_lost_worker_loses_nothing(tmp_path):
    a = adapters.resolve(slow_manifest(tmp_path))
    cases = some_cases(8)
    pool = run_cases(a, cases, claim="simple@1", out_dir=tmp_path / "pool", jobs=2, progress=False)
    killed = []

    def kill_one_worker(_r):
        if not killed:
            workers = _workers()
            if workers:
                os.kill(workers[0], signal.SIGKILL)
                killed.append(workers[0])

    dist = run_cases(
        a,
        cases,
        claim="simple@1",
        out_dir=tmp_path / "dask",
        progress=False,
        cluster="local:2",
        on_result=kill_one_worker,
    )
    assert killed, "a worker process was killed mid-run"
    assert [(r.case_id, r.outcome) for r in dist] == [(r.case_id, r.outcome) for r in pool]
    logged = ResultLog(tmp_path / "dask" / "results.jsonl").read()
    assert sorted(logged) == sorted(c.full_id for c in cases)


def test_fuzz_campaign_finds_the_planted_crash_once_and_survives_a_lost_worker(tmp_path, monkeypatch):
    """fuzz --cluster local:2: shards on two workers, one worker killed mid-round; the planted
    skip-chain crash is found, reported once (hits merged across shards), minimised once; and
    no fork server of any shard (the killed worker's included) outlives the campaign."""

    if shutil.which("gcc") is None:
        pytest.skip("gcc not available")
    here = Path(__file__).resolve().parents[1] / "fuzz_decoders"
    subprocess.run(["gcc", "-O1", "-o", str(tmp_path / "skipchain"), str(here / "skipchain.c")], check=True)
    m = tmp_path / "skipchain.toml"
    m.write_text(
        'name = "planted-skipchain"\nclaims = ["simple@1"]\ninputs = ["fba"]\noutputs = ["faps"]\n'
        'faps_format = "fap"\n[commands]\ndecode = ["{manifest_dir}/skipchain", "{input}", "{faps_out}"]\n'
        "[limits]\ntimeout_s = 2\nmemory_mb = 256\noutput_mb = 16\n"
    )
    killed = []
    # the workers' shard folders (tempfile) under tmp_path: their servers' command lines name it
    (tmp_path / "tmp").mkdir()
    monkeypatch.setenv("TMPDIR", str(tmp_path / "tmp"))

    servers, done = [0], threading.Event()

    def count_servers():  # the most shard servers seen at once while the campaign runs
        while not done.wait(0.25):
            servers[0] = max(servers[0], len(alive(str(tmp_path))))

    def kill_one_worker():
        workers = _workers()
        if workers:
            os.kill(workers[0], signal.SIGKILL)
            killed.append(workers[0])

    with cluster.client("local:2") as c:
        timer = threading.Timer(4.0, kill_one_worker)
        timer.start()
        threading.Thread(target=count_servers, daemon=True).start()
        camp, findings = run_campaign(
            c,
            ShardSpec(str(m), timeout_s=1.0),
            workers=2,
            seconds=8,
            seed=5,
            out=tmp_path / "out",
            minimise_seconds=5,
            progress=lambda _m: None,
        )
        timer.cancel()
        done.set()
    assert killed, "a worker was killed mid-round"
    assert camp.shards == 2  # the lost worker's shard was rerun, not lost nor counted twice
    crashes = [f for f in findings if f.verdict.cls == "crash" and "SIGSEGV" in f.verdict.signature]
    assert len(crashes) == 1 == len({f.verdict.key for f in findings})
    doc = json.loads((crashes[0].path / "finding.json").read_text())
    assert doc["minimal"]["bytes"] < doc["original"]["bytes"]
    assert len(list((tmp_path / "out" / "findings").iterdir())) == len(findings)
    assert servers[0] >= 1  # the shards' servers were counted while they ran
    assert alive(str(tmp_path), grace_s=5.0) == []


def test_a_fuzz_campaigns_workers_read_the_manifest_under_the_labs_ceilings(tmp_path):
    """A manifest asking for more than the default ceilings, allowed by the lab's --max-timeout-s,
    is read the same way in every worker (before, a worker re-read it under the defaults and
    refused it)."""
    m = python_decoder(tmp_path, "slowpoke", "sys.exit(0)\n", limits="timeout_s = 700")
    with pytest.raises(FbaconfInputError, match="700"):
        campaign._target(ShardSpec(str(m)), tmp_path / "default")
    t = campaign._target(ShardSpec(str(m), ceilings=Ceilings(timeout_s=800)), tmp_path / "raised")
    try:
        assert t.adapter.limits.timeout_s == 700
    finally:
        t.close()
