"""Speed measurement (harness/speed/measure.py, `fbaconf bench`): the fit against a known start-up and
per-frame cost, verdicts against the level minimums — pass, fail, and inconclusive when the
machine did not give the decoder its CPU — exit codes.

No test here depends on how fast or how busy this machine is, but one: where a verdict depends
on the measured time, every run of the real decoder still happens (its output is checked), but
the seconds it reports and the machine's counters around it are a synthetic clock's and a
:class:`FakeMachine`'s, so the fit, the adaptive lengths and the verdicts are exact. The one
real run under busy loops (``test_a_saturated_machine_...``) asserts only what load cannot
change. The measurement against real time is ``benchmarks/bench_harness_speed.py``."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import jsonschema
import numpy as np
import pytest

from fbaconf.animation.engine import animate
from fbaconf.bitstreams.decoder import decode
from fbaconf.certification.certify import _statement
from fbaconf.certification.package import derive_verdict
from fbaconf.cli import main
from fbaconf.harness import sysinfo
from fbaconf.harness.adapters import PythonAdapter, load_manifest
from fbaconf.harness.reports import html_report, report_json, terminal_summary
from fbaconf.harness.results import RunRecord
from fbaconf.harness.speed import load as speed_load, measure as speed
from fbaconf.harness.speed.check import images_problem
from fbaconf.harness.speed.content import BLOCK_FRAMES, Content
from fbaconf.harness.speed.runs import DECODE_IMAGE_SIZE, RENDER_SUPERSAMPLE
from fbaconf.harness.sysinfo import MachineSample
from fbaconf.harness.verdict import speed_verdict
from fbaconf.rendering.render import render_frames
from fbaconf.rendering.scenario import Scenario

from lib.manifests import write_manifest

# A decoder whose cost is known: sleeps STARTUP, then PER_FRAME x frames (the frame count comes
# from the {frames} placeholder, so counting frames costs nothing), then writes its output —
# the reference decoding (the speed check compares a sample of frames with it).
DECODER = textwrap.dedent("""\
    import sys, time
    startup, per_frame = float(sys.argv[1]), float(sys.argv[2])
    time.sleep(startup)
    frames = int(sys.argv[4])
    time.sleep(per_frame * frames)
    if len(sys.argv) > 6 and sys.argv[6] == "fail":
        sys.exit(5)
    from fbaconf.reference.pipeline import reference_outputs
    reference_outputs(sys.argv[3], faps_out=sys.argv[5])
""")


class FakeMachine:
    """Machine counters a test dictates. Each run takes the seconds the test says; during it the
    decoder uses ``cpu`` (a fraction of those seconds) and waits ``stall`` (a fraction), other
    processes hold ``others`` of the CPUs; between runs (``gap`` seconds) they hold ``between``."""

    def __init__(
        self,
        monkeypatch,
        *,
        cpus: int = 2,
        cpu: float = 1.0,
        stall: float = 0.0,
        others: float = 0.0,
        between: float = 0.0,
        gap: float = 0.2,
    ) -> None:
        self.cpus, self.cpu, self.stall, self.others, self.between, self.gap = cpus, cpu, stall, others, between, gap
        self.t = self.busy = self.own = 0.0
        monkeypatch.setattr(sysinfo, "usable_cpus", lambda: cpus)

    def _sample(self) -> MachineSample:
        return MachineSample(t=self.t, busy_s=self.busy, pressure_s=None, own_s=self.own, load=4.0)

    def window(self, n: int, seconds: float) -> speed_load.Window:
        self.t += self.gap
        self.busy += self.between * self.cpus * self.gap
        before = self._sample()
        cpu = self.cpu * seconds
        self.t += seconds
        self.busy += self.others * self.cpus * seconds + cpu
        self.own += cpu
        return speed_load.Window(
            n, seconds, before, self._sample(), cpu_s=cpu, stall_s=self.stall * seconds, stall_source="thread"
        )


def synthetic_clock(
    monkeypatch, startup: float, per_frame: float, jitter: float = 0.0, machine: FakeMachine | None = None
) -> list[int]:
    """Every speed run takes ``startup + per_frame * n`` seconds (times ``1 +- jitter``,
    alternating) on ``machine`` (default: an idle one, the decoder on a CPU all the time); the
    decoder still runs. Returns the list of frame counts run."""
    runs: list[int] = []
    real = speed._Runner.run
    machine = machine or FakeMachine(monkeypatch)

    def run(self, n: int) -> speed_load.Window:
        real(self, n)
        runs.append(n)
        sign = 1 if len(runs) % 2 else -1
        return machine.window(n, (startup + per_frame * n) * (1 + sign * jitter))

    monkeypatch.setattr(speed._Runner, "run", run)
    return runs


def _manifest(
    tmp_path: Path, startup: float, per_frame: float, *, extra: str = "", claims=("simple@1",), name="timed"
) -> Path:
    script = tmp_path / "timed_decoder.py"
    script.write_text(DECODER)
    argv = ["{python}", str(script), str(startup), str(per_frame), "{input}", "{frames}", "{faps_out}"]
    return write_manifest(
        tmp_path / f"{name}.toml",
        argv + ([extra] if extra else []),
        claims=claims,
        faps_format=None,
        limits="timeout_s = 30",
    )


def test_accuracy_known_startup_and_per_frame(tmp_path, monkeypatch):
    """Acceptance: start-up 0.3 s, 2 ms/frame, timings off by +-3 % -> per-frame cost within +-10 %."""
    true_pf, true_startup = 0.002, 0.3
    synthetic_clock(monkeypatch, true_startup, true_pf, jitter=0.03)
    a = load_manifest(_manifest(tmp_path, 0.0, 0.0))
    r = speed.measure(a, "simple@1", "decode", lengths=[20, 160, 320], repeats=3, work_dir=tmp_path / "w")
    assert r is not None
    err = r.per_frame_s / true_pf - 1
    print(
        f"per-frame {r.per_frame_s * 1000:.4f} ms (true 2 ms, {err:+.2%}); "
        f"start-up {r.startup_s:.3f} s; r2 {r.fit_r2:.4f}"
    )
    assert abs(err) <= 0.10, r.message
    assert 0.27 <= r.startup_s <= 0.33, r.message
    assert r.rate_fps == pytest.approx(1 / r.per_frame_s)
    assert r.required_fps == 30 and r.passed and r.provenance == "provisional"
    assert len(r.samples) == 9 and {s["frames"] for s in r.samples} == {20, 160, 320}
    assert r.fit_r2 > 0.9


def test_adaptive_lengths_fast_decoder(tmp_path, monkeypatch):
    """Default (adaptive) lengths: grow until the frame-dependent time is long enough."""
    true_pf = 0.001
    synthetic_clock(monkeypatch, 0.05, true_pf)
    a = load_manifest(_manifest(tmp_path, 0.0, 0.0))
    r = speed.measure(a, "simple@1", "decode", repeats=1, target_s=0.25, work_dir=tmp_path / "w")
    lengths = sorted({s["frames"] for s in r.samples})
    assert len(lengths) == 3 and lengths[-1] >= 200, lengths  # 0.25 s of frames at 1 ms
    assert abs(r.per_frame_s / true_pf - 1) <= 0.2, r.message


def test_too_slow_decoder_fails_speed_only(tmp_path, capsys, monkeypatch):
    # 40 ms/frame = 25 fps < simple@1's 30 fps decode minimum, on an idle machine
    synthetic_clock(monkeypatch, 0.01, 0.04)
    m = _manifest(tmp_path, 0.0, 0.0)
    r = speed.measure(load_manifest(m), "simple@1", "decode", lengths=[2, 12], repeats=1)
    assert not r.passed and r.rate_fps < 30 and "below" in r.message
    assert r.verdict == "fail" and "not busy" in r.reason, r.reason
    code = main(["bench", "--decoder", str(m), "--lengths", "2,12", "--repeats", "1"])
    out = capsys.readouterr().out
    assert code == 3, out
    assert "FAIL" in out and "provisional *" in out


def test_fast_decoder_passes_bench(tmp_path, capsys, monkeypatch):
    synthetic_clock(monkeypatch, 0.01, 0.001)
    m = _manifest(tmp_path, 0.0, 0.0)
    code = main(
        ["bench", "--decoder", str(m), "--claim", "simple@1", "--lengths", "10,100", "--repeats", "1", "--json"]
    )
    doc = json.loads(capsys.readouterr().out)
    assert code == 0 and doc["exit_code"] == 0
    [dec] = doc["speed"]
    assert dec["operation"] == "decode" and dec["passed"] and dec["verdict"] == "pass" and dec["required_fps"] == 30
    assert dec["cpu_s"] == pytest.approx(dec["wall_s"]) and dec["others_share"] == 0.0  # the fake idle machine
    assert [s["reason"] for s in doc["skipped"] if s["operation"] == "render"]  # no images output


def test_failing_decoder(tmp_path, capsys):
    m = _manifest(tmp_path, 0.0, 0.0, extra="fail")
    a = load_manifest(m)
    with pytest.raises(speed.SpeedRunError) as ei:
        speed.measure(a, "simple@1", "decode", lengths=[1, 2], repeats=1)
    assert "exited with code 5" in str(ei.value)
    [r] = speed.measure_claim(a, "simple@1", lengths=[1, 2], repeats=1)
    assert not r.passed and "failed" in r.message and math.isnan(r.per_frame_s)
    assert main(["bench", "--decoder", str(m), "--lengths", "1,2", "--repeats", "1"]) == 1
    assert main(["bench", "--decoder", str(m), "--claim", "nosuch@1"]) == 2
    capsys.readouterr()


def test_missing_output_is_a_failure(tmp_path):
    script = tmp_path / "noout.py"
    script.write_text("pass\n")
    m = tmp_path / "noout.toml"
    m.write_text(
        f'name = "noout"\nclaims = ["simple@1"]\ninputs = ["fba"]\noutputs = ["faps"]\n'
        f'[commands]\ndecode = ["{{python}}", "{script}", "{{input}}", "{{faps_out}}"]\n'
    )
    with pytest.raises(speed.SpeedRunError, match="wrote no output"):
        speed.measure(load_manifest(m), "simple@1", "decode", lengths=[1, 2], repeats=1)


class _SleepyRenderer(PythonAdapter):
    """In-process adapter with images (its cost comes from the test's synthetic clock): the
    reference decoding and rendering of what it is given, as the scenario asks."""

    outputs = ["faps", "images"]
    claims = ["simple@2"]

    def run(self, job):
        from fbaconf.reference.pipeline import reference_outputs  # noqa: PLC0415

        reference_outputs(
            job.path("input"),
            scenario=job.path("scenario"),
            faps_out=job.path("faps_out"),
            images_dir=job.path("images_dir"),
        )


def test_in_process_adapter_decode_and_render(monkeypatch):
    real = speed._Runner.run
    machine = FakeMachine(monkeypatch)
    monkeypatch.setattr(
        speed._Runner,
        "run",
        lambda self, n: (real(self, n), machine.window(n, (0.005 if self.operation == "decode" else 0.003) * n))[1],
    )
    a = _SleepyRenderer()
    res = speed.measure_claim(a, lengths=[10, 40], repeats=1)  # claim: the adapter's highest
    assert [r.operation for r in res] == ["decode", "render"]
    dec, ren = res
    assert dec.claim == "simple@2" and dec.required_fps == 240 and ren.required_fps == 30
    assert dec.per_frame_s == pytest.approx(0.005)
    assert ren.per_frame_s == pytest.approx(0.003)
    assert dec.passed is False and ren.passed is True  # 200 fps < 240; 333 fps >= 30


def test_skip_render_without_images(tmp_path):
    a = load_manifest(_manifest(tmp_path, 0.0, 0.0))
    assert speed.skip_reason(a, "render")
    assert speed.measure(a, "simple@1", "render") is None
    with pytest.raises(speed.SpeedError):
        speed.measure(a, "simple@1", "transcode")


def test_speed_content_is_fresh_and_its_sampled_reference_is_the_decoding(tmp_path):
    """Every run's stream is new — no run, and no block of a run, repeats another, within one
    measurement or across two — and the expected frames of any sample (decoded from their
    blocks only) are the reference decoding of the whole stream."""
    blocks: list[bytes] = []
    runs = [Content(tmp_path / "a").make(n) for n in (1, 7, BLOCK_FRAMES, 250, 250)]
    runs.append(Content(tmp_path / "b").make(250))  # another measurement, the same length
    for run in runs:
        f = decode(run.stream_bytes()).frames
        assert len(f) == run.n
        ks = np.arange(run.n)
        e = run.expected(ks)
        assert np.array_equal(e.values, f.values) and np.array_equal(e.status, f.status)
        assert np.array_equal(e.high, f.high) and np.array_equal(e.frame_number, f.frame_number)
        assert np.allclose(e.time_ms, f.time_ms)
        blocks += [f.values[j : j + BLOCK_FRAMES].tobytes() for j in range(0, run.n, BLOCK_FRAMES)]
        # every FAP but the two high-level ones moves from frame to frame (the noise is per frame)
        if run.n > 2:
            assert (np.diff(f.values[:, 2:], axis=0) != 0).mean() > 0.5
    assert len(set(blocks)) == len(blocks)


def test_fit_line_and_claims():
    pf, st, r2 = speed.fit_line([10, 20, 40], [1.1, 1.2, 1.4])
    assert pf == pytest.approx(0.01) and st == pytest.approx(1.0) and r2 == pytest.approx(1.0)
    with pytest.raises(ValueError):
        speed.fit_line([5, 5], [1, 2])
    assert speed.required_rate("simple@2", "decode")[:2] == (240.0, "provisional")
    assert speed.required_rate("simple@1", "render")[0] == 15.0
    with pytest.raises(speed.SpeedError):
        speed.required_rate("bogus@9", "decode")


def test_sandboxed_command_decoder_reads_the_generated_content(tmp_path):
    """The speed phase's content lives outside the case folder: the sandbox must show it
    (the subprocess reference could not open it: every speed run was a set-up Error)."""
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "fbaconf",
            "bench",
            "--decoder",
            "reference",
            "--operation",
            "decode",
            "--repeats",
            "1",
            "--lengths",
            "4,16",
            "--json",
        ],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp_path,
    )
    # 0: fast enough, 3: below the level's minimum (this machine's speed is not the point);
    # never 1 (a decoder run failed) or 2 (set-up)
    assert r.returncode in (0, 3, 4), r.stdout + r.stderr  # 4: below it on a busy machine
    [dec] = json.loads(r.stdout)["speed"]
    assert len(dec["samples"]) == 2, dec


def test_bifs_only_decoder_gets_a_bifs_scene(tmp_path):
    """A decoder that declares only the binary scene input is timed with the default head as
    BIFS (it used to be refused: 'speed measurement supplies BT scenes only'). The decoder
    checks what it got: a .bifs file the BIFS reader accepts."""
    script = tmp_path / "bifs_only.py"
    script.write_text(
        textwrap.dedent("""\
        import sys
        if not sys.argv[2].endswith(".bifs"):
            sys.exit(7)
        from fbaconf.scenes import bifs
        bifs.read(sys.argv[2])  # BT text would raise BifsError: a non-zero exit
        from fbaconf.reference.pipeline import reference_outputs
        reference_outputs(sys.argv[1], faps_out=sys.argv[3])
    """)
    )
    m = tmp_path / "bifs-only.toml"
    m.write_text(
        'name = "bifs-only"\nclaims = ["predictable@1"]\ninputs = ["fba", "bifs"]\noutputs = ["faps"]\n'
        f'[commands]\ndecode = ["{{python}}", "{script}", "{{input}}", "{{scene}}", "{{faps_out}}"]\n'
        "[limits]\ntimeout_s = 60\n"
    )
    r = speed.measure(load_manifest(m), "predictable@1", "decode", lengths=[4, 16], repeats=1, work_dir=tmp_path / "w")
    assert r is not None and len(r.samples) == 2, r.message
    # (two short lengths timed once: the fit may not resolve a slope, which is its own message)
    assert "cannot supply" not in r.message and "failed" not in r.message.lower(), r.message
    assert any("scene" in n for n in r.message.split("; ")), r.message


def test_a_decoder_that_stops_early_on_long_streams_fails(tmp_path):
    """A lazy decoder cannot earn a rate by decoding only the start of a long stream: every
    run's output must hold the frames it was given."""
    script = tmp_path / "lazy.py"
    script.write_text(
        "import sys\nfrom fbaconf.bitstreams.decoder import decode\n"
        "from fbaconf.bitstreams.faptext import write_fap_file\n"
        "frames = decode(open(sys.argv[1], 'rb').read()).frames\n"
        "write_fap_file(sys.argv[2], frames.select(slice(0, 50)))\n"
    )
    m = tmp_path / "lazy.toml"
    m.write_text(
        'name = "lazy"\nclaims = ["simple@1"]\ninputs = ["fba"]\noutputs = ["faps"]\n'
        f'[commands]\ndecode = ["{{python}}", "{script}", "{{input}}", "{{faps_out}}"]\n'
    )
    a = load_manifest(m)
    with pytest.raises(speed.SpeedRunError, match="was given 200 frames but its output .* holds 50"):
        speed.measure(a, "simple@1", "decode", lengths=[20, 200], repeats=1)
    (r,) = [x for x in speed.measure_claim(a, lengths=[20, 200], repeats=1) if x is not None]
    assert not r.passed


class _OneImageRenderer(_SleepyRenderer):
    """A lazy renderer: the first frame's image only, whatever the number of frames asked for."""

    def run(self, job):
        if "images_dir" not in job.values:
            return super().run(job)
        from fbaconf.reference.pipeline import reference_outputs  # noqa: PLC0415
        from fbaconf.rendering.scenario import Scenario  # noqa: PLC0415

        one = job.workdir / "one.toml"
        one.write_text(Scenario.load(job.path("scenario")).with_(frames=(0,)).to_toml())
        reference_outputs(job.path("input"), scenario=one, images_dir=job.path("images_dir"))


def test_a_renderer_that_skips_frames_fails():
    with pytest.raises(
        speed.SpeedRunError, match="not the rendering of the content.*frame 9: .*frame_00009.png: cannot read"
    ):
        speed.measure(_OneImageRenderer(), "simple@2", "render", lengths=[10, 20], repeats=1)


# ------------------------------------------------------------------ the machine's load
# A decoder that costs 20 ms of CPU a frame (50 fps; simple@1 asks 30) on a machine where it gets
# 40 % of a CPU: 50 ms a frame of wall time (20 fps), waiting the other 60 %. Hand computation of
# the uncontended time per run (speed_load): others hold 80 % of the 2 CPUs, i.e. 0.8 s of every
# CPU a second; the wait they explain is min(0.6 s, 0.8 s) = 0.6 s of each second, which leaves
# 0.4 s: 20 ms a frame, 50 fps.
LOADED = dict(cpu=0.4, stall=0.6, others=0.8, between=0.8)


def _loaded(tmp_path, monkeypatch, per_frame: float = 0.05, **machine):
    synthetic_clock(monkeypatch, 0.2, per_frame, machine=FakeMachine(monkeypatch, **{**LOADED, **machine}))
    return speed.measure(load_manifest(_manifest(tmp_path, 0.0, 0.0)), "simple@1", "decode", lengths=[4, 24], repeats=1)


def test_too_slow_only_under_load_is_inconclusive_not_fail(tmp_path, monkeypatch, capsys):
    r = _loaded(tmp_path, monkeypatch)
    assert r.rate_fps == pytest.approx(20.0) and r.uncontended_fps == pytest.approx(50.0), r.message
    assert r.verdict == "inconclusive" and not r.passed, r.message
    assert r.others_share == pytest.approx(0.8) and r.others_share_between == pytest.approx(0.8)
    assert "busy" in r.reason and "50.0 fps" in r.reason and "20.0 fps" in r.reason, r.reason
    d = r.to_json()
    assert d["passed"] is False and d["verdict"] == "inconclusive"
    assert {"cpu_s", "wall_s", "stall_s", "load", "reason"} <= set(d)
    assert speed_verdict([d]) == ("SPEED INCONCLUSIVE", 4)
    code = main(["bench", "--decoder", str(tmp_path / "timed.toml"), "--lengths", "4,24", "--repeats", "1"])
    out = capsys.readouterr().out
    assert code == 4 and "INCONCLUSIVE" in out, out


def test_a_wait_of_its_own_making_fails(tmp_path, monkeypatch):
    """The same readings where other processes did not hold the machine between the runs (the
    load came and went with the decoder: its own), or at all (it waited on its own threads)."""
    for machine in (dict(between=0.0), dict(others=0.0, between=0.0)):
        r = _loaded(tmp_path, monkeypatch, **machine)
        assert r.verdict == "fail" and r.rate_fps == pytest.approx(20.0), r.message
        assert "not busy" in r.reason, r.reason


def test_a_sleeper_fails_on_a_busy_machine_too(tmp_path, monkeypatch):
    """Slow by itself: it sleeps (5 % on a CPU, never waiting for one) — nothing the others did
    explains its time."""
    r = _loaded(tmp_path, monkeypatch, cpu=0.05, stall=0.0)
    assert r.verdict == "fail" and r.uncontended_fps == pytest.approx(20.0), r.message
    assert "even without the wait other processes explain it is 20.0 fps" in r.reason, r.reason


def test_a_rate_that_meets_the_minimum_passes_whatever_the_load(tmp_path, monkeypatch):
    r = _loaded(tmp_path, monkeypatch, per_frame=0.02, others=1.0, between=1.0)
    assert r.verdict == "pass" and r.passed and r.rate_fps == pytest.approx(50.0), r.message


def test_speed_verdict_of_results():
    ok = {"passed": True, "verdict": "pass"}
    slow = {"passed": False, "verdict": "fail"}
    busy = {"passed": False, "verdict": "inconclusive"}
    assert speed_verdict(None) is None and speed_verdict([ok, ok]) is None
    assert speed_verdict([ok, busy]) == ("SPEED INCONCLUSIVE", 4)
    assert speed_verdict([busy, slow]) == ("SPEED FAIL", 3)
    # results written before verdicts existed: by "passed"
    assert speed_verdict([{"passed": True}]) is None
    assert speed_verdict([{"passed": False}]) == ("SPEED FAIL", 3)
    # contradictions are failures: only a result that says it passed passes
    for bad in (
        {"passed": True, "verdict": "fail"},
        {"passed": True, "verdict": "inconclusive"},
        {"passed": False, "verdict": "pass"},
        {"verdict": "pass"},
        {"passed": "yes"},
    ):
        assert speed_verdict([bad]) == ("SPEED FAIL", 3), bad


# Costs 1/80 s of its own CPU per frame (not of wall time: it spins until its CPU clock has
# advanced), then writes the reference decoding: 80 fps on an idle core, simple@1 asks 30.
BURNER = textwrap.dedent("""\
    import sys, time
    frames = int(sys.argv[2])
    t = time.thread_time()
    while time.thread_time() - t < frames / 80.0:
        pass
    from fbaconf.reference.pipeline import reference_outputs
    reference_outputs(sys.argv[1], faps_out=sys.argv[3])
""")


def test_a_saturated_machine_does_not_fail_a_decoder_that_is_fast_on_an_idle_one(tmp_path):
    """Busy loops on every CPU, three times over (started here, outside this process's tree,
    killed after): the decoder gets a quarter of a CPU or less, about 20 fps; its reading may
    pass or be inconclusive, never fail. (Which of the two depends on the machine: the assertion
    is what load cannot change.)"""
    script = tmp_path / "burner.py"
    script.write_text(BURNER)
    m = tmp_path / "burner.toml"
    m.write_text(
        'name = "burner"\nclaims = ["simple@1"]\ninputs = ["fba"]\noutputs = ["faps"]\n'
        f'[commands]\ndecode = ["{{python}}", "{script}", "{{input}}", "{{frames}}", "{{faps_out}}"]\n'
        "[limits]\ntimeout_s = 120\n"
    )
    n = 3 * (os.cpu_count() or 1)
    # each loop's parent shell exits at once: the loops are no child of this process; each in a
    # session of its own, so a kernel that shares CPU time out by session (autogroup) weighs
    # every loop as much as the decoder's session
    loop = f"{sys.executable} -c 'import os; os.setsid()\nwhile True: pass'"
    start = subprocess.run(
        ["/bin/sh", "-c", f"for i in $(seq {n}); do {loop} </dev/null >/dev/null 2>&1 & echo $!; done"],
        capture_output=True,
        text=True,
        timeout=30,
    )
    loops = [int(x) for x in start.stdout.split()]
    try:
        assert len(loops) == n
        r = speed.measure(load_manifest(m), "simple@1", "decode", lengths=[12, 72], repeats=1, work_dir=tmp_path / "w")
    finally:
        for pid in loops:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
    print(r.message)
    assert r.verdict in ("pass", "inconclusive"), r.message
    assert r.others_share is not None and r.others_share > 0.5, r.message  # the loops did load the machine


def test_an_inconclusive_reading_in_the_verdict_reports_and_statement(tmp_path, monkeypatch):
    """What the lead's verdict rests on (speed_verdict through derive_verdict and the exit code)
    and what the reader sees: the reports' speed table and verdict line, the report schema, the
    certificate's statement — with the numbers and the reason."""
    r = _loaded(tmp_path, monkeypatch)
    assert r.verdict == "inconclusive"
    cv = derive_verdict([], strict=False, speed=[r.to_json()])
    assert (cv.verdict, cv.exit_code, cv.differences) == ("SPEED INCONCLUSIVE", 4, [])
    slow = {**r.to_json(), "verdict": "fail"}
    cv = derive_verdict([], strict=False, speed=[r.to_json(), slow])
    assert (cv.verdict, cv.exit_code) == ("SPEED FAIL", 3)
    cv = derive_verdict([], strict=False, speed=None)
    assert (cv.verdict, cv.exit_code) == ("PASS", 0)
    rec = RunRecord(decoder={"name": "timed"}, claim="simple@1", suites=[], system={}, speed=[r], exit_code=4)
    text = terminal_summary(rec)
    assert "result: SPEED INCONCLUSIVE" in text and "1 inconclusive (below it on a busy machine)" in text, text
    assert "INCONCLUSIVE" in text.split("speed:")[1].splitlines()[2], text  # the table row
    assert "c-QualityWarning'>INCONCLUSIVE" in html_report(rec, tmp_path)
    schema = json.loads((Path(speed.__file__).parents[1] / "data" / "run-report.schema.json").read_text())
    jsonschema.validate(report_json(rec), schema)
    basis = {
        "tools": [],
        "coverage_points_exercised": 0,
        "coverage_points_of_claim": 0,
        "not_exercised": [],
        "cases_not_taken": [],
    }
    st = _statement(rec, derive_verdict([], strict=False, speed=[r.to_json()]), True, basis)
    line = next(x for x in st.splitlines() if x.startswith("- decode:"))
    assert "20.0 frames/s measured, 30 required (provisional) — INCONCLUSIVE: the machine was busy" in line, line
    assert "50.0 fps" in line and "other processes used 80 %" in line, line


def test_a_decoder_of_images_only_is_judged_on_the_frames_it_was_asked_to_draw(tmp_path):
    """A decoder whose only output is images gets two small frames to draw per run (the first and
    one drawn for the run): judged as images, a faithful drawing passes, a blank one fails."""
    script = tmp_path / "painter.py"
    script.write_text(
        textwrap.dedent("""\
        import sys
        from fbaconf.reference.pipeline import reference_outputs
        from fbaconf.rendering.scenario import Scenario
        ks = Scenario.load(sys.argv[2]).frames
        assert len(ks) == 2 and ks[0] == 0, ks  # the first frame and one drawn
        reference_outputs(sys.argv[1], scenario=sys.argv[2], images_dir=sys.argv[3])
        if len(sys.argv) > 4:  # blank: every pixel black
            import numpy as np
            from fbaconf.rendering.images import write_png
            for k in ks:
                write_png(f"{sys.argv[3]}/frame_{k:05d}.png", np.zeros((8, 8, 3)))
    """)
    )
    for extra, ok in (("", True), ("blank", False)):
        m = tmp_path / f"painter{extra}.toml"
        args = ", ".join(
            f'"{a}"'
            for a in ["{python}", str(script), "{input}", "{scenario}", "{images_dir}"] + ([extra] if extra else [])
        )
        m.write_text(
            f'name = "painter"\nclaims = ["simple@1"]\ninputs = ["fba"]\noutputs = ["images"]\n'
            f"[commands]\ndecode = [{args}]\n"
        )
        a = load_manifest(m)
        if ok:
            r = speed.measure(a, "simple@1", "decode", lengths=[6, 30], repeats=1)
            assert r is not None and len(r.samples) == 2, r.message
        else:
            with pytest.raises(speed.SpeedRunError, match="not the rendering of the content"):
                speed.measure(a, "simple@1", "decode", lengths=[6, 30], repeats=1)


def test_a_faithful_drawing_of_the_decode_frames_passes_whatever_the_content(tmp_path):
    """The decode operation's two check frames, drawn as a faithful renderer draws them (2 x 2
    samples per pixel, the image stage's floor), pass the image comparison on fresh contents:
    at 8 x 8 pixels one content in forty failed an honest decoder on the lab's own noise."""
    s = DECODE_IMAGE_SIZE
    for t in range(6):
        run = Content(tmp_path / f"c{t}").make(6)
        ks = [0, 1 + t % 5]
        drawn = tmp_path / f"drawn{t}"
        sc = Scenario.default().with_(width=s, height=s, supersample=RENDER_SUPERSAMPLE, frames=None)
        render_frames(animate(run.expected(ks)), sc, drawn)
        for i, k in enumerate(ks):  # the files as a decoder names them: frame_<k>.png
            (drawn / f"frame_{i:05d}.png").rename(drawn / f"k{k:05d}.png")
        for k in ks:
            (drawn / f"k{k:05d}.png").rename(drawn / f"frame_{k:05d}.png")
        assert images_problem(drawn, run, ks, width=s, height=s, max_bytes=2**26) is None, t
