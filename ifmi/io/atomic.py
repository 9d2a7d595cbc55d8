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
* Temporaries and backups are named ``.NAME.PID-XXXXXXXX.tmp`` and
  ``.NAME.PID-XXXXXXXX.old`` beside the target ``NAME`` (``PID`` the
  writer's process). A writer killed mid-write (SIGKILL, power loss) leaves
  them; :func:`remove_leftovers`, which the next run calls on its own
  outputs, removes those whose process is gone.
* :func:`write_folder` writes a whole output folder as one set: it is built
  in a temporary sibling folder and swapped in when complete (an atomic
  exchange where the system has one). :func:`check_output_folder` refuses,
  before any work, an existing folder the command did not write itself.

Failures raise :class:`~ifmi.errors.OutputError` naming the user's path
and the OS reason.
"""

from __future__ import annotations

import ctypes
import errno
import json
import os
import re
import shutil
import stat
import sys
import tempfile
import warnings
from pathlib import Path
from typing import Callable, Collection, Mapping

from ifmi.errors import OutputError

__all__ = ["atomic_write_bytes", "atomic_write_text", "atomic_write_json", "atomic_write_files",
           "writable_target", "probe_writable", "json_text", "check_output_folder", "write_folder",
           "folder_of_kind", "path_within", "remove_leftovers", "utf8_bytes"]

# Tries at a free backup name (names are random; a clash is already unlikely).
_BACKUP_ATTEMPTS = 16
# Entries of a refused folder named in the error message (the rest are counted).
_LISTED_ENTRIES = 3
# renameat2(2) arguments (<linux/fs.h>, <fcntl.h>): swap two paths atomically, relative to the cwd.
_RENAME_EXCHANGE = 2
_AT_FDCWD = -100
# A temporary or backup of this module: ``.NAME.PID-XXXXXXXX.tmp`` or ``.old`` (``PID-`` missing in
# the names of earlier versions; the 8 characters are tempfile's random ones).
_LEFTOVER_NAME = re.compile(r"^\.(?P<name>.+)\.(?:(?P<pid>\d+)-)?[a-z0-9_]{8}\.(?:tmp|old)$")


def path_within(path: str | os.PathLike, folder: str | os.PathLike) -> bool:
    """True when ``path`` is ``folder`` or lies below it, symbolic links resolved on both."""
    path, folder = Path(os.path.realpath(path)), Path(os.path.realpath(folder))
    return path == folder or folder in path.parents


def _umask() -> int:
    # Linux reports the umask in /proc without changing it; elsewhere it is read by setting it.
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            return next(int(ln.split()[1], 8) for ln in fh if ln.startswith("Umask:"))
    except (OSError, StopIteration, ValueError):
        umask = os.umask(0o022)
        os.umask(umask)
        return umask


def _default_file_mode() -> int:
    # Temporary files are created 0600; a finished file gets the mode a plain
    # open() would give it (0666 less the process umask).
    return 0o666 & ~_umask()


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
        fd, tmp = tempfile.mkstemp(prefix=_leftover_prefix(target), suffix=".tmp", dir=target.parent)
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


def _leftover_prefix(target: Path) -> str:
    """Start of the name of a temporary or backup of ``target`` (see :data:`_LEFTOVER_NAME`)."""
    return f".{target.name}.{os.getpid()}-"


def _process_alive(pid: int) -> bool:
    """True when a process ``pid`` runs on this machine (this one included)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, OSError):
        return True  # another user's process, or a number the system will not check: keep its files
    return True


def remove_leftovers(folder: str | os.PathLike, *, names: Collection[str] | None = None) -> list[Path]:
    """Remove the temporaries and backups that killed writers of this module left in ``folder``.

    Parameters
    ----------
    folder : path
        The folder of the outputs (not searched below it).
    names : collection of str, optional, keyword-only
        The outputs' file names whose leftovers are removed (default: every
        name, for a folder the command owns, such as a dataset's
        ``images/``).

    Returns
    -------
    list of Path
        The files removed. Those of a writer that still runs are kept (its
        process id is in the name); names of earlier versions, without it,
        are removed. A folder that cannot be listed, or a file that cannot
        be removed, is left as it is.
    """
    removed = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for entry in entries:
        match = _LEFTOVER_NAME.match(entry.name)
        if match is None or (names is not None and match["name"] not in names):
            continue
        if match["pid"] is not None and _process_alive(int(match["pid"])):
            continue
        try:
            if entry.is_file(follow_symlinks=False):
                os.unlink(entry.path)
                removed.append(Path(entry.path))
        except OSError:
            pass
    return removed


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


def utf8_bytes(text: str) -> bytes:
    """``text`` as UTF-8; a lone surrogate is written as its ``\\udcXX`` escape.

    Python gives a byte of a file name that is not UTF-8 as a lone surrogate
    (``os.fsdecode``), which UTF-8 cannot hold; a file name quoted in a
    written text (a frame's failure reason, a report's command line) keeps it
    visible that way instead of failing the write.
    """
    return text.encode("utf-8", errors="backslashreplace")


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write UTF-8 ``text`` to ``path`` atomically (lone surrogates escaped, :func:`utf8_bytes`)."""
    atomic_write_bytes(path, utf8_bytes(text))


def json_text(obj) -> str:
    """``obj`` as the JSON text every writer of the project uses (indented, sorted keys)."""
    return json.dumps(obj, indent=2, sort_keys=True) + "\n"


def atomic_write_json(path: str | os.PathLike, obj) -> None:
    """Write ``obj`` as indented JSON to ``path`` atomically."""
    atomic_write_text(path, json_text(obj))


def atomic_write_files(files: Mapping[str | os.PathLike, bytes]) -> None:
    """Write several files as one set: all of them, or none.

    A target that already holds the same bytes is left untouched (not
    written again: a finished output on a read-only mount is no error).
    Every other file is first written to a synced temporary beside its target;
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
    files = {path: data for path, data in files.items() if not _holds(targets[Path(path)], data)}
    if not files:
        return
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


def _holds(target: Path, data: bytes) -> bool:
    """True when the regular file ``target`` exists and holds exactly ``data``."""
    try:
        return target.stat().st_size == len(data) and target.read_bytes() == data
    except OSError:
        return False


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
        name = tempfile.mktemp(prefix=_leftover_prefix(target), suffix=".old", dir=target.parent)
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


def _entries_text(names: list[str]) -> str:
    """``a, b, c and 4 more`` for a folder's entry names."""
    shown = ", ".join(names[:_LISTED_ENTRIES])
    more = len(names) - _LISTED_ENTRIES
    return f"{shown} and {more} more" if more > 0 else shown


def check_output_folder(path: str | os.PathLike, *, is_own: Callable[[Path], bool],
                        what: str) -> Path:
    """Check, before any work, that a command may write its output folder ``path``.

    A folder that does not exist yet, an empty one, or one ``is_own``
    recognises (the command wrote it before) may be written; any other
    existing folder holds files of the user's and is refused.

    Parameters
    ----------
    path : path
        The output folder. A symbolic link is followed: the folder it
        points to is the one checked (and later replaced).
    is_own : callable, keyword-only
        ``is_own(folder)`` is True for a folder the command wrote.
    what : str, keyword-only
        What such a folder is, for the message (``"an evaluation folder"``).

    Returns
    -------
    Path
        The folder with links resolved (give it to :func:`write_folder`).

    Raises
    ------
    OutputError
        ``path`` is a file, or a folder holding other files than the
        command's own (the message lists some of them).
    """
    path = Path(path)
    try:
        out = path.resolve()
        if out.exists() and not out.is_dir():
            raise OutputError(path, "exists and is not a folder")
        entries = sorted(e.name for e in out.iterdir()) if out.is_dir() else []
    except OutputError:
        raise
    except OSError as exc:
        raise OutputError.from_os_error(path, exc) from None
    except RuntimeError:  # Path.resolve of a link loop before Python 3.13
        raise OutputError(path, "symbolic link loop") from None
    if entries and not is_own(out):
        raise OutputError(path, f"holds {_entries_text(entries)} but is not {what} (expected a new "
                                "path, an empty folder or an earlier output of this command); "
                                "refusing to replace it")
    return out


def folder_of_kind(path: str | os.PathLike, file_name: str, kind: str, *,
                   legacy_keys: Collection[str] = ()) -> bool:
    """True when ``path/file_name`` is a JSON object a command wrote: of ``kind``, or an older form.

    Parameters
    ----------
    path : path
        The folder.
    file_name : str
        Its JSON record (``evaluation.json``, ``report.json``, ``sweep.json``).
    kind : str
        The record's ``"kind"`` field.
    legacy_keys : collection of str, keyword-only
        Records written before the kind was stored count when they have no
        kind and hold every one of these keys; empty: no such older form.

    Returns
    -------
    bool
        False for a missing, unreadable or foreign record.
    """
    if not (Path(path) / file_name).is_file():  # missing, or a FIFO whose read would block
        return False
    try:
        document = json.loads((Path(path) / file_name).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError):  # RecursionError: nested too deeply
        return False
    if not isinstance(document, dict):
        return False
    if "kind" in document:
        return document["kind"] == kind
    return bool(legacy_keys) and all(key in document for key in legacy_keys)


def _directory_mode(out: Path) -> int:
    """The mode a finished folder gets: that of the folder it replaces, else 0777 less the umask."""
    try:
        return stat.S_IMODE(os.stat(out).st_mode)
    except OSError:
        return 0o777 & ~_umask()


def _exchange(a: Path, b: Path) -> bool:
    """Swap two existing paths in one atomic step (Linux ``renameat2``); False where unsupported."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        renameat2 = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return False
    renameat2.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    renameat2.restype = ctypes.c_int
    if renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP, errno.EOPNOTSUPP):
        return False
    raise OSError(err, os.strerror(err), str(b))


def _swap_folder(staging: Path, out: Path) -> Path | None:
    """Put ``staging`` in the place of ``out``; returns where the old folder now is (to remove).

    An atomic exchange where the system has one; else two renames, the old
    folder put back if the second fails.
    """
    if not out.exists():
        os.rename(staging, out)
        return None
    if _exchange(staging, out):
        return staging
    old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.parent))
    try:
        os.rename(out, old / out.name)
    except OSError:
        old.rmdir()
        raise
    try:
        os.rename(staging, out)
    except OSError:
        os.rename(old / out.name, out)
        old.rmdir()
        raise
    return old


def _move_entries(names: list[str], source: Path, destination: Path) -> None:
    """Rename each entry ``names`` of ``source`` into ``destination``; on failure move them back."""
    moved: list[str] = []
    try:
        for name in names:
            if (destination / name).exists() or (destination / name).is_symlink():
                raise OSError(errno.EEXIST, f"{name} is both kept and written", str(destination))
            os.rename(source / name, destination / name)
            moved.append(name)
    except BaseException:
        for name in reversed(moved):
            os.rename(destination / name, source / name)
        raise


def _failure_reason(exc: OSError) -> str:
    if isinstance(exc, OutputError):
        return exc.reason
    failures = exc.args[0] if isinstance(exc, shutil.Error) and exc.args else None
    if isinstance(failures, list) and failures and len(failures[0]) == 3:
        # copytree gathers every file's (source, destination, reason): the first one says enough.
        source, _, reason = failures[0]
        more = f" and {len(failures) - 1} more" if len(failures) > 1 else ""
        return f"{reason} (copying {source}{more})"
    return exc.strerror or str(exc)


def write_folder(out: str | os.PathLike, fill: Callable[[Path], None], *,
                 replaces: Collection[str]) -> None:
    """Write the output folder ``out`` as one set: built beside it, swapped in when complete.

    ``fill`` writes every file into a new temporary folder beside ``out``
    (same parent, so the same file system). Entries of an existing ``out``
    that are not in ``replaces`` (the user's notes, say) are moved into it;
    then it takes the place of ``out`` (atomically where the system can
    exchange two folders) and the old folder is removed. If anything fails
    the old folder is unchanged and no temporary folder is left.

    Parameters
    ----------
    out : path
        The output folder, checked by :func:`check_output_folder` (links resolved).
    fill : callable
        ``fill(folder)`` writes the new content into the empty ``folder``.
    replaces : collection of str, keyword-only
        Names of the entries the command writes (an old one is dropped even
        when the new set lacks it).

    Raises
    ------
    OutputError
        Names ``out`` and the OS reason (never the temporary folder).

    Warns
    -----
    UserWarning
        The new folder is in place but the old one could not be removed
        entirely (e.g. an immutable file in it); names where it was left.
    """
    out = Path(out)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.new-", dir=out.parent))
    except OSError as exc:
        raise OutputError(out, _failure_reason(exc)) from None
    old, kept = None, []
    try:
        fill(staging)
        os.chmod(staging, _directory_mode(out))
        kept = sorted(e.name for e in out.iterdir() if e.name not in replaces) if out.is_dir() else []
        _move_entries(kept, out, staging)
        try:
            old = _swap_folder(staging, out)
        except BaseException:
            _move_entries(kept, staging, out)
            raise
    except OSError as exc:
        raise OutputError(out, _failure_reason(exc)) from None
    finally:
        # The temporary folder is removed unless entries of the user's are still in it
        # (only if moving them back failed too): better a stray folder than lost files.
        if (staging != old and staging.exists()
                and not any(os.path.lexists(staging / name) for name in kept)):
            shutil.rmtree(staging, ignore_errors=True)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
        if old.exists():
            warnings.warn(f"{out}: written, but the previous folder could not be removed "
                          f"entirely; what is left of it is in {old}", UserWarning, stacklevel=2)
