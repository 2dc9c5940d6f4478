"""Fuzzing the readers: whatever the bytes, ``load_dataset`` returns a valid Dataset or raises DataError.

Never another exception, never a warning (pytest turns warnings into errors), never a message
of more than one line or without the file's name. The number of files tried is printed at the
end of the run (``readers fuzz: ...`` in the terminal summary).
"""

from __future__ import annotations

import codecs
import itertools
import os
import warnings
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

import piezohyst as ph
from piezohyst.data import DataError

from ._labfiles import savemat73

TRIED: Counter[str] = Counter()
LOADED: Counter[str] = Counter()
_seq = itertools.count()


class _Summary:
    @staticmethod
    def pytest_terminal_summary(terminalreporter):  # pragma: no cover - output only
        if TRIED:
            parts = ", ".join(f"{k} {v} ({LOADED[k]} loaded)" for k, v in sorted(TRIED.items()))
            terminalreporter.write_line(f"readers fuzz: {sum(TRIED.values())} files tried, each loaded or refused "
                                        f"with a DataError: {parts}")


@pytest.fixture(scope="module", autouse=True)
def _report(request):
    plugin = _Summary()
    request.config.pluginmanager.register(plugin, "piezohyst-readers-fuzz")
    yield


@pytest.fixture(scope="module")
def workdir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


def fuzz(n: int) -> settings:
    """``n`` examples (times ``PIEZOHYST_FUZZ_SCALE`` for a long hunt)."""
    return settings(max_examples=n * int(os.environ.get("PIEZOHYST_FUZZ_SCALE", "1")), deadline=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def check(path: Path, kind: str, **kwargs) -> None:
    """Load and check the contract: a valid Dataset, or one line of DataError naming the file."""
    TRIED[kind] += 1
    try:
        ds = ph.load_dataset(path, **kwargs)
    except DataError as exc:
        msg = str(exc)
        assert "\n" not in msg, msg
        assert str(path) in msg or msg.startswith("units") or "PIEZOHYST" in msg, msg
        return
    LOADED[kind] += 1
    assert isinstance(ds, ph.Dataset)
    assert len(ds.t) == len(ds.u) == len(ds.y) >= 2
    assert np.all(np.isfinite(ds.t)) and np.all(np.isfinite(ds.u)) and np.all(np.isfinite(ds.y))
    assert np.all(np.diff(ds.t) > 0)


def fresh(workdir: Path, suffix: str) -> Path:
    return workdir / f"f{next(_seq)}{suffix}"


SUFFIXES = ["", ".csv", ".txt", ".dat", ".tsv", ".mat", ".npz", ".npy", ".h5", ".parquet", ".xlsx", ".tdms"]
COLUMN = st.one_of(st.none(), st.integers(-2, 6), st.sampled_from(["t", "u", "y", "time", "Voltage", "x",
                                                                  "a.b", "s.signals[0].values", "M[:, 1]",
                                                                  "rec.Y(2).Data", "", "[", "0"]))
ANY_OPTIONS = st.fixed_dictionaries({}, optional={
    "u_col": COLUMN, "y_col": COLUMN, "t_col": COLUMN,
    "fs": st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-5, 5000)),
    "resample": st.booleans(),
})
# half the time no options (found by name), else plausible ones, else anything
OPTIONS = st.one_of(
    st.just({}),
    st.fixed_dictionaries({}, optional={"fs": st.sampled_from([1.0, 1000.0, 2.0]), "resample": st.booleans()}),
    ANY_OPTIONS,
)


# ---- 1. random bytes -------------------------------------------------------------------------
@fuzz(100)
@given(data=st.binary(max_size=2048), suffix=st.sampled_from(SUFFIXES), prefix=st.sampled_from(
    [b"", b"MATLAB 5.0 MAT-file", b"MATLAB 7.3 MAT-file", b"\x93NUMPY", b"PK\x03\x04", b"PAR1",
     b"\x89HDF\r\n\x1a\n", codecs.BOM_UTF8, codecs.BOM_UTF16_LE, b"TDSm",
     b"LabVIEW Measurement\t\nX_Columns\tNo\n***End_of_Header***\n\nChannels\t2\nDelta_X\t0.001\t0.001\n"
     b"***End_of_Header***\nX_Value\tU\tY\tComment\n"]), opts=OPTIONS)
def test_random_bytes(workdir, data, suffix, prefix, opts):
    p = fresh(workdir, suffix)
    p.write_bytes(prefix + data)
    check(p, "bytes", **opts)


# ---- 2. CSV-ish text -------------------------------------------------------------------------
NAMES = ["t", "u", "y", "time", "Time", "voltage", "Displacement", "x", "v", "input", "output", "a", "",
         "Unnamed: 0", "Weg", "Zeit", "sample #", "t_s", "u_V", "y_um", "y_nm", "u_mV", "t/s", "x in mm"]
UNITS = ["", " [s]", " [ms]", " (us)", " [V]", " [mV]", " (kV)", " [um]", " [µm]", " (nm)", " [mm]", " [m]",
         " [furlong]", " [-]", " [a.u.]", " (sensor 2)", " [V/um]", " []", " [mA]"]
VALUE = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, width=64).map(repr),
    st.floats(min_value=-1e3, max_value=1e3, allow_nan=False).map(lambda v: f"{v:.6g}"),
    st.integers(-10**6, 10**6).map(str),
    st.sampled_from(["", "nan", "NaN", "inf", "-inf", "1e999", "abc", "1,5", "0,001", "1.2.3", '"3"', "--",
                     "#", "N/A", "1e-320", " 7 ", "∞", "1_0"]),
)


@st.composite
def csv_text(draw):
    """Half the time a plausible lab table (then often loadable), else anything table-like."""
    plausible = draw(st.booleans())
    ncols = draw(st.integers(1, 5))
    sep = draw(st.sampled_from([",", ";", "\t"] if plausible else [",", ";", "\t", " ", "  ", "|"]))
    decimal = draw(st.sampled_from([".", ","])) if sep != "," else "."
    lines = []
    for _ in range(draw(st.integers(0, 3))):
        lines.append("# " + draw(st.text(max_size=20)).replace("\n", " ").replace("\r", " "))
    if plausible:  # a time, a voltage and a displacement, in some order, maybe with extra columns
        ncols = draw(st.integers(3, 5))
        names = [draw(st.sampled_from(["t", "time", "Time", "Zeit", "t_s", "t/ms"]))
                 + draw(st.sampled_from(["", " [s]", " (ms)", " [us]"])),
                 draw(st.sampled_from(["u", "Voltage", "u_mV", "input"])) + draw(st.sampled_from(["", " [V]", " (mV)"])),
                 draw(st.sampled_from(["y", "x", "Displacement", "y_nm", "Weg"]))
                 + draw(st.sampled_from(["", " [µm]", " (nm)", " [mm]"]))]
        names = (names + ["extra", "other"])[:ncols]
        lines.append(sep.join(draw(st.permutations(names))))
    elif draw(st.booleans()):
        lines.append(sep.join(draw(st.sampled_from(NAMES)) + draw(st.sampled_from(UNITS)) for _ in range(ncols)))
        if draw(st.booleans()):
            lines.append(sep.join(draw(st.sampled_from(["s", "V", "um", "nm", "ms", "", "x"])) for _ in range(ncols)))
    nrows = draw(st.integers(0, 30))
    regular = plausible or draw(st.booleans())
    step = draw(st.sampled_from([1e-3, 0.5, 1.0]))
    time_col = lines[-1].split(sep).index(next(n for n in lines[-1].split(sep) if n[:1] in "tTZ")) \
        if plausible else 0
    for i in range(nrows):
        if regular:
            cells = [f"{np.sin(i + j):.6f}" for j in range(ncols)]
            cells[time_col] = f"{i * step:.6g}"
            if draw(st.integers(0, 40)) == 0:
                cells[draw(st.integers(0, ncols - 1))] = draw(VALUE)
            if draw(st.integers(0, 40)) == 0:
                cells = cells[:-1] if len(cells) > 1 else cells + ["1"]
        else:
            width = ncols + draw(st.sampled_from([0, 0, 0, -1, 1]))
            cells = [draw(VALUE) for _ in range(max(width, 0))]
        if decimal == ",":
            cells = [c.replace(".", ",") for c in cells]
        lines.append(sep.join(cells))
    ending = draw(st.sampled_from(["\n", "\r\n", "\r"]))
    text = ending.join(lines) + (ending if draw(st.booleans()) else "")
    encoding = draw(st.sampled_from(["utf-8", "utf-8-sig", "cp1252", "utf-16", "latin-1"]))
    return text, encoding


@fuzz(200)
@given(doc=csv_text(), suffix=st.sampled_from([".csv", ".txt", ".dat", ""]), opts=OPTIONS)
# found by a random run: a sample rate of 1e-308 Hz made k / fs overflow (a RuntimeWarning, not a
# DataError saying the time axis does not fit in a float)
@example(doc=("t/ms [s],u,y,extra\n0,0.841471,0.909297\n0.001,0.909297,0.141120,-0.756802\n0.002,0.141120,"
              "-0.756802,-0.958924", "utf-8"), suffix=".csv", opts={"fs": 1.1125369292536007e-308})
def test_csv_like_text(workdir, doc, suffix, opts):
    text, encoding = doc
    p = fresh(workdir, suffix)
    p.write_bytes(text.encode(encoding, errors="replace"))
    check(p, "text", **opts)


# ---- 3. random .npz / .mat contents ----------------------------------------------------------
ARRAY_NAMES = st.sampled_from(["t", "u", "y", "x", "time", "voltage", "y_nm", "t_ms", "data", "meta", "tout"])
SHAPE = st.lists(st.integers(0, 6), min_size=0, max_size=3).map(tuple)
DTYPE = st.sampled_from(["f8", "f4", "i4", "u1", "?", "c16"])


@st.composite
def arrays(draw):
    out = {}
    if draw(st.booleans()):  # plausible: t, u, y of one length, as row, column or flat vectors
        n = draw(st.integers(0, 12))
        shape = draw(st.sampled_from([(n,), (n, 1), (1, n)]))
        names = draw(st.sampled_from([("t", "u", "y"), ("time", "voltage", "y_nm"), ("tout", "u", "x")]))
        for name, a in zip(names, (np.arange(n) * 1e-3, np.sin(np.arange(n)), np.cos(np.arange(n)))):
            if draw(st.integers(0, 5)) > 0:
                out[name] = a.reshape(shape)
    for _ in range(draw(st.integers(0, 4))):
        name = draw(ARRAY_NAMES)
        shape = draw(SHAPE)
        kind = draw(st.sampled_from(["ramp", "random", "nan"]))
        size = int(np.prod(shape)) if shape else 1
        if kind == "ramp":
            a = np.arange(size, dtype=float)
        elif kind == "random":
            a = np.asarray(draw(st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=size,
                                         max_size=size)), dtype=float)
        else:
            a = np.full(size, np.nan)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # NaN cast to integers while building the input
            out[name] = a.reshape(shape).astype(draw(DTYPE))
    return out


@fuzz(100)
@given(content=arrays(), opts=OPTIONS)
def test_random_npz(workdir, content, opts):
    p = fresh(workdir, ".npz")
    np.savez(p, **content)
    check(p, "npz", **opts)


@fuzz(60)
@given(content=arrays(), v73=st.booleans(), nest=st.booleans(), opts=OPTIONS)
def test_random_mat(workdir, content, v73, nest, opts):
    import scipy.io as sio

    content = {k: v for k, v in content.items() if v.dtype.kind != "c" or not v73}
    if v73:
        content = {k: v.astype(float) for k, v in content.items() if v.size > 0}
    if nest:
        content = {"s": content or {"empty": np.zeros(0) if not v73 else np.zeros(1)}}
    p = fresh(workdir, ".mat")
    if v73:
        savemat73(p, content)
    else:
        sio.savemat(p, content)
    check(p, "mat", **opts)


# ---- 4. damaged good files -------------------------------------------------------------------
def _good_files(workdir: Path) -> dict[str, bytes]:
    import scipy.io as sio

    t = np.arange(20) * 1e-3
    ds = ph.Dataset(t, np.sin(t * 300), np.cos(t * 300))
    out = {}
    for suffix in (".csv", ".npz"):
        p = workdir / f"good{suffix}"
        ph.save_dataset(p, ds, force=True)
        out[suffix] = p.read_bytes()
    p = workdir / "good.mat"
    sio.savemat(p, {"t": t, "u": ds.u, "y": ds.y})
    out[".mat"] = p.read_bytes()
    p = workdir / "good73.mat"
    savemat73(p, {"t": t, "u": ds.u, "y": ds.y})
    out["73.mat"] = p.read_bytes()
    return out


@fuzz(100)
@given(which=st.sampled_from([".csv", ".npz", ".mat", "73.mat"]), cut=st.floats(0, 1),
       flips=st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)), max_size=6))
def test_damaged_files(workdir, which, cut, flips):
    key = "_good"
    if key not in _CACHE:
        _CACHE[key] = _good_files(workdir)
    data = bytearray(_CACHE[key][which])
    for where, value in flips:
        data[int(where * (len(data) - 1))] = value
    data = data[: max(1, int(cut * len(data)))] if cut < 0.98 else data
    p = fresh(workdir, which[-4:])
    p.write_bytes(bytes(data))
    check(p, "damaged")


_CACHE: dict[str, dict[str, bytes]] = {}


_FIELD = st.one_of(
    st.floats(allow_nan=False, allow_infinity=False, width=32).map(repr),
    st.integers(-10**6, 10**6).map(str),
    st.sampled_from(["1,5", "-,5", "2.", ".5", "1e-3", "1E+03", "nan", "inf", "-Infinity", "", "NA", "x", "1.2.3",
                     '"3.5"', "1#2", "e5", "+", "5e", " 7 ", "\t8"]),
)


@given(fields=st.lists(_FIELD, min_size=1, max_size=6),
       joiner=st.sampled_from(["\t", ";", ",", "|", " ", "  ", " ; ", ", ", "\t\t"]),
       cand=st.sampled_from(__import__("piezohyst.data._text", fromlist=["CANDIDATES"]).CANDIDATES))
def test_whole_line_classes_equal_field_by_field(fields, joiner, cand):
    """The sniffer's shortcut for lines of numbers only gives every field the class that
    splitting the line and classifying each field gives."""
    from piezohyst.data._text import _classify, _cls, _split

    line = joiner.join(fields)
    delim, decimal = cand
    assert _classify(line, delim, decimal) == tuple(_cls(f, decimal) for f in _split(line.split("#", 1)[0], delim))
