"""Decoder manifests (TOML) and the small Python programs the tests run as decoders under test.

Values are written as JSON literals, which are valid TOML basic strings and arrays for the
paths and argv the tests use."""

from __future__ import annotations

import json
import textwrap
from collections.abc import Sequence
from pathlib import Path

PRELUDE = "import os, signal, sys, time\n"


def _toml(v: object) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (list, tuple)):
        return json.dumps(list(v))
    return json.dumps(v)


def write_manifest(
    path: Path,
    decode: Sequence[str],
    *,
    name: str | None = None,
    claims: Sequence[str] = ("simple@1",),
    inputs: Sequence[str] = ("fba",),
    outputs: Sequence[str] = ("faps",),
    faps_format: str | None = "fap",
    serve: Sequence[str] | None = None,
    limits: str = "timeout_s = 20",
    extra: str = "",
    **top: object,
) -> Path:
    """Write a manifest to ``path`` (its folder made): ``top`` adds top-level keys (``tools``,
    ``serve_equivalent``…), ``extra`` raw top-level TOML lines, ``limits`` the [limits] body."""
    lines = [f"name = {_toml(name or path.stem)}", f"claims = {_toml(claims)}", f"inputs = {_toml(inputs)}"]
    lines.append(f"outputs = {_toml(outputs)}")
    if faps_format is not None:
        lines.append(f"faps_format = {_toml(faps_format)}")
    lines += [f"{k} = {_toml(v)}" for k, v in top.items()]
    if extra:
        lines.append(extra.rstrip("\n"))
    lines += ["[commands]", f"decode = {_toml(decode)}"]
    if serve is not None:
        lines.append(f"serve = {_toml(serve)}")
    lines += ["[limits]", limits.rstrip("\n")]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path


def program(path: Path, body: str, *, prelude: str = PRELUDE) -> Path:
    """A Python program (``prelude`` + the dedented ``body``) at ``path``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(prelude + textwrap.dedent(body))
    return path


def python_decoder(
    folder: Path,
    name: str,
    body: str,
    *,
    serve_body: str | None = None,
    prelude: str = PRELUDE,
    **manifest: object,
) -> Path:
    """A decoder written in Python, run as ``{python} SCRIPT {input} {faps_out}`` (and, with
    ``serve_body``, a serve program ``{python} SERVE``); returns its manifest ``folder/NAME.toml``."""
    script = program(folder / f"{name}.py", body, prelude=prelude)
    serve = None
    if serve_body is not None:
        serve = ["{python}", str(program(folder / f"{name}-serve.py", serve_body, prelude=prelude))]
    return write_manifest(
        folder / f"{name}.toml",
        ["{python}", str(script), "{input}", "{faps_out}"],
        name=name,
        serve=serve,
        **manifest,  # type: ignore[arg-type]
    )


HONEST = """\
import os, sys, signal, subprocess, time
IN, OUT = sys.argv[1], sys.argv[2]
def honest():
    from fbaconf.reference.pipeline import reference_outputs
    reference_outputs(IN, faps_out=OUT)
"""


def decoder(
    tmp_path: Path, name: str, body: str, *, limits: str = "timeout_s = 20\n", faps_format: str = "npz"
) -> Path:
    """A (possibly hostile) decoder written in Python, run as ``{python} SCRIPT {input} {faps_out}``;
    ``body`` sees IN, OUT (paths) and may call honest() to decode with the reference."""
    script = program(tmp_path / f"{name}.py", body, prelude=HONEST)
    return write_manifest(
        tmp_path / f"{name}.toml",
        ["{python}", str(script), "{input}", "{faps_out}"],
        faps_format=faps_format,
        limits=limits,
    )
