"""Build hook for the optional C extension (everything else is in pyproject.toml).

``fbaconf.bitstreams._fastarith`` is the native inner loop of the arithmetic coder and
``fbaconf.rendering._fastraster`` the rasteriser's scan conversion and depth test. Both are
optional: when no C compiler is available the build continues without them and the
pure-Python/numpy reference paths (bitstreams/arith.py, rendering/raster.py) are used.
FBACONF_PURE_PYTHON=1 forces the reference paths at run time.
"""
from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension(
            "fbaconf.bitstreams._fastarith",
            sources=["bitstreams/_fastarith.c"],
            optional=True,
            extra_compile_args=["-O2"],
        ),
        Extension(
            "fbaconf.rendering._fastraster",
            sources=["rendering/_fastraster.c"],
            optional=True,
            # no fused multiply-add: the same double rounding as numpy's separate * and +
            extra_compile_args=["-O2", "-ffp-contract=off"],
        ),
    ]
)
