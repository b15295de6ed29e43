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

import hashlib
import importlib
import re
import shutil
import sys
import time
import tomllib
import traceback
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fbaconf.errors import FbaconfInputError
from fbaconf.isolation import bounds, view
from fbaconf.isolation.endings import DEFAULT_REJECT_EXIT_CODES, Ending, EndingKind, crash_report
from fbaconf.isolation.sandbox import Limits, View, default_view, python_view
from fbaconf.profiles.model import Claim
from fbaconf.safefs import read_regular

# the vocabulary callers import from here too, re-exported (`X as X`)
from .manifest import (
    COMMANDS as COMMANDS,
    FAPS_FORMATS as FAPS_FORMATS,
    INPUT_KINDS as INPUT_KINDS,
    LIMIT_KEYS as LIMIT_KEYS,
    MANIFEST_KEYS as MANIFEST_KEYS,
    MAX_MANIFEST_BYTES as MAX_MANIFEST_BYTES,
    MAX_MANIFEST_DEPTH as MAX_MANIFEST_DEPTH,
    OUTPUT_KINDS as OUTPUT_KINDS,
    OUTPUT_PLACEHOLDER as OUTPUT_PLACEHOLDER,
    PLACEHOLDER_PATTERN as PLACEHOLDER_PATTERN,
    PLACEHOLDERS as PLACEHOLDERS,
    QUOTE_CHARS as QUOTE_CHARS,
    SERVE_PLACEHOLDERS as SERVE_PLACEHOLDERS,
    ManifestError as ManifestError,
    check_manifest as check_manifest,
    nesting_depth as nesting_depth,
    quote as quote,
)

BUNDLED_DIR = Path(__file__).resolve().parent / "adapters"


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

    def need(self, name: str) -> Path:
        """The path of placeholder ``name``; KeyError when the job has none (as for an argv)."""
        p = self.path(name)
        if p is None:
            raise KeyError(name)
        return p


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

    def describe(self) -> dict[str, Any]:
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
        self, data: dict[str, Any], path: Path | None, text: str, ceilings: bounds.Ceilings = bounds.DEFAULT_CEILINGS
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

    def sandbox_view(self, argv: list[str], workdir: Path, hidden: Sequence[Path | str] = ()) -> View:
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
            found: str | None = shutil.which(first)
            return found
        p = Path(first)
        return str(p.resolve()) if p.is_file() else None


def _limits(d: dict[str, Any], path: Path | None, ceilings: bounds.Ceilings = bounds.DEFAULT_CEILINGS) -> Limits:
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


def expand(template: list[str | list[str]], job: Job, manifest_path: Path | None) -> list[str]:
    """Fill an argv template (see module doc). Raises KeyError(name) for a missing placeholder
    outside an optional group."""
    values = dict(job.values)
    if manifest_path is not None:
        values.setdefault("manifest_dir", str(Path(manifest_path).resolve().parent))
    values.setdefault("python", sys.executable)
    values.setdefault("workdir", str(job.workdir))
    values.setdefault("frames", str(job.frames))

    def fill(s: str) -> str:
        return PLACEHOLDER_PATTERN.sub(lambda m: values[m.group(1)], s)

    out: list[str] = []
    for item in template:
        if isinstance(item, list):
            names = [n for s in item for n in PLACEHOLDER_PATTERN.findall(s)]
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
        raise ManifestError(f"not valid TOML: {quote(str(e))}", rule="manifest-toml", file=str(path)) from None
    except RecursionError:
        data = None
    if data is None or nesting_depth(data, MAX_MANIFEST_DEPTH) > MAX_MANIFEST_DEPTH:
        raise ManifestError(
            f"nested more than {MAX_MANIFEST_DEPTH} tables/arrays deep", rule="manifest-toml", file=str(path)
        )
    check_manifest(data, path)
    owner = reserved_names().get(data["name"].lower())
    if owner is not None and path.resolve() != owner.resolve():
        raise ManifestError(
            f"name {quote(data['name'])} is reserved: a bundled adapter of fbaconf uses it, and a "
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


def _python_adapter(data: dict[str, Any], path: Path | None, text: str, ceilings: bounds.Ceilings) -> Adapter:
    target = data["python"]
    mod_name, _, cls_name = target.partition(":")
    try:
        cls = getattr(importlib.import_module(mod_name), cls_name)
    except (ImportError, AttributeError) as e:
        raise ManifestError(
            f"python = {quote(target)}: cannot import: {quote(str(e))}", rule="manifest-python", file=str(path)
        ) from None
    except Exception as e:  # noqa: BLE001 - the module's own import failed: the manifest's problem
        raise ManifestError(
            f"python = {quote(target)}: importing it raised {type(e).__name__}", rule="manifest-python", file=str(path)
        ) from None
    if not (isinstance(cls, type) and issubclass(cls, PythonAdapter)):
        raise ManifestError(
            f"python = {quote(target)} is not a subclass of fbaconf.harness.adapters.PythonAdapter",
            rule="manifest-python",
            file=str(path),
        )
    kwargs = data.get("options", {})
    try:
        adapter = cls(**kwargs)
    except TypeError as e:
        raise ManifestError(
            f"[options] do not fit {target}: {quote(str(e))}", rule="manifest-options", file=str(path)
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
        f"no decoder manifest {quote(str(spec))}: give a .toml path or one of the bundled adapters "
        f"({', '.join(names)})",
        rule="manifest-missing",
        file=str(spec)[:QUOTE_CHARS],
    )
