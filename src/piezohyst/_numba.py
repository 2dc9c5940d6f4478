"""One place that decides how kernels are compiled.

Sequential-in-time recursions (play operator, Bouc-Wen step, rig) are compiled with numba and
cached on disk, so a second process pays no compile time. Set ``PIEZOHYST_NO_CACHE=1`` to
switch the on-disk cache off (e.g. on a read-only install).
"""

from __future__ import annotations

import os
from typing import Any, Callable, TypeVar

import numba

F = TypeVar("F", bound=Callable[..., Any])

_CACHE = os.environ.get("PIEZOHYST_NO_CACHE", "") not in ("1", "true", "yes")


def njit(func: F) -> F:
    """``numba.njit`` with the project's settings (cached, no Python fallback)."""
    return numba.njit(cache=_CACHE, nogil=True)(func)  # type: ignore[no-any-return]


def njit_parallel(func: F) -> F:
    """As :func:`njit`, for kernels that spread independent work over cores with ``prange``."""
    return numba.njit(cache=_CACHE, nogil=True, parallel=True)(func)  # type: ignore[no-any-return]


prange = numba.prange
