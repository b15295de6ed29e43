"""Build hook for the optional C extension (everything else is in pyproject.toml).

``fbaconf.bitstreams._fastarith`` is the native inner loop of the arithmetic coder. It is
optional: when no C compiler is available the build continues without it and the
pure-Python coder (bitstreams/arith.py, the reference) is used. FBACONF_PURE_PYTHON=1
forces the pure path at run time.
"""
from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension(
            "fbaconf.bitstreams._fastarith",
            sources=["bitstreams/_fastarith.c"],
            optional=True,
            extra_compile_args=["-O2"],
        )
    ]
)
