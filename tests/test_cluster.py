"""Cases as Dask tasks (issue 19): the same verdicts as the local pool, and a worker lost
mid-run loses no case."""
from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest

from fbaconf.conformance.suite import load_suites
from fbaconf.harness import adapters, cluster
from fbaconf.harness.results import ResultLog
from fbaconf.harness.runner import run_cases

# Dask (distributed) is the optional extra fbaconf[cluster]; the test extras install it, so a
# missing Dask fails these tests (harness.cluster names the extra) rather than skipping them.


def some_cases(n: int):
    (s,) = load_suites(names=["simple-l1-core"])
    (e,) = load_suites(names=["simple-l1-error"])
    return s.cases[:n] + e.cases[:3]


def slow_manifest(tmp_path: Path) -> Path:
    script = tmp_path / "slow.py"
    script.write_text("import sys, time\ntime.sleep(0.4)\n"
                      "from fbaconf.pipeline import reference_outputs\n"
                      "try:\n    reference_outputs(sys.argv[1], faps_out=sys.argv[2])\n"
                      "except Exception as e:\n    print(e, file=sys.stderr); sys.exit(1)\n")
    m = tmp_path / "slow.toml"
    m.write_text('name = "slow"\nclaims = ["simple@1"]\ninputs = ["fba"]\noutputs = ["faps"]\nfaps_format = "npz"\n'
                 f'[commands]\ndecode = ["{{python}}", "{script}", "{{input}}", "{{faps_out}}"]\n')
    return m


@pytest.mark.parametrize("spec,expected", [("local", ("local", os.cpu_count() or 1)), ("local:3", ("local", 3)),
                                           ("tcp://10.1.2.3:8786", ("tcp", "tcp://10.1.2.3:8786"))])
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


def test_cluster_verdicts_equal_the_pool_and_a_lost_worker_loses_nothing(tmp_path):
    a = adapters.resolve(slow_manifest(tmp_path))
    cases = some_cases(8)
    pool = run_cases(a, cases, claim="simple@1", out_dir=tmp_path / "pool", jobs=2, progress=False)
    killed = []

    def kill_one_worker(_r):
        if not killed:
            workers = [p for p in _children() if b"spawn_main" in Path(f"/proc/{p}/cmdline").read_bytes()]
            if workers:
                os.kill(workers[0], signal.SIGKILL)
                killed.append(workers[0])

    dist = run_cases(a, cases, claim="simple@1", out_dir=tmp_path / "dask", progress=False, cluster="local:2",
                     on_result=kill_one_worker)
    assert killed, "a worker process was killed mid-run"
    assert [(r.case_id, r.outcome) for r in dist] == [(r.case_id, r.outcome) for r in pool]
    logged = ResultLog(tmp_path / "dask" / "results.jsonl").read()
    assert sorted(logged) == sorted(c.full_id for c in cases)
