"""A decoder manifest's vocabulary (inputs, outputs, commands, placeholders) and its keys and
values checked before anything of it is used: one :class:`ManifestError` line naming the file,
the key and the rule (the adapters built from it: :mod:`.adapters`)."""

from __future__ import annotations

import difflib
import re
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

from fbaconf.bitstreams import readings
from fbaconf.errors import FbaconfInputError
from fbaconf.isolation.environ import env_problem
from fbaconf.profiles.model import Claim, load_profiles

INPUT_KINDS = ("fba", "fap", "scene", "bifs")
OUTPUT_KINDS = ("faps", "vertices", "images")
FAPS_FORMATS = ("fap", "npz")
PLACEHOLDERS = (
    "input",
    "fba",
    "fap",
    "scene",
    "scene_bt",
    "scene_bifs",
    "scenario",
    "faps_out",
    "vertices_out",
    "images_dir",
    "frames",
    "workdir",
    "manifest_dir",
    "python",
    "faps_out_dir",
    "inputs",
)
# decode: one process per input; decode_multi: one per multi-face case; serve: the persistent
# protocol (isolation/persistent.py), one process for many inputs, each sent on stdin.
COMMANDS = ("decode", "decode_multi", "serve")
SERVE_PLACEHOLDERS = ("workdir", "manifest_dir", "python")
OUTPUT_PLACEHOLDER = {"faps": "faps_out", "vertices": "vertices_out", "images": "images_dir"}
PLACEHOLDER_PATTERN = re.compile(r"\{([a-z_]+)\}")


class ManifestError(FbaconfInputError):
    """A decoder manifest is malformed (names file, key and rule)."""


def check_manifest(data: dict[str, Any], path: Path | None) -> None:
    """Every rule of a manifest's schema (docs/harness.md); raises :class:`ManifestError` naming
    the file and the rule broken."""
    where = str(path) if path else "<manifest>"

    def bad(msg: str, rule: str) -> ManifestError:
        return ManifestError(msg if len(msg) <= 400 else msg[:400] + "…", rule=rule, file=where)

    _check_keys(data, bad)
    _check_values(data, bad)
    if "python" not in data:
        _check_commands(data, bad)


# how a check names a broken rule: the error to raise (file and length handled)
_Bad = Callable[[str, str], ManifestError]


def _check_keys(data: dict[str, Any], bad: _Bad) -> None:
    """Required keys present, no unknown or [sandbox] key, each value of its type."""
    for key in ("name", "claims", "inputs", "outputs"):
        if key not in data:
            raise bad(f"missing required key {key!r}", "manifest-key")
    if "sandbox" in data:
        raise bad(
            "[sandbox] is not a manifest key: the lab, not the decoder, sets what a decoder sees (a folder "
            "the decoder's runtime needs is the lab's `--sandbox-ro PATH`, recorded in the statement)",
            "manifest-sandbox",
        )
    for key in data:
        if key not in MANIFEST_KEYS:
            raise bad(f"unknown key {quote(key)}{_did_you_mean(str(key), MANIFEST_KEYS)}", "manifest-key")
    for key, kind, what in (
        ("name", str, "a string"),
        ("description", str, "a string"),
        ("claims", list, "a list"),
        ("tools", list, "a list of tool names"),
        ("readings", list, "a list of reading ids"),
        ("inputs", list, "a list"),
        ("outputs", list, "a list"),
        ("faps_format", str, "a string"),
        ("commands", dict, "a table"),
        ("limits", dict, "a table"),
        ("env", dict, "a table"),
        ("python", str, "a string"),
        ("options", dict, "a table"),
        ("reject_exit_codes", list, "a list"),
        ("serve_equivalent", bool, "true or false"),
    ):
        if key in data and not isinstance(data[key], kind):
            raise bad(f"{key} must be {what}, not {type(data[key]).__name__}", _KEY_RULE.get(key, "manifest-key"))
    if "tools" in data and not all(isinstance(t, str) for t in data["tools"]):
        raise bad("tools must be a list of tool names (strings)", "manifest-tools")


def _check_values(data: dict[str, Any], bad: _Bad) -> None:
    """The values: limits, env, python target, exit codes, name, claims, forms, tools."""
    for key in data.get("limits", {}) if isinstance(data.get("limits"), dict) else ():
        if key not in LIMIT_KEYS:
            raise bad(f"[limits]: unknown key {key!r}{_did_you_mean(key, LIMIT_KEYS)}", "manifest-limits")
    env = data.get("env", {})
    if not isinstance(env, dict) or not all(isinstance(v, (str, int, float, bool)) for v in env.values()):
        raise bad("[env] must be a table of NAME = value", "manifest-env")
    for k, v in env.items():
        why = env_problem(str(k), str(v))
        if why:
            raise bad(f"[env] {why}", "manifest-env")
    if "python" in data and not _PYTHON_TARGET.fullmatch(data["python"]):
        raise bad('python must be "package.module:Class" (dotted names)', "manifest-python")
    if "options" in data and not isinstance(data["options"], dict):
        raise bad("[options] must be a table", "manifest-options")
    rc = data.get("reject_exit_codes", [1])
    if (
        not isinstance(rc, list)
        or not rc
        or any(not isinstance(c, int) or isinstance(c, bool) or not 1 <= c <= 255 or c in (69, 126, 127) for c in rc)
    ):
        raise bad(
            "reject_exit_codes must be a non-empty list of exit codes 1..255 other than 69 (not supported) "
            "and 126/127 (cannot execute)",
            "manifest-reject-codes",
        )
    if not isinstance(data["name"], str) or not re.fullmatch(r"[A-Za-z0-9_@+-][A-Za-z0-9._@+-]{0,63}", data["name"]):
        raise bad(
            "name must be 1-64 letters, digits, '.', '_', '-', '+' or '@', not starting with '.' "
            "(it names the run folder)",
            "manifest-name",
        )
    if not isinstance(data["claims"], list) or not data["claims"]:
        raise bad('claims must be a non-empty list like ["simple@1"]', "manifest-claims")
    for c in data["claims"]:
        try:
            Claim.parse(c)
        except ValueError as e:
            raise bad(f"claims: {e}", "manifest-claims") from None
    for key, allowed in (("inputs", INPUT_KINDS), ("outputs", OUTPUT_KINDS)):
        vals = data[key]
        if not isinstance(vals, list) or not vals or any(v not in allowed for v in vals):
            raise bad(f"{key} must be a non-empty list of {', '.join(allowed)}; got {quote(vals)}", f"manifest-{key}")
    if not ({"fba", "fap"} & set(data["inputs"])):
        raise bad("inputs must include a stream form: fba and/or fap", "manifest-inputs")
    if data.get("faps_format", "fap") not in FAPS_FORMATS:
        raise bad(f"faps_format must be one of {FAPS_FORMATS}", "manifest-faps-format")
    if "tools" in data:
        known = load_profiles().tools
        unknown = [t for t in data["tools"] if t not in known]
        if unknown:
            raise bad(f"unknown tool(s) {quote(unknown)} (known: {', '.join(known)})", "manifest-tools")
    unknown = [r for r in data.get("readings", []) if not isinstance(r, str) or r not in readings.catalogue()]
    if unknown:
        raise bad(
            f"readings: unknown reading(s) {quote(unknown)} (known: {', '.join(readings.catalogue())}; "
            f'docs/harness.md, "Provisional requirements")',
            "manifest-readings",
        )


def _check_commands(data: dict[str, Any], bad: _Bad) -> None:
    """[commands]: decode given, known commands, argv lists of strings, known placeholders (the
    persistent ``serve`` only its own), every output's placeholder named by decode."""
    cmds = data.get("commands")
    if not isinstance(cmds, dict) or "decode" not in cmds:
        raise bad('[commands] must define decode (an argv list), or give python = "module:Class"', "manifest-commands")
    for cname, argv in cmds.items():
        if cname not in COMMANDS:
            raise bad(f"[commands] {quote(cname)}: unknown command ({', '.join(COMMANDS)})", "manifest-commands")
        if not isinstance(argv, list) or not argv or not isinstance(argv[0], str):
            raise bad(f"[commands] {cname} must be an argv list starting with the program", "manifest-commands")
        for item in argv:
            for s in item if isinstance(item, list) else [item]:
                if not isinstance(s, str):
                    raise bad(
                        f"[commands] {cname}: argv items must be strings or lists of strings", "manifest-commands"
                    )
                _check_placeholders(cname, s, bad)
    text = " ".join(str(x) for x in _flatten(cmds["decode"]))
    for out in data["outputs"]:
        ph = "{" + OUTPUT_PLACEHOLDER[out] + "}"
        if ph not in text:
            raise bad(f"outputs lists {out!r} but [commands] decode never names {ph}", "manifest-outputs")


def _check_placeholders(cname: str, s: str, bad: _Bad) -> None:
    for n in PLACEHOLDER_PATTERN.findall(s):
        if cname == "serve" and n not in SERVE_PLACEHOLDERS:
            usable = ", ".join("{" + p + "}" for p in SERVE_PLACEHOLDERS)
            raise bad(
                f"[commands] serve: {{{n}}} has no value for a persistent decoder, which gets "
                f"each input on stdin (usable: {usable})",
                "manifest-placeholder",
            )
        if n not in PLACEHOLDERS:
            raise bad(
                f"[commands] {cname}: unknown placeholder {quote(n)} (known: "
                f"{', '.join('{' + p + '}' for p in PLACEHOLDERS)})",
                "manifest-placeholder",
            )


MANIFEST_KEYS = (
    "name",
    "description",
    "claims",
    "tools",
    "readings",
    "inputs",
    "outputs",
    "faps_format",
    "commands",
    "limits",
    "env",
    "python",
    "options",
    "reject_exit_codes",
    "serve_equivalent",
)
LIMIT_KEYS = ("timeout_s", "memory_mb", "memory_kind", "output_mb", "processes")
_KEY_RULE = {
    "name": "manifest-name",
    "claims": "manifest-claims",
    "tools": "manifest-tools",
    "readings": "manifest-readings",
    "inputs": "manifest-inputs",
    "outputs": "manifest-outputs",
    "faps_format": "manifest-faps-format",
    "commands": "manifest-commands",
    "limits": "manifest-limits",
    "env": "manifest-env",
    "python": "manifest-python",
    "options": "manifest-options",
    "reject_exit_codes": "manifest-reject-codes",
}
_PYTHON_TARGET = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*:[A-Za-z_][A-Za-z0-9_]*")
MAX_MANIFEST_BYTES = 1 << 20
MAX_MANIFEST_DEPTH = 6  # a table of commands of argv lists of optional groups: 4 levels suffice
QUOTE_CHARS = 80


def quote(value: object) -> str:
    """A value of the manifest as an error message quotes it: repr, at most QUOTE_CHARS."""
    text = repr(value)
    return text if len(text) <= QUOTE_CHARS else text[:QUOTE_CHARS] + "…"


def nesting_depth(value: object, limit: int) -> int:
    """Nesting depth of parsed TOML (tables and arrays), counting no deeper than ``limit`` + 1."""
    stack: list[tuple[object, int]] = [(value, 1)]
    deepest = 0
    while stack:
        v, d = stack.pop()
        if isinstance(v, (dict, list)):
            deepest = max(deepest, d)
            if d > limit:
                return d
            stack.extend((x, d + 1) for x in (v.values() if isinstance(v, dict) else v))
    return deepest


def _did_you_mean(word: str, choices: Sequence[str]) -> str:
    close = difflib.get_close_matches(word, choices, n=1)
    return f" (did you mean {close[0]!r}?)" if close else f" (known: {', '.join(choices)})"


def _flatten(argv: Iterable[object]) -> Iterator[object]:
    for x in argv:
        if isinstance(x, list):
            yield from x
        else:
            yield x
