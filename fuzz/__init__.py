"""Fuzzing bitstream parsers: ``fbaconf fuzz`` (docs/fuzzing.md).

One module per concern: :mod:`.model` (the syntax model and its features), :mod:`.choosers`,
:mod:`.generators` (valid streams), :mod:`.mutators` (field- and byte-level), :mod:`.scenes`
(BT scene inputs), :mod:`.text` (.fap text inputs, for players), :mod:`.corpus` (seeds), :mod:`.targets` (the decoder under test, or
fbaconf itself, and the verdicts), :mod:`.minimise`, :mod:`.engine` (the loop),
:mod:`.findings` (on disk, replay), :mod:`.promote` (into the regression suite),
:mod:`.strategies` (hypothesis strategies; needs hypothesis), :mod:`.cli` (the verb),
:mod:`.atheris_entry`. The names below are the stage's public API.
"""
from .choosers import RandomChooser
from .corpus import conformance_seeds, default_seeds, scene_seeds, short_prefixes
from .engine import Finding, Fuzzer
from .findings import replay, write_finding, write_summary
from .generators import Entry, gen_valid
from .minimise import ddmin, minimise
from .model import DICTIONARY, StreamModel, stream_model
from .mutators import BYTE_MUTATORS, FIELD_MUTATORS, m_skip_chain, m_zero_frame_rate, mutate_stream
from .promote import REGRESSION_SUITE, promote
from .scenes import gen_scene, mutate_scene
from .targets import CLASSES, DecoderTarget, FuzzSetupError, SelfTarget, Verdict, stack_hash

__all__ = ["BYTE_MUTATORS", "CLASSES", "DICTIONARY", "DecoderTarget", "Entry", "FIELD_MUTATORS", "Finding",
           "FuzzSetupError", "Fuzzer", "REGRESSION_SUITE", "RandomChooser", "SelfTarget", "StreamModel", "Verdict",
           "conformance_seeds", "ddmin", "default_seeds", "gen_scene", "gen_valid", "m_skip_chain",
           "m_zero_frame_rate", "minimise", "mutate_scene", "mutate_stream", "promote", "replay", "scene_seeds",
           "short_prefixes", "stack_hash", "stream_model", "write_finding", "write_summary"]
