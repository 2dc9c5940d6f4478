"""The command line that files written by this process name (``producer()`` in ``_fileio``).

Kept apart, with no imports, so that the command line records it before it parses its
arguments without loading the file-writing machinery (``piezohyst --help`` stays quick).
"""

from __future__ import annotations

#: the command line of a ``piezohyst`` run, as the user typed it (set by the command line's
#: ``main``); None in Python, where the script's own arguments are recorded
command_line: list[str] | None = None


def set_command_line(words: list[str] | None) -> None:
    """Record the command line that files written from now on name (``piezohyst rig --out x``)."""
    global command_line
    command_line = None if words is None else [str(w) for w in words]
