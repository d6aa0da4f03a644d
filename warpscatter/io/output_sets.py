"""The render's output set on disk: files written through temporaries and renamed in all or nothing, one writer per
output name, clean-up after writers that did not finish, and the checks of an output folder and name before any work.

Every write is atomic (temporary file, fsync, :func:`os.replace`), a whole output set all or nothing; the files'
contents come from writers ``write(temporary_path)`` (:mod:`.images` encodes the images, the CSM and report writers
their own files).

One writer per output: a write holds the advisory lock ``.NAME.lock`` beside its files (another writer of the name
waits, at most :data:`OUTPUT_LOCK_TIMEOUT_S`); a set of several files is renamed in under a commit manifest
``.NAME.commit.json`` that the next write (or :func:`remove_stale_temporaries`) uses to complete or roll back a set
whose writer was killed, so a folder only ever keeps a complete set.
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import os
import platform
import re
import secrets
import stat
import threading
import time
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor, wait
from pathlib import Path

from ..errors import ConfigError, WarpscatterError

try:
    import fcntl
except ImportError:  # Windows: no advisory locks (writes are still atomic, set by set)
    fcntl = None

__all__ = [
    "AOV_CHANNELS",
    "ImageWriteError",
    "OUTPUT_LOCK_TIMEOUT_S",
    "OutputBusyError",
    "OutputFolderError",
    "OutputNameError",
    "check_output_name",
    "check_output_target",
    "is_internal_name",
    "output_lock",
    "remove_stale_temporaries",
    "temp_name",
    "write_file_atomic",
]


#: Channel count of each render output, in file order: the standard outputs, then the debug ones (the files of a
#: render's output set; :mod:`.images` encodes them).
AOV_CHANNELS = {"color": 3, "scattering": 3, "surface": 3, "depth": 1, "rectified": 3, "epipole_mask": 1,
                "rectified_map": 2, "mip_level": 1, "evaluated_pixels": 1, "epipolar_samples": 1}


log = logging.getLogger("warpscatter")


class ImageWriteError(OSError):
    """An image file could not be written; the message names the file and OpenImageIO's error."""


class OutputNameError(ConfigError, ValueError):
    """An output folder or name refused before anything is written (exit code 2): the problem lines name
    ``output.dir`` or ``output.name``."""

    def __reduce__(self):  # keep the problem lines through pickling (process executors)
        return self.__class__, (self.problems, self.source)


class OutputFolderError(ImageWriteError, WarpscatterError):
    """An output folder that cannot hold the outputs (under a regular file, not writable, paths too long), found
    before anything is written (exit code 2); the message starts with the key (``output.dir``)."""

    exit_code = 2


class OutputBusyError(ImageWriteError, WarpscatterError):
    """Another writer held an output's lock for longer than :data:`OUTPUT_LOCK_TIMEOUT_S` (exit code 2, nothing
    written); the message names the output and the other writer's process."""

    exit_code = 2


#: Seconds a write waits for another writer of the same output name (its lock) before giving up; the environment
#: variable ``WARPSCATTER_OUTPUT_LOCK_TIMEOUT`` overrides it.
OUTPUT_LOCK_TIMEOUT_S = 120.0


def _host_tag() -> str:
    """This machine in temporary names (host name letters and digits, at most 16), for folders shared by machines."""
    return re.sub(r"[^A-Za-z0-9]", "", platform.node())[:16] or "host"


def temp_name(path: Path) -> Path:
    """Hidden temporary sibling of ``path`` keeping the real extension last (``.name.tmp-HOST-PID-XXXXXX.exr``)."""
    return path.with_name(f".{path.stem}.tmp-{_host_tag()}-{os.getpid()}-{secrets.token_hex(3)}{path.suffix}")


def _backup_name(path: Path) -> Path:
    """Hidden sibling keeping the previous file while a set is renamed in (``.name.bak-HOST-PID-XXXXXX.exr``)."""
    return path.with_name(f".{path.stem}.bak-{_host_tag()}-{os.getpid()}-{secrets.token_hex(3)}{path.suffix}")


def _lock_name(name: str) -> str:
    """The lock file of output ``name`` (a set's stem, or a single file's name): ``.NAME.lock``."""
    return f".{name}.lock"


def _manifest_name(name: str) -> str:
    """The commit manifest of output set ``name``, present only while its files are renamed in."""
    return f".{name}.commit.json"


_TEMP_PATTERN = re.compile(r"^\.(?P<stem>.+)\.(?P<kind>tmp|bak)-(?P<host>[A-Za-z0-9]+)-(?P<pid>\d+)-[0-9a-f]{6}"
                           r"(?P<suffix>\.[A-Za-z0-9]+)$")
_LOCK_PATTERN = re.compile(r"^\.(?P<name>.+)\.lock$")
_MANIFEST_PATTERN = re.compile(r"^\.(?P<name>.+)\.commit\.json$")
#: First bytes of a lock file and key of a manifest: only files carrying them are ever removed as warpscatter's.
_LOCK_MARK = b"warpscatter-lock "
_MANIFEST_KEY = "warpscatter_commit"
#: Digits reserved for the process id in the longest temporary name (2^32 has 10).
_PID_DIGITS = 10

#: (real folder path, file name) of this process's temporaries, backups and manifests in progress.
_active: set[tuple[str, str]] = set()
_active_lock = threading.Lock()


def is_internal_name(filename: str) -> bool:
    """Whether a file name is one of the writer's own: a temporary, a backup, a lock or a commit manifest (hidden;
    :func:`remove_stale_temporaries` may remove or rename it)."""
    return bool(_TEMP_PATTERN.match(filename) or _LOCK_PATTERN.match(filename)
                or _MANIFEST_PATTERN.match(filename))


def _set_suffixes(aovs: Iterable[str] | None) -> list[str]:
    """The suffixes the files of a render's output set add to its name (all outputs when ``aovs`` is None)."""
    aovs = list(AOV_CHANNELS) if aovs is None else list(aovs)
    return [".exr", ".png", ".json"] + [f".{a}.exr" for a in dict.fromkeys(aovs) if a != "color"]


def check_output_name(name: str, aovs: Iterable[str] | None = None, suffixes: Iterable[str] | None = None,
                      key: str = "output.name") -> None:
    """Refuse an output name whose files (``name`` + each suffix; default: the render outputs of ``aovs``, all when
    None) would look like the writer's own (``.NAME.bak-HOST-PID-XXXXXX``: a later write in the folder would delete
    or rename them).

    Raises:
        OutputNameError: naming ``key`` and the file (exit code 2).
    """
    for suffix in _set_suffixes(aovs) if suffixes is None else suffixes:
        if is_internal_name(name + suffix):
            raise OutputNameError(
                f"{key}: {name!r} is reserved: its file {name + suffix!r} would look like a temporary, backup, "
                f"lock or commit file of warpscatter's writer (a later write in the folder would remove it); "
                f"choose a name that is not hidden like these")


def _longest_internal_name(filename: str) -> str:
    """The longest name the writer gives files of ``filename`` (its temporary or backup, with a 10-digit pid)."""
    stem, suffix = os.path.splitext(filename)
    return f".{stem}.tmp-{_host_tag()}-{'9' * _PID_DIGITS}-ffffff{suffix}"


def check_output_target(out_dir: str | Path, name: str, aovs: Iterable[str] | None = None,
                        suffixes: Iterable[str] | None = None, *, dir_key: str = "output.dir",
                        name_key: str = "output.name") -> None:
    """Check, before any work, that an output set ``NAME.*`` can be written in ``out_dir``: the folder is (or can be
    created as) a folder, it is writable, and every file name the writer makes (temporaries included) fits the
    folder's file system (``NAME_MAX``, ``PATH_MAX``). ``suffixes``: the files' suffixes (default: the render
    outputs of ``aovs``, all outputs when None); the name must not be reserved (:func:`check_output_name`).

    Raises:
        OutputNameError: (a ValueError) a reserved or too long name, naming ``name_key`` (exit code 2).
        OutputFolderError: (an ImageWriteError) a folder that cannot hold the files, naming ``dir_key`` (exit
            code 2). Nothing is written either way.
    """
    suffixes = _set_suffixes(aovs) if suffixes is None else list(suffixes)
    check_output_name(name, suffixes=suffixes, key=name_key)
    folder = Path(os.path.abspath(os.fspath(out_dir)))
    existing = None
    for p in (folder, *folder.parents):
        try:
            st = os.stat(p)
        except (FileNotFoundError, NotADirectoryError):
            continue
        except OSError as exc:
            raise OutputFolderError(f"{dir_key}: cannot use {folder}: {exc.strerror or exc} ({p})") from None
        existing = p
        if not stat.S_ISDIR(st.st_mode):
            what = f"{p} is a file, not a folder" if p == folder else f"{p} is a file: no folder can be made in it"
            raise OutputFolderError(f"{dir_key}: cannot write in {folder}: {what}")
        break
    if existing is None:
        return
    if not os.access(existing, os.W_OK | os.X_OK):
        where = "" if existing == folder else f" (cannot create {folder} in it)"
        raise OutputFolderError(f"{dir_key}: {existing} is not writable{where}")

    def limit(what: str, default: int) -> int:
        try:
            return int(os.pathconf(existing, what))
        except (OSError, ValueError, TypeError):
            return default

    name_max, path_max = limit("PC_NAME_MAX", 255), limit("PC_PATH_MAX", 4096)
    files = [name + s for s in suffixes]
    longest = max((_longest_internal_name(f) for f in files), key=lambda n: len(os.fsencode(n)))
    longest = max([longest, _manifest_name(name)], key=lambda n: len(os.fsencode(n)))
    excess = len(os.fsencode(longest)) - name_max
    if excess > 0:
        raise OutputNameError(
            f"{name_key}: {name!r} is too long for {existing}: its files and the writer's temporary names (e.g. "
            f"{len(os.fsencode(longest))} bytes for {files[0]!r}) exceed the file system's limit of {name_max} bytes "
            f"per name; shorten the name by at least {excess} byte(s)")
    full = len(os.fsencode(str(folder / longest)))
    if full >= path_max:
        raise OutputFolderError(f"{dir_key}: {folder} is too deep: the paths of its files would be {full} bytes, "
                              f"the file system allows {path_max - 1}")


def _process_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # exists, owned by another user
        return True
    return True


def _lock_timeout() -> float:
    text = os.environ.get("WARPSCATTER_OUTPUT_LOCK_TIMEOUT")
    try:
        value = float(text) if text else OUTPUT_LOCK_TIMEOUT_S
    except ValueError:
        return OUTPUT_LOCK_TIMEOUT_S
    return value if value >= 0 else OUTPUT_LOCK_TIMEOUT_S


def _same_file(fd: int, path: Path) -> bool:
    """Whether the open file ``fd`` is still the file at ``path`` (a lock file is unlinked when released)."""
    try:
        a, b = os.fstat(fd), os.stat(path)
    except OSError:
        return False
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)


def _try_lock(path: Path) -> int | None:
    """The lock file ``path``, opened and locked (exclusive, not waiting): its descriptor, or None where another
    holds it. OSError when it cannot be created."""
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            return None
        except BaseException:
            os.close(fd)
            raise
        if _same_file(fd, path):
            return fd
        os.close(fd)  # released and removed by its holder in between: lock the new file


def _release_lock(fd: int, path: Path) -> None:
    try:
        os.unlink(path)  # first: a waiter that locks the removed file sees it is gone and opens the new one
    except OSError:
        pass
    os.close(fd)


def _lock_holder(path: Path) -> str:
    try:
        with open(path, "rb") as f:
            text = f.read(200)
    except OSError:
        return "unknown"
    if not text.startswith(_LOCK_MARK):
        return "unknown"
    parts = text[len(_LOCK_MARK):].decode("ascii", "replace").split()
    return f"pid {parts[0]} on {parts[1]}" if len(parts) >= 2 else "unknown"


@contextlib.contextmanager
def output_lock(folder: str | Path, name: str, timeout: float | None = None, what: str | Path | None = None):
    """Hold the advisory lock of output ``name`` in ``folder`` (``.NAME.lock``, ``fcntl.flock``; removed on
    release) while the block runs; another writer of the name waits, at most ``timeout`` seconds (default
    :data:`OUTPUT_LOCK_TIMEOUT_S`, or ``WARPSCATTER_OUTPUT_LOCK_TIMEOUT``). A no-op without ``fcntl`` (Windows).

    Raises:
        OutputBusyError: still held by another writer after ``timeout`` (the message names it and its process).
        ImageWriteError: the lock file cannot be created (a read-only folder, say).
    """
    if fcntl is None:
        yield None
        return
    path = Path(folder) / _lock_name(name)
    what = what if what is not None else Path(folder) / f"{name}.*"
    timeout = _lock_timeout() if timeout is None else timeout
    deadline = time.monotonic() + timeout
    delay = 0.01
    while True:
        try:
            fd = _try_lock(path)
        except OSError as exc:
            raise ImageWriteError(f"cannot write {what}: cannot create its lock file: {exc}") from exc
        if fd is not None:
            break
        if time.monotonic() >= deadline:
            raise OutputBusyError(
                f"cannot write {what}: another warpscatter process ({_lock_holder(path)}) is writing it and held "
                f"its lock {path} for more than {timeout:g} s; wait for it or choose another output name "
                f"(WARPSCATTER_OUTPUT_LOCK_TIMEOUT sets the wait)")
        time.sleep(delay)
        delay = min(2 * delay, 0.2)
    try:
        try:
            os.write(fd, _LOCK_MARK + f"{os.getpid()} {_host_tag()}\n".encode())
        except OSError:  # a full disk: the lock holds all the same
            pass
        yield path
    finally:
        _release_lock(fd, path)


def _read_manifest(path: Path) -> list[tuple[str, str, str, bool]] | None:
    """The (final, temporary, backup, had a previous file) names of a commit manifest; None if it is not a
    complete, valid manifest of this writer (names are checked: plain names of the writer's own form)."""
    try:
        with open(path, encoding="utf-8") as f:
            data = json.loads(f.read(1 << 20))
        entries = [(e["final"], e["temp"], e["backup"], e["previous"]) for e in data["files"]]
        if data.get(_MANIFEST_KEY) != 1:
            return None
    except (OSError, ValueError, KeyError, TypeError):
        return None
    for final, tmp, backup, previous in entries:
        if not all(isinstance(n, str) and n == os.path.basename(n) and n not in ("", ".", "..")
                   for n in (final, tmp, backup)) or not isinstance(previous, bool):
            return None
        for n in (tmp, backup):
            m = _TEMP_PATTERN.match(n)
            if not m or m.group("stem") + m.group("suffix") != final:
                return None
    return entries


def _write_manifest(path: Path, entries: list[tuple[Path, Path, Path, bool]]) -> None:
    """Write and flush (file and folder) the manifest of a set about to be renamed in."""
    data = {_MANIFEST_KEY: 1, "pid": os.getpid(), "host": _host_tag(),
            "files": [{"final": f.name, "temp": t.name, "backup": b.name, "previous": p} for f, t, b, p in entries]}
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            fd = -1
            f.write(json.dumps(data, indent=1) + "\n")
            f.flush()
            os.fsync(f.fileno())
    except BaseException:
        if fd >= 0:
            os.close(fd)
        with contextlib.suppress(OSError):
            os.unlink(path)
        raise
    _fsync_folder(path.parent)


def _finish_commit(manifest: Path) -> list[Path]:
    """Complete or roll back the set of a writer that stopped while renaming it in (the caller holds its lock);
    return the files removed or moved back. Every new file renamed in (no temporary left): the new set stays and the
    backups go; else every previous file returns and the new ones (with no previous file) and the temporaries go."""
    folder = manifest.parent
    entries = _read_manifest(manifest)
    changed: list[Path] = []
    if entries is None:  # torn (killed while writing it: nothing was renamed yet), or not one of ours
        if os.path.lexists(manifest) and _MANIFEST_PATTERN.match(manifest.name):
            with contextlib.suppress(OSError):
                with open(manifest, "rb") as f:
                    head = f.read(64)
                if not head.strip() or _MANIFEST_KEY.encode() in head or head.lstrip().startswith(b"{"):
                    os.unlink(manifest)
        return changed
    files = [(folder / f, folder / t, folder / b, p) for f, t, b, p in entries]
    forward = not any(os.path.lexists(t) for _, t, _, _ in files)
    if forward:
        for _, _, backup, _ in files:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(backup)
                changed.append(backup)
    else:
        for final, tmp, backup, previous in files:
            if os.path.lexists(backup):
                if not (os.path.isdir(final) and not os.path.islink(final)):
                    os.replace(backup, final)
                if os.path.lexists(backup):  # a hard link of final itself: the rename did nothing
                    os.unlink(backup)
                changed.append(backup)
            elif not previous and not os.path.lexists(tmp) and os.path.lexists(final) and not os.path.isdir(final):
                os.unlink(final)  # renamed in, no previous file
                changed.append(final)
        for _, tmp, _, _ in files:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
                changed.append(tmp)
    _fsync_folder(folder)
    os.unlink(manifest)
    _fsync_folder(folder)
    log.warning("%s the output set %s of a writer that stopped while renaming it in",
                "completed" if forward else "rolled back", folder / _MANIFEST_PATTERN.match(manifest.name)["name"])
    return changed


def _recover_if_free(manifest: Path) -> tuple[list[Path], bool]:
    """:func:`_finish_commit` if no writer holds the set's lock: (files changed, whether it was done)."""
    name = _MANIFEST_PATTERN.match(manifest.name)["name"]
    if fcntl is None:
        return [], False
    lock = manifest.parent / _lock_name(name)
    try:
        fd = _try_lock(lock)
    except OSError:
        return [], False
    if fd is None:
        return [], False
    try:
        return _finish_commit(manifest), True
    except OSError as exc:
        log.warning("cannot complete or roll back the interrupted write of %s: %s", manifest, exc)
        return [], False
    finally:
        _release_lock(fd, lock)


def remove_stale_temporaries(folder: str | Path) -> list[Path]:
    """Clean up after writers that did not finish; return the temporaries and backups removed or moved back.

    A set whose writer stopped while renaming it in (its commit manifest is there and its lock is free) is first
    completed or rolled back as a whole. Then temporaries of dead processes (and this process's unused ones) are
    removed; a dead writer's backups are moved back when its temporaries remain (it stopped before its last rename),
    else removed; unused lock files are removed. Files of running processes and of other machines (the host is in
    the name) are left alone."""
    removed: list[Path] = []
    try:
        entries = list(os.scandir(folder))
        where = os.path.realpath(folder)
    except OSError:
        return removed
    with _active_lock:
        active = {name for parent, name in _active if parent == where}
    listed: set[str] = set()  # files of sets still under a manifest: only their commit's recovery touches them
    for entry in entries:
        if _MANIFEST_PATTERN.match(entry.name) and entry.name not in active and entry.is_file(follow_symlinks=False):
            changed, done = _recover_if_free(Path(entry.path))
            removed += changed
            if not done:
                listed.update(n for e in (_read_manifest(Path(entry.path)) or []) for n in e[1:3])
    if removed:
        entries = list(os.scandir(folder))
    stale: dict[int, list[tuple[os.DirEntry, re.Match]]] = {}
    for entry in entries:
        m = _TEMP_PATTERN.match(entry.name)
        if not m or entry.name in active or entry.name in listed or entry.is_dir(follow_symlinks=False):
            continue
        pid = int(m.group("pid"))
        if m.group("host") != _host_tag():  # another machine's writer: only it can tell whether it runs
            continue
        if pid == os.getpid() or not _process_alive(pid):
            stale.setdefault(pid, []).append((entry, m))
    for files in stale.values():
        unfinished = any(m.group("kind") == "tmp" for _, m in files)
        for entry, m in sorted(files, key=lambda f: f[1].group("kind")):  # backups ("bak") before temporaries
            try:
                if m.group("kind") == "bak" and unfinished:
                    target = os.path.join(os.path.dirname(entry.path), m.group("stem") + m.group("suffix"))
                    if os.path.isdir(target) and not os.path.islink(target):
                        continue
                    os.replace(entry.path, target)
                    if os.path.lexists(entry.path):  # a hard link of the target itself: the rename did nothing
                        os.unlink(entry.path)
                else:
                    os.unlink(entry.path)
                removed.append(Path(entry.path))
            except OSError:
                pass
    _remove_unused_locks(entries)
    if removed:
        log.info("cleaned up %d temporary or backup file(s) of an unfinished write in %s", len(removed), folder)
    return removed


def _remove_unused_locks(entries: list[os.DirEntry]) -> None:
    """Remove the lock files (ours: they start with the mark) that no writer holds, left by killed writers."""
    if fcntl is None:
        return
    for entry in entries:
        if not _LOCK_PATTERN.match(entry.name) or not entry.is_file(follow_symlinks=False):
            continue
        path = Path(entry.path)
        try:
            with open(path, "rb") as f:
                if not f.read(len(_LOCK_MARK)) == _LOCK_MARK:
                    continue
            fd = _try_lock(path)
        except OSError:
            continue
        if fd is not None:
            _release_lock(fd, path)


def _run_writers(jobs: list[tuple[Path, Callable[[Path], None]]],
                 temps: list[Path]) -> tuple[Path, Exception] | None:
    """Run every writer on its temporary path, one thread each (OpenImageIO releases the GIL); return (output, error)
    of the first failure in job order, or None. All writers have finished when this returns or raises."""
    if len(jobs) == 1:
        try:
            jobs[0][1](temps[0])
        except Exception as exc:
            return jobs[0][0], exc
        return None
    pool = ThreadPoolExecutor(max_workers=len(jobs), thread_name_prefix="warpscatter-write")
    try:
        futures = [pool.submit(writer, tmp) for (_, writer), tmp in zip(jobs, temps, strict=True)]
        wait(futures)
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
    for (final, _), future in zip(jobs, futures, strict=True):
        exc = future.exception()
        if exc is not None:
            if not isinstance(exc, Exception):  # KeyboardInterrupt, SystemExit in a writer: pass it on
                raise exc
            return final, exc
    return None


def _fsync(path: Path) -> None:
    """Flush a written file to disk (its data and size) before it is renamed over a previous file."""
    fd = os.open(path, os.O_RDWR if os.name == "nt" else os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_folder(folder: Path) -> None:
    """Flush a folder's entries (the renames) to disk; a no-op where folders cannot be opened (Windows)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _synced(writer: Callable[[Path], None]) -> Callable[[Path], None]:
    def write_and_sync(path: Path) -> None:
        writer(path)
        _fsync(path)

    return write_and_sync


def _set_aside(final: Path, backup: Path) -> bool:
    """Keep the file at ``final`` as ``backup`` (hard link, else rename); return whether there was one."""
    try:
        st = os.lstat(final)
    except FileNotFoundError:
        return False
    if stat.S_ISDIR(st.st_mode):
        raise IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR), str(final))
    try:
        os.link(final, backup, follow_symlinks=False)
    except (OSError, NotImplementedError):  # no hard links here (FAT, some network file systems)
        os.rename(final, backup)
    return True


def _roll_back(commits: list[tuple[Path, Path, Path]], temps: list[Path]) -> list[str]:
    """Undo a partly renamed set (backups back, temporaries removed); return what could not be undone."""
    problems = []
    for final, tmp, backup in reversed(commits):
        try:
            if os.path.lexists(backup):
                os.replace(backup, final)
                if os.path.lexists(backup):  # still the same file as final (the new one was not renamed in)
                    os.unlink(backup)
            elif not os.path.lexists(tmp) and os.path.lexists(final):  # renamed in, no previous file
                os.unlink(final)
        except OSError as exc:
            problems.append(f"{final}: {exc}" + (f" (the previous file is kept as {backup})"
                                                 if os.path.lexists(backup) else ""))
    for tmp in temps:
        if not os.path.lexists(tmp):  # never created (the write failed first), or renamed in
            continue
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        except OSError as exc:
            problems.append(f"temporary {tmp} left behind: {exc}")
    return problems


def _write_all(jobs: list[tuple[Path, Callable[[Path], None]]], name: str | None = None) -> list[Path]:
    """Write every job to a temporary file and fsync it, then rename all into place, all or nothing, holding the
    lock of output ``name`` (default: the first file's name); several files in one folder are renamed in under a
    commit manifest (``.NAME.commit.json``) so that a killed writer's set is completed or rolled back later."""
    finals = [final for final, _ in jobs]
    folder = finals[0].parent
    name = name or finals[0].name
    what = finals[0] if len(jobs) == 1 else folder / f"{name}.*"
    manifest = folder / _manifest_name(name) if len(jobs) > 1 and all(f.parent == folder for f in finals) else None
    temps = [temp_name(final) for final in finals]
    backups = [_backup_name(final) for final in finals]
    commits: list[tuple[Path, Path, Path]] = []
    current = finals[0]
    in_use = {(os.path.realpath(p.parent), p.name) for p in temps + backups + ([manifest] if manifest else [])}
    with output_lock(folder, name, what=what):
        if manifest is not None and os.path.lexists(manifest):
            try:
                _finish_commit(manifest)
            except OSError as exc:
                raise ImageWriteError(f"cannot write {what}: the interrupted write of a previous writer "
                                      f"({manifest}) cannot be completed or rolled back: {exc}") from exc
        with _active_lock:
            _active.update(in_use)
        try:
            _commit(jobs, temps, backups, commits, manifest)
        except _CommitError as failure:
            current, exc = failure.final, failure.error
            problems = _roll_back(commits, temps)
            if manifest is not None and not problems:
                with contextlib.suppress(OSError):
                    os.unlink(manifest)
            if problems:  # the manifest (if written) stays: the next write completes the rollback
                log.error("could not restore the previous outputs: %s", "; ".join(problems))
            if not isinstance(exc, Exception):
                raise exc from None
            text = f"cannot write {current}: {exc}"
            if problems:
                text += "; the rollback failed too: " + "; ".join(problems)
            raise ImageWriteError(text) from exc
        finally:
            with _active_lock:
                _active.difference_update(in_use)
    return finals


class _CommitError(Exception):
    """Internal: the output being written (or renamed in) when ``error`` (any BaseException) stopped a commit."""

    def __init__(self, final: Path, error: BaseException):
        super().__init__(final, error)
        self.final, self.error = final, error


def _commit(jobs: list[tuple[Path, Callable[[Path], None]]], temps: list[Path], backups: list[Path],
            commits: list[tuple[Path, Path, Path]], manifest: Path | None) -> None:
    """The steps of :func:`_write_all`: temporaries written and flushed, the manifest, the renames, clean-up; a
    failure or an interruption is raised as :class:`_CommitError` naming the output (``commits``: renames begun)."""
    current = jobs[0][0]
    try:
        failure = _run_writers([(final, _synced(writer)) for final, writer in jobs], temps)
        if failure is not None:
            current, error = failure
            raise error
        if manifest is not None:
            _write_manifest(manifest, [(final, tmp, backup, os.path.lexists(final))
                                       for (final, _), tmp, backup in zip(jobs, temps, backups, strict=True)])
        for (final, _), tmp, backup in zip(jobs, temps, backups, strict=True):
            current = final
            commits.append((final, tmp, backup))  # before any change: an interruption is rolled back
            _set_aside(final, backup)
            os.replace(tmp, final)
        for folder in dict.fromkeys(final.parent for final, _ in jobs):
            _fsync_folder(folder)
    except BaseException as exc:
        raise _CommitError(current, exc) from exc
    for backup in backups:
        try:
            os.unlink(backup)
        except FileNotFoundError:
            pass
        except OSError as exc:
            log.warning("cannot remove the backup %s: %s", backup, exc)
    if manifest is not None:
        try:
            os.unlink(manifest)
        except OSError as exc:  # the next write finds every file renamed in: it keeps the set
            log.warning("cannot remove the commit manifest %s: %s", manifest, exc)


def write_file_atomic(path: str | Path, write: Callable[[Path], None]) -> Path:
    """Write one file atomically through ``write(temporary)``, holding the file's lock (``.FILE.lock``); the
    previous file survives any failure (:class:`ImageWriteError` naming the file and the reason)."""
    return _write_all([(Path(path), write)])[0]
