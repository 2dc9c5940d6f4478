"""The documentation: every public name has a docstring and a place in the API reference, every
docstring example runs (doctest), and, when MkDocs is installed, the site builds with warnings as
errors."""

from __future__ import annotations

import doctest
import os
import importlib
import inspect
import pkgutil
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import piezohyst as ph

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"


def _own_doc(obj: object) -> str | None:
    """The docstring an object has itself (not a dataclass's generated signature)."""
    if isinstance(obj, property):
        obj = obj.fget
    if isinstance(obj, (classmethod, staticmethod)):
        obj = obj.__func__
    if inspect.isclass(obj):
        doc = obj.__dict__.get("__doc__")
        if doc and doc.startswith(obj.__name__ + "("):  # @dataclass writes the signature there
            return None
        return doc
    return getattr(obj, "__doc__", None)


def _public_names() -> dict[str, object]:
    """``piezohyst.__all__``, what its submodules define (public names), and the public methods
    and properties of those classes."""
    out: dict[str, object] = {}
    items = [(n, getattr(ph, n)) for n in ph.__all__ if n != "__version__"]
    for name, mod in list(items):
        if inspect.ismodule(mod):
            own = getattr(mod, "__all__", None) or [k for k in vars(mod) if not k.startswith("_")]
            items += [(f"{name}.{k}", getattr(mod, k)) for k in own
                      if getattr(getattr(mod, k), "__module__", "").startswith("piezohyst")]
    for name, obj in items:
        out[name] = obj
        if inspect.isclass(obj):
            for member, value in vars(obj).items():
                if not member.startswith("_") and (
                        callable(value) or isinstance(value, (property, classmethod, staticmethod))):
                    out[f"{name}.{member}"] = value
    return out


def test_every_public_name_has_a_docstring():
    names = _public_names()
    assert len(names) > 250  # the walk found the API, not an empty list
    missing = sorted(n for n, obj in names.items() if not (_own_doc(obj) or "").strip())
    assert not missing, f"{len(missing)} public names without a docstring: {missing}"


def test_every_public_name_is_in_the_api_reference():
    pages = "\n".join(p.read_text(encoding="utf-8") for p in (DOCS / "api").glob("*.md"))
    documented = set(re.findall(r"^::: piezohyst\.(\w+)", pages, flags=re.M))
    # submodules are described in the overview page
    missing = sorted(n for n in ph.__all__ if n != "__version__" and n not in documented
                     and not (inspect.ismodule(getattr(ph, n)) and f"`{n}`" in pages))
    assert not missing, f"not in docs/api/*.md: {missing}"


def test_the_file_format_page_names_every_model_kind_and_the_schema():
    text = (DOCS / "formats.md").read_text(encoding="utf-8")
    from piezohyst.modelio import SCHEMA_NAME, SCHEMA_VERSION

    assert f"{SCHEMA_NAME}/{SCHEMA_VERSION}" in text
    for kind in ph.kinds():
        assert f"`{kind}`" in text, kind
        for key in _example_parameters(kind):  # every parameter of the kind's model file
            assert f"`{key}`" in text, (kind, key)


def _example_parameters(kind: str) -> list[str]:
    import numpy as np

    from piezohyst.models.asymmetric_pi import OutputMap
    from piezohyst.models.preisach import grid_size

    pi = ph.PrandtlIshlinskii(ph.equal_thresholds(3, 10.0), np.full(3, 0.1))
    examples = {
        "prandtl-ishlinskii": pi,
        "bouc-wen": ph.BoucWen(m=0.75, b=27.96, k=8.54e7, d1=2.15e-8, alpha=0.472, beta=0.072),
        "rate-dependent": ph.RateDependent(static=pi, taus=[0.01], lag_weights=[0.01], dt=1e-3),
        "asymmetric-pi": ph.AsymmetricPI(pi, OutputMap(knots=[0.2], coefficients=[0.1], centre=0.5)),
        "preisach": ph.Preisach(lo=0.0, hi=1.0, weights=np.full(grid_size(2), 0.1), slope=0.1),
    }
    if kind not in examples:  # a kind without an example here: only its name is checked
        return []
    example = examples[kind]
    keys = []
    for key, value in example.to_dict().items():
        keys.append(key)
        if isinstance(value, dict) and "kind" not in value:
            keys += list(value)
    return keys


def _modules() -> list[str]:
    names = []
    for info in pkgutil.walk_packages(ph.__path__, prefix="piezohyst."):
        if ".cli" in info.name or info.name.endswith("__main__"):  # the command line: --help, test_cli_*
            continue
        names.append(info.name)
    return sorted(names)


def _docstring_tests(module: str) -> list[doctest.DocTest]:
    """The docstring examples of ``module`` (only docstrings that hold at least one example)."""
    finder = doctest.DocTestFinder(exclude_empty=True)
    return [t for t in finder.find(importlib.import_module(module), module) if t.examples]


def _modules_with_examples() -> list[str]:
    """The modules with at least one docstring example, computed (not listed by hand): a test per
    module without one ran nothing and passed (52 of 69 did), which hid whether any ran at all."""
    return [m for m in _modules() if _docstring_tests(m)]


@pytest.mark.parametrize("module", _modules_with_examples())
def test_docstring_examples_run(module):
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    for test in _docstring_tests(module):
        runner.run(test)
    res = runner.summarize(verbose=False)
    assert res.attempted > 0, f"no docstring example of {module} ran"
    assert res.failed == 0, f"{res.failed} of {res.attempted} docstring examples in {module} fail (see above)"


def test_there_are_docstring_examples_to_run():
    with_examples = _modules_with_examples()
    assert with_examples, "no module has a docstring example: test_docstring_examples_run checks nothing"
    count = sum(len(t.examples) for m in with_examples for t in _docstring_tests(m))
    assert count >= 20, count


@pytest.mark.skipif(importlib.util.find_spec("mkdocs") is None or importlib.util.find_spec("mkdocstrings") is None,
                    reason="MkDocs is not installed (`make docs` installs it from the docs extra)")
def test_site_builds_with_warnings_as_errors(tmp_path):
    site = tmp_path / "site"
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-f", str(ROOT / "mkdocs.yml"),
                           "-d", str(site)], capture_output=True, text=True, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert (site / "index.html").exists()
    html = (site / "api" / "identify" / "index.html").read_text(encoding="utf-8")
    assert 'id="piezohyst.fit_model"' in html
    # Sphinx roles in docstrings were turned into Markdown, not shown raw
    raw = [p for p in site.rglob("*.html") if re.search(r":(func|class|mod|meth):", p.read_text(encoding="utf-8"))]
    assert not raw, raw
    shutil.rmtree(site)


def test_importing_a_submodule_does_not_hide_a_public_name():
    # `import piezohyst.X` sets the package attribute X to the module; a public name X (lazy) must win
    modules = {info.name for info in pkgutil.iter_modules(ph.__path__)}
    clashes = sorted(set(ph._LAZY) & modules)
    code = ("import importlib, types, piezohyst as ph\n"
            f"for n in {clashes!r}:\n"
            "    importlib.import_module('piezohyst.' + n)\n"
            "    assert not isinstance(getattr(ph, n), types.ModuleType), n\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(Path(ph.__file__).parent.parent)})
    assert proc.returncode == 0, proc.stderr
