"""One place that decides how kernels are compiled.

Sequential-in-time recursions (play operator, Bouc-Wen step, rig) are compiled with numba and
cached on disk, so a second process pays no compile time. Set ``PIEZOHYST_NO_CACHE=1`` to
switch the on-disk cache off.

Where nothing can be written (a read-only install and a read-only home, no ``NUMBA_CACHE_DIR``),
numba cannot place its cache and would refuse to decorate the kernels. Then the cache goes to a
private folder in the temporary directory (``piezohyst-numba-UID``, mode 0700, used only if it is
ours and nobody else can write in it: numba's cache files are loaded as code), and failing that
the kernels are compiled in every process without a cache. Either is said once, on the
``piezohyst`` logger; nothing fails.
"""

from __future__ import annotations

import contextlib
import logging
import os
import stat
import tempfile
from typing import Any, Callable, Iterator, TypeVar

import numba

F = TypeVar("F", bound=Callable[..., Any])

_CACHE = os.environ.get("PIEZOHYST_NO_CACHE", "") not in ("1", "true", "yes")

_log = logging.getLogger("piezohyst")
_said: set[str] = set()
_fallback_dir: str | None | bool = False  # False: not decided yet; None: no usable folder


def _say_once(key: str, message: str) -> None:
    if key not in _said:
        _said.add(key)
        _log.warning(message)


def _private_cache_dir() -> str | None:
    """``$TMPDIR/piezohyst-numba-UID``, created 0700, or None if it is not safely ours."""
    global _fallback_dir
    if _fallback_dir is not False:
        return _fallback_dir  # type: ignore[return-value]
    uid = os.getuid() if hasattr(os, "getuid") else 0
    path = os.path.join(tempfile.gettempdir(), f"piezohyst-numba-{uid}")
    created = False
    try:
        try:
            os.mkdir(path, 0o700)
            created = True
        except FileExistsError:
            pass
        st = os.lstat(path)
        ours = stat.S_ISDIR(st.st_mode) and (not hasattr(os, "getuid") or st.st_uid == uid)
        if not ours or st.st_mode & 0o022:
            _fallback_dir = None
            return None
        probe = tempfile.TemporaryFile(dir=path)
        probe.close()
    except OSError:
        _fallback_dir = None
        return None
    _fallback_dir = path
    if created:
        _say_once("tmp", f"piezohyst: numba cannot write its cache beside the package or in the home folder; "
                         f"caching compiled kernels in {path}")
    return path


@contextlib.contextmanager
def _cache_dir(path: str) -> Iterator[None]:
    """numba's CACHE_DIR set while our kernels are decorated (their locator keeps the path),
    then restored: other libraries' kernels are not moved."""
    old = numba.config.CACHE_DIR  # type: ignore[attr-defined]  # set by numba at import, not declared
    numba.config.CACHE_DIR = path  # type: ignore[attr-defined]
    try:
        yield
    finally:
        numba.config.CACHE_DIR = old  # type: ignore[attr-defined]


def _compile(func: F, **opts: Any) -> F:
    if _CACHE:
        try:
            return numba.njit(cache=True, **opts)(func)  # type: ignore[no-any-return]
        except RuntimeError as exc:  # "cannot cache function ...: no locator available"
            if "locator" not in str(exc):
                raise
        path = _private_cache_dir()
        if path is not None:
            try:
                with _cache_dir(path):
                    return numba.njit(cache=True, **opts)(func)  # type: ignore[no-any-return]
            except RuntimeError as exc:
                if "locator" not in str(exc):
                    raise
        _say_once("none", "piezohyst: nowhere to write numba's cache (read-only install, home and temporary "
                          "folder); compiling the kernels in this process without a cache")
    return numba.njit(cache=False, **opts)(func)  # type: ignore[no-any-return]


def njit(func: F) -> F:
    """``numba.njit`` with the project's settings (cached, no Python fallback)."""
    return _compile(func, nogil=True)


def njit_fast(fastmath: Any) -> Callable[[F], F]:
    """As :func:`njit`, with numba's ``fastmath`` flags (e.g. ``{"reassoc"}``: sums vectorised)."""
    def deco(func: F) -> F:
        return _compile(func, nogil=True, fastmath=fastmath)
    return deco


def njit_parallel(func: F) -> F:
    """As :func:`njit`, for kernels that spread independent work over cores with ``prange``."""
    return _compile(func, nogil=True, parallel=True)


prange = numba.prange
