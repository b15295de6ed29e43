"""Generators: code that makes the bundled models and the conformance suites. Run on purpose (``fbaconf
suites build``, ``python -m fbaconf.generators.models``), never at test time: what they make is
committed as data."""
