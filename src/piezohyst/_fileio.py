"""Writing files safely: atomically, never over a user's file unless asked, saying who wrote it.

Three promises, for one file (:func:`atomic_write`) and for a set of files in one folder
(:class:`OutputFolder`):

* **whole or absent**: the content is written to a temporary name beside the target and moved
  into place in one step, so an interrupted run (an error, Ctrl-C, SIGTERM) leaves the previous
  file or folder, or the new one, never half of one; its temporary files are removed;
* **exclusive**: without ``force`` the final name is taken with an operation that fails if the
  name exists (``os.link`` for a file, ``rename`` onto an absent or empty folder), so a file that
  appeared while the run worked is never replaced: not check-then-replace;
* **ordinary permissions**: outputs get ``0o666 & ~umask`` (folders ``0o777 & ~umask``), as
  ``open()`` would give them, not the private mode of a temporary file.

Every refusal is an :class:`OutputError` (an ``OSError``) naming the path and the problem;
:class:`OverwriteRefused` (also a ``FileExistsError``) when the target exists.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import errno
import hashlib
import json
import math
import os
import re
import shutil
import signal
import sys
import tempfile
import threading
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator


def to_jsonable(obj: Any) -> Any:
    """Plain JSON data from nested dicts/lists with numpy arrays and scalars; NaN and inf become None."""
    import numpy as np

    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return to_jsonable(obj.item())
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def dumps_strict(obj: Any, **kw: Any) -> str:
    """``json.dumps`` of :func:`to_jsonable` data, refusing NaN/inf (strict JSON every reader parses)."""
    return json.dumps(to_jsonable(obj), allow_nan=False, **kw)


def loads_strict(text: str, *, bad_constant: Callable[[str], Exception],
                 bad_number: Callable[[str], Exception], object_pairs_hook: Any = None) -> Any:
    """``json.loads`` as the standard defines JSON, the reverse of :func:`dumps_strict`: ``NaN`` and
    ``Infinity`` raise ``bad_constant(name)``, a number beyond float range ``bad_number(text)``."""
    def constant(name: str) -> Any:
        raise bad_constant(name)

    def number(token: str) -> float:
        v = float(token)
        if not math.isfinite(v):
            raise bad_number(token)
        return v

    return json.loads(text, parse_constant=constant, parse_float=number, object_pairs_hook=object_pairs_hook)


class OutputError(OSError, ValueError):
    """An output path that cannot be written: a file where a folder is expected, a folder where a
    file is expected, a folder nobody can write in. The message names the path.

    Both an ``OSError`` and a ``ValueError`` (a bad value for a path), like
    ``io.UnsupportedOperation``."""


class OverwriteRefused(OutputError, FileExistsError):
    """The output exists (or appeared while the run worked) and ``force`` was not given."""


def producer() -> str:
    """One line saying what wrote a file: package, version, command line, UTC time.

    The command line is quoted as a shell would need it (``shlex.join``), so it can be run
    again; run as ``python -m piezohyst`` it is the ``piezohyst`` command it amounts to (it was
    ``__main__.py rig --out loops dir``: found by a helper)."""
    import shlex

    from . import __version__

    from ._provenance import command_line

    if command_line is not None:
        argv = shlex.join(command_line)
    else:
        argv = shlex.join([os.path.basename(a) if i == 0 else a for i, a in enumerate(sys.argv)])
    now = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
    return f"piezohyst {__version__}; command: {argv}; at {now}"


# ------------------------------------------------------------------------------------------------
# permissions and signals
def current_umask() -> int:
    """The process's umask, read without changing it where the system tells it (Linux >= 4.7)."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    with _UMASK_LOCK:  # elsewhere: set and restore (not atomic for other threads, hence the lock)
        mask = os.umask(0o022)
        os.umask(mask)
    return mask


_UMASK_LOCK = threading.Lock()


def _chmod_ordinary(path: Path, folder: bool = False) -> None:
    """Give ``path`` the mode ``open()``/``mkdir()`` would have given it under the current umask."""
    os.chmod(path, (0o777 if folder else 0o666) & ~current_umask())


@contextlib.contextmanager
def deferred_signals() -> Iterator[None]:
    """Hold SIGINT/SIGTERM/SIGHUP during a few system calls that must not be split (publishing an
    output and removing its temporary name); they are delivered right after.

    Blocking them in this thread is not enough: the kernel hands a process's signal to any thread
    that does not block it (numba's, BLAS's, Dask's), and Python then runs its handler in the main
    thread, inside the block (found by a helper: 9 of 400 interrupts left a temporary file behind
    with threads running). So the main thread also swaps each held signal's handler for one that
    notes it, and after the block restores the handlers and raises what was noted. Elsewhere than
    in the main thread only the blocking is possible (handlers belong to the main thread)."""
    sigs = {signal.SIGINT, signal.SIGTERM} | ({signal.SIGHUP} if hasattr(signal, "SIGHUP") else set())
    main = threading.current_thread() is threading.main_thread()
    can = hasattr(signal, "pthread_sigmask") and main
    noted: list[int] = []
    swapped: dict[signal.Signals, Any] = {}
    if main:
        for sig in sigs:
            h = signal.getsignal(sig)
            if h is not None and h is not signal.SIG_IGN:  # (None: a handler set outside Python)
                swapped[sig] = signal.signal(sig, lambda signum, frame: noted.append(signum))
    if can:
        old = signal.pthread_sigmask(signal.SIG_BLOCK, sigs)
    try:
        yield
    finally:
        # the handlers back first, so that what the mask held goes to them. signal.signal() runs
        # the handlers of signals already pending before it sets one, and one put back a moment
        # ago may raise (a Ctrl-C handed to another thread just now): caught, that handler is set
        # all the same (it was not), every other one too and the mask restored, then raised (a
        # KeyboardInterrupt out of the middle of this left SIGTERM noted for good and the signals
        # blocked: found by a reviewer)
        raised: list[BaseException] = []
        for sig, handler in swapped.items():
            for _ in range(100):
                try:
                    signal.signal(sig, handler)
                    break
                except BaseException as exc:  # noqa: BLE001 - kept, and raised below
                    raised.append(exc)
        if can:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)
        if raised:
            raise raised[0]
        for n in dict.fromkeys(noted):
            signal.raise_signal(n)


# ------------------------------------------------------------------------------------------------
# checks (cheap, before any long work)
def _nearest_existing(p: Path) -> Path:
    q = p
    while not os.path.lexists(q):
        if q.parent == q:
            break
        q = q.parent
    return q


def _probe_writable(folder: Path, target: Path) -> None:
    """Create and remove a temporary entry in ``folder`` (the only test of writability that also
    holds for root, read-only file systems and /proc)."""
    with deferred_signals():
        try:
            tmp = tempfile.mkdtemp(prefix=".piezohyst-probe-", dir=folder)
        except OSError as exc:
            raise OutputError(f"cannot write {target}: cannot create files in {folder} "
                              f"({exc.strerror or exc})") from None
        os.rmdir(tmp)


def _check_parent(p: Path) -> None:
    """The folder that will hold ``p`` exists (or can be created) and can be written."""
    parent = p.parent
    anc = _nearest_existing(parent)
    if not anc.is_dir():
        raise OutputError(f"cannot write {p}: {anc} is a file, not a folder")
    _probe_writable(anc, p)


def check_output_file(path: str | os.PathLike[str], force: bool) -> Path:
    """Refuse, before any work, an output file that cannot be written or would replace a file
    without ``force``; return the path.

    Raises
    ------
    OverwriteRefused
        ``path`` exists and ``force`` is false.
    OutputError
        ``path`` is a folder, or its folder cannot be created or written.
    """
    p = Path(path).expanduser()  # "~/models/m.json" from Python made a folder named "~" here
    if p.is_dir():
        raise OutputError(f"{p} is a folder; give a file name")
    if os.path.lexists(p) and not force:
        raise OverwriteRefused(f"{p} exists; not overwriting it (pass force=True / --force)")
    _check_parent(p)
    return p


#: The former name (kept: other modules and user code call it).
check_writable = check_output_file


#: The most bytes of an output's name that its temporary names beside it repeat: a name may be up
#: to 255 bytes, and ``.NAME.XXXXXXXX.tmp`` must fit too (a 245-character model name was refused
#: after its fit, naming the temporary file: found by a helper).
TEMP_NAME_BYTES = 120


def _short(name: str) -> str:
    """``name`` for a temporary name: whole, or its first characters and a hash of the rest."""
    raw = name.encode("utf-8", "surrogateescape")
    if len(raw) <= TEMP_NAME_BYTES:
        return name
    head = raw[:TEMP_NAME_BYTES - 9].decode("utf-8", "ignore")  # (a character cut in two is left out)
    return f"{head}~{hashlib.sha256(raw).hexdigest()[:8]}"


def _remove(path: Path) -> None:
    try:
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)
    except OSError:
        pass


# ------------------------------------------------------------------------------------------------
# one file
def _named(p: Path, exc: OSError) -> OutputError:
    """``exc`` (raised writing a temporary file) as an error naming ``p``, the file the user asked
    for, with its errno (a full disk stays ENOSPC to a caller)."""
    out = OutputError(f"cannot write {p}: {exc.strerror or exc}")
    out.errno = exc.errno
    return out


def _publish_file(tmp: Path, p: Path, force: bool) -> None:
    """Move the finished ``tmp`` to ``p``: replacing only with ``force``, else exclusively."""
    if force:
        if p.is_dir():
            raise OutputError(f"{p} is a folder; give a file name")
        os.replace(tmp, p)
        return
    try:
        os.link(tmp, p)  # fails if p exists: never replaces a file that appeared meanwhile
    except FileExistsError:
        raise OverwriteRefused(f"{p} appeared while this run worked; not replacing it (pass force=True / --force)") from None
    except OSError as exc:
        if exc.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EXDEV, errno.EMLINK, errno.EACCES):
            raise
        # no hard links here (some network and FAT file systems): take the name exclusively,
        # then move the content onto it
        try:
            fd = os.open(p, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600)
        except FileExistsError:
            raise OverwriteRefused(f"{p} appeared while this run worked; not replacing it (pass force=True / --force)") from None
        os.close(fd)
        os.replace(tmp, p)
        return
    tmp.unlink()


def atomic_write(path: str | os.PathLike[str], write: Callable[[Path], object], *, force: bool = False) -> Path:
    """Call ``write(tmp_path)``, then move the temporary file to ``path`` in one step.

    A crash or an error part-way leaves the old file (or no file) in place, never half a file,
    and no temporary file. Without ``force`` an existing ``path`` is refused up front, and one
    that appeared while ``write`` ran is not replaced (:class:`OverwriteRefused`). The file gets
    the ordinary mode ``0o666 & ~umask``.
    """
    p = check_output_file(path, force)
    tmps: list[Path] = []
    try:
        _write_beside(p, write, tmps)
        with deferred_signals():
            _publish_file(tmps[0], p, force)
    finally:
        with deferred_signals():
            for tmp in tmps:
                tmp.unlink(missing_ok=True)
    return p


def _write_beside(p: Path, write: Callable[[Path], object], tmps: list[Path]) -> None:
    """``write`` a temporary file beside ``p`` (its folder created if needed), appended to ``tmps``
    as soon as it exists (the caller removes it), with the ordinary mode; an error of the write
    names ``p``, the file the user asked for, not the hidden temporary one."""
    p.parent.mkdir(parents=True, exist_ok=True)
    with deferred_signals():  # a signal now would leave the temporary file unnamed
        fd, name = tempfile.mkstemp(prefix=f".{_short(p.name)}.", suffix=".tmp", dir=p.parent)
        os.close(fd)
        tmps.append(Path(name))
    try:
        write(tmps[-1])
    except OSError as exc:
        if isinstance(exc, OutputError):
            raise
        raise _named(p, exc) from exc
    _chmod_ordinary(tmps[-1])


def atomic_write_text(path: str | os.PathLike[str], text: str, *, force: bool = False) -> Path:
    """Write ``text`` (UTF-8) atomically."""
    return atomic_write(path, lambda t: t.write_text(text, encoding="utf-8"), force=force)


def atomic_write_files(writes: dict[Path, Callable[[Path], object]], *, force: bool = False) -> list[Path]:
    """:func:`atomic_write` for several files that belong together, published together: each
    ``write(tmp)`` fills a temporary file beside its target (a full disk or an error leaves none
    of them), then all are moved into place in one block that signals wait for
    (:func:`deferred_signals`); if one of them cannot be (it appeared meanwhile), the ones moved
    before it are put back (with ``force``, the files they replaced). So a C header and its source
    are never left as one without the other or as halves of two runs, nor a batch's summary.csv,
    summary.parquet and histograms (found by helpers: an interrupt between them left
    compensator.h alone, and with force a new header beside the old source, which compiled; a
    fleet's files came from two runs). Returns the paths, in the order given."""
    paths = [check_output_file(p, force) for p in writes]
    tmps: list[Path] = []
    try:
        for p, write in zip(paths, writes.values()):
            _write_beside(p, write, tmps)
        moved: list[tuple[Path, Path | None]] = []  # (path, the name its previous content was moved to)
        with deferred_signals():
            try:
                for tmp, p in zip(tmps, paths):
                    backup = None
                    if force and os.path.lexists(p) and not p.is_dir():
                        fd, name = tempfile.mkstemp(prefix=f".{_short(p.name)}.", suffix=".old", dir=p.parent)
                        os.close(fd)
                        backup = Path(name)
                        try:
                            os.replace(p, backup)
                        except BaseException:
                            backup.unlink(missing_ok=True)
                            raise
                    try:
                        _publish_file(tmp, p, force)
                    except BaseException:
                        if backup is not None:
                            os.replace(backup, p)
                        raise
                    moved.append((p, backup))
            except BaseException:
                for q, backup in reversed(moved):  # as it was: the previous files, or none
                    if backup is not None:
                        os.replace(backup, q)
                    else:
                        q.unlink(missing_ok=True)
                raise
            for _, backup in moved:
                if backup is not None:
                    backup.unlink(missing_ok=True)
    finally:
        with deferred_signals():
            for tmp in tmps:
                tmp.unlink(missing_ok=True)
    return paths


def atomic_write_texts(texts: dict[Path, str], *, force: bool = False) -> list[Path]:
    """:func:`atomic_write_files` of UTF-8 texts."""
    def writer(text: str) -> Callable[[Path], object]:
        return lambda t: t.write_text(text, encoding="utf-8")

    return atomic_write_files({p: writer(text) for p, text in texts.items()}, force=force)


# ------------------------------------------------------------------------------------------------
# one writer per folder
class FolderBusy(OutputError, BlockingIOError):
    """Another process holds the folder's lock (:func:`folder_lock`): it is writing there."""


@contextlib.contextmanager
def folder_lock(folder: str | os.PathLike[str], name: str, what: str) -> Iterator[Path]:
    """Hold an exclusive lock on ``folder`` (created if absent) while the block runs, or refuse at
    once (:class:`FolderBusy`, naming the folder and the holder's process id) where another
    process holds it: two runs writing one folder took each other's files for a user's and their
    summary marked records as errors whose model files were there (found by a helper).

    The lock is ``fcntl.flock`` on the file ``folder/name``, which records the holder's pid; the
    system releases it when the holder ends, however it ends (a killed run leaves no stale lock).
    The file is removed when the block ends (removed while still locked, and a process that locked
    a file already removed tries again, so two never hold it at once). ``what`` names the writer
    in the refusal ("another piezohyst fleet run"). Yields the lock file's path.
    """
    folder = Path(folder)
    try:
        import fcntl
    except ImportError:  # no flock here (Windows): no lock; runs sharing a folder are not kept apart
        yield folder / name
        return
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    fd = -1
    try:
        while True:
            with deferred_signals():  # a signal now would leave the descriptor open
                fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as exc:
                if exc.errno in (errno.ENOLCK, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EINVAL):
                    os.close(fd)  # a file system without locks (some network ones): as without fcntl
                    fd = -1
                    break
                if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                    os.close(fd)
                    fd = -1
                    raise
                try:
                    pid = os.read(fd, 32).decode("ascii", "replace").strip()
                except OSError:
                    pid = ""
                os.close(fd)  # not ours: neither removed nor unlocked here
                fd = -1
                who = f"{what} (pid {pid})" if pid.isdigit() else what
                raise FolderBusy(f"{folder} is in use: {who} is writing there; wait for it to end, or give "
                                 f"another folder (lock file {path})") from None
            try:
                now, held = os.stat(path), os.fstat(fd)
                same = (now.st_dev, now.st_ino) == (held.st_dev, held.st_ino)
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)  # locked a file its holder removed as it ended: take the new one
            fd = -1
        if fd >= 0:
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode("ascii"))
        yield path
    finally:
        if fd >= 0:
            with deferred_signals():
                with contextlib.suppress(OSError):
                    path.unlink()
                os.close(fd)  # (releases the lock)


# ------------------------------------------------------------------------------------------------
# a set of files
MANIFEST = "manifest.json"


def _renameat2(src: Path, dst: Path, flags: int) -> bool:
    """Linux ``renameat2``; False when the system or file system does not offer it."""
    if not sys.platform.startswith("linux"):
        return False
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd = -100
    rc = fn(at_fdcwd, os.fsencode(src), at_fdcwd, os.fsencode(dst), ctypes.c_uint(flags))
    if rc == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP, errno.EOPNOTSUPP):
        return False
    raise OSError(err, os.strerror(err), str(dst))


_RENAME_NOREPLACE, _RENAME_EXCHANGE = 1, 2


def _manifest_files(folder: Path) -> set[str]:
    try:
        doc = json.loads((folder / MANIFEST).read_text(encoding="utf-8"))
        return {str(k) for k in doc.get("files", {})}
    except (OSError, ValueError, AttributeError, RecursionError):
        return set()


def _mount_points() -> set[str]:
    """The mount points Linux lists for this process (``/proc/self/mountinfo``; empty elsewhere):
    a bind mount on the same file system is one that ``os.path.ismount`` does not see."""
    try:
        with open("/proc/self/mountinfo", encoding="utf-8", errors="surrogateescape") as fh:
            lines = fh.read().splitlines()
    except OSError:
        return set()
    out = set()
    for line in lines:
        fields = line.split(" ")
        if len(fields) > 4:  # the fifth field, with spaces and the like written as octal escapes
            out.add(re.sub(r"\\([0-7]{3})", lambda m: chr(int(m.group(1), 8)), fields[4]))
    return out


class OutputFolder:
    """A set of files written into one folder as a whole (a run's figures, report and results).

    The files are written into a temporary folder beside ``path`` (``.NAME.tmp-XXXX``) with a
    ``manifest.json`` (each file's size and SHA-256, and what wrote them) written last; the
    temporary folder is then moved onto ``path`` in one step. An interrupted or failed run
    leaves the previous set, or nothing; two runs racing for one folder leave one whole set,
    never a mix.

    * ``path`` absent or empty: the set is moved into place; if files appeared there meanwhile,
      the move fails and nothing is replaced (:class:`OverwriteRefused`).
    * ``path`` holds files: refused without ``force``; with ``force`` it must hold nothing but a
      previous set of the same files (``names``, the manifest and what the manifest lists), and
      the two folders are exchanged in one step (Linux ``renameat2``; elsewhere two renames).
      A folder holding other files is never replaced: those files would be lost.

    Use :meth:`check` before a long run, then ``with folder as tmp:`` to write the files into
    ``tmp``; the set is published when the block ends without an exception.

    Parameters
    ----------
    path : path
        The folder.
    names : iterable of str
        The files of the set (others may be added; these are the ones a previous set may hold).
    force : bool
        Replace a previous set.
    """

    def __init__(self, path: str | os.PathLike[str], names: Iterable[str], *, force: bool = False):
        self.path = Path(path)
        self.names = set(names)
        self.force = bool(force)
        self._tmp: Path | None = None

    # -- checks -----------------------------------------------------------------------------
    def _foreign(self, folder: Path) -> list[str]:
        allowed = self.names | {MANIFEST} | _manifest_files(folder)
        return sorted(n for n in os.listdir(folder) if n not in allowed)

    def check(self) -> Path:
        """Refuse now, before the work, what :meth:`publish` would refuse; return the path."""
        p = self.path
        if os.path.lexists(p) and not p.is_dir():
            raise OutputError(f"{p} is a file, not a folder")
        anc = _nearest_existing(p.parent)
        if not anc.is_dir():
            raise OutputError(f"cannot write {p}: {anc} is a file, not a folder")
        _probe_writable(p if self._is_mount_point() else anc, p)  # (a read-only volume said "busy")
        if p.is_dir():
            entries = sorted(os.listdir(p))
            if entries and not self.force:
                raise OverwriteRefused(f"{p} already holds files ({_few(entries)}); not replacing them "
                                       f"(pass force=True / --force to replace a previous output, or give a new folder)")
            if entries:
                foreign = self._foreign(p)
                if foreign:
                    raise OutputError(f"{p} holds files this command did not write ({_few(foreign)}); not "
                                      f"replacing the folder even with force: give a new or empty folder")
        return p

    # -- writing ----------------------------------------------------------------------------
    def _is_mount_point(self) -> bool:
        """A folder that is a mount point (a Docker volume, a bind mount) cannot be renamed onto:
        the set was written, then refused with "Device or resource busy" naming the temporary
        folder (found by a helper). Its files are then moved into it one by one (each atomically,
        the manifest last), from a temporary folder inside it (the same file system)."""
        if not self.path.is_dir():
            return False
        if self.path.is_symlink():
            # a link to a results folder elsewhere: a rename onto the link would replace the link
            # (or fail, "not a directory", reported as files that appeared: found by a helper); the
            # files go into the folder it names, as into a mount point
            return True
        return os.path.ismount(self.path) or str(self.path.resolve()) in _mount_points()

    def __enter__(self) -> Path:
        self.check()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        inside = self._is_mount_point()
        try:
            with deferred_signals():  # a signal now would leave the temporary folder unnamed
                self._tmp = Path(tempfile.mkdtemp(prefix=f".{_short(self.path.name)}.tmp-",
                                                  dir=self.path if inside else self.path.parent))
        except BaseException:
            if self._tmp is not None:
                with deferred_signals():
                    _remove(self._tmp)
                self._tmp = None
            raise
        return self._tmp

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        tmp, self._tmp = self._tmp, None
        if tmp is None:
            return
        try:
            if exc_type is None:
                self._publish(tmp)
            elif isinstance(exc, OSError):
                # name the file the user will look for, not the hidden temporary folder
                renamed: OutputError | None = None
                if isinstance(exc, OutputError):  # the project's own message, naming the temporary path
                    if str(tmp) in str(exc):
                        renamed = OutputError(str(exc).replace(str(tmp), str(self.path)))
                else:
                    named = self._users_name(tmp, exc)
                    if named is not None:
                        renamed = _named(named, exc)
                if renamed is not None:
                    renamed.errno = exc.errno  # (ENOSPC stays visible to a caller; the original is its cause)
                    raise renamed from exc
        finally:
            with deferred_signals():
                _remove(tmp)

    def _users_name(self, tmp: Path, exc: OSError) -> Path | None:
        """The path in the user's folder of the file ``exc`` names inside ``tmp``, or None."""
        for name in (exc.filename, exc.filename2):
            if name is None:
                continue
            try:
                return self.path / Path(os.fsdecode(name)).relative_to(tmp)
            except ValueError:
                continue
        return None

    def _write_manifest(self, tmp: Path) -> None:
        files = {}
        for f in sorted(tmp.iterdir()):
            if f.name == MANIFEST or not f.is_file():
                continue
            h = hashlib.sha256(f.read_bytes()).hexdigest()
            files[f.name] = {"bytes": f.stat().st_size, "sha256": h}
            _chmod_ordinary(f)
        doc = {"producer": producer(), "files": files}
        (tmp / MANIFEST).write_text(json.dumps(doc, indent=2, allow_nan=False) + "\n", encoding="utf-8")
        _chmod_ordinary(tmp / MANIFEST)
        _chmod_ordinary(tmp, folder=True)

    def _publish_into_mount_point(self, tmp: Path) -> None:
        p = self.path
        entries = [n for n in os.listdir(p) if n != tmp.name]
        if entries and not self.force:
            raise OverwriteRefused(f"{p} received files while this run worked; not replacing them "
                                   f"(pass force=True / --force to replace a previous output)")
        foreign = [n for n in self._foreign(p) if n != tmp.name]
        if foreign:
            raise OutputError(f"{p} holds files this command did not write ({_few(foreign)}); not replacing "
                              f"them even with force: give a new or empty folder")
        previous = _manifest_files(p)
        with deferred_signals():
            new = [f.name for f in tmp.iterdir() if f.name != MANIFEST]
            for name in new:
                os.replace(tmp / name, p / name)
            for name in previous - set(new):  # the previous set's files this one does not have
                if name and os.path.basename(name) == name and name not in (".", ".."):
                    _remove(p / name)
            os.replace(tmp / MANIFEST, p / MANIFEST)

    def _publish(self, tmp: Path) -> None:
        self._write_manifest(tmp)
        p = self.path
        if tmp.parent == p:
            self._publish_into_mount_point(tmp)
            return
        appeared = (f"{p} received files while this run worked; not replacing them "
                    f"(pass force=True / --force to replace a previous output)")
        with deferred_signals():
            if not os.path.lexists(p) or (p.is_dir() and not os.listdir(p)):
                try:
                    # onto an absent name, or an empty folder: fails if files appeared meanwhile
                    os.rename(tmp, p)
                except OSError as exc:
                    if exc.errno in (errno.EEXIST, errno.ENOTEMPTY, errno.ENOTDIR, errno.EISDIR):
                        raise OverwriteRefused(appeared) from None
                    raise
                return
            if not p.is_dir():
                raise OutputError(f"{p} is a file, not a folder")
            if not self.force:
                raise OverwriteRefused(appeared)
            foreign = self._foreign(p)
            if foreign:
                raise OutputError(f"{p} holds files this command did not write ({_few(foreign)}); not replacing "
                                  f"the folder even with force: give a new or empty folder")
            if _renameat2(tmp, p, _RENAME_EXCHANGE):
                # tmp now holds the previous set; a file someone put in p between the check and the
                # exchange would be lost with it: put everything back and refuse
                late = self._foreign(tmp)
                if late:
                    _renameat2(tmp, p, _RENAME_EXCHANGE)
                    raise OutputError(f"{p} received other files ({_few(late)}) while this run worked; "
                                      f"not replacing it")
                return
            old = Path(tempfile.mkdtemp(prefix=f".{_short(p.name)}.old-", dir=p.parent))
            os.rmdir(old)
            os.rename(p, old)
            try:
                os.rename(tmp, p)
            except OSError:
                os.rename(old, p)
                raise
            _remove(old)


def _few(names: list[str], k: int = 3) -> str:
    return ", ".join(names[:k]) + (f" and {len(names) - k} more" if len(names) > k else "")
