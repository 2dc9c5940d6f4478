"""Fuzzing the model files and the command line (issue 13), with hypothesis.

* Model files: random JSON documents, and real model documents of every kind with one number
  replaced (NaN, inf, huge, negative, zero, another type) or one key removed. Loading must give
  a model or a :class:`~piezohyst.modelio.ModelFileError` naming the file, nothing else (no
  KeyError, IndexError, RecursionError, ...).
* The command line: random argument lists built from every command's options and bad values.
  Each runs through :func:`piezohyst.cli.main` with the long work stubbed out (the fits, the
  rig's excitation, the experiment: reaching them means every up-front check passed); the
  outcome must be exit 0, exit 2 with exactly one line on stderr, or the stub, never a
  traceback or an internal error.

The number of cases tried is printed at the end (``test_zz_fuzz_summary``).
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import warnings

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import piezohyst as ph
from piezohyst.modelio import ModelFileError

TRIED: dict[str, int] = {}


def _count(name: str) -> None:
    TRIED[name] = TRIED.get(name, 0) + 1


# ------------------------------------------------------------------------------------------------
# model files
@pytest.fixture(scope="module")
def model_docs(tmp_path_factory):
    """A real document of every registered kind (fitted on a small record)."""
    from piezohyst import paper_values as pv
    from piezohyst.models.base import kinds
    from piezohyst.modelio import model_to_dict

    dt = 1e-3
    u = ph.sinusoid(2.0, 3, 0.0, 100.0, dt)
    y = pv.pi_model().simulate(u) * 0.02 + 1e-4 * u**2
    docs = {"prandtl-ishlinskii": model_to_dict(pv.pi_model()), "bouc-wen": model_to_dict(pv.bouc_wen_model())}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for kind in kinds():
            if kind not in docs:
                docs[kind] = model_to_dict(ph.fit_model(u, y, dt, kind, n=6).model)
    return {k: json.loads(json.dumps(v)) for k, v in docs.items()}


@pytest.fixture(scope="module")
def scratch(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


def _load(path) -> object:
    """load_model: a model or ModelFileError, else the test fails (with the document)."""
    try:
        return ph.load_model(path)
    except ModelFileError as exc:
        assert str(path) in str(exc)  # names the file
        return None


json_leaves = (st.none() | st.booleans() | st.integers(min_value=-(10**30), max_value=10**30)
               | st.floats(allow_nan=True, allow_infinity=True) | st.text(max_size=12))
json_docs = st.recursive(json_leaves, lambda kids: st.lists(kids, max_size=6)
                         | st.dictionaries(st.text(max_size=10), kids, max_size=6), max_leaves=40)


@settings(suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow], deadline=None)
@given(doc=json_docs, keep_header=st.booleans(), kind=st.sampled_from(["prandtl-ishlinskii", "bouc-wen", "preisach",
                                                                       "rate-dependent", "asymmetric-pi", "x"]))
def test_random_json_documents_load_or_are_refused(scratch, doc, keep_header, kind):
    _count("random JSON model files")
    if keep_header:  # past the schema check, into the kinds' own parameter checks
        doc = {"schema": "piezohyst.model/2", "kind": kind, "parameters": doc}
    p = scratch / "random.json"
    p.write_text(json.dumps(doc, allow_nan=True))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        _load(p)


def _paths(obj, prefix=()):
    """Every leaf of a JSON document, as a path of keys and indices."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _paths(v, (*prefix, i))
    else:
        yield prefix


def _set(obj, path, value, delete=False):
    for k in path[:-1]:
        obj = obj[k]
    if delete:
        del obj[path[-1]]
    else:
        obj[path[-1]] = value


replacements = st.one_of(
    st.sampled_from([math.nan, math.inf, -math.inf, 0.0, -0.0, -1.0, 1e308, -1e308, 1e-308, 1e300, 2**63, -(2**63)]),
    st.floats(allow_nan=True, allow_infinity=True), st.integers(), st.none(), st.booleans(), st.text(max_size=5),
    st.lists(st.floats(), max_size=3), st.dictionaries(st.text(max_size=3), st.integers(), max_size=2))


@settings(suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow], deadline=None)
@given(data=st.data())
def test_real_model_files_with_one_value_changed(model_docs, scratch, data):
    _count("real model files, one value changed")
    kind = data.draw(st.sampled_from(sorted(model_docs)))
    doc = json.loads(json.dumps(model_docs[kind]))
    leaves = [pth for pth in _paths(doc) if pth]
    path = data.draw(st.sampled_from(leaves))
    delete = isinstance(path[-1], str) and data.draw(st.booleans())
    _set(doc, path, None if delete else data.draw(replacements), delete=delete)
    p = scratch / "changed.json"
    p.write_text(json.dumps(doc, allow_nan=True))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        model = _load(p)
    if model is not None:  # what loads saves back, finite, and loads again the same
        q = scratch / "again.json"
        ph.save_model(model, q, force=True)
        assert ph.load_model(q).to_dict() == model.to_dict()


# ------------------------------------------------------------------------------------------------
# the command line
class Reached(BaseException):  # not an Exception: main() must not catch it
    """The long work was reached: every up-front check passed."""


def _stub(*a, **k):
    raise Reached


@pytest.fixture(scope="module")
def cli_files(tmp_path_factory):
    from piezohyst import paper_values as pv

    d = tmp_path_factory.mktemp("fuzzcli")
    dt = 1e-3
    u = ph.sinusoid(2.0, 2, 0.0, 100.0, dt)
    y = pv.pi_model().simulate(u) * 0.02
    (d / "data.csv").write_text("t,u,y\n" + "\n".join(f"{i * dt:.6g},{a:.9g},{b:.9g}" for i, (a, b) in
                                                     enumerate(zip(u, y))) + "\n")
    ph.save_model(ph.fit_pi(u, y, n=6).model, d / "pi.json")
    (d / "bad.json").write_text("{")
    (d / "settings.json").write_text('{"noise_rms_um": 0.001}')
    (d / "exists.json").write_text("{}")
    (d / "out").mkdir()
    return d


def _values(files):
    paths = [str(files / n) for n in ("data.csv", "pi.json", "bad.json", "settings.json", "exists.json", "out",
                                      "missing.csv", "out/new", "data.csv/x")]
    numbers = ["0", "1", "-1", "2", "3", "1.5", "-0.5", "1e-9", "1e9", "1e300", "-1e300", "nan", "inf", "-inf",
               "1e-300", "5000", "0.001", "100", "abc", "", "1,3", "1,,2", "0:10", "10:0", ":5", "5:", "a:b",
               "auto", "pi", "bouc-wen", "preisach", "-", "--", "2000", "999999999999"]
    return st.sampled_from(paths + numbers)


OPTIONS = {
    "models": ["--freq", "--json"],
    "rig": ["--freq", "--cycles", "--u-low", "--u-high", "--out", "--force", "--json", "--seed", "--rig-gamma",
            "--rig-creep-scale", "--rig-noise-scale", "--rig-settings"],
    "track": ["--model", "--method", "--freq", "--cycles", "--low", "--high", "--feedback", "--kp", "--ki", "--kd",
              "--json", "--seed", "--rig-settings", "--rig-gamma"],
    "identify": ["--u-col", "--y-col", "--t-col", "--fs", "--model", "--method", "--n", "--seed", "--iterations",
                 "--no-polish", "--delay", "--train", "--validate", "--validate-data", "-o", "--force", "--json"],
    "reproduce": ["--out", "--force", "--json", "--seed", "--rig-gamma", "--rig-creep-scale", "--rig-noise-scale",
                  "--rig-settings"],
    "benchmark": ["--data", "--seed", "--json"],
}
FLAGS = {"--json", "--force", "--no-polish"}


@st.composite
def command_lines(draw, files):
    cmd = draw(st.sampled_from(sorted(OPTIONS)))
    argv = [cmd]
    if cmd == "identify":
        argv.append(draw(_values(files)))
    if cmd == "benchmark":
        argv.append(draw(st.sampled_from(["bouc-wen", "other"])))
    for opt in draw(st.lists(st.sampled_from(OPTIONS[cmd]), max_size=6)):
        argv.append(opt)
        if opt not in FLAGS:
            argv.append(draw(_values(files)))
    if draw(st.booleans()) and len(argv) > 2:  # now and then a token out of place
        i = draw(st.integers(1, len(argv) - 1))
        argv.insert(i, draw(_values(files) | st.sampled_from(["--debug-not", "--freq", "-o"])))
    return argv


@pytest.fixture(scope="module")
def stubbed():
    """The long work replaced by a stub that raises Reached."""
    import importlib

    import piezohyst.control.tracking as tracking
    import piezohyst.experiments.boucwen_benchmark as bench
    import piezohyst.experiments.paper as paper
    import piezohyst.rig as rig

    commission = importlib.import_module("piezohyst.commissioning")
    mp = pytest.MonkeyPatch()
    for obj, name in ((ph, "fit_pi"), (ph, "fit_bouc_wen"), (ph, "fit_model"), (ph, "sinusoid"),
                      (tracking, "track"), (commission, "commission"), (paper, "run_paper_experiment"),
                      (bench, "run_benchmark"), (rig.VirtualRig, "excite")):
        mp.setattr(obj, name, _stub)
    import piezohyst.signals as signals

    mp.setattr(signals, "sinusoid", _stub)
    yield
    mp.undo()


@settings(suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow], deadline=None)
@given(data=st.data())
def test_command_line_fuzz(cli_files, stubbed, data, monkeypatch):
    from piezohyst.cli import main

    argv = data.draw(command_lines(cli_files))
    _count("command lines")
    out, err = io.StringIO(), io.StringIO()
    monkeypatch.chdir(cli_files)
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as exc:
            code = exc.code
        except Reached:
            code = "reached"
    text = err.getvalue()
    lines = [ln for ln in text.splitlines() if ln.strip()]
    if code == "reached":
        return
    assert "Traceback" not in text, (argv, text)
    assert code in (0, 2), (argv, code, text)
    if code == 2:
        assert len(lines) == 1 and "error" in lines[0], (argv, text)
    if "--json" in argv and code == 0:
        json.loads(out.getvalue())  # strict JSON when it succeeds


def test_zz_fuzz_summary(capsys):
    with capsys.disabled():
        print("\nfuzz cases tried: " + ", ".join(f"{k} {v}" for k, v in TRIED.items()))
    assert all(v > 0 for v in TRIED.values())
