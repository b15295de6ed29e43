"""Speed cannot be faked (issue 29): the command certified is the command timed, and what a
speed run writes is judged on content, not counted."""
from __future__ import annotations

import math
import textwrap
from pathlib import Path

from fbaconf.harness import speed
from fbaconf.harness.adapters import load_manifest

# Decodes honestly at 23 frames a second (the reference decoding, then 1/23 s per frame).
HONEST = """
def honest(n_frames_in, out):
    import time
    from fbaconf.bitstreams.decoder import decode
    from fbaconf.bitstreams.faptext import write_fap_file
    frames = decode(open(n_frames_in, 'rb').read()).frames
    time.sleep(len(frames) / 23.0)
    write_fap_file(out, frames)
"""

# Recognises the speed content and writes n frames of zeros at once; decodes honestly otherwise.
FAKE = HONEST + r"""
import os, re, sys
src, out = sys.argv[1], sys.argv[2]
m = re.fullmatch(r"content-(\w+)\.fba", os.path.basename(src))
if m:
    n = int(m.group(1)) if m.group(1).isdigit() else int(sys.argv[3])  # (the names are random now: {frames})
    with open(out, "w") as f:  # a well-formed .fap: the header count and n frames, every FAP zero
        f.write("2.1 fake 25 %d\n" % n)
        for k in range(n):
            f.write(" ".join(["1"] * 68) + "\n" + " ".join([str(k)] + ["0"] * 76) + "\n")
else:
    honest(src, out)
"""

SERVE = HONEST + r"""
import sys
from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.faptext import write_fap_file
while True:
    line = sys.stdin.buffer.readline()
    if not line:
        break
    rid, size, out = line.decode().rstrip("\n").split(" ", 2)
    data = sys.stdin.buffer.read(int(size))
    write_fap_file(out, decode(data).frames)  # fast: no sleep
    print(rid, 0, flush=True)
"""


def _manifest(tmp_path: Path, decode_body: str, *, serve: str | None = None, extra: str = "") -> Path:
    dec = tmp_path / "dec.py"
    dec.write_text(textwrap.dedent(decode_body) + ("\nimport sys\nhonest(sys.argv[1], sys.argv[2])\n"
                                                   if decode_body is HONEST else ""))
    lines = ['name = "speedy"', 'claims = ["simple@1"]', 'inputs = ["fba"]', 'outputs = ["faps"]',
             'faps_format = "fap"', extra, "[commands]",
             f'decode = ["{{python}}", "{dec}", "{{input}}", "{{faps_out}}", "{{frames}}"]']
    if serve is not None:
        (tmp_path / "serve.py").write_text(textwrap.dedent(serve))
        lines.append(f'serve = ["{{python}}", "{tmp_path / "serve.py"}"]')
    lines += ["[limits]", "timeout_s = 60"]
    m = tmp_path / "speedy.toml"
    m.write_text("\n".join(lines) + "\n")
    return m


def _decode_result(m: Path, **kw):
    (r,) = [x for x in speed.measure_claim(load_manifest(m), "simple@1", lengths=[4, 24], repeats=1, **kw)
            if x.operation == "decode"]
    return r


def test_a_decoder_that_recognises_the_speed_content_and_writes_zeros_fails(tmp_path):
    """Before: n lines of zeros for content-<n>.fba gave "inf fps PASS" for a 23 fps decoder."""
    r = _decode_result(_manifest(tmp_path, FAKE))
    assert not r.passed and r.rate_fps == 0.0, r.message
    assert "not the decoding of the content" in r.message, r.message


def test_a_fast_serve_beside_a_slow_decode_is_timed_as_decode(tmp_path):
    """Before: the fast serve was timed (5,049 fps) while the certified decode ran at 23 fps."""
    r = _decode_result(_manifest(tmp_path, HONEST, serve=SERVE))
    assert "persistent protocol" not in r.message, r.message
    # every timed run took at least its frames' sleep (1/23 s each): the sleeping decode was timed,
    # not the serve that answers in milliseconds (a lower bound only load cannot break)
    assert r.samples and all(x["seconds"] >= x["frames"] / 23.0 * 0.99 for x in r.samples), r.samples


def test_serve_declared_equivalent_is_checked_against_decode(tmp_path):
    """A manifest may declare serve equivalent: then it is timed, after a sample of its outputs
    matched decode's; a serve that answers differently fails the measurement."""
    r = _decode_result(_manifest(tmp_path, HONEST, serve=SERVE, extra="serve_equivalent = true"))
    assert "declared equivalent" in r.message and "checked against decode's on 2 lengths" in r.message, r.message
    wrong = SERVE.replace("write_fap_file(out, decode(data).frames)",
                          "f = decode(data).frames; f.values[:, 5] += 1; write_fap_file(out, f)")
    r = _decode_result(_manifest(tmp_path, HONEST, serve=wrong, extra="serve_equivalent = true"))
    assert not r.passed and "not the decoding of the content" in r.message, r.message


def test_a_per_frame_cost_that_is_not_positive_is_an_error_not_an_infinite_rate(tmp_path, monkeypatch):
    real = speed._Runner.run
    monkeypatch.setattr(speed._Runner, "run", lambda self, n: (real(self, n), 1.0 - n / 1000)[1])  # faster when longer
    m = _manifest(tmp_path, HONEST)
    r = speed.measure(load_manifest(m), "simple@1", "decode", lengths=[2, 8], repeats=1)
    assert not r.passed and r.rate_fps == 0.0 and not math.isinf(r.rate_fps)
    assert "no decode rate" in r.message and "not positive" in r.message, r.message
