"""Fuzzing bitstream parsers: ``fbaconf fuzz`` (docs/fuzzing.md).

One module per concern: :mod:`.model` (the syntax model and its features), :mod:`.choosers`,
:mod:`.generators` (valid streams), :mod:`.mutators` (field- and byte-level), :mod:`.scenes`
(BT scene inputs), :mod:`.text` (.fap text inputs, for players), :mod:`.corpus` (seeds),
:mod:`.targets` (the decoder under test, or fbaconf itself, and the verdicts), :mod:`.minimise`,
:mod:`.engine` (the loop), :mod:`.findings` (on disk, replay), :mod:`.promote` (into the
regression suite), :mod:`.strategies` (hypothesis strategies; needs hypothesis), :mod:`.cli`
(the verb), :mod:`.atheris_entry`. Import a name from its module; the package re-exports nothing.
"""
