"""Hypothesis strategies built from the generators and mutators, for property tests of any parser."""

from __future__ import annotations

import random

from .choosers import DrawChooser
from .inputs import Entry, gen_valid
from .mutators import mutate_stream
from .scenes import gen_scene, mutate_scene


def valid_entries():
    """Hypothesis strategy: valid stream :class:`Entry` objects (with the encoder's reconstruction)."""
    from hypothesis import strategies as st  # noqa: PLC0415 (test-only dependency)

    return st.composite(lambda draw: gen_valid(DrawChooser(draw)))()


def valid_streams():
    """Hypothesis strategy: valid streams (bytes) from the generator (content + encoder options)."""
    return valid_entries().map(lambda e: e.data)


def near_valid_streams(seeds: list[bytes] | None = None):
    """Hypothesis strategy: a valid stream (generated, or one of ``seeds``) with 1-3 mutations."""
    from hypothesis import strategies as st  # noqa: PLC0415 (test-only dependency)

    @st.composite
    def strat(draw):
        if seeds and draw(st.booleans()):
            e = Entry(draw(st.sampled_from(seeds)))
        else:
            e = gen_valid(DrawChooser(draw))
        rng = random.Random(draw(st.integers(0, 2**32 - 1)))
        data = e.data
        for _ in range(draw(st.integers(1, 3))):
            data, _how = mutate_stream(rng, Entry(data), [e])
        return data

    return strat()


def bt_scenes(mutated: bool = False):
    """Hypothesis strategy: BT scene text from the node tables (``mutated``: plus token mutations)."""
    from hypothesis import strategies as st  # noqa: PLC0415 (test-only dependency)

    @st.composite
    def strat(draw):
        e = gen_scene(DrawChooser(draw))
        if mutated:
            rng = random.Random(draw(st.integers(0, 2**32 - 1)))
            data, _ = mutate_scene(rng, e, [e])
            return data.decode("utf-8", "replace")
        return e.data.decode("utf-8")

    return strat()
