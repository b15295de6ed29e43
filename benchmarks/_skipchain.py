"""The planted test decoder (tests/fuzz_decoders/skipchain.c) for the benchmarks: built into a
folder with a manifest beside it, in its fixed form (-DSKIPCHAIN_FIXED) or with its planted bug,
with or without [commands] serve."""

from __future__ import annotations

import subprocess
from pathlib import Path

SOURCE = Path(__file__).resolve().parent.parent / "tests" / "fuzz_decoders" / "skipchain.c"


def build(cc: str, folder: Path, name: str = "skipchain", *, fixed: bool = False, serve: bool = False) -> Path:
    """Compile ``folder/name`` and write ``folder/name[-serve].toml``; returns the manifest."""
    exe = folder / name
    if not exe.exists():
        subprocess.run([cc, "-O2", *(["-DSKIPCHAIN_FIXED"] if fixed else []), "-o", str(exe), str(SOURCE)], check=True)
    text = (
        'name = "skipchain"\nclaims = ["simple@1"]\ninputs = ["fba"]\noutputs = ["faps"]\nfaps_format = "fap"\n'
        f'[commands]\ndecode = ["{{manifest_dir}}/{name}", "{{input}}", "{{faps_out}}"]\n'
        + (f'serve = ["{{manifest_dir}}/{name}", "--serve"]\n' if serve else "")
        + "[limits]\ntimeout_s = 2\nmemory_mb = 256\noutput_mb = 16\n"
    )
    manifest = folder / f"{name}{'-serve' if serve else ''}.toml"
    manifest.write_text(text)
    return manifest
