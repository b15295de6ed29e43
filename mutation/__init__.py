"""The suite's self-check: mutant decoders (the reference with one realistic bug) that the
suites must kill. :mod:`.core` applies a mutant, :mod:`.measure` holds the suite's own
mutants and runs them, :mod:`.independent` the mutants written from the spec notes alone
(``fbaconf suites mutants``; ``mutation/data/``)."""
