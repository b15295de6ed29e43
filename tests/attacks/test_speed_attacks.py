"""Speed cannot be faked: the command certified is the command timed, on content made fresh for
every run from a secret the measurement draws, and what a speed run writes is judged on
content — FAPs on a sample of frames, images as images — never counted.

Each hostile decoder here is a small program written from a description of the attack. Where
the attack needs content it could know in advance, a control shows it working on such
content (the secret fixed, or runs repeated): the defence, not the attack's own weakness, is
what fails it. The rates measured are printed (``-s``)."""

from __future__ import annotations

import json
import math
import textwrap
from pathlib import Path

from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.faptext import write_fap
from fbaconf.harness.adapters import load_manifest
from fbaconf.harness.speed import content as speed_content, load as speed_load, measure as speed
from fbaconf.harness.sysinfo import MachineSample
from fbaconf.harness.verdict import speed_verdict

from lib.manifests import program, write_manifest

CLAIM = "simple@2"  # decode 240 fps, render 30 fps per face: the hostile decoders below are honest at 25 fps
# (measured on two short lengths, once: a 25 fps reading comes out between about 20 and 35 fps)

# Decodes honestly at 25 frames a second (the reference decoding, then 1/25 s per frame).
HONEST = """
def honest(src, out):
    import time
    from fbaconf.bitstreams.decoder import decode
    from fbaconf.bitstreams.faptext import write_fap_file
    frames = decode(open(src, 'rb').read()).frames
    time.sleep(len(frames) / 25.0)
    write_fap_file(out, frames)
"""

# Recognises the speed content and writes n frames of zeros at once; decodes honestly otherwise.
FAKE = (
    HONEST
    + r"""
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
)

# Ships a table: the sha256 of every stream it has seen -> its decoding; answers from it at once,
# decodes honestly (25 fps) what it does not know.
TABLE = (
    HONEST
    + r"""
import hashlib, sys
src, out = sys.argv[1], sys.argv[2]
known = TABLE.get(hashlib.sha256(open(src, 'rb').read()).hexdigest())
if known is not None:
    open(out, "w").write(known)
else:
    honest(src, out)
"""
)

SERVE = r"""
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

# A serve that remembers: a stream it has answered, or any plane-start-code segment of one, costs
# it nothing again; what it has not seen costs 1/RATE s a frame. Its answers are always right.
CACHE = r"""
import hashlib, sys, time
from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.faptext import write_fap_file
RATE = float(sys.argv[1])
seen = set()
while True:
    line = sys.stdin.buffer.readline()
    if not line:
        break
    rid, size, out = line.decode().rstrip("\n").split(" ", 2)
    data = sys.stdin.buffer.read(int(size))
    frames = decode(data).frames
    parts = data.split(b"\x00\x00\x01\xbb")
    new = [p for p in parts if hashlib.sha256(p).digest() not in seen]
    if hashlib.sha256(data).digest() not in seen:
        time.sleep(len(frames) / RATE * sum(map(len, new)) / len(data))  # the share of it not seen before
    seen.update(hashlib.sha256(p).digest() for p in [data, *parts])
    write_fap_file(out, frames)
    print(rid, 0, flush=True)
"""


def _manifest(
    tmp_path: Path,
    decode_body: str,
    *,
    serve: str | None = None,
    extra: str = "",
    serve_args: tuple[str, ...] = (),
    images: bool = False,
) -> Path:
    main = "\nimport sys\nhonest(sys.argv[1], sys.argv[2])\n"  # a body that only defines honest() runs it
    body = textwrap.dedent(decode_body) + ("" if "sys.argv" in decode_body else main)
    dec = program(tmp_path / "dec.py", body, prelude="")
    argv = ["{python}", str(dec), "{input}", "{faps_out}", "{frames}"] + (
        ["{images_dir}", "{scenario}"] if images else []
    )
    srv = None
    if serve is not None:
        srv = ["{python}", str(program(tmp_path / "serve.py", serve, prelude="")), *serve_args]
    return write_manifest(
        tmp_path / "speedy.toml",
        argv,
        claims=[CLAIM],
        outputs=["faps", "images"] if images else ["faps"],
        serve=srv,
        extra=extra,
        limits="timeout_s = 60",
    )


def _decode_result(m: Path, lengths=(4, 24), repeats: int = 1, **kw):
    (r,) = [
        x
        for x in speed.measure_claim(load_manifest(m), CLAIM, lengths=list(lengths), repeats=repeats, **kw)
        if x.operation == "decode"
    ]
    print(f"\n{m.parent.name}: {r.verdict} at {r.rate_fps:.1f} fps — {r.message}")
    return r


def test_a_decoder_that_recognises_the_speed_content_and_writes_zeros_fails(tmp_path):
    """Before: n lines of zeros for content-<n>.fba gave "inf fps PASS" for a 25 fps decoder."""
    r = _decode_result(_manifest(tmp_path, FAKE))
    assert not r.passed and r.verdict == "fail" and r.rate_fps == 0.0, r.message
    assert "not the decoding of the content" in r.message, r.message
    assert speed_verdict([r.to_json()]) == ("SPEED FAIL", 3)


def _fixed_secret(monkeypatch):
    """Every Content draws the same secret: content an attacker could have made in advance."""
    real = speed_content.Content.__init__

    def init(self, root):
        real(self, root)
        self._secret = b"k" * 32

    monkeypatch.setattr(speed_content.Content, "__init__", init)


def _table(tmp_path: Path, lengths=(4, 24), runs: int = 6) -> dict[str, str]:
    """What an attacker ships: the decoding of the runs the public generator makes, by digest."""
    import hashlib  # noqa: PLC0415

    table = {}
    for n in lengths:
        c = speed_content.Content(tmp_path / f"table-{n}")
        for _ in range(runs):
            data = c.make(n).stream_bytes()
            table[hashlib.sha256(data).hexdigest()] = write_fap(decode(data).frames)
    return table


def test_a_table_of_the_content_matches_nothing(tmp_path, monkeypatch):
    """Before: a 25 fps decoder was certified at ~5,000 fps by recognising the content (one fixed
    sequence) in a table it shipped. Control: with the secret fixed, the table answers every run
    (no run takes the time honest decoding would); with the secret the measurement draws, nothing
    matches and the decoder is timed decoding: 25 fps, SPEED FAIL."""
    lengths = (4, 60)
    for d in ("control", "real"):
        (tmp_path / d).mkdir()
    with monkeypatch.context() as mp:
        _fixed_secret(mp)
        body = f"TABLE = {json.dumps(_table(tmp_path / 'control', lengths))}\n" + TABLE
        r = _decode_result(_manifest(tmp_path / "control", body), lengths)
    assert all(x["seconds"] < x["frames"] / 25.0 for x in r.samples if x["frames"] == 60), r.samples  # hits
    body = f"TABLE = {json.dumps(_table(tmp_path / 'real', lengths))}\n" + TABLE
    r = _decode_result(_manifest(tmp_path / "real", body), lengths)
    assert all(x["seconds"] >= x["frames"] / 25.0 * 0.99 for x in r.samples), r.samples  # decoded every run
    assert r.verdict == "fail" and r.rate_fps < 100, r.message
    assert speed_verdict([r.to_json()]) == ("SPEED FAIL", 3)


def test_a_fast_serve_beside_a_slow_decode_is_timed_as_decode(tmp_path):
    """Without serve_equivalent the fast serve is never timed."""
    r = _decode_result(_manifest(tmp_path, HONEST, serve=SERVE))
    assert "persistent protocol" not in r.message, r.message
    # every timed run took at least its frames' sleep (1/25 s each): the sleeping decode was timed
    assert r.samples and all(x["seconds"] >= x["frames"] / 25.0 * 0.99 for x in r.samples), r.samples
    assert r.verdict == "fail" and r.rate_fps < 100, r.message


def test_a_fast_serve_declared_equivalent_is_not_what_is_timed(tmp_path):
    """Before: serve_equivalent = true with a fast serve certified a 25 fps decode at 3,781-9,957
    fps (the two wrote the same frames). Now decode is timed beside serve on the speed content:
    25 times slower, so serve is not what is certified and decode is measured: SPEED FAIL."""
    r = _decode_result(_manifest(tmp_path, HONEST, serve=SERVE, extra="serve_equivalent = true"))
    # serve 25 times faster than decode (or, under load, no time growing with the frames it decoded): either
    # way decode is what is timed
    assert "decode was timed" in r.message, r.message
    assert r.verdict == "fail" and r.rate_fps < 100, r.message
    assert all(x["seconds"] >= x["frames"] / 25.0 * 0.99 for x in r.samples), r.samples


def test_a_serve_that_answers_differently_fails(tmp_path):
    wrong = SERVE.replace(
        "write_fap_file(out, decode(data).frames)",
        "f = decode(data).frames; f.values[:, 5] += 1; write_fap_file(out, f)",
    )
    r = _decode_result(_manifest(tmp_path, HONEST, serve=wrong, extra="serve_equivalent = true"))
    assert r.verdict == "fail" and "not the decoding of the content" in r.message, r.message


def test_a_serve_answering_repeats_from_a_cache_never_hits(tmp_path, monkeypatch):
    """Before: a serve answering repeated inputs (and blocks) from a cache was timed at ~500 fps.
    Control: with the content of a length repeated, as it used to be, the cache answers and serve
    looks many times faster than decode (the equivalence check then times decode). With fresh
    content the cache never hits: serve and decode agree, both at their 100 fps: SPEED FAIL."""
    lengths = (4, 100)
    with monkeypatch.context() as mp:
        made: dict[int, speed_content.Run] = {}
        real = speed_content.Content.make

        def repeated(self, n):
            if n not in made:
                made[n] = real(self, n)
            made[n].remove = lambda: None  # kept for the next run of that length
            return made[n]

        mp.setattr(speed_content.Content, "make", repeated)
        (tmp_path / "control").mkdir()
        m = _manifest(
            tmp_path / "control",
            HONEST.replace("25.0", "100.0"),
            serve=CACHE,
            serve_args=("100",),
            extra="serve_equivalent = true",
        )
        r = _decode_result(m, lengths, repeats=3)
    assert "serve is not what is certified" in r.message, r.message  # the cache hit
    (tmp_path / "real").mkdir()
    m = _manifest(
        tmp_path / "real",
        HONEST.replace("25.0", "100.0"),
        serve=CACHE,
        serve_args=("100",),
        extra="serve_equivalent = true",
    )
    r = _decode_result(m, lengths, repeats=3)
    assert "persistent protocol" in r.message and "the same frames" in r.message, r.message  # timed through serve
    assert r.verdict == "fail" and 50 < r.rate_fps < 150, r.message


# Writes the FAPs honestly and fast; its images are what the attack says (argv: ... images_dir scenario).
RENDER = r"""
import os, sys, shutil
from fbaconf.reference.pipeline import reference_outputs
src, out, n, images, scenario = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4], sys.argv[5]
reference_outputs(src, faps_out=out)
os.makedirs(images, exist_ok=True)
names = [os.path.join(images, "frame_%05d.png" % k) for k in range(n)]
MODE = sys.argv[6] if len(sys.argv) > 6 else "{mode}"
if MODE == "empty":
    for p in names:
        open(p, "wb").close()
elif MODE == "blank":
    import numpy as np
    from fbaconf.rendering.images import write_png
    write_png(names[0], np.zeros((64, 64, 3)))
    for p in names[1:]:
        shutil.copyfile(names[0], p)
elif MODE == "first":  # renders frame 0 as asked, and shows it for every frame
    from fbaconf.rendering.scenario import Scenario
    one = os.path.join(os.path.dirname(out), "one.toml")
    open(one, "w").write(Scenario.load(scenario).with_(frames=(0,)).to_toml())
    reference_outputs(src, scenario=one, images_dir=images)
    for p in names[1:]:
        shutil.copyfile(names[0], p)
else:  # the honest renderer: every frame, as the scenario asks
    reference_outputs(src, scenario=scenario, images_dir=images)
"""


def test_render_outputs_are_judged_as_images(tmp_path):
    """Before: the render rate counted files, so empty files passed (353 fps). Empty files, one
    blank image for every frame, or frame 0's picture for every frame: each fails the render
    measurement; the honest renderer (the control) passes it."""
    rates = {}
    for mode in ("empty", "blank", "first", "honest"):
        d = tmp_path / mode
        d.mkdir()
        m = _manifest(d, RENDER.replace("{mode}", mode), images=True)
        r = speed.measure_claim(load_manifest(m), CLAIM, lengths=[12, 48], repeats=1)
        (ren,) = [x for x in r if x.operation == "render"]
        rates[mode] = (ren.verdict, ren.rate_fps)
        if mode == "honest":
            # a pass, or on a busy machine inconclusive (even no rate at all: the slope is the load's)
            assert ren.verdict == "inconclusive" or (ren.verdict == "pass" and ren.rate_fps > 0), ren.message
        else:
            assert ren.verdict == "fail" and ren.rate_fps == 0.0, ren.message
            assert "not the rendering of the content" in ren.message, ren.message
    print(rates)


def test_a_per_frame_cost_that_is_not_positive_is_an_error_not_an_infinite_rate(tmp_path, monkeypatch):
    real = speed._Runner.run
    idle = MachineSample(t=0.0, busy_s=0.0, pressure_s=None, own_s=0.0, load=0.0)

    def faster_when_longer(self, n):
        real(self, n)
        return speed_load.Window(n, 1.0 - n / 1000, idle, idle, cpu_s=None, stall_s=None, stall_source="none")

    monkeypatch.setattr(speed._Runner, "run", faster_when_longer)
    m = _manifest(tmp_path, HONEST)
    r = speed.measure(load_manifest(m), CLAIM, "decode", lengths=[2, 8], repeats=1)
    assert not r.passed and r.verdict == "fail" and r.rate_fps == 0.0 and not math.isinf(r.rate_fps)
    assert "no decode rate" in r.message and "not positive" in r.message, r.message


def test_a_per_frame_cost_that_is_not_positive_on_a_busy_machine_is_inconclusive(tmp_path, monkeypatch):
    """An honest renderer measured -2.4 ms a frame at load 6 on 2 cores: on a machine other work
    held (here 80 % of the CPUs, during and between the runs) the slope is the lab's noise."""
    real = speed._Runner.run
    clock = iter(range(0, 10_000, 1))

    def sample():
        t = float(next(clock))
        return MachineSample(t=t, busy_s=1.6 * t, pressure_s=None, own_s=0.0, load=6.0)

    def faster_when_longer_on_a_busy_machine(self, n):
        real(self, n)
        before = sample()
        after = sample()
        return speed_load.Window(n, 1.0 - n / 1000, before, after, cpu_s=0.1, stall_s=None, stall_source="none")

    monkeypatch.setattr(speed._Runner, "run", faster_when_longer_on_a_busy_machine)
    m = _manifest(tmp_path, HONEST)
    r = speed.measure(load_manifest(m), CLAIM, "decode", lengths=[2, 8], repeats=1)
    assert r.verdict == "inconclusive" and not r.passed and r.rate_fps == 0.0, r.message
    assert "not positive" in r.message and "the machine was busy" in r.message, r.message


# Sleeps 1/25 s a frame and meanwhile keeps four threads busy: it makes itself wait for a CPU,
# hoping its reading is taken for a busy machine's.
CONTENDER = HONEST.replace(
    "    time.sleep(len(frames) / 25.0)\n",
    """\
    import threading
    stop = []
    def spin():
        while not stop:
            pass
    threads = [threading.Thread(target=spin) for _ in range(4)]
    for t in threads:
        t.start()
    time.sleep(len(frames) / 25.0)
    stop.append(1)
""",
)


def test_a_decoder_cannot_make_itself_inconclusive(tmp_path, monkeypatch):
    """Its busy threads are its own CPU time, not other processes' — and on a machine where
    nothing else runs (the counters of other processes read as zero: the decoder's own accounting
    is real) the wait it made for itself excuses nothing: SPEED FAIL."""
    monkeypatch.setattr(speed_load, "_others", lambda *a, **k: 0.0)
    r = _decode_result(_manifest(tmp_path, CONTENDER))
    assert r.verdict == "fail" and r.rate_fps < 240, r.message
    assert r.cpu_s is not None and r.cpu_s > 0.3 * r.wall_s, r.message  # its spinning threads were counted as its own
    assert r.stall_s is not None and r.stall_s > 0, r.message  # and it did wait for a CPU


def test_a_decoder_failing_in_the_speed_phase_is_named_by_its_manifest(tmp_path):
    """The message names the decoder ("speedy exited with code 3"), as a case's does — not the
    runtime that ran it (python3)."""
    r = _decode_result(_manifest(tmp_path, "import sys\nsys.exit(3)\n"))
    assert not r.passed and r.verdict == "fail"
    assert "speedy exited with code 3" in r.message, r.message
