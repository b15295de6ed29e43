"""Fuzzing fbaconf's own readers in-process (``fbaconf fuzz --self``): every exception that is not
one of its typed input errors is a finding."""

from __future__ import annotations

import re
import time
import traceback
from pathlib import Path

import numpy as np

from fbaconf import rules as R
from fbaconf.animation.engine import animate
from fbaconf.bitstreams import decoder
from fbaconf.bitstreams.faptext import read_fap_text
from fbaconf.bitstreams.frames import FapFrames
from fbaconf.errors import FbaconfInputError
from fbaconf.harness.compare import compare_faps
from fbaconf.profiles import checker
from fbaconf.scenes import bifs, bt

from .inputs import Entry, InputKind
from .model import stream_features
from .scenes import scene_features
from .targets import ExecResult, Verdict, stack_hash


class SelfTarget:
    """fbaconf's own parsers in-process: the decoder (typed errors only, sane output, round trip of
    generated streams), the checker (never raises, no internal diagnostic), the BT scene reader
    and the binary BIFS reader (typed errors only)."""

    name = "self"

    def __init__(self, *, checker_every: int = 4, slow_s: float = 5.0, scene_stream: bytes | None = None) -> None:
        self.bt, self.decoder, self.checker = bt, decoder, checker
        self.bifs = bifs
        self.checker_every = max(1, checker_every)
        self.slow_s = slow_s
        self.count = 0
        self.scene_stream = scene_stream
        self.kind = InputKind.STREAM

    def ext(self) -> str:
        return "fba"

    def execute(self, inp: Entry) -> ExecResult:
        self.count += 1
        t0 = time.thread_time()  # the parsers' own CPU time: wall time on a loaded machine is not theirs
        feats: set[str] = set()
        try:
            v = getattr(self, f"_{inp.kind}")(inp, feats)
        except Exception as e:  # noqa: BLE001 - anything escaping is the finding
            tb = traceback.format_exc()
            st = stack_hash(tb)
            where = _innermost_fbaconf_frame(e)
            v = Verdict(
                "exception",
                f"{inp.kind}:{type(e).__name__}:{where}:{st[1] if st else ''}",
                f"{inp.kind} parser raised {type(e).__name__}: {e} (at {where})",
                {"traceback": tb[-3000:]},
            )
        dt = time.thread_time() - t0
        if v is None and dt > self.slow_s:
            v = Verdict(
                "slow", f"{inp.kind}", f"{inp.kind} input took {dt:.1f} s of CPU (> {self.slow_s:g} s)", {"seconds": dt}
            )
        return ExecResult(v, feats)

    def _stream(self, inp: Entry, feats: set[str]) -> Verdict | None:
        data = inp.data
        try:
            res = self.decoder.decode(data)
        except FbaconfInputError as e:
            rule = getattr(e, "rule", "?")
            feats.add(f"rule:{rule}")
            if rule == "internal":
                return Verdict(
                    "internal-error", f"decoder:{e.message.split(':')[0][:80]}", f"decoder internal failure: {e}"
                )
            res = None
        if res is not None:
            feats |= stream_features(res.planes, res.end_code, None)
            fr = res.frames
            if fr.values.dtype != np.int32 or not np.isfinite(fr.time_ms).all() or len(fr.values) != len(fr.status):
                return Verdict(
                    "bad-output",
                    "decoder:frames",
                    "decoded FapFrames malformed (dtype, non-finite times or inconsistent lengths)",
                )
            if inp.recon is not None:
                r = compare_faps(inp.recon, fr, text_output=False)
                if not r.outcome.ok:
                    return Verdict(
                        "round-trip",
                        f"decoder:{(r.first_difference or {}).get('what')}",
                        f"generated stream decodes differently from the encoder's reconstruction: {r.message}",
                        {"first_difference": r.first_difference},
                    )
        if self.count % self.checker_every == 0:
            return self._check(data, None)
        return None

    def _check(self, data: bytes, scene) -> Verdict | None:
        rep = self.checker.analyse(
            data, scene=scene, claim="simple@1" if scene is None else "predictable@2", smallest_claim=True
        )
        bad = [d for d in rep.diagnostics if d.code == R.CHECK_INTERNAL or d.code not in R.CODES]
        if bad:
            msg = bad[0].message
            return Verdict(
                "internal-error", f"checker:{re.sub(r'[0-9]+', 'N', msg)[:80]}", f"checker internal failure: {msg}"
            )
        return None

    def _scene(self, inp: Entry, feats: set[str]) -> Verdict | None:
        try:
            text = inp.data.decode("utf-8")
        except UnicodeDecodeError:
            text = inp.data.decode("utf-8", "replace")
        try:
            scene = self.bt.parse(text)
        except FbaconfInputError as e:
            feats.add(f"rule:{getattr(e, 'rule', '?')}")
            return None
        feats |= scene_features(scene, None, text)
        if self.count % 2 == 0:
            self._compile(scene, feats)
        if self.scene_stream is not None and self.count % self.checker_every == 0:
            return self._check(self.scene_stream, scene)
        if self.bifs is not None and hasattr(self.bifs, "encode") and self.count % self.checker_every == 1:
            try:  # a scene the reader accepts either encodes and reads back, or is refused with a typed error
                blob = self.bifs.encode(scene)
            except FbaconfInputError:
                return None
            self.bifs.decode(blob)
        return None

    def _text(self, inp: Entry, feats: set[str]) -> Verdict | None:
        """The .fap reader: any text is read or refused with a typed error."""
        try:
            _frames, _header, warnings = read_fap_text(inp.data.decode("utf-8", "replace"))
            feats |= {f"text-warning:{w.rule}" for w in warnings}
            feats.add("text:ok")
        except FbaconfInputError as e:
            feats.add(f"text-rule:{getattr(e, 'rule', '?')}")
        return None

    def _bifs(self, inp: Entry, feats: set[str]) -> Verdict | None:
        if self.bifs is None:
            return None
        try:
            scene = self.bifs.decode(inp.data)
            feats.add("bifs:ok")
        except FbaconfInputError as e:
            feats.add(f"bifs-rule:{getattr(e, 'rule', '?')}")
            return None
        self._compile(scene, feats)
        return None

    def _compile(self, scene, feats: set[str]) -> None:
        """Scene compilation and one animated frame (FDP calibration, FIT, FaceDefTables): a scene
        the reader accepts either animates or is refused with a typed error — anything else
        escapes to execute() and is the finding."""
        try:
            animate(FapFrames.empty(1), scene)
            feats.add("compile:ok")
        except FbaconfInputError as e:
            feats.add(f"compile-rule:{getattr(e, 'rule', '?')}")


def _innermost_fbaconf_frame(e: BaseException) -> str:
    tb = traceback.extract_tb(e.__traceback__)
    for fr in reversed(tb):
        if "fbaconf" in fr.filename or "/work/" in fr.filename:
            return f"{Path(fr.filename).name}:{fr.lineno}"
    return f"{Path(tb[-1].filename).name}:{tb[-1].lineno}" if tb else "?"
