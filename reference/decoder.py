"""The bundled reference decoder as a program (its in-process adapter: :mod:`.refadapter`).

As a program (what ``adapters/reference.toml`` runs in a subprocess)::

    python -m fbaconf.reference.decoder decode IN.fba|IN.fap [--scene S.bt|S.bifs] [--scenario SC.toml]
        [--faps-out F.npz|F.fap] [--vertices-out V.npz] [--images-dir DIR] [--reading ID ...]
    python -m fbaconf.reference.decoder decode-multi --out-dir DIR [--reading ID ...] IN1.fba IN2.fba ...

``--reading D7:rewind-14`` decodes by another reading of a provisional decision
(``bitstreams/data/readings.toml``): what a decoder that follows it writes, and declares in its
manifest (``readings = [...]``).

Exit codes: 0 done, 2 the input was rejected (a typed error on stderr), 69 not supported.
The chain itself is :mod:`fbaconf.reference.pipeline`, which also makes the goldens, so the reference passes
by construction only if the whole pipeline is deterministic — which the golden tooling
checks by regenerating bit for bit.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from fbaconf.bitstreams import readings
from fbaconf.errors import FbaconfInputError
from fbaconf.reference.pipeline import is_fap_text, multi_outputs, reference_outputs

# Nothing of the harness is imported here: this program starts once per case.


# how the program says it rejects its input (exit 2); what follows is the typed error
ERROR_PREFIX = "fbaconf-refdecoder: error: "


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="fbaconf-refdecoder", description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    d = sub.add_parser("decode")
    d.add_argument("input", type=Path)
    d.add_argument("--scene", type=Path)
    d.add_argument("--scenario", type=Path)
    d.add_argument("--faps-out", type=Path)
    d.add_argument("--vertices-out", type=Path)
    d.add_argument("--images-dir", type=Path)
    d.add_argument("--reading", action="append", default=[])
    m = sub.add_parser("decode-multi")
    m.add_argument("--reading", action="append", default=[])
    m.add_argument("--out-dir", type=Path, required=True)
    m.add_argument("--format", choices=("npz", "fap"), default="npz")
    m.add_argument("inputs", type=Path, nargs="+")
    a = ap.parse_args(argv)
    try:
        with readings.using(*a.reading):
            if a.cmd == "decode":
                reference_outputs(
                    a.input,
                    scene=a.scene,
                    scenario=a.scenario,
                    faps_out=a.faps_out,
                    vertices_out=a.vertices_out,
                    images_dir=a.images_dir,
                    player_state=is_fap_text(a.input),
                )
            else:
                multi_outputs(a.inputs, a.out_dir, a.format)
    except FbaconfInputError as e:
        print(f"{ERROR_PREFIX}{e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
