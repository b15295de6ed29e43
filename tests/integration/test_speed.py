"""Speed measurement (harness/speed.py, `fbaconf bench`): the fit against a known start-up and
per-frame cost, verdicts against the level minimums, exit codes.

No test here depends on how fast this machine is: where a verdict depends on the measured
time, every run of the real decoder still happens (its output is checked), but the seconds it
reports are a synthetic clock's (:func:`synthetic_clock`), so the fit, the adaptive lengths and
the verdicts are exact. The measurement against real time is ``benchmarks/bench_harness_speed.py``."""
from __future__ import annotations

import json
import math
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from fbaconf.bitstreams.decoder import decode
from fbaconf.cli import main
from fbaconf.harness import speed
from fbaconf.harness.adapters import PythonAdapter, load_manifest

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
    from fbaconf.pipeline import reference_outputs
    reference_outputs(sys.argv[3], faps_out=sys.argv[5])
""")


def synthetic_clock(monkeypatch, startup: float, per_frame: float, jitter: float = 0.0) -> list[int]:
    """Every speed run takes ``startup + per_frame * n`` seconds (times ``1 +- jitter``,
    alternating); the decoder still runs. Returns the list of frame counts run."""
    runs: list[int] = []
    real = speed._Runner.run

    def run(self, n: int) -> float:
        real(self, n)
        runs.append(n)
        sign = 1 if len(runs) % 2 else -1
        return (startup + per_frame * n) * (1 + sign * jitter)
    monkeypatch.setattr(speed._Runner, "run", run)
    return runs


def _manifest(tmp_path: Path, startup: float, per_frame: float, *, extra: str = "",
              claims=("simple@1",), name="timed") -> Path:
    script = tmp_path / "timed_decoder.py"
    script.write_text(DECODER)
    m = tmp_path / f"{name}.toml"
    args = ", ".join(f'"{a}"' for a in ["{python}", str(script), str(startup), str(per_frame), "{input}",
                                         "{frames}", "{faps_out}"] + ([extra] if extra else []))
    m.write_text(f'name = "{name}"\nclaims = {json.dumps(list(claims))}\ninputs = ["fba"]\noutputs = ["faps"]\n'
                 f'[commands]\ndecode = [{args}]\n[limits]\ntimeout_s = 30\n')
    return m


def test_accuracy_known_startup_and_per_frame(tmp_path, monkeypatch):
    """Acceptance: start-up 0.3 s, 2 ms/frame, timings off by +-3 % -> per-frame cost within +-10 %."""
    true_pf, true_startup = 0.002, 0.3
    synthetic_clock(monkeypatch, true_startup, true_pf, jitter=0.03)
    a = load_manifest(_manifest(tmp_path, 0.0, 0.0))
    r = speed.measure(a, "simple@1", "decode", lengths=[20, 160, 320], repeats=3, work_dir=tmp_path / "w")
    assert r is not None
    err = r.per_frame_s / true_pf - 1
    print(f"per-frame {r.per_frame_s * 1000:.4f} ms (true 2 ms, {err:+.2%}); "
          f"start-up {r.startup_s:.3f} s; r2 {r.fit_r2:.4f}")
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
    # 40 ms/frame = 25 fps < simple@1's 30 fps decode minimum
    synthetic_clock(monkeypatch, 0.01, 0.04)
    m = _manifest(tmp_path, 0.0, 0.0)
    r = speed.measure(load_manifest(m), "simple@1", "decode", lengths=[2, 12], repeats=1)
    assert not r.passed and r.rate_fps < 30 and "below" in r.message
    code = main(["bench", "--decoder", str(m), "--lengths", "2,12", "--repeats", "1"])
    out = capsys.readouterr().out
    assert code == 3, out
    assert "FAIL" in out and "provisional *" in out


def test_fast_decoder_passes_bench(tmp_path, capsys, monkeypatch):
    synthetic_clock(monkeypatch, 0.01, 0.001)
    m = _manifest(tmp_path, 0.0, 0.0)
    code = main(["bench", "--decoder", str(m), "--claim", "simple@1", "--lengths", "10,100", "--repeats", "1",
                 "--json"])
    doc = json.loads(capsys.readouterr().out)
    assert code == 0 and doc["exit_code"] == 0
    [dec] = doc["speed"]
    assert dec["operation"] == "decode" and dec["passed"] and dec["required_fps"] == 30
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
    m.write_text(f'name = "noout"\nclaims = ["simple@1"]\ninputs = ["fba"]\noutputs = ["faps"]\n'
                 f'[commands]\ndecode = ["{{python}}", "{script}", "{{input}}", "{{faps_out}}"]\n')
    with pytest.raises(speed.SpeedRunError, match="wrote no output"):
        speed.measure(load_manifest(m), "simple@1", "decode", lengths=[1, 2], repeats=1)


class _SleepyRenderer(PythonAdapter):
    """In-process adapter with images (its cost comes from the test's synthetic clock)."""
    outputs = ["faps", "images"]
    claims = ["simple@2"]

    def run(self, job):
        n = job.frames
        if "images_dir" in job.values:
            d = job.path("images_dir")
            d.mkdir(parents=True, exist_ok=True)
            for i in range(n):  # an image per frame (the speed check counts them)
                (d / f"{i:06d}.png").write_bytes(b"x")
        if "faps_out" in job.values:  # the frames it was given (the speed check compares a sample)
            decode(job.path("input").read_bytes()).frames.save_npz(job.path("faps_out"))


def test_in_process_adapter_decode_and_render(monkeypatch):
    real = speed._Runner.run
    monkeypatch.setattr(speed._Runner, "run", lambda self, n: (real(self, n), (
        0.005 if self.operation == "decode" else 0.003) * n)[1])
    a = _SleepyRenderer()
    res = speed.measure_claim(a, lengths=[10, 100], repeats=1)  # claim: the adapter's highest
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


def test_content_streams_decode_to_n_frames():
    block = decode(speed.content_stream(speed.BLOCK_FRAMES)).frames
    for n in (1, 7, speed.BLOCK_FRAMES, 250):
        f = decode(speed.content_stream(n)).frames
        assert len(f) == n
        if n > speed.BLOCK_FRAMES:  # repeated block + tail: the block's frames tiled
            idx = np.arange(n) % speed.BLOCK_FRAMES
            assert np.array_equal(f.values, block.values[idx])
            assert np.array_equal(f.status, block.status[idx])


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
    r = subprocess.run([sys.executable, "-m", "fbaconf", "bench", "--decoder", "reference", "--operation", "decode",
                        "--repeats", "1", "--lengths", "4,16", "--json"], capture_output=True, text=True, timeout=300,
                       cwd=tmp_path)
    # 0: fast enough, 3: below the level's minimum (this machine's speed is not the point);
    # never 1 (a decoder run failed) or 2 (set-up)
    assert r.returncode in (0, 3), r.stdout + r.stderr
    [dec] = json.loads(r.stdout)["speed"]
    assert len(dec["samples"]) == 2, dec


def test_bifs_only_decoder_gets_a_bifs_scene(tmp_path):
    """A decoder that declares only the binary scene input is timed with the default head as
    BIFS (it used to be refused: 'speed measurement supplies BT scenes only'). The decoder
    checks what it got: a .bifs file the BIFS reader accepts."""
    script = tmp_path / "bifs_only.py"
    script.write_text(textwrap.dedent("""\
        import sys
        if not sys.argv[2].endswith(".bifs"):
            sys.exit(7)
        from fbaconf.scenes import bifs
        bifs.read(sys.argv[2])  # BT text would raise BifsError: a non-zero exit
        from fbaconf.pipeline import reference_outputs
        reference_outputs(sys.argv[1], faps_out=sys.argv[3])
    """))
    m = tmp_path / "bifs-only.toml"
    m.write_text('name = "bifs-only"\nclaims = ["predictable@1"]\ninputs = ["fba", "bifs"]\noutputs = ["faps"]\n'
                 f'[commands]\ndecode = ["{{python}}", "{script}", "{{input}}", "{{scene}}", "{{faps_out}}"]\n'
                 '[limits]\ntimeout_s = 60\n')
    r = speed.measure(load_manifest(m), "predictable@1", "decode", lengths=[4, 16], repeats=1,
                      work_dir=tmp_path / "w")
    assert r is not None and len(r.samples) == 2, r.message
    # (two short lengths timed once: the fit may not resolve a slope, which is its own message)
    assert "cannot supply" not in r.message and "failed" not in r.message.lower(), r.message
    assert any("scene" in n for n in r.message.split("; ")), r.message


def test_a_decoder_that_stops_early_on_long_streams_fails(tmp_path):
    """A lazy decoder cannot earn a rate by decoding only the start of a long stream: every
    run's output must hold the frames it was given."""
    script = tmp_path / "lazy.py"
    script.write_text("import sys\nfrom fbaconf.bitstreams.decoder import decode\n"
                      "from fbaconf.bitstreams.faptext import write_fap_file\n"
                      "frames = decode(open(sys.argv[1], 'rb').read()).frames\n"
                      "write_fap_file(sys.argv[2], frames.select(slice(0, 50)))\n")
    m = tmp_path / "lazy.toml"
    m.write_text('name = "lazy"\nclaims = ["simple@1"]\ninputs = ["fba"]\noutputs = ["faps"]\n'
                 f'[commands]\ndecode = ["{{python}}", "{script}", "{{input}}", "{{faps_out}}"]\n')
    a = load_manifest(m)
    with pytest.raises(speed.SpeedRunError, match="was given 200 frames but its output .* holds 50"):
        speed.measure(a, "simple@1", "decode", lengths=[20, 200], repeats=1)
    (r,) = [x for x in speed.measure_claim(a, lengths=[20, 200], repeats=1) if x is not None]
    assert not r.passed


class _OneImageRenderer(_SleepyRenderer):
    """A lazy renderer: one image, whatever the number of frames it was asked for."""

    def run(self, job):
        if "images_dir" in job.values:
            d = job.path("images_dir")
            d.mkdir(parents=True, exist_ok=True)
            (d / "000000.png").write_bytes(b"x")
        elif "faps_out" in job.values:
            super().run(job)


def test_a_renderer_that_skips_frames_fails():
    with pytest.raises(speed.SpeedRunError, match="asked to render 10 frames but wrote 1 images"):
        speed.measure(_OneImageRenderer(), "simple@2", "render", lengths=[10, 20], repeats=1)
