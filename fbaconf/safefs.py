"""Files an untrusted decoder produced, handled defensively; paths that must stay inside
their folder.

* :func:`remove_tree` deletes a folder however deep it is (no recursion, no path-length
  limit: it walks by directory file descriptors) without following a symlink out of it;
* :func:`empty_tree` empties a reused case folder to its kept folders the same way, while the
  decoder that may change it runs;
* :func:`open_regular` / :func:`read_regular` open a file only if it is a regular file (no
  FIFO, device, socket or symlink — which could block the harness, stream forever or point
  at a file the decoder must not choose) and cap how much is read;
* :func:`confined` joins a relative path to a base folder and refuses anything that would
  leave it (``..``, an absolute path, a symlink on the way), for names that come from data
  (manifest names, case ids, suite files, package entries, fuzz findings).
"""

from __future__ import annotations

import errno
import os
import re
import stat
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, TypeAlias

from fbaconf.errors import FbaconfInputError


class UnsafeFileError(FbaconfInputError):
    """A file a decoder produced is not a regular file, or is larger than allowed."""

    rule = "output-unsafe"


class PathEscapeError(FbaconfInputError):
    """A path taken from data would leave the folder it belongs to."""

    rule = "path-escape"


_DIR_FLAGS = os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | getattr(os, "O_CLOEXEC", 0)


def remove_tree(path: Path | str) -> None:
    """Delete ``path`` and everything below it; never follows symlinks, never recurses, holds
    one directory descriptor at a time whatever the depth (a 50,000-level tree is removed).
    A missing path is fine; a symlink or file at ``path`` is simply unlinked."""
    path = os.fspath(path)
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    if not stat.S_ISDIR(st.st_mode):
        os.unlink(path)
        return
    parent_fd = os.open(os.path.dirname(os.path.abspath(path)) or "/", _DIR_FLAGS)
    try:
        _walk(parent_fd, os.path.basename(os.path.abspath(path)), remove=True, stop_at=None)
    finally:
        os.close(parent_fd)


class TreeChangedError(OSError):
    """A folder moved while it was walked (its ``..`` is not the folder the walk came from)."""


def _open_dir(parent_fd: int, name: str) -> int:
    try:
        return os.open(name, _DIR_FLAGS, dir_fd=parent_fd)
    except PermissionError:
        _chmod_dir(parent_fd)
        try:
            os.chmod(name, 0o700, dir_fd=parent_fd, follow_symlinks=False)
        except (OSError, NotImplementedError):
            pass
        return os.open(name, _DIR_FLAGS, dir_fd=parent_fd)


def _scan(fd: int, remove: bool, sizes: list[int]) -> list[str]:
    """The subdirectory names of the folder ``fd``; its other entries unlinked (``remove``) or
    their sizes added to ``sizes[0]`` (regular files only)."""
    subdirs = []
    with os.scandir(fd) as it:
        for e in it:
            if _is_dir(e):
                subdirs.append(e.name)
            elif remove:
                try:
                    os.unlink(e.name, dir_fd=fd)
                except PermissionError:
                    _chmod_dir(fd)
                    os.unlink(e.name, dir_fd=fd)
                except FileNotFoundError:
                    pass
            else:
                try:
                    if e.is_file(follow_symlinks=False):
                        sizes[0] += e.stat(follow_symlinks=False).st_size
                except OSError:
                    pass
    return subdirs


@dataclass
class _Frame:
    """One level of the walk: the folder's name in its parent, the (device, inode) of that
    parent (checked on the way back up) and the subdirectories still to visit."""

    name: str
    parent: tuple[int, int]
    left: list[str]


def _walk(parent_fd: int, name: str, *, remove: bool, stop_at: int | None, sizes: list[int] | None = None) -> int:
    """Walk the folder ``name`` in ``parent_fd`` depth first with one descriptor open: down by
    name, back up by ``..`` (checked against the device and inode recorded on the way down, so
    a folder moved meanwhile stops the walk with :class:`TreeChangedError`). ``remove``: unlink
    everything and remove the folders on the way back up; else sum the regular files' sizes
    (stopping once past ``stop_at``) into ``sizes[0]``. Returns the bytes counted."""
    sizes = [0] if sizes is None else sizes
    top = os.fstat(parent_fd)
    fd = _open_dir(parent_fd, name)
    frames = [_Frame(name, (top.st_dev, top.st_ino), _scan(fd, remove, sizes))]
    again: dict[int, int] = {}
    try:
        while frames:
            if stop_at is not None and sizes[0] > stop_at:
                return sizes[0]
            frame = frames[-1]
            if frame.left:
                sub = frame.left.pop()
                here = os.fstat(fd)
                try:
                    child = _open_dir(fd, sub)
                except (FileNotFoundError, NotADirectoryError):
                    continue
                except OSError:
                    if remove:
                        raise
                    continue
                os.close(fd)
                fd = child
                frames.append(_Frame(sub, (here.st_dev, here.st_ino), _scan(fd, remove, sizes)))
                continue
            frames.pop()
            if frames:
                up = os.open("..", _DIR_FLAGS, dir_fd=fd)
                st = os.fstat(up)
                if (st.st_dev, st.st_ino) != frame.parent:
                    os.close(up)
                    raise TreeChangedError(f"{frame.name!r} moved while its tree was walked")
            else:
                up = parent_fd
            os.close(fd)
            fd = up
            if remove:
                try:
                    os.rmdir(frame.name, dir_fd=up)
                except PermissionError:
                    _chmod_dir(up)
                    os.rmdir(frame.name, dir_fd=up)
                except OSError as e:  # something appeared in it meanwhile: once more
                    if e.errno != errno.ENOTEMPTY or again.get(id(frame), 0) > 2:
                        raise
                    again[id(frame)] = again.get(id(frame), 0) + 1
                    fd = _open_dir(up, frame.name)
                    frame.left = _scan(fd, remove, sizes)
                    frames.append(frame)
    finally:
        if fd != parent_fd:
            os.close(fd)
    return sizes[0]


# folders kept by name, each emptied to its own tree (None: left as it is)
Tree: TypeAlias = "Mapping[str, Tree | None]"


def empty_tree(path: Path | str, keep: Tree) -> None:
    """Remove everything below the directory ``path`` but the folders named in ``keep``: a
    name mapped to a mapping is a folder emptied the same way (made if missing), one mapped to
    None is left as it is. ``path`` that is not a real directory (a link, a file) is removed
    and made anew.

    The walk holds directory descriptors, each opened without following a link, and never
    resolves a path below ``path`` again: a decoder that runs meanwhile (the next input of a
    pipelined worker) and swaps a folder for a link to one of the host's cannot have the
    harness empty that one — a check of the path followed by a use of it could."""
    path = os.fspath(path)
    try:
        fd = os.open(path, _DIR_FLAGS)
    except FileNotFoundError:
        os.mkdir(path)
        fd = os.open(path, _DIR_FLAGS)
    except OSError:  # a link or a file in its place
        remove_tree(path)
        os.mkdir(path)
        fd = os.open(path, _DIR_FLAGS)
    try:
        _empty_at(fd, keep)
    finally:
        os.close(fd)


def _empty_at(fd: int, keep: Tree) -> None:
    """:func:`empty_tree` of the folder ``fd``."""
    seen = set()
    with os.scandir(fd) as it:
        entries = [(e.name, _is_dir(e)) for e in it]
    for name, is_dir in entries:
        if is_dir and name in keep:
            seen.add(name)
            sub = keep[name]
            if sub is None:
                continue
            try:
                child = _open_dir(fd, name)
            except OSError:  # swapped meanwhile (a link, a file, gone)
                _remove_at(fd, name)
                seen.discard(name)
                continue
            try:
                _empty_at(child, sub)
            finally:
                os.close(child)
        else:
            _remove_at(fd, name)
    for name, sub in keep.items():
        if name not in seen and sub is not None:  # missing, or something else in its place
            _remove_at(fd, name)
            os.mkdir(name, 0o755, dir_fd=fd)
            child = _open_dir(fd, name)
            try:
                _empty_at(child, sub)  # its own kept folders made too
            finally:
                os.close(child)


def _is_dir(e: os.DirEntry[str]) -> bool:
    try:
        return e.is_dir(follow_symlinks=False)
    except OSError:
        return False


def _remove_at(fd: int, name: str) -> None:
    """Remove the entry ``name`` of the folder ``fd``, whatever it is (a folder with its tree);
    one swapped for another kind meanwhile is tried again as what it has become."""
    for _ in range(3):
        try:
            try:
                os.unlink(name, dir_fd=fd)
            except PermissionError:
                _chmod_dir(fd)
                os.unlink(name, dir_fd=fd)
            return
        except FileNotFoundError:
            return
        except IsADirectoryError:
            pass
        try:
            _walk(fd, name, remove=True, stop_at=None)
            return
        except FileNotFoundError:
            return
        except OSError as e:
            if e.errno not in (errno.ELOOP, errno.ENOTDIR):
                raise
    raise TreeChangedError(f"{name!r} kept changing while it was removed")


def tree_size(path: Path | str, stop_at: int) -> int:
    """Bytes in the regular files below ``path`` (links not followed, any depth, no recursion,
    one directory descriptor at a time); stops counting once past ``stop_at``. A tree that
    changes while it is counted (a running decoder) gives what was counted so far."""
    path = os.path.abspath(os.fspath(path))
    try:
        parent_fd = os.open(os.path.dirname(path) or "/", _DIR_FLAGS)
    except OSError:
        return 0
    sizes = [0]
    try:
        return _walk(parent_fd, os.path.basename(path), remove=False, stop_at=stop_at, sizes=sizes)
    except OSError:  # a folder moved or vanished meanwhile: what was counted
        return sizes[0]
    finally:
        os.close(parent_fd)


def _chmod_dir(fd: int) -> None:
    try:
        os.fchmod(fd, 0o700)
    except OSError:
        pass


def open_regular(path: Path | str, max_bytes: int) -> BinaryIO:
    """A binary file object for ``path`` if it is a regular file of at most ``max_bytes``;
    :class:`UnsafeFileError` otherwise (naming what it is)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as e:
        if os.path.islink(path):
            raise UnsafeFileError("is a symbolic link (outputs must be regular files)", file=str(path)) from None
        raise UnsafeFileError(f"cannot open: {e.strerror}", file=str(path)) from None
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode):
        os.close(fd)
        kind = (
            "a FIFO"
            if stat.S_ISFIFO(st.st_mode)
            else "a device"
            if stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode)
            else "a socket"
            if stat.S_ISSOCK(st.st_mode)
            else "a directory"
            if stat.S_ISDIR(st.st_mode)
            else "not a regular file"
        )
        raise UnsafeFileError(f"is {kind} (outputs must be regular files)", file=str(path))
    if st.st_size > max_bytes:
        os.close(fd)
        raise UnsafeFileError(f"is {st.st_size} bytes, over the {max_bytes} byte limit", file=str(path))
    os.set_blocking(fd, True)
    return os.fdopen(fd, "rb")


def read_regular(path: Path | str, max_bytes: int) -> bytes:
    """The bytes of a regular file of at most ``max_bytes`` (see :func:`open_regular`)."""
    with open_regular(path, max_bytes) as f:
        data: bytes = f.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise UnsafeFileError(f"grew past the {max_bytes} byte limit while being read", file=str(path))
    return data


def confined(base: Path | str, rel: str, *, what: str = "path") -> Path:
    """``base / rel`` if ``rel`` is a plain relative path that stays inside ``base`` (no
    ``..``, not absolute, no NUL, no symlink on the way, no component the file system cannot
    name); :class:`PathEscapeError` otherwise (quoting at most 80 characters of ``rel``)."""
    shown = repr(rel) if not isinstance(rel, str) or len(rel) <= 80 else repr(rel[:80]) + f"… ({len(rel)} characters)"
    if not isinstance(rel, str) or not rel or "\x00" in rel or "\\" in rel:
        raise PathEscapeError(f"{what} {shown} is not a relative path name")
    p = Path(rel)
    if p.is_absolute() or any(part in ("..", "") for part in rel.split("/")) or rel.startswith("~"):
        raise PathEscapeError(f"{what} {shown} would leave {base}")
    if any(len(os.fsencode(part)) > 255 for part in p.parts):
        raise PathEscapeError(f"{what} {shown}: a path component longer than 255 bytes")
    base = Path(base)
    out = base / p
    cur = base
    try:
        for part in p.parts:
            cur = cur / part
            if cur.is_symlink():
                raise PathEscapeError(f"{what} {shown}: {cur} is a symbolic link")
        out.resolve().relative_to(base.resolve())
    except ValueError:
        raise PathEscapeError(f"{what} {shown} would leave {base}") from None
    except OSError as e:  # a name the file system refuses (too long, a loop...)
        raise PathEscapeError(f"{what} {shown}: {e.strerror or e}") from None
    return out


def safe_name(name: str, *, what: str = "name") -> str:
    """A single path component made of letters, digits, ``.``, ``_``, ``-`` and ``@``
    (not starting with a dot): safe as a folder or file name."""
    if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z0-9_@+-][A-Za-z0-9._@+-]{0,127}", name):
        raise PathEscapeError(
            f"{what} {name!r} must be 1-128 letters, digits, '.', '_', '-', '+' or '@' (not starting with '.')"
        )
    return name
