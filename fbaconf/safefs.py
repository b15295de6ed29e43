"""Files an untrusted decoder produced, handled defensively; paths that must stay inside
their folder.

* :func:`remove_tree` deletes a folder however deep it is (no recursion, no path-length
  limit: it walks by directory file descriptors) without following a symlink out of it;
* :func:`open_regular` / :func:`read_regular` open a file only if it is a regular file (no
  FIFO, device, socket or symlink — which could block the harness, stream forever or point
  at a file the decoder must not choose) and cap how much is read;
* :func:`confined` joins a relative path to a base folder and refuses anything that would
  leave it (``..``, an absolute path, a symlink on the way), for names that come from data
  (manifest names, case ids, suite files, package entries, fuzz findings).
"""
from __future__ import annotations

import os
import re
import stat
from pathlib import Path

from fbaconf.errors import FbaconfInputError


class UnsafeFileError(FbaconfInputError):
    """A file a decoder produced is not a regular file, or is larger than allowed."""
    rule = "output-unsafe"


class PathEscapeError(FbaconfInputError):
    """A path taken from data would leave the folder it belongs to."""
    rule = "path-escape"


_DIR_FLAGS = os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | getattr(os, "O_CLOEXEC", 0)


def remove_tree(path: Path | str) -> None:
    """Delete ``path`` and everything below it; never follows symlinks, never recurses.
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
        _remove_dir_at(parent_fd, os.path.basename(os.path.abspath(path)))
    finally:
        os.close(parent_fd)


def _remove_dir_at(parent_fd: int, name: str) -> None:
    # Stack of (fd of a directory, its name in the parent, fd of the parent).
    root_fd = os.open(name, _DIR_FLAGS, dir_fd=parent_fd)
    stack = [(root_fd, name, parent_fd)]
    while stack:
        fd, dname, pfd = stack[-1]
        descended = False
        with os.scandir(fd) as it:
            for entry in it:
                try:
                    is_dir = entry.is_dir(follow_symlinks=False)
                except OSError:
                    is_dir = False
                if is_dir:
                    try:
                        child = os.open(entry.name, _DIR_FLAGS, dir_fd=fd)
                    except OSError:
                        _chmod_dir(fd)
                        child = os.open(entry.name, _DIR_FLAGS, dir_fd=fd)
                    stack.append((child, entry.name, fd))
                    descended = True
                    break
                try:
                    os.unlink(entry.name, dir_fd=fd)
                except PermissionError:
                    _chmod_dir(fd)
                    os.unlink(entry.name, dir_fd=fd)
        if descended:
            continue
        stack.pop()
        os.close(fd)
        try:
            os.rmdir(dname, dir_fd=pfd)
        except PermissionError:
            _chmod_dir(pfd)
            os.rmdir(dname, dir_fd=pfd)


def empty_dir(path: Path | str, keep: frozenset[str] = frozenset()) -> None:
    """Remove everything inside the directory ``path`` but the entries named in ``keep``
    (links not followed: a link is removed, never its target). A ``path`` that is not a
    real directory (a decoder put a link or a file in its place) is removed and made anew."""
    path = os.fspath(path)
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        os.mkdir(path)
        return
    if not stat.S_ISDIR(st.st_mode):
        remove_tree(path)
        os.mkdir(path)
        return
    with os.scandir(path) as it:
        names = [e.name for e in it if e.name not in keep]
    for name in names:
        remove_tree(os.path.join(path, name))


def tree_size(path: Path | str, stop_at: int) -> int:
    """Bytes in the regular files below ``path`` (links not followed, any depth, no
    recursion); stops counting once past ``stop_at``."""
    try:
        root = os.open(path, _DIR_FLAGS)
    except OSError:
        return 0
    total, stack = 0, [root]
    try:
        while stack:
            fd = stack.pop()
            try:
                with os.scandir(fd) as it:
                    for e in it:
                        try:
                            if e.is_dir(follow_symlinks=False):
                                stack.append(os.open(e.name, _DIR_FLAGS, dir_fd=fd))
                            elif e.is_file(follow_symlinks=False):
                                total += e.stat(follow_symlinks=False).st_size
                        except OSError:
                            pass
                        if total > stop_at:
                            return total
            finally:
                os.close(fd)
    finally:
        for fd in stack:
            os.close(fd)
    return total


def _chmod_dir(fd: int) -> None:
    try:
        os.fchmod(fd, 0o700)
    except OSError:
        pass


def open_regular(path: Path | str, max_bytes: int):
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
        kind = ("a FIFO" if stat.S_ISFIFO(st.st_mode) else "a device" if stat.S_ISCHR(st.st_mode) or
                stat.S_ISBLK(st.st_mode) else "a socket" if stat.S_ISSOCK(st.st_mode) else
                "a directory" if stat.S_ISDIR(st.st_mode) else "not a regular file")
        raise UnsafeFileError(f"is {kind} (outputs must be regular files)", file=str(path))
    if st.st_size > max_bytes:
        os.close(fd)
        raise UnsafeFileError(f"is {st.st_size} bytes, over the {max_bytes} byte limit", file=str(path))
    os.set_blocking(fd, True)
    return os.fdopen(fd, "rb")


def read_regular(path: Path | str, max_bytes: int) -> bytes:
    """The bytes of a regular file of at most ``max_bytes`` (see :func:`open_regular`)."""
    with open_regular(path, max_bytes) as f:
        data = f.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise UnsafeFileError(f"grew past the {max_bytes} byte limit while being read", file=str(path))
    return data


def confined(base: Path | str, rel: str, *, what: str = "path") -> Path:
    """``base / rel`` if ``rel`` is a plain relative path that stays inside ``base`` (no
    ``..``, not absolute, no NUL, no symlink on the way); :class:`PathEscapeError` otherwise."""
    if not isinstance(rel, str) or not rel or "\x00" in rel or "\\" in rel:
        raise PathEscapeError(f"{what} {rel!r} is not a relative path name")
    p = Path(rel)
    if p.is_absolute() or any(part in ("..", "") for part in rel.split("/")) or rel.startswith("~"):
        raise PathEscapeError(f"{what} {rel!r} would leave {base}")
    base = Path(base)
    out = base / p
    cur = base
    for part in p.parts:
        cur = cur / part
        if cur.is_symlink():
            raise PathEscapeError(f"{what} {rel!r}: {cur} is a symbolic link")
    try:
        out.resolve().relative_to(base.resolve())
    except ValueError:
        raise PathEscapeError(f"{what} {rel!r} would leave {base}") from None
    return out


def safe_name(name: str, *, what: str = "name") -> str:
    """A single path component made of letters, digits, ``.``, ``_``, ``-`` and ``@``
    (not starting with a dot): safe as a folder or file name."""
    if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z0-9_@+-][A-Za-z0-9._@+-]{0,127}", name):
        raise PathEscapeError(f"{what} {name!r} must be 1-128 letters, digits, '.', '_', '-', '+' or '@' "
                              f"(not starting with '.')")
    return name
