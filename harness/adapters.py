"""Decoder adapters: a TOML manifest for command-line decoders (any language) or a Python class.

Manifest (docs/harness.md, "Write a manifest")::

    name = "example"
    description = "..."
    claims = ["simple@1"]                 # profile@level claimed
    tools = ["arithmetic", "dct"]         # optional: tools supported (default: all of the claimed profile)
    inputs = ["fba", "fap", "scene", "bifs"]
    outputs = ["faps", "vertices", "images"]
    faps_format = "fap"                   # or "npz": the FAP output file the decoder writes
    python = "package.module:Class"       # optional: an in-process adapter instead of commands
    [commands]                            # argv lists, {placeholders} filled by the harness
    decode = ["exampledec", "{input}", ["--scene", "{scene}"], "--out", "{faps_out}"]
    decode_multi = ["exampledec", "--out-dir", "{faps_out_dir}", "{inputs}"]
    [limits]
    timeout_s = 30
    memory_mb = 2048
    memory_kind = "address-space"         # or "rss" (JVM etc.) or "none"
    output_mb = 256
    [env]                                 # extra environment variables for the decoder
    EXAMPLE_MODE = "strict"

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
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from fbaconf.errors import FbaconfInputError
from fbaconf.isolation.endings import DEFAULT_REJECT_EXIT_CODES
from fbaconf.isolation.sandbox import Limits, default_view, python_view
from fbaconf.profiles.model import Claim, load_profiles

INPUT_KINDS = ("fba", "fap", "scene", "bifs")
OUTPUT_KINDS = ("faps", "vertices", "images")
FAPS_FORMATS = ("fap", "npz")
PLACEHOLDERS = ("input", "fba", "fap", "scene", "scene_bt", "scene_bifs", "scenario", "faps_out", "vertices_out",
                "images_dir", "frames", "workdir", "manifest_dir", "python", "faps_out_dir", "inputs")
# decode: one process per input; decode_multi: one per multi-face case; serve: the persistent
# protocol (isolation/persistent.py), one process for many inputs, each sent on stdin.
COMMANDS = ("decode", "decode_multi", "serve")
SERVE_PLACEHOLDERS = ("workdir", "manifest_dir", "python")
OUTPUT_PLACEHOLDER = {"faps": "faps_out", "vertices": "vertices_out", "images": "images_dir"}
_PH = re.compile(r"\{([a-z_]+)\}")
BUNDLED_DIR = Path(__file__).resolve().parent / "adapters"


class ManifestError(FbaconfInputError):
    """A decoder manifest is malformed (names file, key and rule)."""


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
        return {"name": self.name, "kind": self.kind, "description": self.description, "claims": list(self.claims),
                "tools": self.tools, "inputs": list(self.inputs), "outputs": list(self.outputs),
                "faps_format": self.faps_format, "manifest": str(self.manifest_path) if self.manifest_path else None,
                "reject_exit_codes": sorted(self.reject_exit_codes),
                "manifest_sha256": self.digest(),
                "limits": {"timeout_s": self.limits.timeout_s, "memory_mb": self.limits.memory_mb,
                           "memory_kind": self.limits.memory_kind, "output_mb": self.limits.output_mb}}


class PythonAdapter(Adapter):
    """Base class for in-process decoders: override :meth:`run` (write the outputs named in
    ``job.values``: ``faps_out``, ``vertices_out``, ``images_dir``, ``faps_out_dir``).
    Raise :class:`NotSupportedError` for "not supported"; any other exception is a Fail
    (the decoder rejected or crashed on the input) with its message. In-process decoders
    share the harness's process: the timeout is checked after the call returns, and memory
    is not limited — use a command manifest for untrusted code."""
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


class NotSupportedError(Exception):
    """Raised by an in-process adapter for input it does not support (= exit code 69)."""


class CommandAdapter(Adapter):
    kind = "command"

    def __init__(self, data: dict, path: Path | None, text: str) -> None:
        self.manifest_path = path
        self.manifest_text = text
        self.name = data["name"]
        self.description = data.get("description", "")
        self.claims = list(data["claims"])
        self.tools = list(data["tools"]) if "tools" in data else None
        self.inputs = list(data["inputs"])
        self.outputs = list(data["outputs"])
        self.faps_format = data.get("faps_format", "fap")
        self.commands = data["commands"]
        self.env = {str(k): str(v) for k, v in data.get("env", {}).items()}
        self.limits = _limits(data.get("limits", {}), path)
        self.reject_exit_codes = frozenset(data.get("reject_exit_codes", DEFAULT_REJECT_EXIT_CODES))
        self.sandbox = dict(data.get("sandbox", {}))
        self.supports_multi = "decode_multi" in self.commands

    def argv(self, command: str, job: Job) -> list[str]:
        return expand(self.commands[command], job, self.manifest_path)

    def sandbox_view(self, argv: list[str], workdir: Path, hidden=()):
        """What this decoder sees in the sandbox: its program's and manifest's folders and the
        manifest's ``[sandbox] read_only`` paths read-only, its case folder (inputs read-only),
        and — when started through ``{python}`` — the Python installation and the fbaconf
        package read-only with ``hidden`` (goldens, suites, the run folder) emptied."""
        v = default_view(argv, workdir)
        if self.manifest_path is not None:
            v.read_only.append(Path(self.manifest_path).resolve().parent)
        v.read_only += [Path(p) for p in self.sandbox.get("read_only", [])]
        if argv[0] == sys.executable or Path(argv[0]).resolve() == Path(sys.executable).resolve():
            v.read_only += python_view()
        v.hidden += [Path(h) for h in hidden]
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


def _limits(d: dict, path) -> Limits:
    if not isinstance(d, dict):
        raise ManifestError("[limits] must be a table", rule="manifest-limits", file=str(path))
    try:
        return Limits(timeout_s=d.get("timeout_s", 60), memory_mb=d.get("memory_mb", 2048),
                      memory_kind=str(d.get("memory_kind", "address-space")), output_mb=d.get("output_mb", 256),
                      processes=d.get("processes", 64))
    except (TypeError, ValueError, OverflowError) as e:
        raise ManifestError(f"[limits]: {e}", rule="manifest-limits", file=str(path)) from None


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
            if all(n in values for n in names) and not (("inputs" in names) and not job.faces) \
                    and not (set(names) & job.unwanted):
                out.extend(fill(s) for s in item)
            continue
        if item == "{inputs}":
            out.extend(job.faces)
            continue
        out.append(fill(item))
    return out


def _check_manifest(data: dict, path: Path | None) -> None:  # noqa: C901
    where = str(path) if path else "<manifest>"

    def bad(msg: str, rule: str) -> ManifestError:
        return ManifestError(msg, rule=rule, file=where)

    for key in ("name", "claims", "inputs", "outputs"):
        if key not in data:
            raise bad(f"missing required key {key!r}", "manifest-key")
    for key in data:
        if key not in MANIFEST_KEYS:
            raise bad(f"unknown key {key!r}{_did_you_mean(key, MANIFEST_KEYS)}", "manifest-key")
    for key in data.get("limits", {}) if isinstance(data.get("limits"), dict) else ():
        if key not in LIMIT_KEYS:
            raise bad(f"[limits]: unknown key {key!r}{_did_you_mean(key, LIMIT_KEYS)}", "manifest-limits")
    env = data.get("env", {})
    if not isinstance(env, dict) or not all(isinstance(v, (str, int, float, bool)) for v in env.values()):
        raise bad("[env] must be a table of NAME = value", "manifest-env")
    if "python" in data and (not isinstance(data["python"], str) or ":" not in data["python"]):
        raise bad('python must be "package.module:Class"', "manifest-python")
    if "options" in data and not isinstance(data["options"], dict):
        raise bad("[options] must be a table", "manifest-options")
    sb = data.get("sandbox", {})
    if not isinstance(sb, dict) or any(k not in SANDBOX_KEYS for k in sb) or \
            not all(isinstance(x, str) and x.startswith("/") for x in sb.get("read_only", [])):
        raise bad("[sandbox] may only give read_only = [absolute paths] (extra folders the decoder needs, "
                  "e.g. its runtime)", "manifest-sandbox")
    rc = data.get("reject_exit_codes", [1])
    if (not isinstance(rc, list) or not rc or
            any(not isinstance(c, int) or isinstance(c, bool) or not 1 <= c <= 255 or c in (69, 126, 127) for c in rc)):
        raise bad("reject_exit_codes must be a non-empty list of exit codes 1..255 other than 69 (not supported) "
                  "and 126/127 (cannot execute)", "manifest-reject-codes")
    if not isinstance(data["name"], str) or not re.fullmatch(r"[A-Za-z0-9_@+-][A-Za-z0-9._@+-]{0,63}", data["name"]):
        raise bad("name must be 1-64 letters, digits, '.', '_', '-', '+' or '@', not starting with '.' "
                  "(it names the run folder)", "manifest-name")
    if not isinstance(data["claims"], list) or not data["claims"]:
        raise bad("claims must be a non-empty list like [\"simple@1\"]", "manifest-claims")
    for c in data["claims"]:
        try:
            Claim.parse(c)
        except ValueError as e:
            raise bad(f"claims: {e}", "manifest-claims") from None
    for key, allowed in (("inputs", INPUT_KINDS), ("outputs", OUTPUT_KINDS)):
        vals = data[key]
        if not isinstance(vals, list) or not vals or any(v not in allowed for v in vals):
            raise bad(f"{key} must be a non-empty list of {', '.join(allowed)}; got {vals!r}", f"manifest-{key}")
    if not ({"fba", "fap"} & set(data["inputs"])):
        raise bad("inputs must include a stream form: fba and/or fap", "manifest-inputs")
    if data.get("faps_format", "fap") not in FAPS_FORMATS:
        raise bad(f"faps_format must be one of {FAPS_FORMATS}", "manifest-faps-format")
    if "tools" in data:
        known = load_profiles().tools
        unknown = [t for t in data["tools"] if t not in known]
        if unknown:
            raise bad(f"unknown tool(s) {unknown} (known: {', '.join(known)})", "manifest-tools")
    if "python" in data:
        return
    cmds = data.get("commands")
    if not isinstance(cmds, dict) or "decode" not in cmds:
        raise bad("[commands] must define decode (an argv list), or give python = \"module:Class\"",
                  "manifest-commands")
    for cname, argv in cmds.items():
        if cname not in COMMANDS:
            raise bad(f"[commands] {cname}: unknown command ({', '.join(COMMANDS)})", "manifest-commands")
        if not isinstance(argv, list) or not argv or not isinstance(argv[0], str):
            raise bad(f"[commands] {cname} must be an argv list starting with the program", "manifest-commands")
        for item in argv:
            parts = item if isinstance(item, list) else [item]
            for s in parts:
                if not isinstance(s, str):
                    raise bad(f"[commands] {cname}: argv items must be strings or lists of strings", "manifest-commands")  # noqa: E501
                for n in _PH.findall(s):
                    if cname == "serve" and n not in SERVE_PLACEHOLDERS:
                        raise bad(f"[commands] serve: {{{n}}} has no value for a persistent decoder, which gets "
                                  f"each input on stdin (usable: {', '.join('{' + p + '}' for p in SERVE_PLACEHOLDERS)})",  # noqa: E501
                                  "manifest-placeholder")
                    if n not in PLACEHOLDERS:
                        raise bad(f"[commands] {cname}: unknown placeholder {{{n}}} (known: "
                                  f"{', '.join('{' + p + '}' for p in PLACEHOLDERS)})", "manifest-placeholder")
    text = " ".join(str(x) for x in _flatten(cmds["decode"]))
    for out in data["outputs"]:
        ph = "{" + OUTPUT_PLACEHOLDER[out] + "}"
        if ph not in text:
            raise bad(f"outputs lists {out!r} but [commands] decode never names {ph}", "manifest-outputs")


MANIFEST_KEYS = ("name", "description", "claims", "tools", "inputs", "outputs", "faps_format", "commands", "limits",
                 "env", "python", "options", "reject_exit_codes", "sandbox")
LIMIT_KEYS = ("timeout_s", "memory_mb", "memory_kind", "output_mb", "processes")
SANDBOX_KEYS = ("read_only",)


def _did_you_mean(word: str, choices) -> str:
    close = difflib.get_close_matches(word, choices, n=1)
    return f" (did you mean {close[0]!r}?)" if close else f" (known: {', '.join(choices)})"


def _flatten(argv):
    for x in argv:
        if isinstance(x, list):
            yield from x
        else:
            yield x


def load_manifest(path: Path) -> Adapter:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise ManifestError(f"cannot read decoder manifest: {e.strerror}", rule="manifest-missing",
                            file=str(path)) from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ManifestError(f"not valid TOML: {e}", rule="manifest-toml", file=str(path)) from None
    _check_manifest(data, path)
    if "python" in data:
        return _python_adapter(data, path, text)
    return CommandAdapter(data, path, text)


def _python_adapter(data: dict, path: Path | None, text: str) -> Adapter:
    target = data["python"]
    mod_name, _, cls_name = target.partition(":")
    try:
        cls = getattr(importlib.import_module(mod_name), cls_name)
    except (ImportError, AttributeError) as e:
        raise ManifestError(f"python = {target!r}: cannot import: {e}", rule="manifest-python",
                            file=str(path)) from None
    kwargs = data.get("options", {})
    try:
        adapter = cls(**kwargs)
    except TypeError as e:
        raise ManifestError(f"[options] do not fit {target}: {e}", rule="manifest-options", file=str(path)) from None
    adapter.name = data["name"]
    adapter.description = data.get("description", getattr(adapter, "description", ""))
    adapter.claims = list(data["claims"])
    adapter.tools = list(data["tools"]) if "tools" in data else None
    adapter.inputs = list(data["inputs"])
    adapter.outputs = list(data["outputs"])
    adapter.faps_format = data.get("faps_format", getattr(adapter, "faps_format", "npz"))
    adapter.limits = _limits(data.get("limits", {}), path)
    adapter.reject_exit_codes = frozenset(data.get("reject_exit_codes", DEFAULT_REJECT_EXIT_CODES))
    adapter.manifest_path = path
    adapter.manifest_text = text
    return adapter


def highest_claim(adapter: Adapter) -> str:
    """The adapter's highest claim (profile rank, then level)."""
    return str(max(Claim.parse(c) for c in adapter.claims))


def bundled() -> dict[str, Path]:
    return {p.stem: p for p in sorted(BUNDLED_DIR.glob("*.toml"))}


def resolve(spec: str | Path) -> Adapter:
    """``--decoder`` value: a manifest path, or the name of a bundled adapter (``reference``,
    ``reference-inprocess``, ``dummy``...)."""
    p = Path(spec)
    if p.suffix == ".toml" or p.exists():
        return load_manifest(p.resolve())
    names = bundled()
    if str(spec) in names:
        return load_manifest(names[str(spec)])
    raise ManifestError(f"no decoder manifest {spec!r}: give a .toml path or one of the bundled adapters "
                        f"({', '.join(names)})", rule="manifest-missing", file=str(spec))
