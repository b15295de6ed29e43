"""Build hook: the package map and package data, discovered (nothing hand-listed), and the
optional C extensions.

Every top-level stage folder (a folder with an ``__init__.py``) is installed as
``fbaconf.<folder>`` (``fbaconf/`` itself as ``fbaconf``), so no import name collides with
another distribution; every sub-folder with an ``__init__.py`` is a sub-package, and every
other file under a package (data, C sources, manifests) is package data.

``fbaconf.bitstreams._fastarith`` is the native inner loop of the arithmetic coder and
``fbaconf.rendering._fastraster`` the rasteriser's scan conversion and depth test. Both are
optional: when no C compiler is available the build continues without them and the
pure-Python/numpy reference paths (bitstreams/arith.py, rendering/raster.py) are used.
FBACONF_PURE_PYTHON=1 forces the reference paths at run time.
"""

from pathlib import Path

from setuptools import Extension, setup

ROOT = Path(__file__).resolve().parent
# Folders beside the stages that are not part of the distribution.
NOT_INSTALLED = {"tests", "benchmarks", "examples", "docs", "build", "dist"}
SKIP_PARTS = {"__pycache__"}
SKIP_SUFFIXES = {".pyc", ".pyo", ".so", ".o"}


def _stages() -> dict[str, str]:
    out = {}
    for d in sorted(ROOT.iterdir()):
        if (
            d.is_dir()
            and not d.name.startswith((".", "_"))
            and d.name not in NOT_INSTALLED
            and (d / "__init__.py").is_file()
        ):
            out["fbaconf" if d.name == "fbaconf" else f"fbaconf.{d.name}"] = d.name
    return out


def _discover() -> tuple[dict[str, str], list[str], dict[str, list[str]]]:
    package_dir, packages, package_data = {}, [], {}
    for name, folder in _stages().items():
        base = ROOT / folder
        pkg_dirs = sorted(p.parent for p in base.rglob("__init__.py") if not SKIP_PARTS & set(p.parts))
        for d in pkg_dirs:
            rel = d.relative_to(base)
            pkg = ".".join([name, *rel.parts]) if rel.parts else name
            package_dir[pkg] = str(Path(folder, *rel.parts))
            packages.append(pkg)
        # Data: every non-Python file, attributed to the innermost package above it.
        for f in sorted(base.rglob("*")):
            if not f.is_file() or SKIP_PARTS & set(f.parts) or f.suffix in SKIP_SUFFIXES or f.suffix == ".py":
                continue
            owner = max((d for d in pkg_dirs if d in f.parents), key=lambda d: len(d.parts))
            rel = owner.relative_to(base)
            pkg = ".".join([name, *rel.parts]) if rel.parts else name
            package_data.setdefault(pkg, []).append(str(f.relative_to(owner)))
    return package_dir, packages, package_data


PACKAGE_DIR, PACKAGES, PACKAGE_DATA = _discover()

setup(
    package_dir=PACKAGE_DIR,
    packages=PACKAGES,
    package_data=PACKAGE_DATA,
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
    ],
)
