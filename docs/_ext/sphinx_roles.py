"""Griffe extension for the documentation build: Sphinx roles in docstrings become Markdown.

The docstrings use numpydoc with Sphinx cross-reference roles (``:func:`fit_model```,
``:class:`~piezohyst.data.Dataset```), which MkDocs does not read. This rewrites each role as
inline code, linked to the API reference when its target is one of ``piezohyst.__all__`` (the
names the reference documents), so the rendered pages show no raw roles.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path
from typing import Any

import griffe

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "src"))
import piezohyst  # noqa: E402

PUBLIC = set(piezohyst.__all__)
ROLE = re.compile(r":(?:py:)?(func|class|meth|mod|data|attr|exc|obj|const)s?:`([^`]+)`")


def _replace(m: re.Match[str]) -> str:
    role, body = m.group(1), m.group(2).strip()
    explicit = re.fullmatch(r"(.+?)\s*<([^>]+)>", body)
    if explicit:
        text, target = explicit.group(1), explicit.group(2)
    else:
        target = body.lstrip("~")
        text = target.rsplit(".", 1)[-1] if body.startswith("~") else target
    if role in ("func", "meth") and not text.endswith(")"):
        text += "()"
    name = target.rsplit(".", 1)[-1]
    if role != "mod" and name in PUBLIC and target.split(".")[0] in ("piezohyst", name):
        return f"[`{text}`][piezohyst.{name}]"
    return f"`{text}`"


def convert(text: str) -> str:
    """Docstring text with every Sphinx role replaced (see the module docstring)."""
    return ROLE.sub(_replace, text)


class SphinxRoles(griffe.Extension):
    """Rewrite Sphinx roles in every docstring once the package is loaded."""

    def on_object(self, *, obj: Any, loader: Any, **kwargs: Any) -> None:
        if obj.is_alias or obj.docstring is None:
            return
        obj.docstring.value = convert(obj.docstring.value)

    def on_package(self, *, pkg: Any, loader: Any, **kwargs: Any) -> None:
        # the root package is not passed to on_object
        if pkg.docstring is not None:
            pkg.docstring.value = convert(pkg.docstring.value)
