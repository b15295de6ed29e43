"""Which folders a decoder may be shown, judged by what they hold, not by where they are.

A manifest's command names files — the program, a script, a jar, a model — and the sandbox
shows each one's folder read-only (a folder named as such is shown as itself). A folder is
shown only when it holds nothing but the decoder's files: the lab walks it (links not
followed, as the sandbox shows them as links) and refuses it when it, or a folder above it,
holds any of

* git data: a ``.git`` entry, or a git directory (``HEAD`` beside ``objects/`` and ``refs/``, or
  a worktree's ``commondir``) — its objects hold every file ever committed, goldens included;
* a copy of fbaconf's goldens (a ``golden/`` folder holding ``MANIFEST.json``) or suites (a
  ``conformance/suites`` folder) — an fbaconf checkout, a wheel build (``build/lib*/``), an
  installed fbaconf's package data;
* a file whose sha256 is that of a golden or of a suite's expected output (``.fap``, ``.npz``,
  ``.json``) — a copy made under another name.

A folder of more than :data:`MAX_ENTRIES` entries is refused too (the lab cannot check it in
reasonable time). What the sandbox empties inside a folder (``hidden``: the run folder, the
goldens, the suites) is not walked: the decoder never sees it. Each folder is judged once per
process and set of such folders: the sandbox shows it read-only, so no decoder can change it
between cases.

:func:`named_paths` says which absolute paths a command's arguments name: an argument itself,
the part after a ``=`` (``--model=/opt/m.bin``), each part of a ``:`` list (``-cp a.jar:b.jar``)
and a ``@file`` (a JVM argument file).
"""

from __future__ import annotations

import functools
import hashlib
import os
import threading
from collections.abc import Iterable
from pathlib import Path

from fbaconf.conformance.suite import golden_root, suites_root

from .sandbox import SYSTEM_TOPS, view_problem

MAX_ENTRIES = 100_000
MIN_HASHED = 64  # smaller files are too common to mean a copy (an empty __init__.py)
_EXPECTED_SUFFIXES = (".fap", ".npz", ".json")  # what a suite holds that is an expected output


def _sha256(path: Path) -> str | None:
    h = hashlib.sha256()
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    except OSError:
        return None
    try:
        while chunk := os.read(fd, 1 << 20):
            h.update(chunk)
    except OSError:
        return None
    finally:
        os.close(fd)
    return h.hexdigest()


@functools.lru_cache(maxsize=1)
def _known() -> dict[int, dict[str, str]]:
    """size -> {sha256: the file's name} of every golden and every expected output of the suites."""
    out: dict[int, dict[str, str]] = {}
    for root, suffixes in ((golden_root(), None), (suites_root(), _EXPECTED_SUFFIXES)):
        for dirpath, _dirs, files in os.walk(root):
            for f in files:
                p = Path(dirpath) / f
                if suffixes is not None and p.suffix.lower() not in suffixes:
                    continue
                try:
                    size = p.stat().st_size
                except OSError:
                    continue
                digest = _sha256(p) if size >= MIN_HASHED else None
                if digest:
                    out.setdefault(size, {})[digest] = str(p.relative_to(root.parent))
    return out


def _is_git_dir(d: Path) -> bool:
    try:
        return (d / "HEAD").is_file() and (
            (d / "objects").is_dir() and (d / "refs").is_dir() or (d / "commondir").is_file()
        )
    except OSError:
        return False


def _marker(d: Path) -> str | None:
    """What ``d`` itself is, when it is one of the things a decoder never sees."""
    if d.name == ".git" or _is_git_dir(d):
        return f"{d} is git data (its objects hold every committed file, goldens included)"
    if d.name == "golden" and (d / "MANIFEST.json").is_file():
        return f"{d} is a copy of fbaconf's goldens"
    if d.name == "suites" and d.parent.name == "conformance":
        return f"{d} is a copy of fbaconf's conformance suites"
    return None


_CACHE: dict[tuple[Path, tuple[Path, ...]], str | None] = {}
_LOCK = threading.Lock()


def folder_problem(folder: Path, hidden: Iterable[Path | str] = ()) -> str | None:
    """Why ``folder`` must not be shown to a decoder, judged by content (see the module doc),
    or None; the folders in ``hidden`` (emptied in the sandbox) are not walked. Cached."""
    folder = Path(os.path.abspath(folder))
    skip = tuple(sorted({Path(os.path.abspath(h)) for h in hidden} | {Path(h).resolve() for h in hidden}))
    key = (folder, tuple(h for h in skip if _under(h, [folder, folder.resolve()])))
    with _LOCK:
        if key in _CACHE:
            return _CACHE[key]
    why = _judge(folder, key[1])
    with _LOCK:
        _CACHE[key] = why
    return why


def _judge(folder: Path, skip: tuple[Path, ...]) -> str | None:
    try:
        real = folder.resolve()
    except OSError as e:
        return f"it cannot be resolved ({e.strerror})"
    for q in dict.fromkeys([folder, real]):
        for a in [q, *q.parents]:
            why = _marker(a)
            if why:
                return why if a == q else f"it lies inside {a}: " + why.split(" is ", 1)[1]
    return _walk(real, set(skip))


def _walk(top: Path, skip: set[Path]) -> str | None:
    known = _known()
    seen = 0
    todo = [top]
    while todo:
        d = todo.pop()
        try:
            it = os.scandir(d)
        except OSError:
            continue
        with it:
            for e in it:
                seen += 1
                if seen > MAX_ENTRIES:
                    return (
                        f"it holds more than {MAX_ENTRIES} files and folders, too many for the lab to check "
                        f"that it holds nothing but the decoder's"
                    )
                p = Path(e.path)
                if e.name == ".git":
                    return f"it holds {p}, git data (its objects hold every committed file, goldens included)"
                try:
                    is_dir = e.is_dir(follow_symlinks=False)
                    is_file = not is_dir and e.is_file(follow_symlinks=False)
                except OSError:
                    continue
                if is_dir and p in skip:
                    continue  # emptied in the sandbox
                if is_dir:
                    why = _marker(p)
                    if why:
                        return f"it holds {why}"
                    todo.append(p)
                elif is_file:
                    try:
                        size = e.stat(follow_symlinks=False).st_size
                    except OSError:
                        continue
                    if size in known:
                        digest = _sha256(p)
                        if digest in known[size]:
                            return f"it holds {p}, a copy of {known[size][digest]}"
    return None


def named_paths(args: list[str]) -> list[Path]:
    """The existing absolute paths ``args`` name (see the module doc), in order, once each."""
    out: dict[str, None] = {}
    for a in args:
        forms = [a, a[1:] if a.startswith("@") else ""]
        if "=" in a:
            forms.append(a.split("=", 1)[1])
        for f in forms:
            for part in f.split(os.pathsep) if f else ():
                if part.startswith("/") and os.path.lexists(part):
                    out.setdefault(os.path.normpath(part), None)
    return [Path(p) for p in out]


def _under(p: Path, roots: Iterable[Path | str]) -> bool:
    return any(p == r or r in p.parents for r in map(Path, roots))


_OWN = [Path(t) for t in ("/dev", "/proc", "/sys", "/run")]


def command_folders(
    argv: list[str], workdir: Path, program_dirs: list[Path], *, through_python: bool
) -> list[tuple[Path, str]]:
    """The folders a command's files would show (the program's — unless it is fbaconf's own
    ``{python}`` —, and each named file's or folder's, as given and with links resolved), each
    with the words that say why; not the case's own files, and not what the sandbox has of its
    own (``/``, ``/tmp``, ``/dev/null``, ``/proc/self/…``) or never shows (``/sys``, ``/run``)."""
    out = [] if through_python else [(p, f"the folder of the program {argv[0]}") for p in program_dirs]
    for p in named_paths(argv[1:]):
        own = p in (Path("/"), Path("/tmp"))  # noqa: S108 - what the sandbox mounts of its own, never the host's
        if _under(p, [workdir, *_OWN]) or own or (through_python and p.resolve() == Path(argv[0]).resolve()):
            continue  # the case's own files; what the sandbox has of its own (/, /tmp, /dev, /proc) or never shows
        what = f"the folder {p}, which [commands] names" if p.is_dir() else f"the folder of {p}, which [commands] names"
        out += [(f, what) for f in dict.fromkeys([p, p.resolve()] if p.is_dir() else [p.parent, p.resolve().parent])]
    return out


def checked(
    shown: list[tuple[Path, str]], hidden: Iterable[Path | str] = (), trusted: Iterable[Path | str] = ()
) -> tuple[list[Path], tuple[Path, str, str] | None]:
    """The folders of ``shown`` a view may hold (the system folders every sandbox shows left
    out), and the first that it may not: (folder, why it is shown, why not), or None. Each is
    judged by place (:func:`~.sandbox.view_problem`) and, unless ``trusted`` (the bundled
    manifests' folder), by content (:func:`folder_problem`)."""
    out: list[Path] = []
    for p, what in shown:
        if _under(p, SYSTEM_TOPS) or p in out:
            continue
        why = view_problem(p, hidden) or (None if p in trusted else folder_problem(p, hidden))
        if why:
            return out, (p, what, why)
        out.append(p)
    return out, None


def installed_data(roots: list[Path]) -> list[Path]:
    """The goldens and suites of every fbaconf installed in the site-packages folders under
    ``roots`` (the folders a ``{python}`` decoder is shown): hidden from it wherever they are."""
    out = []
    for r in roots:
        for pkg in list(Path(r).glob("lib/python3*/*-packages/fbaconf")) + list(Path(r).glob("*-packages/fbaconf")):
            out += [pkg / "golden", pkg / "conformance" / "suites"]
    return [p for p in out if p.is_dir()]
