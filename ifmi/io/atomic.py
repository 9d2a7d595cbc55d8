"""Atomic file writes: a reader never sees a half-written file or a half-written set.

Every writer goes through a temporary file in the target's folder, synced
to disk, then renamed over the target. Further rules:

* A symbolic link as target is written through: the file it points to is
  replaced (atomically), the link stays a link.
* Only regular files are replaced: a device node, FIFO, socket or folder in
  the target's place is refused.
* :func:`atomic_write_files` writes several files as one set: all
  temporaries first, then the renames; if any step fails, the renamed ones
  are put back, so either the whole new set is in place or the old files
  are byte-identical.

Failures raise :class:`~ifmi.errors.OutputError` naming the user's path
and the OS reason.
"""

from __future__ import annotations

import errno
import json
import os
import stat
import tempfile
from pathlib import Path
from typing import Mapping

from ..errors import OutputError

__all__ = ["atomic_write_bytes", "atomic_write_text", "atomic_write_json", "atomic_write_files",
           "writable_target", "probe_writable", "json_text"]

# Tries at a free backup name (names are random; a clash is already unlikely).
_BACKUP_ATTEMPTS = 16


def _default_file_mode() -> int:
    # Temporary files are created 0600; a finished file gets the mode a plain
    # open() would give it (0666 less the process umask). Linux reports the
    # umask in /proc without changing it; elsewhere it is read by setting it.
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            umask = next(int(ln.split()[1], 8) for ln in fh if ln.startswith("Umask:"))
    except (OSError, StopIteration, ValueError):
        umask = os.umask(0o022)
        os.umask(umask)
    return 0o666 & ~umask


def _blocking_file(folder: Path) -> Path | None:
    """The first existing ancestor of ``folder`` (or itself) that is not a folder, if any."""
    for candidate in (folder, *folder.parents):
        if candidate.exists() or candidate.is_symlink():
            return None if candidate.is_dir() else candidate
    return None


def writable_target(path: str | os.PathLike) -> Path:
    """The file a write to ``path`` replaces: ``path``, or the end of its symbolic links.

    Raises
    ------
    OutputError
        ``path`` (or where its links lead) is a folder, a device node, a
        FIFO or a socket; a link loop; or a regular file stands where a
        folder of the path should be.
    """
    path = Path(path)
    try:
        target = Path(os.path.realpath(path, strict=False)) if path.is_symlink() else path
    except OSError as exc:
        raise OutputError.from_os_error(path, exc) from exc
    if target.is_symlink():
        raise OutputError(path, "symbolic link loop")
    try:
        mode = os.stat(target).st_mode
    except FileNotFoundError:
        mode = None
    except OSError as exc:
        if exc.errno == errno.ENOTDIR:
            blocker = _blocking_file(target.parent)
            raise OutputError(path, f"Not a directory: a file is in the way ({blocker})") from exc
        raise OutputError.from_os_error(path, exc) from exc
    if mode is not None and not stat.S_ISREG(mode):
        kind = "a folder" if stat.S_ISDIR(mode) else "a device, FIFO or socket, not a regular file"
        raise OutputError(path, f"is {kind}; refusing to replace it")
    blocker = _blocking_file(target.parent)
    if blocker is not None:
        raise OutputError(path, f"Not a directory: a file is in the way ({blocker})")
    return target


def probe_writable(path: str | os.PathLike) -> Path:
    """Check, before any work, that ``path`` can be written; returns :func:`writable_target`.

    When the target's folder exists a temporary file is created in it and
    removed again (the true test: permissions, read-only file systems, a
    full disk's inode table); otherwise the nearest existing folder above
    must be writable. Nothing is left behind.

    Raises
    ------
    OutputError
        As :func:`writable_target`, or the OS reason the folder cannot be written.
    """
    target = writable_target(path)
    folder = next(f for f in target.parents if f.exists())
    if folder == target.parent:
        try:
            fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".probe", dir=folder)
        except OSError as exc:
            raise OutputError.from_os_error(path, exc) from exc
        os.close(fd)
        _remove(tmp)
    elif not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError(path, f"Permission denied (cannot create folders in {folder})")
    return target


def _temporary_copy(path: Path, target: Path, data: bytes) -> str:
    """Write ``data`` to a synced temporary file beside ``target``; returns its name."""
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    except OSError as exc:
        raise OutputError.from_os_error(path, exc) from exc
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
            os.fchmod(fh.fileno(), _default_file_mode())
    except BaseException as exc:
        _remove(tmp)
        if isinstance(exc, OSError):
            raise OutputError.from_os_error(path, exc) from exc
        raise
    return tmp


def _remove(name: str | os.PathLike) -> None:
    try:
        os.unlink(name)
    except FileNotFoundError:
        pass


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file in the same folder and a rename.

    Raises
    ------
    OutputError
        The folder cannot be made or written (read-only, permission, full
        disk, a regular file in the way), or ``path`` is not a regular file
        (see :func:`writable_target`): names ``path`` and the OS reason.
        The temporary file is removed and an existing ``path`` is unchanged.
    """
    atomic_write_files({path: data})


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write UTF-8 ``text`` to ``path`` atomically."""
    atomic_write_bytes(path, text.encode("utf-8"))


def json_text(obj) -> str:
    """``obj`` as the JSON text every writer of the project uses (indented, sorted keys)."""
    return json.dumps(obj, indent=2, sort_keys=True) + "\n"


def atomic_write_json(path: str | os.PathLike, obj) -> None:
    """Write ``obj`` as indented JSON to ``path`` atomically."""
    atomic_write_text(path, json_text(obj))


def atomic_write_files(files: Mapping[str | os.PathLike, bytes]) -> None:
    """Write several files as one set: all of them, or none.

    Every file is first written to a synced temporary beside its target;
    then each existing target is kept under a backup link and the
    temporaries are renamed over the targets. If a write or a rename fails,
    the targets already renamed get their old content back (or are removed
    when they did not exist), so the old set stays byte-identical.

    Parameters
    ----------
    files : mapping of path -> bytes
        Targets in rename order (put the file readers look for first last).

    Raises
    ------
    OutputError
        Names the path that failed and the OS reason.
    """
    targets = {Path(p): writable_target(p) for p in files}
    if len(set(targets.values())) != len(targets):
        raise ValueError(f"two outputs of one set are the same file: {sorted(map(str, files))}")
    new_folders = sorted({folder for target in targets.values() for folder in _missing_folders(target)},
                         key=lambda folder: len(folder.parts), reverse=True)
    temporaries: dict[Path, str] = {}
    try:
        for path, data in files.items():
            path = Path(path)
            temporaries[path] = _temporary_copy(path, targets[path], data)
        _commit(temporaries, targets)
    except BaseException:
        for tmp in temporaries.values():
            _remove(tmp)
        for folder in new_folders:
            try:
                folder.rmdir()
            except OSError:
                pass
        raise


def _missing_folders(target: Path) -> list[Path]:
    """The folders above ``target`` that do not exist yet (made by the write)."""
    return [folder for folder in target.parents if not folder.exists()]


def _commit(temporaries: dict[Path, str], targets: dict[Path, Path]) -> None:
    """Rename every temporary over its target; on failure put the old targets back."""
    backups: dict[Path, str | None] = {}
    done: list[Path] = []
    kept: set[str] = set()
    try:
        for path, tmp in temporaries.items():
            target = targets[path]
            backups[path] = _backup(path, target) if len(temporaries) > 1 else None
            os.replace(tmp, target)
            done.append(path)
    except BaseException as exc:
        for renamed in reversed(done):
            backup = backups.get(renamed)
            try:
                if backup is not None:
                    os.replace(backup, targets[renamed])
                else:
                    _remove(targets[renamed])
            except OSError:
                # The old content stays in the backup file rather than being lost.
                kept.add(backup)
        if isinstance(exc, OSError):
            raise OutputError.from_os_error(path, exc) from exc
        raise
    finally:
        for backup in backups.values():
            if backup is not None and backup not in kept:
                _remove(backup)


def _backup(path: Path, target: Path) -> str | None:
    """The current ``target`` under a temporary name beside it (None if it does not exist).

    A hard link costs nothing; where the file system has none, a copy.
    """
    if not target.exists():
        return None
    for _ in range(_BACKUP_ATTEMPTS):
        name = tempfile.mktemp(prefix=f".{target.name}.", suffix=".old", dir=target.parent)
        try:
            os.link(target, name)
            return name
        except FileExistsError:
            continue
        except OSError as exc:
            if exc.errno not in (errno.EPERM, errno.ENOTSUP, errno.EXDEV, errno.EMLINK):
                raise OutputError.from_os_error(path, exc) from exc
            return _temporary_copy(path, target, target.read_bytes())
    raise OutputError(path, f"cannot make a backup name beside {target}")
