"""Promotion of findings into the regression suite (conformance/data/regression.toml)."""

from __future__ import annotations

import json
import tomllib
from collections.abc import Callable
from pathlib import Path

from fbaconf._atomic import atomic_write_bytes, atomic_write_text
from fbaconf.bitstreams.decoder import decode
from fbaconf.conformance.suite import package_root
from fbaconf.errors import FbaconfInputError
from fbaconf.profiles.checker import check_stream
from fbaconf.safefs import confined, read_regular, safe_name

from .findings import load_findings
from .targets import FuzzSetupError

REGRESSION_SUITE = "simple-l1-regression"
REGRESSION_HEADER = f"""# fbaconf regression suite: fuzz findings promoted by `fbaconf fuzz --promote DIR`.
#
# Each case is a committed input under conformance/data/regression/ (generator = "file"). With
# `expect` (the error diagnostics fbaconf check gives for it) it is an error case: a decoder must
# reject it with one of its documented reject exit codes, within its limits — decoding it without
# complaint, a crash, a hang or a memory blow-up fails.
# Without `expect` the input is a valid stream whose reference output becomes the golden.
# Appended by the tool; edit descriptions freely, keep ids stable.

[[suite]]
name = "{REGRESSION_SUITE}"
claim = "simple@1"
group = "regression"
description = "Simple profile, level 1: inputs that crashed, hung or blew up decoders (fuzz findings)"
"""


MAX_FINDING_BYTES = 16 * 2**20


def _toml_str(s: str) -> str:
    return json.dumps(s, ensure_ascii=False)


def promote(fuzz_dir: Path, data_dir: Path | None = None, *, log: Callable[[str], None] = print) -> list[dict]:
    """Copy each stream finding's minimal input to ``data_dir/regression/<id>.fba`` and append a
    ``[[case]]`` to ``data_dir/regression.toml`` (created with its ``[[suite]]`` table). Returns
    the cases added (ids already present are skipped)."""
    if data_dir is None:
        data_dir = package_root() / "data"
    data_dir = Path(data_dir)
    reg = data_dir / "regression.toml"
    text = reg.read_text("utf-8") if reg.is_file() else REGRESSION_HEADER
    try:
        existing = {c["id"] for c in tomllib.loads(text).get("case", [])}
    except tomllib.TOMLDecodeError as e:
        raise FuzzSetupError(f"{reg}: not valid TOML: {e}") from None
    findings = load_findings(fuzz_dir)
    if not findings:
        raise FuzzSetupError(f"no findings under {Path(fuzz_dir) / 'findings'}")
    added = []
    for d, doc in findings:
        if doc.get("input_kind", "stream") != "stream":
            log(f"skipped {d.name}: a {doc.get('input_kind')} finding (the regression suite holds streams)")
            continue
        try:  # a finding folder is data: its id names a file, its minimal input must stay inside it
            cid = "fuzz-" + safe_name(str(doc.get("id", "")), what="finding id")
            minimal = (doc.get("minimal") or {}).get("file") if isinstance(doc.get("minimal"), dict) else None
            data = read_regular(confined(d, str(minimal), what="minimal input"), MAX_FINDING_BYTES)
        except FbaconfInputError as e:
            log(f"skipped {d.name}: {e.message}")
            continue
        if cid in existing:
            log(f"skipped {cid}: already in {reg.name}")
            continue
        valid = True
        try:
            decode(data)
        except FbaconfInputError:
            valid = False
        codes = sorted({x.code for x in check_stream(data, claim="simple@1") if x.severity == "error"})
        if codes:
            valid = False
        rel = f"regression/{cid}.fba"
        (data_dir / "regression").mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(data_dir / rel, data)
        dec = doc.get("decoder") or {}
        origin = str(doc.get("origin", "")).split("<-")[-1]
        desc = (
            f"fuzz finding {doc.get('id')}: {doc.get('class')} ({doc.get('signature')}) of decoder "
            f"{dec.get('name', doc.get('target', '?'))}; minimal input of {len(data)} bytes "
            f"(from {origin})"
        )[:300]
        lines = [
            "",
            "[[case]]",
            f"suite = {_toml_str(REGRESSION_SUITE)}",
            f"id = {_toml_str(cid)}",
            f"description = {_toml_str(desc)}",
            'generator = "file"',
            f"file = {_toml_str(rel)}",
        ]
        if not valid:
            lines.append("expect = [" + ", ".join(_toml_str(c) for c in codes) + "]")
        text = text.rstrip("\n") + "\n" + "\n".join(lines) + "\n"
        existing.add(cid)
        case = {"id": cid, "file": rel, "valid": valid, "expect": None if valid else codes}
        added.append(case)
        log(
            f"promoted {cid}: {rel} ({len(data)} bytes, "
            + ("valid stream: decode case, run `fbaconf golden regenerate`" if valid else f"error case, expect {codes}")
            + ")"
        )
    tomllib.loads(text)  # never write a file the suite builder cannot read
    atomic_write_text(reg, text)
    return added
