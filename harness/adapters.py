"""Decoder adapters: a TOML manifest for command-line decoders (any language) or a Python class.

The manifest's keys, limits, ``[env]`` rule and reserved names: docs/harness.md, "Write a
manifest" (``[limits]``: :mod:`fbaconf.isolation.bounds`; ``[env]``: :mod:`fbaconf.isolation.environ`).

Placeholders: ``{input}`` (the stream the decoder gets: ``.fba`` when it accepts ``fba``,
else the ``.fap`` text), ``{fba}``, ``{fap}``, ``{scene}`` (BT, or BIFS when the decoder
accepts only ``bifs``), ``{scene_bt}``, ``{scene_bifs}``, ``{scenario}``, ``{faps_out}``,
``{vertices_out}``, ``{images_dir}``, ``{frames}``, ``{workdir}``, ``{manifest_dir}``,
``{python}`` (this Python), and for multi-face cases ``{faps_out_dir}`` and ``{inputs}``
(an argv element that is exactly ``{inputs}`` expands to one element per face stream;
each face's output is ``{faps_out_dir}/<stream stem>.fap|.npz``). A nested list in an argv
is an optional group: included only when every placeholder in it has a value (e.g.
``["--scene", "{scene}"]`` for cases without a scene) and, for output placeholders, when
the case compares that output (``["--images-dir", "{images_dir}"]`` is dropped for cases
without image goldens, so the decoder need not render them). One command is run per case; it
must write every output whose placeholder it names.
"""

from __future__ import annotations

import difflib
import hashlib
import importlib
import re
import shutil
import sys
import time
import tomllib
import traceback
from dataclasses import dataclass, field
from pathlib import Path

from fbaconf.bitstreams import readings
from fbaconf.errors import FbaconfInputError
from fbaconf.isolation import bounds, view
from fbaconf.isolation.endings import DEFAULT_REJECT_EXIT_CODES, Ending, EndingKind, crash_report
from fbaconf.isolation.environ import env_problem
from fbaconf.isolation.sandbox import Limits, default_view, python_view
from fbaconf.profiles.model import Claim, load_profiles
from fbaconf.safefs import read_regular

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
_PH = re.compile(r"\{([a-z_]+)\}")
BUNDLED_DIR = Path(__file__).resolve().parent / "adapters"


class ManifestError(FbaconfInputError):
    """A decoder manifest is malformed (names file, key and rule)."""


class ViewError(FbaconfInputError):
    """A folder the sandbox would show a decoder shows too much (set-up error, exit 2)."""

    rule = "sandbox-view"


@dataclass
class Job:
    """One decoder invocation's files: inputs copied into its own directory, output paths."""

    workdir: Path
    values: dict[str, str]  # placeholder -> value (only those available)
    faces: list[str] = field(default_factory=list)  # multi-face input paths
    frames: int = 0
    # output placeholders the case does not compare: an optional argv group naming one is
    # dropped (a decoder that needs them unconditionally still gets a path to write to)
    unwanted: frozenset[str] = frozenset()

    def path(self, name: str) -> Path | None:
        v = self.values.get(name)
        return Path(v) if v is not None else None


class Adapter:
    """Common interface of decoder adapters."""

    name: str = "decoder"
    description: str = ""
    claims: list[str]
    tools: list[str] | None = None
    readings: tuple[str, ...] = ()  # other readings of provisional decisions the decoder follows
    inputs: list[str]
    outputs: list[str]
    faps_format: str = "npz"
    limits: Limits
    kind: str = "python"
    supports_multi: bool = False
    manifest_path: Path | None = None
    manifest_text: str = ""
    reject_exit_codes: frozenset[int] = DEFAULT_REJECT_EXIT_CODES

    @property
    def is_player(self) -> bool:
        """A decoder that reads only the .fap text form: a FAP *player*. It can be tested (``run``)
        but cannot hold an MPEG-4 profile certificate, which requires decoding the binary
        face-object stream."""
        return "fba" not in self.inputs

    def digest(self) -> str:
        return hashlib.sha256(self.manifest_text.encode("utf-8")).hexdigest()

    def describe(self) -> dict:
        return {
            "name": self.name,
            "kind": self.kind,
            "description": self.description,
            "claims": list(self.claims),
            "tools": self.tools,
            "readings": list(self.readings),
            "inputs": list(self.inputs),
            "outputs": list(self.outputs),
            "faps_format": self.faps_format,
            "manifest": str(self.manifest_path) if self.manifest_path else None,
            "reject_exit_codes": sorted(self.reject_exit_codes),
            "env": dict(getattr(self, "env", None) or {}),
            "manifest_sha256": self.digest(),
            "limits": {
                "timeout_s": self.limits.timeout_s,
                "memory_mb": self.limits.memory_mb,
                "memory_kind": self.limits.memory_kind,
                "output_mb": self.limits.output_mb,
            },
        }


class PythonAdapter(Adapter):
    """Base class for in-process decoders: override :meth:`run` (write the outputs named in
    ``job.values``: ``faps_out``, ``vertices_out``, ``images_dir``, ``faps_out_dir``).
    Raise :class:`NotSupportedError` for "not supported", a typed input error
    (:class:`fbaconf.errors.FbaconfInputError`) to reject the stream; any other exception is a
    crash. In-process decoders share the harness's process: the timeout is checked after the call
    returns, and memory is not limited — use a command manifest for untrusted code.
    :meth:`execute` is the one way ``run``, the speed phase and ``fuzz`` call it."""

    kind = "python"

    def __init__(self) -> None:
        if not hasattr(self, "claims"):
            self.claims = []
        if not hasattr(self, "inputs"):
            self.inputs = ["fba"]
        if not hasattr(self, "outputs"):
            self.outputs = ["faps"]
        if not hasattr(self, "limits"):
            self.limits = Limits()

    def run(self, job: Job) -> None:  # pragma: no cover - interface
        raise NotImplementedError

    def execute(self, job: Job) -> Execution:
        """Call :meth:`run` once; how it ended in the terms of :mod:`fbaconf.isolation.endings` (a
        typed input error is its reject, an unreadable input a set-up error, an uncaught
        exception its crash with the traceback as its report), judged there like any process."""
        t0 = time.perf_counter()
        try:
            self.run(job)
        except NotSupportedError as e:
            return Execution(
                Ending(EndingKind.NOT_SUPPORTED, f"decoder: not supported: {e}"), 69, "", time.perf_counter() - t0
            )
        except MemoryError:
            return Execution(
                Ending(EndingKind.MEMORY, "in-process decoder raised MemoryError"), None, "", time.perf_counter() - t0
            )
        except FbaconfInputError as e:
            kind, what = (
                (EndingKind.SETUP, "could not read its input")
                if e.rule == "io"
                else (EndingKind.REJECT, "rejected the stream")
            )
            return Execution(
                Ending(kind, f"in-process decoder {what}: {e}"), 2, str(e)[-2000:], time.perf_counter() - t0
            )
        except Exception as e:  # noqa: BLE001 - the decoder's own crash, judged as one
            tb = traceback.format_exc()
            return Execution(
                Ending(EndingKind.CRASH, f"in-process decoder raised {type(e).__name__}: {e}", crash_report(tb)),
                1,
                tb[-2000:],
                time.perf_counter() - t0,
            )
        dt = time.perf_counter() - t0
        if dt > self.limits.timeout_s:
            return Execution(
                Ending(
                    EndingKind.TIMEOUT,
                    f"in-process decoder took {dt:.1f} s, over the {self.limits.timeout_s:g} s limit",
                ),
                None,
                "",
                dt,
            )
        return Execution(Ending(EndingKind.DECODED, "in-process decoder returned"), 0, "", dt)


@dataclass(frozen=True)
class Execution:
    """One call of an in-process decoder: how it ended, its "exit code" (0 decoded, 2 rejected,
    69 not supported, 1 crashed), what it said and how long it took."""

    ending: Ending
    exit_code: int | None
    stderr_tail: str
    elapsed_s: float


class NotSupportedError(Exception):
    """Raised by an in-process adapter for input it does not support (= exit code 69)."""


class CommandAdapter(Adapter):
    kind = "command"

    def __init__(
        self, data: dict, path: Path | None, text: str, ceilings: bounds.Ceilings = bounds.DEFAULT_CEILINGS
    ) -> None:
        self.manifest_path = path
        self.manifest_text = text
        self.name = data["name"]
        self.description = data.get("description", "")
        self.claims = list(data["claims"])
        self.tools = list(data["tools"]) if "tools" in data else None
        self.readings = tuple(data.get("readings", ()))
        self.inputs = list(data["inputs"])
        self.outputs = list(data["outputs"])
        self.faps_format = data.get("faps_format", "fap")
        self.commands = data["commands"]
        self.env = {str(k): str(v) for k, v in data.get("env", {}).items()}
        self.limits = _limits(data.get("limits", {}), path, ceilings)
        self.reject_exit_codes = frozenset(data.get("reject_exit_codes", DEFAULT_REJECT_EXIT_CODES))
        # serve answers what decode writes: speed may be measured through it (checked on a sample: harness/speed/)
        self.serve_equivalent = bool(data.get("serve_equivalent", False)) and "serve" in self.commands
        self.lab_read_only: list[Path] = []  # the lab's --sandbox-ro folders (never the manifest's)
        self.supports_multi = "decode_multi" in self.commands

    def argv(self, command: str, job: Job) -> list[str]:
        return expand(self.commands[command], job, self.manifest_path)

    def sandbox_view(self, argv: list[str], workdir: Path, hidden=()):
        """What this decoder sees in the sandbox (docs/harness.md, "What a decoder sees"): the
        folder of its program and of every other file its command names, its manifest's folder,
        the lab's ``--sandbox-ro`` folders — read-only, each judged by place and by content
        (:mod:`fbaconf.isolation.view`) —, its case folder (inputs read-only), and through
        ``{python}`` the Python installation and the fbaconf package read-only; ``hidden``
        (goldens, suites, the run folder, a key) and every installed fbaconf's data emptied
        wherever they would show. Raises :class:`ViewError` for a folder that would show too much."""
        v = default_view(argv, workdir)
        through_python = argv[0] == sys.executable or Path(argv[0]).resolve() == Path(sys.executable).resolve()
        shown = view.command_folders(argv, Path(workdir), v.read_only, through_python=through_python)
        if self.manifest_path is not None:
            shown.append((Path(self.manifest_path).resolve().parent, "the manifest's folder"))
        shown += [(Path(p), "a folder the lab gave (--sandbox-ro)") for p in self.lab_read_only]
        v.read_only, bad = view.checked(shown, hidden, trusted=[BUNDLED_DIR])
        if bad:
            raise ViewError(
                f"the sandbox would show the decoder {bad[1]} ({bad[0]}): {bad[2]}. Put the decoder's "
                f"files in a folder of their own",
                rule="sandbox-view",
                file=str(self.manifest_path or self.name),
            )
        v.hidden += [Path(h) for h in hidden]
        if through_python:
            v.read_only += python_view()
            v.hidden += view.installed_data(python_view())
        return v

    def program(self) -> str | None:
        """The decode command's program as an absolute path ({manifest_dir} expanded, PATH
        searched for a bare name), or None when it does not exist."""
        first = self.commands["decode"][0]
        if isinstance(first, list):
            return None
        if "{manifest_dir}" in first and self.manifest_path is not None:
            first = first.replace("{manifest_dir}", str(Path(self.manifest_path).resolve().parent))
        if "{python}" in first:
            first = first.replace("{python}", sys.executable)
        if "/" not in first:
            return shutil.which(first)
        p = Path(first)
        return str(p.resolve()) if p.is_file() else None


def _limits(d: dict, path, ceilings: bounds.Ceilings = bounds.DEFAULT_CEILINGS) -> Limits:
    """The manifest's [limits], each a real limit within the lab's ``ceilings`` (isolation/bounds.py)."""
    if not isinstance(d, dict):
        raise ManifestError("[limits] must be a table", rule="manifest-limits", file=str(path))
    try:
        lim = Limits(
            timeout_s=d.get("timeout_s", 60),
            memory_mb=d.get("memory_mb", 2048),
            memory_kind=str(d.get("memory_kind", Limits.memory_kind)),
            output_mb=d.get("output_mb", 256),
            processes=d.get("processes", 64),
        )
    except (TypeError, ValueError, OverflowError) as e:
        raise ManifestError(f"[limits]: {e}", rule="manifest-limits", file=str(path)) from None
    problems = bounds.problems(lim, ceilings)
    if problems:
        raise ManifestError(f"[limits]: {'; '.join(problems)}", rule="manifest-limits", file=str(path))
    return lim


def expand(template: list, job: Job, manifest_path: Path | None) -> list[str]:
    """Fill an argv template (see module doc). Raises KeyError(name) for a missing placeholder
    outside an optional group."""
    values = dict(job.values)
    if manifest_path is not None:
        values.setdefault("manifest_dir", str(Path(manifest_path).resolve().parent))
    values.setdefault("python", sys.executable)
    values.setdefault("workdir", str(job.workdir))
    values.setdefault("frames", str(job.frames))

    def fill(s: str) -> str:
        return _PH.sub(lambda m: values[m.group(1)], s)

    out: list[str] = []
    for item in template:
        if isinstance(item, list):
            names = [n for s in item for n in _PH.findall(s)]
            if (
                all(n in values for n in names)
                and not (("inputs" in names) and not job.faces)
                and not (set(names) & job.unwanted)
            ):
                out.extend(fill(s) for s in item)
            continue
        if item == "{inputs}":
            out.extend(job.faces)
            continue
        out.append(fill(item))
    return out


def _check_manifest(data: dict, path: Path | None) -> None:
    """Every rule of a manifest's schema (docs/harness.md); raises :class:`ManifestError` naming
    the file and the rule broken."""
    where = str(path) if path else "<manifest>"

    def bad(msg: str, rule: str) -> ManifestError:
        return ManifestError(msg if len(msg) <= 400 else msg[:400] + "…", rule=rule, file=where)

    _check_keys(data, bad)
    _check_values(data, bad)
    if "python" not in data:
        _check_commands(data, bad)


def _check_keys(data: dict, bad) -> None:
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
            raise bad(f"unknown key {_quote(key)}{_did_you_mean(str(key), MANIFEST_KEYS)}", "manifest-key")
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


def _check_values(data: dict, bad) -> None:
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
            raise bad(f"{key} must be a non-empty list of {', '.join(allowed)}; got {_quote(vals)}", f"manifest-{key}")
    if not ({"fba", "fap"} & set(data["inputs"])):
        raise bad("inputs must include a stream form: fba and/or fap", "manifest-inputs")
    if data.get("faps_format", "fap") not in FAPS_FORMATS:
        raise bad(f"faps_format must be one of {FAPS_FORMATS}", "manifest-faps-format")
    if "tools" in data:
        known = load_profiles().tools
        unknown = [t for t in data["tools"] if t not in known]
        if unknown:
            raise bad(f"unknown tool(s) {_quote(unknown)} (known: {', '.join(known)})", "manifest-tools")
    unknown = [r for r in data.get("readings", []) if not isinstance(r, str) or r not in readings.catalogue()]
    if unknown:
        raise bad(
            f"readings: unknown reading(s) {_quote(unknown)} (known: {', '.join(readings.catalogue())}; "
            f'docs/harness.md, "Provisional requirements")',
            "manifest-readings",
        )


def _check_commands(data: dict, bad) -> None:
    """[commands]: decode given, known commands, argv lists of strings, known placeholders (the
    persistent ``serve`` only its own), every output's placeholder named by decode."""
    cmds = data.get("commands")
    if not isinstance(cmds, dict) or "decode" not in cmds:
        raise bad('[commands] must define decode (an argv list), or give python = "module:Class"', "manifest-commands")
    for cname, argv in cmds.items():
        if cname not in COMMANDS:
            raise bad(f"[commands] {_quote(cname)}: unknown command ({', '.join(COMMANDS)})", "manifest-commands")
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


def _check_placeholders(cname: str, s: str, bad) -> None:
    for n in _PH.findall(s):
        if cname == "serve" and n not in SERVE_PLACEHOLDERS:
            usable = ", ".join("{" + p + "}" for p in SERVE_PLACEHOLDERS)
            raise bad(
                f"[commands] serve: {{{n}}} has no value for a persistent decoder, which gets "
                f"each input on stdin (usable: {usable})",
                "manifest-placeholder",
            )
        if n not in PLACEHOLDERS:
            raise bad(
                f"[commands] {cname}: unknown placeholder {_quote(n)} (known: "
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


def _quote(value) -> str:
    """A value of the manifest as an error message quotes it: repr, at most QUOTE_CHARS."""
    text = repr(value)
    return text if len(text) <= QUOTE_CHARS else text[:QUOTE_CHARS] + "…"


def _depth(value, limit: int) -> int:
    """Nesting depth of parsed TOML (tables and arrays), counting no deeper than ``limit`` + 1."""
    stack, deepest = [(value, 1)], 0
    while stack:
        v, d = stack.pop()
        if isinstance(v, (dict, list)):
            deepest = max(deepest, d)
            if d > limit:
                return d
            stack.extend((x, d + 1) for x in (v.values() if isinstance(v, dict) else v))
    return deepest


def _did_you_mean(word: str, choices) -> str:
    close = difflib.get_close_matches(word, choices, n=1)
    return f" (did you mean {close[0]!r}?)" if close else f" (known: {', '.join(choices)})"


def _flatten(argv):
    for x in argv:
        if isinstance(x, list):
            yield from x
        else:
            yield x


def load_manifest(
    path: Path, *, untrusted: bool = False, ceilings: bounds.Ceilings = bounds.DEFAULT_CEILINGS
) -> Adapter:
    """The adapter a manifest describes. Any problem is a :class:`ManifestError` naming the file,
    the key and the rule — never another exception. ``untrusted`` (``certify``): an in-process
    ``python =`` adapter is accepted only from the bundled manifests (it runs inside the
    harness's own process, unsandboxed). ``ceilings``: the most its [limits] may ask for (the
    lab's, :mod:`fbaconf.isolation.bounds`)."""
    path = Path(path)
    try:
        raw = read_regular(path, MAX_MANIFEST_BYTES)
    except FbaconfInputError as e:
        raise ManifestError(
            f"cannot read decoder manifest: {e.message}", rule="manifest-missing", file=str(path)
        ) from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ManifestError(f"not UTF-8 text (byte {e.start})", rule="manifest-toml", file=str(path)) from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ManifestError(f"not valid TOML: {_quote(str(e))}", rule="manifest-toml", file=str(path)) from None
    except RecursionError:
        data = None
    if data is None or _depth(data, MAX_MANIFEST_DEPTH) > MAX_MANIFEST_DEPTH:
        raise ManifestError(
            f"nested more than {MAX_MANIFEST_DEPTH} tables/arrays deep", rule="manifest-toml", file=str(path)
        )
    _check_manifest(data, path)
    owner = reserved_names().get(data["name"].lower())
    if owner is not None and path.resolve() != owner.resolve():
        raise ManifestError(
            f"name {_quote(data['name'])} is reserved: a bundled adapter of fbaconf uses it, and a "
            f"report or a certificate must never pass one decoder for another",
            rule="manifest-name",
            file=str(path),
        )
    if "python" in data:
        if untrusted and path.resolve().parent != BUNDLED_DIR:
            raise ManifestError(
                "python = adapters run inside the harness's own process, unsandboxed: certify "
                "accepts them only from the bundled manifests; describe the decoder with "
                "[commands] (docs/harness.md)",
                rule="manifest-python",
                file=str(path),
            )
        return _python_adapter(data, path, text, ceilings)
    return CommandAdapter(data, path, text, ceilings)


def _python_adapter(data: dict, path: Path | None, text: str, ceilings: bounds.Ceilings) -> Adapter:
    target = data["python"]
    mod_name, _, cls_name = target.partition(":")
    try:
        cls = getattr(importlib.import_module(mod_name), cls_name)
    except (ImportError, AttributeError) as e:
        raise ManifestError(
            f"python = {_quote(target)}: cannot import: {_quote(str(e))}", rule="manifest-python", file=str(path)
        ) from None
    except Exception as e:  # noqa: BLE001 - the module's own import failed: the manifest's problem
        raise ManifestError(
            f"python = {_quote(target)}: importing it raised {type(e).__name__}", rule="manifest-python", file=str(path)
        ) from None
    if not (isinstance(cls, type) and issubclass(cls, PythonAdapter)):
        raise ManifestError(
            f"python = {_quote(target)} is not a subclass of fbaconf.harness.adapters.PythonAdapter",
            rule="manifest-python",
            file=str(path),
        )
    kwargs = data.get("options", {})
    try:
        adapter = cls(**kwargs)
    except TypeError as e:
        raise ManifestError(
            f"[options] do not fit {target}: {_quote(str(e))}", rule="manifest-options", file=str(path)
        ) from None
    adapter.name = data["name"]
    adapter.description = data.get("description", getattr(adapter, "description", ""))
    adapter.claims = list(data["claims"])
    adapter.tools = list(data["tools"]) if "tools" in data else None
    adapter.readings = tuple(data.get("readings", ()))
    adapter.inputs = list(data["inputs"])
    adapter.outputs = list(data["outputs"])
    adapter.faps_format = data.get("faps_format", getattr(adapter, "faps_format", "npz"))
    adapter.limits = _limits(data.get("limits", {}), path, ceilings)
    adapter.reject_exit_codes = frozenset(data.get("reject_exit_codes", DEFAULT_REJECT_EXIT_CODES))
    adapter.manifest_path = path
    adapter.manifest_text = text
    return adapter


def reserved_names() -> dict[str, Path]:
    """The names the bundled adapters use (their files' and manifests' ``name``, lower-cased) ->
    the manifest: no other may take one, so nothing printed can pass for them."""
    out = {}
    for stem, p in bundled().items():
        name = _NAME_LINE.search(p.read_text("utf-8"))
        out.update({stem.lower(): p, **({name.group(1).lower(): p} if name else {})})
    return out


_NAME_LINE = re.compile(r'^name\s*=\s*"([^"]+)"', re.M)


def highest_claim(adapter: Adapter) -> str:
    """The adapter's highest claim (profile rank, then level)."""
    return str(max(Claim.parse(c) for c in adapter.claims))


def bundled() -> dict[str, Path]:
    return {p.stem: p for p in sorted(BUNDLED_DIR.glob("*.toml"))}


def resolve(
    spec: str | Path, *, untrusted: bool = False, ceilings: bounds.Ceilings = bounds.DEFAULT_CEILINGS
) -> Adapter:
    """``--decoder`` value: a manifest path, or the name of a bundled adapter (``reference``,
    ``reference-inprocess``, ``dummy``...). ``untrusted``, ``ceilings``: see :func:`load_manifest`."""
    p = Path(spec)
    if p.suffix == ".toml" or p.is_file():  # a folder named like a bundled adapter is not a manifest
        return load_manifest(p.resolve(), untrusted=untrusted, ceilings=ceilings)
    names = bundled()
    if str(spec) in names:
        return load_manifest(names[str(spec)], untrusted=untrusted, ceilings=ceilings)
    raise ManifestError(
        f"no decoder manifest {_quote(str(spec))}: give a .toml path or one of the bundled adapters "
        f"({', '.join(names)})",
        rule="manifest-missing",
        file=str(spec)[:QUOTE_CHARS],
    )
