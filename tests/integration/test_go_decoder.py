"""A Go decoder under the examples' limits: Go reserves hundreds of megabytes of
address space at start, so an address-space limit of 256 MB kills it before it reads a byte
("fatal error: failed to reserve page summary memory"). The default ``memory_kind = "tree"``
limits what the process tree uses (a cgroup limit where cgroups are writable): the decoder
runs, one that really uses more than the limit is a memory ending, and under an explicit
address-space limit the failure is a set-up problem naming the runtime's message and the fix:
per process ending (isolation/endings.py: what the fuzzer and the speed phase see), and for a
whole run one set-up error from the canary (isolation/setup.py), which proves the fix by decoding
the same stream without the address-space limit — no case counted, never a Fail.
Skipped where ``go`` is not installed (the build needs no network: the standard library only).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from fbaconf.harness import adapters
from fbaconf.harness.compare.ladder import outcome_for
from fbaconf.harness.results import Outcome
from fbaconf.isolation import cgroups, endings, sandbox

from lib.sandbox import needs_sandbox

GODEC = """package main

import (
	"bytes"
	"fmt"
	"os"
)

func main() {
	data, err := os.ReadFile(os.Args[1])
	if err != nil {
		fmt.Fprintln(os.Stderr, "godec:", err)
		os.Exit(2)
	}
	if bytes.Contains(data, []byte("HOG")) { // 1 GB, every page touched
		hog := make([][]byte, 0)
		for i := 0; i < 64; i++ {
			b := make([]byte, 16<<20)
			for j := range b {
				b[j] = byte(j)
			}
			hog = append(hog, b)
		}
		fmt.Println(len(hog))
	}
	fmt.Println("decoded", len(data))
}
"""


@pytest.fixture(scope="module")
def godec(tmp_path_factory) -> Path:
    go = shutil.which("go")
    if go is None:
        pytest.skip("go is not installed")
    d = tmp_path_factory.mktemp("godec")
    (d / "main.go").write_text(GODEC)
    (d / "go.mod").write_text("module godec\n\ngo 1.21\n")
    env = {**os.environ, "GOTOOLCHAIN": "local", "GOFLAGS": "-mod=mod", "CGO_ENABLED": "0"}
    r = subprocess.run(
        [go, "build", "-o", str(d / "godec"), "."], cwd=d, env=env, capture_output=True, text=True, timeout=900
    )
    assert r.returncode == 0, r.stderr
    (d / "godec.toml").write_text(
        'name = "godec"\nclaims = ["simple@1"]\ninputs = ["fba"]\noutputs = ["faps"]\n'
        '[commands]\ndecode = ["{manifest_dir}/godec", "{input}", "{faps_out}"]\n'
        "[limits]\ntimeout_s = 30\nmemory_mb = 256\n"
    )
    return d


def _run(godec: Path, tmp_path: Path, data: bytes, limits):
    case = tmp_path / "case"
    (case / "in").mkdir(parents=True, exist_ok=True)
    (case / "in" / "in.fba").write_bytes(data)
    argv = [str(godec / "godec"), str(case / "in" / "in.fba"), str(case / "out.fap")]
    res = sandbox.run(argv, case, limits)
    return res, endings.classify(res, limits)


def test_a_go_decoder_runs_under_the_default_limits(godec, tmp_path):
    a = adapters.load_manifest(godec / "godec.toml")
    assert (a.limits.memory_mb, a.limits.memory_kind) == (256, "tree")  # the manifest names no kind
    res, ending = _run(godec, tmp_path, b"\x00\x00\x01\xba" + bytes(60), a.limits)
    if "memory" not in cgroups.controllers():  # the fallback is an address-space limit: a set-up problem, named
        assert ending.kind == "setup" and "failed to reserve page summary memory" in ending.message
        assert 'memory_kind = \\"tree\\"' in ending.message or 'memory_kind = "tree"' in ending.message
        return
    assert ending.kind == "decoded", ending.message
    assert res.stdout_tail.strip() == "decoded 64"


def test_a_go_decoder_over_the_limit_is_a_memory_ending(godec, tmp_path):
    if "memory" not in cgroups.controllers():
        pytest.skip("no writable memory cgroup here: no whole-tree memory limit")
    a = adapters.load_manifest(godec / "godec.toml")
    res, ending = _run(godec, tmp_path, b"HOG" + bytes(60), a.limits)
    assert ending.kind == "memory", ending.message
    assert "256 MB whole-process-tree memory limit" in ending.message
    assert outcome_for(ending)[0] == Outcome.CRASH


def test_under_an_address_space_limit_the_runtime_is_named_with_the_fix(godec, tmp_path):
    m = godec / "godec-as.toml"
    m.write_text(
        (godec / "godec.toml").read_text().replace("memory_mb = 256", 'memory_mb = 256\nmemory_kind = "address-space"')
    )
    a = adapters.load_manifest(m)
    res, ending = _run(godec, tmp_path, b"\x00\x00\x01\xba" + bytes(60), a.limits)
    assert ending.kind == "setup", ending.message
    assert "fatal error: failed to reserve page summary memory" in ending.message
    assert "256 MB address-space limit" in ending.message and "memory_kind" in ending.message
    assert outcome_for(ending)[0] == Outcome.ERROR  # never the decoder's verdict on a stream


def test_a_run_under_an_address_space_limit_is_one_set_up_error_naming_gos_words_and_the_fix(godec, tmp_path):
    needs_sandbox()  # the canary's retry would run unisolated
    m = godec / "godec-as-run.toml"
    m.write_text(
        (godec / "godec.toml").read_text().replace("memory_mb = 256", 'memory_mb = 256\nmemory_kind = "address-space"')
    )
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "fbaconf",
            "run",
            "--decoder",
            str(m),
            "--case",
            "simple-l1-core/dct-q4",
            "-o",
            str(tmp_path / "run"),
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 2, r.stdout + r.stderr
    assert r.stderr.count("fbaconf run: error: ") == 1 and "godec cannot run as set up" in r.stderr
    assert "| fatal error: failed to reserve page summary memory" in r.stderr
    assert "it decodes the same stream without the address-space limit" in r.stderr
    assert not (tmp_path / "run" / "results.jsonl").exists()  # no case counted, no Fail
