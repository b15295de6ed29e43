"""fbaconf — conformance and profile test suite for MPEG-4 Face Animation decoders.

The project's stage folders (``bitstreams/``, ``profiles/``, ``animation/``,
``rendering/``, ``harness/``, ``conformance/``) are installed as sub-packages of this
namespace (``fbaconf.bitstreams`` …) so that their import names never collide with
other distributions.
"""
__version__ = "0.1.0"
