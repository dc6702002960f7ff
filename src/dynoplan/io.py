"""Atomic outputs: write to a temporary file or folder beside the target, then rename.

A reader never sees a half-written output: either the old file (folder), or the complete
new one. Temporary names carry the writer's process id, so a leftover of a killed run is
recognised (its process is gone) and removed by the next write of the same target, with a
:class:`~dynoplan.errors.DynoplanWarning` naming it. :func:`check_writable` tells, before
any work and creating nothing, whether a staged write of a folder can complete.
:func:`read_json_object` reads the JSON documents dynoplan writes back, with one error
line for a missing, unreadable or malformed file.
"""

import csv
import errno
import json
import os
import re
import shutil
import signal
import tempfile
import warnings
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any

from dynoplan.errors import DynoplanError, DynoplanWarning


@contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path in the target's folder; rename it onto ``path`` on success.

    The temporary name (``.<stem>.<pid>.<random>.tmp<suffix>``) keeps the target's suffix
    so that libraries choosing a format by extension (matplotlib, imageio) still work. On
    any exception, ``KeyboardInterrupt`` included, it is removed; leftovers of killed
    processes for the same target are removed first.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    prefix, suffix = f".{target.stem}.", f".tmp{target.suffix}"
    remove_stale(target.parent, prefix, suffix)
    fd, tmp_name = tempfile.mkstemp(prefix=f"{prefix}{os.getpid()}.", suffix=suffix,
                                    dir=target.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    os.chmod(tmp, 0o666 & ~current_umask())  # mkstemp makes 0600; outputs get the usual mode
    try:
        yield tmp
        os.replace(tmp, target)
    finally:
        if tmp.exists():
            tmp.unlink()


def remove_stale(folder: Path, prefix: str, suffix: str) -> list[Path]:
    """Remove the entries ``<prefix><pid>.<random><suffix>`` of ``folder`` whose process
    ``pid`` no longer runs: temporary files or folders of a killed writer (SIGKILL, a
    machine that went down). Each removal is announced by one
    :class:`~dynoplan.errors.DynoplanWarning`; the removed paths are returned. Entries
    that cannot be removed stay, silently (the write that follows reports the folder)."""
    try:
        names = os.listdir(folder)
    except OSError:
        return []
    pattern = re.compile(re.escape(prefix) + r"(\d+)\.[A-Za-z0-9_]+" + re.escape(suffix))
    removed = []
    for name in sorted(names):
        match = pattern.fullmatch(name)
        if match is None or _running(int(match.group(1))):
            continue
        stale = folder / name
        if stale.is_dir() and not stale.is_symlink():
            shutil.rmtree(stale, ignore_errors=True)
        else:
            with suppress(OSError):
                stale.unlink(missing_ok=True)
        if not stale.exists() and not stale.is_symlink():
            removed.append(stale)
            warnings.warn(f"removed {stale}, left by process {match.group(1)}, which no "
                          "longer runs", DynoplanWarning, stacklevel=2)
    return removed


def _running(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # exists, owned by someone else
        return True
    return True


@contextmanager
def staged_folder(path: str | os.PathLike[str], keep: bool = False,
                  drop: Sequence[str] = ()) -> Iterator[Path]:
    """Yield a new folder beside ``path`` to write into; move its content onto ``path``
    only when the block completes.

    On any exception (``KeyboardInterrupt`` and SIGTERM included, see
    :func:`dynoplan.cli.main.main`) the staged folder is removed and ``path`` is left as
    it was; folders created for it are removed again. On success, with ``keep`` False,
    each top-level entry of the staged folder replaces the entry of that name in ``path``
    (other entries of ``path`` stay); with ``keep`` True the staged folder starts as a
    copy of ``path`` and replaces it whole, so ``path`` is the previous folder, complete,
    until the new one is. The entries of ``path`` named in ``drop`` (a previous run's
    outputs, which the block's replace together) go at the move when the block did not
    write them anew (with ``keep``, they are not copied). The move runs with SIGINT and
    SIGTERM blocked. Paths under the
    staged folder recorded in its JSON files (a dataset, a figure named in a summary) are
    renamed to the same paths under ``path`` before the move (:func:`retarget`: the
    outputs name where they are, never a staging folder).

    Raises:
        DynoplanError: see :func:`check_writable` (checked first: nothing is created then).
    """
    target = Path(path)
    check_writable(target)
    created = _make_dirs(target.parent)
    try:
        prefix = f".{target.name}."
        for suffix in (".staging", ".old"):
            remove_stale(target.parent, prefix, suffix)
        stage = Path(tempfile.mkdtemp(prefix=f"{prefix}{os.getpid()}.", suffix=".staging",
                                      dir=target.parent))
    except BaseException:
        _remove_empty(created)
        raise
    try:
        os.chmod(stage, 0o777 & ~current_umask())  # mkdtemp makes 0700
        if keep and target.is_dir():
            shutil.copytree(target, stage, symlinks=True, dirs_exist_ok=True,
                            ignore=lambda folder, _: drop if folder == str(target) else ())
        yield stage
        _retarget_json_files(stage, target)
        fsync_tree(stage)
        with _signals_blocked():
            _install(stage, target, whole=keep and not Path.cwd().is_relative_to(
                target.resolve()), drop=drop)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        _remove_empty(created)
        raise


def retarget(value: Any, stage: Path, target: Path) -> Any:
    """``value`` (strings, lists, tuples, dicts of them) with every string that names
    ``stage`` or a path under it naming the same path under ``target`` instead: what a
    run into a staged folder (:func:`staged_folder`) recorded, as the outputs will be."""
    if isinstance(value, str):
        head = str(stage)
        if value == head or value.startswith(head + os.sep):
            return str(target) + value[len(head):]
        return value
    if isinstance(value, dict):
        return {k: retarget(v, stage, target) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(retarget(v, stage, target) for v in value)
    return value


def _retarget_json_files(stage: Path, target: Path) -> None:
    """:func:`retarget` in the JSON files under ``stage``: a file that names ``stage`` is
    rewritten with ``target`` in its place (the staging folder's name is unique, so its
    JSON string form is replaced as text; the rest of the file stays as it was)."""
    forms = {json.dumps(str(stage), ensure_ascii=a)[1:-1]: json.dumps(str(target),
                                                                       ensure_ascii=a)[1:-1]
             for a in (True, False)}
    for file in sorted(stage.rglob("*.json")):
        if file.is_symlink() or not file.is_file():
            continue
        try:
            text = file.read_text(encoding="utf-8")
        except UnicodeDecodeError:  # not one of ours
            continue
        changed = text
        for old, new in forms.items():
            changed = changed.replace(old, new)
        if changed != text:
            write_text(file, changed)


def _install(stage: Path, target: Path, whole: bool, drop: Sequence[str] = ()) -> None:
    """Move ``stage`` onto ``target`` (whole: replace it; else entry by entry, and the
    entries named in ``drop`` that ``stage`` does not hold are removed from ``target``)."""
    if not target.exists():
        os.rename(stage, target)
    elif whole:
        _swap(stage, target)
    else:
        staged = set(os.listdir(stage))
        for entry in sorted(stage.iterdir()):
            dest = target / entry.name
            if dest.is_dir() and not dest.is_symlink():
                _swap(entry, dest)
            else:
                os.replace(entry, dest)
        for name in set(drop) - staged:
            gone = target / name
            if gone.is_dir() and not gone.is_symlink():
                shutil.rmtree(gone)
            elif gone.exists() or gone.is_symlink():
                gone.unlink()
        stage.rmdir()
    fsync_dir(target.parent)


def _swap(new: Path, target: Path) -> None:
    """Replace the folder ``target`` by ``new`` (two renames; the old one is deleted)."""
    old = Path(tempfile.mkdtemp(prefix=f".{target.name}.{os.getpid()}.", suffix=".old",
                                dir=target.parent))
    os.rename(target, old / target.name)
    try:
        os.rename(new, target)
    except BaseException:
        os.rename(old / target.name, target)
        raise
    finally:
        shutil.rmtree(old, ignore_errors=True)


@contextmanager
def _signals_blocked() -> Iterator[None]:
    signals = {signal.SIGINT, signal.SIGTERM}
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, signals)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def _make_dirs(folder: Path) -> list[Path]:
    """Create ``folder`` and its missing parents; the ones created, deepest first."""
    missing = []
    current = folder
    while not current.exists() and current != current.parent:
        missing.append(current)
        current = current.parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DynoplanError(f"cannot write to {folder}: {_reason(exc)}") from None
    return missing


def _remove_empty(folders: Sequence[Path]) -> None:
    for folder in folders:  # deepest first
        try:
            folder.rmdir()
        except OSError:
            return


def fsync_dir(folder: Path) -> None:
    """Flush a folder's entries (a rename into it) to disk."""
    fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def fsync_tree(folder: Path) -> None:
    """Flush every file under ``folder`` before a rename, so that a crash cannot expose
    empty files."""
    for item in sorted(folder.rglob("*")):
        if item.is_symlink():
            continue
        if item.is_dir():
            fsync_dir(item)
        else:
            fd = os.open(item, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
    fsync_dir(folder)


def current_umask() -> int:
    """The process umask (read without changing it)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_text(path: str | os.PathLike[str], text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def write_json(path: str | os.PathLike[str], obj: Any) -> None:
    write_text(path, json.dumps(obj, indent=2, sort_keys=False, allow_nan=True) + "\n")


def write_csv(path: str | os.PathLike[str], rows: Sequence[dict[str, Any]]) -> None:
    if not rows:
        raise ValueError("no rows to write")
    columns = list(rows[0])
    with atomic_path(path) as tmp, tmp.open("w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)


def write_with(path: str | os.PathLike[str], writer: Callable[[Path], None]) -> None:
    """Call ``writer(tmp_path)`` and move the result onto ``path`` atomically."""
    with atomic_path(path) as tmp:
        writer(tmp)


def check_writable(path: str | os.PathLike[str]) -> None:
    """Check that the folder ``path`` can be written as :func:`staged_folder` writes it,
    creating nothing that stays: files can be made in ``path`` when it exists (its entries
    are replaced, or it is renamed aside), and in the nearest existing folder above it
    (where the staging folder, and the folders missing on the way, are made).

    Commands call it before any work, so that a read-only or immutable output folder
    costs nothing and leaves nothing beside it.

    Raises:
        DynoplanError: ``path`` is a file, or ``cannot write to FOLDER: REASON`` (reason
            ``permission denied`` for a read-only, immutable or foreign folder).
    """
    target = Path(path)
    if target.exists() and not target.is_dir():
        raise DynoplanError(f"{target}: is a file, expected a folder")
    above = target.parent
    while not above.exists() and above != above.parent:
        above = above.parent
    for folder in ([target] if target.is_dir() else []) + [above]:
        try:
            fd, probe = tempfile.mkstemp(prefix=".write-check.", dir=folder)
            os.close(fd)
            os.unlink(probe)
        except OSError as exc:
            raise DynoplanError(f"cannot write to {folder}: {_reason(exc)}") from None


def _reason(exc: OSError) -> str:
    """What an ``OSError`` of a write means to a user, in lower case."""
    if exc.errno in (errno.EACCES, errno.EPERM):
        return "permission denied"
    return (exc.strerror or str(exc)).lower()


def ensure_writable_dir(path: str | os.PathLike[str]) -> Path:
    """Create ``path`` if needed and check that files can be created in it.

    Raises:
        DynoplanError: the path is a file, or the folder cannot be created or written.
    """
    folder = Path(path)
    if folder.exists() and not folder.is_dir():
        raise DynoplanError(f"{folder}: is a file, expected a folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".write-check.", dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise DynoplanError(f"cannot write to {folder}: {_reason(exc)}") from None
    return folder


def read_json_object(path: str | os.PathLike[str], what: str = "file") -> dict[str, Any]:
    """The JSON object in ``path``.

    Raises:
        DynoplanError: one line naming ``path`` (and ``what`` it should be): a missing or
            unreadable file, invalid JSON, or a document that is not an object.
    """
    file = Path(path)
    try:
        doc = json.loads(file.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DynoplanError(f"{file}: not found") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DynoplanError(f"{file}: not a readable {what} ({exc})") from None
    if not isinstance(doc, dict):
        raise DynoplanError(f"{file}: not a {what} (expected a JSON object, got "
                            f"{type(doc).__name__})")
    return doc
