"""``fuzz_one_input``: the entry point for coverage-guided fuzzers (atheris, OSS-Fuzz).

The same in-process checks as ``fbaconf fuzz --self`` (:class:`fbaconf.fuzz.selftarget.SelfTarget`):
the first byte of the input selects the parser, the rest is its input —

* 0-3: the reference decoder (typed errors only, sane FapFrames; every 4th call also runs
  the stream checker, which must never fail internally);
* 4: the stream checker alone;
* 5: the BT scene reader (the bytes as UTF-8 text);
* 6: the binary BIFS scene reader;
* 7: a valid stream from the structure-aware generator, with the rest of the input driving
  one field-aware mutation (so a byte-level fuzzer reaches deep header states quickly).

A finding raises :class:`FuzzFinding` (atheris reports it as a crash with the traceback).

Run with atheris (``pip install atheris``)::

    python -m fbaconf.fuzz.atheris_entry [libFuzzer options] [CORPUS_DIR]

OSS-Fuzz: a ``fuzz_fbaconf.py`` that imports this module and calls :func:`main`.
"""

from __future__ import annotations

import random
import sys

from .inputs import InputKind

_TARGET = None


class FuzzFinding(AssertionError):
    """An input made one of fbaconf's parsers misbehave (see the message)."""


def _target():
    global _TARGET
    if _TARGET is None:
        from .choosers import RandomChooser
        from .inputs import gen_valid
        from .selftarget import SelfTarget

        stream = gen_valid(RandomChooser(random.Random(0))).data
        _TARGET = SelfTarget(checker_every=4, scene_stream=stream)
    return _TARGET


def fuzz_one_input(data: bytes) -> None:
    """Run one input through fbaconf's own parsers; raise :class:`FuzzFinding` on a finding."""
    from .choosers import RandomChooser
    from .inputs import Entry, gen_valid
    from .mutators import mutate_stream

    t = _target()
    sel = data[0] % 8 if data else 0
    body = bytes(data[1:])
    if sel <= 3:
        e = Entry(body)
    elif sel == 4:
        v = t._check(body, None)
        if v is not None:
            raise FuzzFinding(f"{v.cls} ({v.signature}): {v.message}")
        return
    elif sel == 5:
        e = Entry(body, kind=InputKind.SCENE)
    elif sel == 6:
        e = Entry(body, kind=InputKind.BIFS)
    else:
        rng = random.Random(body)
        base = gen_valid(RandomChooser(rng))
        mutated, _how = mutate_stream(rng, base, [base])
        e = Entry(mutated)
    v = t.execute(e).verdict
    if v is not None:
        raise FuzzFinding(f"{v.cls} ({v.signature}): {v.message}\n{v.detail.get('traceback', '')}")


def main(argv: list[str] | None = None) -> None:  # pragma: no cover - needs atheris
    try:
        import atheris
    except ImportError:
        sys.exit(
            "fuzz_entry: atheris is not installed (pip install atheris); `fbaconf fuzz --self` needs nothing extra"
        )
    with atheris.instrument_imports():
        import fbaconf.bitstreams.decoder
        import fbaconf.profiles.checker
        import fbaconf.scenes.bt  # noqa: F401
    atheris.Setup(sys.argv if argv is None else argv, fuzz_one_input)
    atheris.Fuzz()


if __name__ == "__main__":  # pragma: no cover
    main()
