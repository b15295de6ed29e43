"""fbaconf — conformance and profile test suite for MPEG-4 Face Animation decoders.

Every top-level stage folder of the repository (``bitstreams/``, ``scenes/``, ``animation/``,
``rendering/``, ``profiles/``, ``conformance/``, ``golden/``, ``isolation/``, ``harness/``,
``mutation/``, ``fuzz/``, ``generators/``) is installed as a sub-package of this namespace
(``fbaconf.bitstreams`` …), so their import names never collide with other distributions;
``setup.py`` discovers them. This folder itself holds the small core: the error types, the
rule registry, the reference pipeline and the command line (docs/architecture.md).
"""

__version__ = "0.1.0"
