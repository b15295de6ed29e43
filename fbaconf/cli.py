"""The ``fbaconf`` command line: one entry point, one verb per stage.

Each stage package contributes its verbs through a ``cli.py`` module exposing
``register(subparsers)``; each verb's handler returns the process exit code.
Typed input errors (:class:`FbaconfInputError`) become a one-line message and exit
code 2 — never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from fbaconf import __version__
from fbaconf.errors import FbaconfInputError

# Stage modules that contribute verbs, in help order.
VERB_MODULES = (
    "fbaconf.bitstreams.cli",
    "fbaconf.profiles.cli",
    "fbaconf.animation.cli",
    "fbaconf.rendering.cli",
    "fbaconf.conformance.cli",
    "fbaconf.harness.cli",
    "fbaconf.explain.cli",
    "fbaconf.certification.cli",
    "fbaconf.fuzz.cli",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="fbaconf", description="Conformance and profile test suite for MPEG-4 Face Animation decoders."
    )
    parser.add_argument("--version", action="version", version=f"fbaconf {__version__}")
    sub = parser.add_subparsers(dest="verb", metavar="VERB")
    for name in VERB_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except FbaconfInputError as e:
        print(f"fbaconf {args.verb}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"fbaconf {args.verb}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
