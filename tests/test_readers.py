"""Lab files as they come: every kind loads to the same data as the canonical CSV, or is refused in one line.

The reference is ``save_dataset``'s CSV of one record (t in s, u in V, y in µm). Each test writes
the same record the way another program would (units, delimiters, encodings, MATLAB structs,
DataFrames) and checks that ``load_dataset``/``Dataset.from_dataframe`` return the same t, u, y.
"""

from __future__ import annotations

import codecs
import importlib.util
import json
import os
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import scipy.io as sio

import piezohyst as ph
from piezohyst.data import DataError, data_dir, read_table

from ._labfiles import dspace, savemat73, simulink_structure_with_time, v5_struct_array

N = 40
T = np.round(np.arange(N) * 1e-3, 10)
U = np.round(2.5 + 2.5 * np.sin(2 * np.pi * np.arange(N) / 20), 6)  # V
Y = np.round(0.8 * U + 0.05 * np.cos(2 * np.pi * np.arange(N) / 20), 6)  # µm


@pytest.fixture(scope="module")
def ref(tmp_path_factory):
    """The canonical CSV of the record, loaded."""
    p = tmp_path_factory.mktemp("ref") / "ref.csv"
    ph.save_dataset(p, ph.Dataset(T, U, Y, {"note": "reference"}))
    return ph.load_dataset(p)


def same(ds, ref, rtol=1e-12):
    np.testing.assert_allclose(ds.t, ref.t, rtol=rtol, atol=1e-15)
    np.testing.assert_allclose(ds.u, ref.u, rtol=rtol, atol=1e-15)
    np.testing.assert_allclose(ds.y, ref.y, rtol=rtol, atol=1e-15)


def lines(cols, fmt, sep, decimal="."):
    out = []
    for row in zip(*cols):
        cells = [f % v for f, v in zip(fmt, row)]
        if decimal != ".":
            cells = [c.replace(".", decimal) for c in cells]
        out.append(sep.join(cells))
    return out


# ---- text tables -------------------------------------------------------------------------------
def test_canonical_csv_round_trip_is_exact(ref):
    assert np.array_equal(ref.t, T) and np.array_equal(ref.u, U) and np.array_equal(ref.y, Y)
    assert ref.meta["note"] == "reference"  # the meta comment is read back
    assert ref.meta["units"]["y"]["unit"] == "um" and ref.meta["units"]["y"]["factor"] == 1.0


def test_semicolons_decimal_commas_and_units_in_the_header(tmp_path, ref):
    # the line of issue 15: a German lab export
    p = tmp_path / "lab.csv"
    body = lines([T, U, Y * 1000], ["%.3f", "%.6f", "%.3f"], ";", decimal=",")
    p.write_text("Time [s];Voltage [V];Displacement [nm]\n" + "\n".join(body) + "\n", encoding="utf-8")
    ds = ph.load_dataset(p)
    same(ds, ref)
    assert ds.meta["delimiter"] == "semicolon" and ds.meta["decimal"] == ","
    assert ds.meta["units"]["y"] == {"column": "Displacement [nm]", "unit": "nm", "to": "um", "factor": 0.001}


def test_cp1252_export_with_micro_sign_and_milliseconds(tmp_path, ref):
    p = tmp_path / "win.txt"
    body = lines([T * 1000, U * 1000, Y], ["%.3f", "%.3f", "%.6f"], "\t", decimal=",")
    p.write_bytes(("Zeit (ms)\tSpannung (mV)\tWeg [µm]\r\n" + "\r\n".join(body) + "\r\n").encode("cp1252"))
    ds = ph.load_dataset(p)
    same(ds, ref)
    assert ds.meta["encoding"] == "cp1252"
    assert ds.meta["units"]["t"]["factor"] == 0.001 and ds.meta["units"]["u"]["unit"] == "mV"


def test_latin1_bytes_that_cp1252_cannot_decode(tmp_path, ref):
    p = tmp_path / "latin.csv"
    body = lines([T, U, Y], ["%.3f", "%.6f", "%.6f"], ",")
    # 0x81 is undefined in cp1252; a latin-1 export of a comment may hold it
    p.write_bytes(b"# Pr\xfcfstand \x81\n" + b"t_s,u_V,y_um\n" + "\n".join(body).encode("ascii") + b"\n")
    ds = ph.load_dataset(p)
    same(ds, ref)
    assert ds.meta["encoding"] == "latin-1"


@pytest.mark.parametrize("codec, bom", [("utf-8", codecs.BOM_UTF8), ("utf-16-le", codecs.BOM_UTF16_LE),
                                        ("utf-16-be", codecs.BOM_UTF16_BE)])
def test_byte_order_marks(tmp_path, ref, codec, bom):
    p = tmp_path / "bom.csv"
    body = lines([T, U, Y], ["%.3f", "%.6f", "%.6f"], "\t")
    p.write_bytes(bom + ("time\tvoltage\tdisplacement\n" + "\n".join(body) + "\n").encode(codec))
    ds = ph.load_dataset(p)
    same(ds, ref)
    assert ds.meta["columns"] == {"t": "time", "u": "voltage", "y": "displacement"}


def test_pandas_to_csv_with_its_unnamed_index_column(tmp_path, ref):
    p = tmp_path / "frame.csv"
    pd.DataFrame({"t_s": T, "u_mV": U * 1000, "x_mm": Y / 1000}).to_csv(p)
    ds = ph.load_dataset(p)
    same(ds, ref)
    assert ds.meta["index_column_dropped"] is True
    # column numbers count the columns after the dropped index, as pandas' index_col=0 does
    same(ph.load_dataset(p, t_col=0, u_col=1, y_col=2), ref)


def test_units_after_a_dot_as_r_and_make_names_write_them(tmp_path, ref):
    """R's ``make.names`` (and so ``read.csv``) write "time s" as ``time.s``: a known unit after a
    dot is the column's unit; ``y.1`` (pandas' name for a second ``y``) stays a name."""
    p = tmp_path / "r.csv"
    pd.DataFrame({"time.ms": T * 1e3, "u.mV": U * 1e3, "x.nm": Y * 1e3, "y.1": Y}).to_csv(p, index=False)
    ds = ph.load_dataset(p, y_col="x.nm")
    same(ds, ref)
    assert ds.meta["columns"] == {"t": "time.ms", "u": "u.mV", "y": "x.nm"}


@pytest.mark.parametrize("header", ["t_s,u_V,y_V", "Time_s,Voltage_V,Position_mV", "time s,drive V,sensor V"])
def test_a_sensor_logged_in_volts_is_refused_and_read_with_its_sensitivity(tmp_path, ref, header):
    """A known unit after the name is a stated unit also when of the wrong kind: 'Position_mV'
    was read as um, 1000 times off (found by fuzzing). The message says how to read it: the
    sensor's sensitivity as a factor (a unit such as 'um' would read volts 1:1 as um)."""
    p = tmp_path / "s.csv"
    factor = 1e-3 if "mV" in header else 1.0  # 10 um per volt: the file holds y / 10 volts
    pd.DataFrame(dict(zip(header.split(","), [T, U, Y / 10.0 / factor]))).to_csv(p, index=False)
    with pytest.raises(DataError, match=r"a voltage, but it is read as the output displacement.*"
                                        r"units=\{'y': 10\.0\}"):
        ph.load_dataset(p)
    ds = ph.load_dataset(p, units={"y": 10.0 * factor})
    np.testing.assert_allclose(ds.y, Y, rtol=1e-12, atol=1e-12)


def test_units_given_are_refused_whatever_the_file_holds(tmp_path):
    p = tmp_path / "plain.csv"
    p.write_text("t,u,y\n0,0,0\n1,1,1\n")
    with pytest.raises(DataError, match="furlong"):
        ph.load_dataset(p, units={"y": "furlong"})
    with pytest.raises(DataError, match="a voltage, but it is read as the output displacement"):
        ph.load_dataset(p, units={"y": "mV"})
    with pytest.raises(ValueError, match="furlong"):
        ph.fleet.FitOptions(units={"y": "furlong"})
    assert ph.fleet.FitOptions(units={"y": 10.0}).data_options()["units"] == {"y": 10.0}


@pytest.mark.parametrize("header, role, pick", [
    ("Time,U,X,T", "time", {"t_col": "Time"}),  # T, a temperature, was taken for the time (dt 0.01 s)
    ("Time [s],Command,Drive Voltage [V],Position [um]", "input voltage", {"u_col": "Drive Voltage [V]"}),
])
def test_columns_named_by_two_aliases_of_one_role_are_refused_until_one_is_named(tmp_path, ref, header, role, pick):
    """The first alias in the list used to win silently (found by fuzzing)."""
    p = tmp_path / "two.csv"
    cols = header.split(",")
    values = {"Time": T, "U": U, "X": Y, "T": 25.0 + 0.01 * np.arange(T.size), "Time [s]": T, "Command": 1.01 * Y,
              "Drive Voltage [V]": U, "Position [um]": Y}
    pd.DataFrame({c: values[c] for c in cols}).to_csv(p, index=False)
    with pytest.raises(DataError, match=f"several columns could be the {role}"):
        ph.load_dataset(p)
    same(ph.load_dataset(p, **pick), ref)


def test_comment_lines_anywhere_and_blank_lines(tmp_path, ref):
    p = tmp_path / "c.csv"
    body = lines([T, U, Y], ["%.3f", "%.6f", "%.6f"], ",")
    body.insert(10, "# operator paused the logger here")
    body.insert(20, "")
    p.write_text("# run 7\n# stage B\nt,u,y\n" + "\n".join(body) + "\n")
    same(ph.load_dataset(p), ref)


def test_headerless_whitespace_columns_by_index_with_a_sample_rate(tmp_path, ref):
    p = tmp_path / "raw.dat"
    body = lines([U, np.zeros(N), Y], ["%14.6e", "%14.6e", "%14.6e"], "  ")  # MATLAB save -ascii style
    p.write_text("\n".join(body) + "\n")
    same(ph.load_dataset(p, u_col=0, y_col=2, fs=1000), ref)
    same(ph.load_dataset(p, u_col="0", y_col="2", fs=1000.0), ref)  # the CLI passes strings too


def test_units_on_their_own_line_under_the_header(tmp_path, ref):
    p = tmp_path / "units.csv"
    body = lines([T * 1e6, U / 1000, Y / 1e6], ["%.1f", "%.9f", "%.12f"], ";")
    p.write_text("Time;Voltage;Position\nus;kV;m\n" + "\n".join(body) + "\n")
    ds = ph.load_dataset(p)
    same(ds, ref)
    assert ds.meta["units"]["y"]["unit"] == "m" and ds.meta["units"]["y"]["factor"] == 1e6


def test_preamble_before_the_table_and_a_trailing_delimiter(tmp_path, ref):
    # LabVIEW-measurement-like: key/value lines, an end-of-header mark, then the table
    p = tmp_path / "run.lvm"
    body = [ln + "\t" for ln in lines([T, U, Y], ["%.6f", "%.6f", "%.6f"], "\t")]
    p.write_text("LabVIEW Measurement\t\nWriter_Version\t2\nSeparator\tTab\n***End_of_Header***\t\n"
                 "X_Value\tVoltage\tDisplacement\tComment\n" + "\n".join(body) + "\n")
    ds = ph.load_dataset(p)
    same(ds, ref)
    assert ds.meta["format"] == "lvm" and ds.meta["columns"]["t"] == "X_Value"


def test_columns_by_name_or_index_among_extra_columns(tmp_path, ref):
    p = tmp_path / "wide.csv"
    other = np.arange(N, dtype=float)
    body = lines([other, T, U, other, Y], ["%.0f", "%.3f", "%.6f", "%.0f", "%.6f"], ",")
    p.write_text("sample,Time (s),Drive [V],temperature,Sensor A [um]\n" + "\n".join(body) + "\n")
    same(ph.load_dataset(p, t_col="time", u_col="Drive", y_col=4), ref)
    same(ph.load_dataset(p, t_col="Time (s)", u_col="drive [v]", y_col="Sensor A"), ref)
    with pytest.raises(DataError, match=r"unknown column 'force'.*the columns are \['sample', 'Time \(s\)'"):
        ph.load_dataset(p, u_col="force", y_col=4)
    with pytest.raises(DataError, match=r"column 9 does not exist"):
        ph.load_dataset(p, u_col=9, y_col=4)


# ---- MATLAB, NumPy, HDF5 -----------------------------------------------------------------------
def _write_mat(path, variables, v73):
    if v73:
        savemat73(path, variables)
    else:
        sio.savemat(path, variables)


@pytest.mark.parametrize("v73", [False, True], ids=["v5", "v7.3"])
def test_mat_plain_variables(tmp_path, ref, v73):
    p = tmp_path / "plain.mat"
    _write_mat(p, {"t": T[:, None], "u": U, "y": Y[:, None], "note": "bench 3"}, v73)
    ds = ph.load_dataset(p)
    same(ds, ref)
    assert ds.meta["format"] == ("mat-v7.3" if v73 else "mat-v5")


@pytest.mark.parametrize("v73", [False, True], ids=["v5", "v7.3"])
def test_mat_simulink_structure_with_time(tmp_path, ref, v73):
    p = tmp_path / "sim.mat"
    _write_mat(p, {"logsout": simulink_structure_with_time(T, [("Vin", U), ("x [nm]", Y * 1000)], v73=v73)}, v73)
    by_path = ph.load_dataset(p, u_col="logsout.signals[0].values", y_col="logsout.signals(2).values")
    same(by_path, ref)  # time comes with the struct; the label's unit converts y
    assert by_path.meta["columns"]["t"] == "logsout.time"
    same(ph.load_dataset(p), ref)  # labels "Vin" and "x [nm]" are found by name


@pytest.mark.parametrize("v73", [False, True], ids=["v5", "v7.3"])
def test_mat_one_simulink_structure_per_signal(tmp_path, ref, v73):
    # To Workspace blocks named u and y, each "Structure With Time"
    p = tmp_path / "tw.mat"
    _write_mat(p, {"u": simulink_structure_with_time(T, [("", U)], v73=v73),
                   "y": simulink_structure_with_time(T, [("", Y)], v73=v73)}, v73)
    same(ph.load_dataset(p), ref)
    same(ph.load_dataset(p, u_col="u", y_col="y.signals.values"), ref)


@pytest.mark.parametrize("v73", [False, True], ids=["v5", "v7.3"])
def test_mat_dspace_controldesk_recording(tmp_path, ref, v73):
    p = tmp_path / "rec.mat"
    rec = dspace(T, [("Model Root/amp/Out1", U * 1000, "mV"), ("Model Root/sensor/Displacement", Y * 1000, "nm"),
                     ("Model Root/sensor/temperature", np.full(N, 21.0), "degC")], v73=v73)
    _write_mat(p, {"rec_0007": rec}, v73)
    ds = ph.load_dataset(p, u_col="rec_0007.Y(1).Data")  # y found by its Name, t from X
    same(ds, ref)
    assert ds.meta["units"]["u"]["unit"] == "mV" and ds.meta["columns"]["t"].endswith("X.Data") \
        or ds.meta["columns"]["t"].endswith("X[0].Data")
    same(ph.load_dataset(p, u_col="Out1", y_col="Model Root/sensor/Displacement"), ref)


@pytest.mark.parametrize("v73", [False, True], ids=["v5", "v7.3"])
def test_one_matrix_columns_by_index_or_slice(tmp_path, ref, v73):
    p = tmp_path / "m.mat"
    _write_mat(p, {"data": np.column_stack([T, U, Y])}, v73)
    same(ph.load_dataset(p, t_col=0, u_col=1, y_col=2), ref)
    same(ph.load_dataset(p, t_col="data(:, 1)", u_col="data[:, 1]", y_col="data[:,2]"), ref)


def test_npz_from_save_dataset_and_by_hand(tmp_path, ref):
    p = ph.save_dataset(tmp_path / "d.npz", ref)
    back = ph.load_dataset(p)
    assert back.sha256 == ref.sha256 and back.meta["note"] == "reference"
    q = tmp_path / "hand.npz"
    np.savez(q, time=T, drive_voltage=U, y_nm=Y * 1000)
    same(ph.load_dataset(q), ref)


def test_npy_matrix(tmp_path, ref):
    p = tmp_path / "rows.npy"
    np.save(p, np.column_stack([T, U, Y]))
    same(ph.load_dataset(p, t_col=0, u_col=1, y_col=2), ref)


def test_plain_hdf5_groups(tmp_path, ref):
    import h5py

    p = tmp_path / "run.h5"
    with h5py.File(p, "w") as f:
        g = f.create_group("run1")
        g["time"], g["voltage"], g["position_um"] = T, U, Y
        g["voltage"].attrs["unit"] = "V"
    same(ph.load_dataset(p), ref)
    same(ph.load_dataset(p, t_col="run1/time", u_col="run1/voltage", y_col="run1.position_um"), ref)


@pytest.mark.skipif(importlib.util.find_spec("pyarrow") is None, reason="pyarrow not installed")
def test_parquet(tmp_path, ref):
    p = tmp_path / "d.parquet"
    pd.DataFrame({"Time [ms]": T * 1000, "Voltage [V]": U, "Displacement [nm]": Y * 1000}).to_parquet(p)
    same(ph.load_dataset(p), ref)


@pytest.mark.skipif(importlib.util.find_spec("openpyxl") is None, reason="openpyxl not installed")
def test_xlsx_with_a_units_row(tmp_path, ref):
    p = tmp_path / "d.xlsx"
    df = pd.DataFrame({"Time": ["s"] + list(T), "Voltage": ["V"] + list(U), "Displacement": ["mm"] + list(Y / 1000)})
    df.to_excel(p, index=False)
    ds = ph.load_dataset(p)
    same(ds, ref)
    assert ds.meta["units"]["y"]["unit"] == "mm"


# ---- DataFrames ----------------------------------------------------------------------------------
def test_from_dataframe_and_back(ref):
    df = pd.DataFrame({"Time [ms]": T * 1000, "Voltage (mV)": U * 1000, "Displacement [nm]": Y * 1000})
    same(ph.Dataset.from_dataframe(df), ref)
    same(ph.Dataset.from_dataframe(df, t_col="Time [ms]", u_col=1, y_col="Displacement"), ref)
    out = ref.to_dataframe()
    assert list(out.columns) == ["t", "u", "y"] and out.attrs["units"] == {"t": "s", "u": "V", "y": "um"}
    back = ph.Dataset.from_dataframe(out)
    assert back.sha256 == ref.sha256
    # units in attrs are honoured: the same numbers declared in nm become µm / 1000
    out.attrs["units"] = {"t": "s", "u": "V", "y": "nm"}
    np.testing.assert_allclose(ph.Dataset.from_dataframe(out).y, ref.y / 1000, rtol=1e-15)


def test_from_dataframe_uses_a_time_index():
    df = pd.DataFrame({"u": U, "y": Y}, index=pd.to_timedelta(T, unit="s"))
    ds = ph.Dataset.from_dataframe(df)
    np.testing.assert_allclose(ds.t, T, atol=1e-12)
    df2 = pd.DataFrame({"u": U, "y": Y}, index=pd.Index(T, name="time"))
    np.testing.assert_array_equal(ph.Dataset.from_dataframe(df2).t, T)
    with pytest.raises(DataError, match=r"DataFrame: no time column; give the sample rate \(fs= in Python, --fs"):
        ph.Dataset.from_dataframe(pd.DataFrame({"u": U, "y": Y}))
    np.testing.assert_allclose(ph.Dataset.from_dataframe(pd.DataFrame({"u": U, "y": Y}), fs=1000).t, T, atol=1e-15)


def test_from_dataframe_refusals():
    with pytest.raises(DataError, match=r"row 3 \(index 3\), column 'y' holds 'nan'"):
        ph.Dataset.from_dataframe(pd.DataFrame({"t": T, "u": U, "y": np.where(np.arange(N) == 3, np.nan, Y)}))
    with pytest.raises(DataError, match=r"row 2 .*column 'u' holds 'oops', not a number"):
        ph.Dataset.from_dataframe(pd.DataFrame({"t": T, "u": [0.0, 1.0, "oops"] + list(U[3:]), "y": Y}))
    with pytest.raises(DataError, match="expected a pandas DataFrame"):
        ph.Dataset.from_dataframe({"t": T})


# ---- what is refused (issue 13): no silent wrong results -----------------------------------------
@pytest.mark.parametrize("shape", [(N, 2), (2, N)])
@pytest.mark.parametrize("kind", ["npz", "v5", "v7.3"])
def test_a_matrix_is_never_flattened(tmp_path, kind, shape):
    m = np.arange(2 * N, dtype=float).reshape(shape)
    p = tmp_path / ("d.npz" if kind == "npz" else "d.mat")
    if kind == "npz":
        np.savez(p, u=m, y=Y)
    else:
        _write_mat(p, {"u": m, "y": Y}, kind == "v7.3")
    with pytest.raises(DataError, match=rf"d\.(npz|mat): 'u' has shape {shape[0]}x{shape[1]}: it holds 2 signals, "
                                        r"not one, and is not flattened; pick one, e.g. 'u\["):
        ph.load_dataset(p, fs=1000)


@pytest.mark.parametrize("shape", [(1, N), (N, 1), (N,)])
def test_row_and_column_vectors_are_signals(tmp_path, ref, shape):
    p = tmp_path / "v.npz"
    np.savez(p, t=T.reshape(shape), u=U.reshape(shape), y=Y.reshape(shape))
    same(ph.load_dataset(p), ref)


def test_non_uniform_time_is_refused_or_resampled(tmp_path):
    t = np.arange(N) * 1e-3
    t[25:] += 2e-3  # two samples lost
    p = tmp_path / "gap.csv"
    ph.save_dataset(p, ph.Dataset(t, U, Y))
    # two comment lines and the header: sample 25 is on line 29
    with pytest.raises(DataError, match=r"gap\.csv: the time column 't_s' is not uniformly sampled: the step to "
                                        r"line 29 is 0\.003 s against a median step of 0\.001 s \(200 % off; 1 % "
                                        r"allowed\); resample it .*resample=True in Python, --resample"):
        ph.load_dataset(p)
    ds = ph.load_dataset(p, resample=True)
    assert len(ds) == N + 2 and ds.is_uniform
    assert ds.meta["resampled"]["samples_before"] == N and ds.meta["resampled"]["largest_step_deviation"] == pytest.approx(2)
    np.testing.assert_allclose(ds.u[:25], U[:25], atol=1e-12)  # untouched before the gap
    # jitter within 1 % of the step is a uniform record
    jitter = np.arange(N) * 1e-3 + np.where(np.arange(N) % 2, 4e-6, 0.0)
    q = tmp_path / "jitter.csv"
    ph.save_dataset(q, ph.Dataset(jitter, U, Y))
    assert "resampled" not in ph.load_dataset(q).meta


def test_sample_rate_that_disagrees_with_the_time_column(tmp_path, ref):
    p = tmp_path / "t.csv"
    ph.save_dataset(p, ref)
    with pytest.raises(DataError, match=r"the sample rate 2000 Hz disagrees with the time column 't_s' "
                                        r"\(1 / median step = 1000 Hz\).*--fs"):
        ph.load_dataset(p, fs=2000)
    same(ph.load_dataset(p, fs=1000), ref)


@pytest.mark.parametrize(
    "content, match",
    [
        ("", r"the file is empty"),
        ("# only a comment\n\n", r"no data \(the file is empty or holds only comments\)"),
        ("t,u,y\n", r"only one line \('t,u,y'\) and no data rows"),
        ("t,u,y\n0,1,2\n", r"needs at least 2 samples, found 1"),
        ("t,u,y\n0,1,2\n0.1,2\n0.2,3,4\n0.3,4,5\n", r"line 3 has 2 fields, expected 3"),
        ("t,u,y\n0,1,2\n0.1,2,3,9\n0.2,3,4\n0.3,4,5\n", r"line 3 has 4 fields, expected 3"),
        ("t,u,y\n0,1,2\n0.1,abc,3\n0.2,3,4\n0.3,4,5\n", r"line 3, column 'u': 'abc' is not a number"),
        ("t,u,y\n0,1,2\n0.1,2,3\n0.2,nan,4\n", r"line 4, column 'u' reads 'nan', not a finite number"),
        ("t,u,y\n0,1,2\n0.1,2,3\n0.2,3,inf\n", r"line 4, column 'y' reads 'inf', not a finite number"),
        ("t,u,y\n0,1,2\n0.1,,3\n0.2,3,4\n", r"line 3, column 'u' is empty"),
        ("t,u,y\n0,1,2\n0.1,2,3\n0.1,3,4\n", r"time must increase from sample to sample, but at line 4"),
        ("t,u,y [V]\n0,1,2\n0.1,2,3\n", r"'y \[V\]' is in V, a voltage, but it is read as the output displacement"),
        ("t,u [inch],y\n0,1,2\n0.1,2,3\n", r"the unit 'inch' of 'u \[inch\]'.* is not one piezohyst knows"),
        ("a,b,c\n0,1,2\n0.1,2,3\n", (r"cannot tell which column is the input voltage u; name it \(u_col= in Python, "
                                     r"--u-col at the command line\); the columns are \['a', 'b', 'c'\]")),
        ("0 1 2\n1 2 3\n", r"cannot tell which column is the input voltage u.*no header line"),
        # u and v are both names of the voltage: refused as two of one name are (u won by coming
        # first in the alias list; so did a temperature 'T' over 'Time': found by fuzzing)
        ("t,v,x,u\n0,1,2,3\n0.1,2,3,4\n", r"several columns could be the input voltage u \('u', 'v'\)"),
        # found by fuzzing: column classes voted from rows that each break one of them
        ("t,t,t,t,t\n0.0,0.0,0.0,\u221e,0.0\n0.0,0.0,0.0,0.0,\u221e", r"no table of numbers found in the first 3 lines"),
    ],
)
def test_malformed_text_one_line_naming_the_file(tmp_path, content, match):
    p = tmp_path / "bad.csv"
    p.write_text(content)
    if match is None:
        assert ph.load_dataset(p).meta["columns"]["u"] == "u"
        return
    with pytest.raises(DataError, match=match) as exc:
        ph.load_dataset(p)
    msg = str(exc.value)
    assert msg.startswith(f"{p}: ") and "\n" not in msg


def test_nan_in_a_mat_file_names_the_variable_and_sample(tmp_path):
    p = tmp_path / "nan.mat"
    y = Y.copy()
    y[7] = np.inf
    sio.savemat(p, {"u": U, "y": y})
    with pytest.raises(DataError, match=r"nan\.mat: sample 7 of 'y' is inf, not a finite number"):
        ph.load_dataset(p, fs=1000)


def test_declared_units_override_the_file(tmp_path, ref):
    p = tmp_path / "v.csv"
    body = lines([T, U, Y / 10], ["%.3f", "%.6f", "%.7f"], ",")
    p.write_text("t,u,y [V]\n" + "\n".join(body) + "\n")  # a sensor at 10 µm per volt
    same(ph.load_dataset(p, units={"y": 10.0}), ref)
    with pytest.raises(DataError, match="units keys must be 't', 'u' or 'y'"):
        ph.load_dataset(p, units={"x": "nm"})


def test_too_large_for_the_memory_limit(tmp_path, monkeypatch, ref):
    p = tmp_path / "big.csv"
    ph.save_dataset(p, ref)
    with pytest.raises(DataError, match=r"big\.csv: reading 3 columns of about \d+ rows needs about .* of memory, "
                                        r"over the limit of 1000 bytes; raise it with max_memory= in Python or the "
                                        r"PIEZOHYST_MAX_MEMORY environment variable"):
        ph.load_dataset(p, max_memory=1000)
    monkeypatch.setenv("PIEZOHYST_MAX_MEMORY", "1K")
    with pytest.raises(DataError, match="over the limit of 1 KiB"):
        ph.load_dataset(p)
    q = tmp_path / "big.npz"
    np.savez(q, u=U, y=Y)
    with pytest.raises(DataError, match=r"big\.npz: reading 2 arrays of up to 40 values needs about"):
        ph.load_dataset(q, fs=1)
    monkeypatch.setenv("PIEZOHYST_MAX_MEMORY", "lots")
    with pytest.raises(DataError, match="PIEZOHYST_MAX_MEMORY must be a size in bytes"):
        ph.load_dataset(p)


def _sparse(path, size):
    try:
        os.truncate(path, size)
    except OSError:  # pragma: no cover - a file system without sparse files
        pytest.skip("cannot make a sparse file here")


def test_a_terabyte_file_is_refused_before_reading_it(tmp_path):
    # a real (sparse) 1 TiB file, default limit: refused from its size, in well under a second
    p = tmp_path / "huge.csv"
    p.write_text("t,u,y\n" + "".join(f"{i * 1e-3:.6f},{np.sin(i):.6f},{np.cos(i):.6f}\n" for i in range(3000)))
    _sparse(p, 1 << 40)
    with pytest.raises(DataError, match=r"huge\.csv: reading 3 columns of about [\d,]+ rows needs about [\d.]+ TiB "
                                        r"of memory, over the limit of"):
        ph.load_dataset(p)
    q = tmp_path / "huge.npy"
    with open(q, "wb") as fh:
        np.lib.format.write_array_header_1_0(fh, {"descr": "<f8", "fortran_order": False, "shape": (10**11, 3)})
    _sparse(q, 24 * 10**11 + 128)
    with pytest.raises(DataError, match=r"huge\.npy: reading 1 array of up to 300,000,000,000 values needs about"):
        ph.load_dataset(q, t_col=0, u_col=1, y_col=2)


def test_a_resampled_gap_is_also_size_checked(tmp_path):
    p = tmp_path / "gap.csv"
    ph.save_dataset(p, ph.Dataset(np.r_[0.0, 1e-3, 2e-3, 1e6], [0.0, 1, 2, 3], [0.0, 1, 2, 3]))
    # refused before anything is allocated: once by the size check ("resampling to 1000000001
    # samples needs about ..."), now already as a pause no resampling should bridge
    with pytest.raises(DataError, match=r"gap of 1e\+06 s .* resampling would invent"):
        ph.load_dataset(p, resample=True, max_memory="1G")


@pytest.mark.parametrize(
    "payload, name, match",
    [
        (b"TDSm\x00\x00\x00\x00" + bytes(64), "run.tdms", r"a LabVIEW TDMS file"),
        (bytes(range(256)) * 8, "blob.bin", r"not a text file \(it contains NUL bytes\) nor another format piezohyst reads"),
        (None, "notes.zip", r"a zip archive that is neither \.npz nor a spreadsheet"),
        (b"PK\x03\x04garbage", "broken.npz", r"a damaged zip archive"),
    ],
)
def test_unsupported_formats_list_the_supported_ones(tmp_path, payload, name, match):
    import zipfile

    p = tmp_path / name
    if payload is None:
        with zipfile.ZipFile(p, "w") as z:
            z.writestr("readme.txt", "hello")
    else:
        p.write_bytes(payload)
    with pytest.raises(DataError, match=match) as exc:
        ph.load_dataset(p)
    assert "supported formats: text tables" in str(exc.value) and "MATLAB .mat (v4, v5, v7 and v7.3)" in str(exc.value)


def test_objects_are_never_unpickled(tmp_path):
    p = tmp_path / "evil.npy"
    np.save(p, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(DataError, match="evil.npy: holds Python objects, which are never loaded"):
        ph.load_dataset(p, u_col=0, y_col=0)
    q = tmp_path / "evil.npz"
    np.savez(q, u=np.array([object(), object()], dtype=object), y=Y)
    with pytest.raises(DataError, match=r"evil\.npz: 'u' \(the input voltage u\) is Python objects, which are never"):
        ph.load_dataset(q, fs=1)


def test_a_damaged_mat_file_is_refused_not_crashed(tmp_path, ref):
    # Found by fuzzing: one byte set to 220 in a variable's data-type tag made scipy's compiled
    # v5 reader crash the interpreter (segmentation fault). The file is now checked first.
    p = tmp_path / "ok.mat"
    sio.savemat(p, {"t": T, "u": U, "y": Y})
    same(ph.load_dataset(p), ref)
    data = bytearray(p.read_bytes())
    # header 128 bytes; variable t: miMATRIX tag (8), flags (16), dims (16), name "t" (8): data tag at 176
    assert data[176] == 9  # miDOUBLE
    data[176] = 220
    q = tmp_path / "damaged.mat"
    q.write_bytes(bytes(data))
    with pytest.raises(DataError, match=r"damaged\.mat: a damaged MATLAB file \(unknown element type 220"):
        ph.load_dataset(q)
    q.write_bytes(p.read_bytes()[:300])
    with pytest.raises(DataError, match=r"damaged\.mat: a damaged MATLAB file \(the variable at byte \d+ runs past"):
        ph.load_dataset(q)
    # Found by fuzzing in CI: the text header damaged ("\x97ATLA\x80 5.0"), so our sniffing took it
    # for v4, but scipy goes by the endian mark and sent it to the v5 reader unchecked; a flags
    # word claiming a complex array with no imaginary part then crashed it.
    data = bytearray(p.read_bytes())
    data[0], data[5] = 0x97, 0x80
    assert data[144:148] == bytes([6, 0, 0, 0])  # t's array flags: class double, no flag bits
    data[145] = 0xDA  # complex, logical, global
    q.write_bytes(bytes(data))
    with pytest.raises(DataError, match=r"damaged\.mat: a damaged MATLAB file \(the complex array at byte 128"):
        ph.load_dataset(q)


def test_matlab_v4_and_ascii_mat_files(tmp_path, ref):
    p = tmp_path / "v4.mat"
    sio.savemat(p, {"t": T, "u": U, "y": Y}, format="4")
    ds = ph.load_dataset(p)
    same(ds, ref)
    assert ds.meta["format"] == "mat-v4"
    q = tmp_path / "ascii.mat"  # MATLAB's save -ascii: a text table under a .mat name
    np.savetxt(q, np.column_stack([T, U, Y]), fmt="%.15e")
    same(ph.load_dataset(q, t_col=0, u_col=1, y_col=2), ref)


def test_paths_into_structs_that_do_not_exist(tmp_path):
    p = tmp_path / "s.mat"
    sio.savemat(p, {"log": {"signals": v5_struct_array([{"values": U[:, None]}, {"values": Y[:, None]}]),
                            "time": T[:, None]}})
    with pytest.raises(DataError, match=r"index 5 is out of range in 'log.signals', which has 2 elements"):
        ph.load_dataset(p, u_col="log.signals[5].values", y_col="log.signals[1].values")
    with pytest.raises(DataError, match=r"no variable or signal 'log.sig' .*the file holds log.signals\[0\].values"):
        ph.load_dataset(p, u_col="log.sig", y_col="log.signals[1].values")
    with pytest.raises(DataError, match=r"a column number \(0\) picks from the one matrix in a file"):
        ph.load_dataset(p, u_col=0, y_col=1)


def test_missing_file_and_directory():
    with pytest.raises(DataError, match="no such file"):
        ph.load_dataset("/nonexistent/file.csv")
    with pytest.raises(DataError, match="is a directory"):
        ph.load_dataset(Path(__file__).parent)
    with pytest.raises(DataError, match="a data file is given by its path"):
        ph.load_dataset(12)


# ---- read_table (the command line's reference loader reads through it) ---------------------------
def test_read_table(tmp_path):
    p = tmp_path / "ref.csv"
    p.write_text("# desired path\ntime [s];x [um]\n0,0;1,5\n0,1;2,5\n")
    names, arr, header = read_table(p)
    assert names == ["time [s]", "x [um]"] and header and arr.tolist() == [[0.0, 1.5], [0.1, 2.5]]
    q = tmp_path / "one.txt"
    q.write_text("1.0\n2.0\n3.0\n")
    names, arr, header = read_table(q)
    assert names == ["0"] and not header and arr.shape == (3, 1)
    with pytest.raises(DataError, match=r"line 3, column '0': 'x' is not a number"):
        q.write_text("1.0\n2.0\nx\n4.0\n")
        read_table(q)


# ---- the bundled data sets -----------------------------------------------------------------------
def test_bundled_data_through_importlib_resources(monkeypatch):
    from importlib.resources import files

    monkeypatch.delenv("PIEZOHYST_DATA", raising=False)
    res = files("piezohyst") / "datasets" / "piezo-dbo" / "Model_Vi_Do.dat"
    assert res.is_file() and Path(str(res)).resolve() == (data_dir() / "piezo-dbo" / "Model_Vi_Do.dat").resolve()
    root = Path(__file__).resolve().parents[1]
    # the repository paths the documented commands use still work (data/ links to the package's)
    for rel in ("data/piezo-dbo/Model_Vi_Do.dat", "data/bouc-wen-benchmark/bouc-wen.mat"):
        assert (root / rel).is_file()
    assert ph.load_piezo_dbo().sha256 == ph.load_dataset(root / "data/piezo-dbo/Model_Vi_Do.dat",
                                                         u_col=0, y_col=4, fs=200).sha256


def test_data_dir_honours_the_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("PIEZOHYST_DATA", str(tmp_path))
    assert data_dir() == tmp_path
    with pytest.raises(DataError, match="the bundled data set is missing"):
        ph.load_piezo_dbo()


def test_every_bundled_file_is_package_data():
    root = Path(__file__).resolve().parents[1]
    conf = tomllib.loads((root / "pyproject.toml").read_text())
    patterns = conf["tool"]["setuptools"]["package-data"]["piezohyst.datasets"]
    base = root / "src" / "piezohyst" / "datasets"
    shipped = {p for pat in patterns for p in base.glob(pat) if p.is_file()}
    present = {p for p in base.rglob("*") if p.is_file()}
    assert present and shipped == present, sorted(str(p.relative_to(base)) for p in present - shipped)


def test_meta_is_json_ready(tmp_path, ref):
    p = tmp_path / "m.csv"
    ph.save_dataset(p, ref)
    ds = ph.load_dataset(p)
    json.dumps(ds.meta)
    assert ds.meta["source"] == str(p) and len(ds.meta["source_sha256"]) == 64
    assert os.fspath(p) in ds.meta["source"]


# ---- tables of several records (``piezohyst rig``: one (t, u, y) triple per frequency) ---------
def _triples(tmp_path, records):
    """A CSV with ``t_<tag>_s, u_<tag>_V, y_<tag>_um`` per record, shorter records padded with nan."""
    n = max(k for _, k in records)
    names, cols = [], []
    for tag, k in records:
        names += [f"t_{tag}_s", f"u_{tag}_V", f"y_{tag}_um"]
        pad = np.full(n - k, np.nan)
        cols += [np.concatenate([T[:k], pad]), np.concatenate([U[:k], pad]), np.concatenate([Y[:k], pad])]
    p = tmp_path / "loops.csv"
    p.write_text(",".join(names) + "\n" + "\n".join(lines(cols, ["%.10g"] * len(cols), ",")) + "\n")
    return p


def test_a_table_of_one_record_per_tag_names_its_columns_itself(tmp_path):
    ds = ph.load_dataset(_triples(tmp_path, [("1Hz", N)]))
    np.testing.assert_allclose(ds.u, U)
    np.testing.assert_allclose(ds.y, Y)
    np.testing.assert_allclose(ds.t, T)


def test_a_table_of_several_records_asks_which_and_takes_that_records_time(tmp_path):
    p = _triples(tmp_path, [("1Hz", N), ("5Hz", 25)])
    with pytest.raises(DataError, match=r"holds 2 records \(1hz, 5hz\).*'u_1Hz_V', 'u_5Hz_V'"):
        ph.load_dataset(p)
    ds = ph.load_dataset(p, u_col="u_5Hz_V", y_col="y_5Hz_um")  # its time column, its 25 rows
    assert len(ds) == 25 and ds.meta["empty_rows_dropped_at_the_end"] == N - 25
    np.testing.assert_allclose(ds.t, T[:25])
    np.testing.assert_allclose(ds.y, Y[:25])


def test_an_empty_cell_in_only_one_column_is_still_an_error(tmp_path):
    p = tmp_path / "gap.csv"
    rows = ["t,u,y"] + [f"{T[i]},{U[i]},{Y[i]}" for i in range(10)] + [f"{T[10]},{U[10]},nan"]
    p.write_text("\n".join(rows) + "\n")
    with pytest.raises(DataError, match=r"line 12, column 'y' reads 'nan'"):
        ph.load_dataset(p)


@pytest.mark.parametrize("spare", ["index", "text"])
def test_large_file_with_one_spare_column_reads_the_same(tmp_path, spare):
    """A file large enough for pandas' threaded reader (>= 5 MB) with one column more than t, u, y:
    a numeric index is read along (pandas reads all columns in parallel, but only when not told
    ``usecols``); a text column makes that read fail and the wanted columns are read alone. Both
    give exactly the numbers written."""
    n = 300_000
    rng = np.random.default_rng(3)
    t = np.arange(n) * 1e-4
    u = np.round(rng.uniform(0, 100, n), 6)
    y = np.round(rng.normal(0, 10, n), 6)
    frame = pd.DataFrame({"t": t, "u": u, "y": y})
    if spare == "text":
        frame.insert(0, "status", np.where(rng.uniform(size=n) < 0.5, "ok", "hold"))
    p = tmp_path / "big.csv"
    frame.to_csv(p, index=spare == "index", float_format="%.10g")
    assert p.stat().st_size >= 5 * 1024 * 1024
    ds = ph.load_dataset(p, t_col="t", u_col="u", y_col="y")
    np.testing.assert_array_equal(ds.u, u)
    np.testing.assert_array_equal(ds.y, y)
    np.testing.assert_allclose(ds.t, t, rtol=0, atol=1e-12)


def test_resampling_refuses_to_bridge_a_pause_in_the_recording(tmp_path):
    # found by fuzzing: a 60 s pause in a 4 s record became 60,000 interpolated samples, and
    # identify scored its hold-out on that invented ramp
    t = np.arange(4000) * 1e-3
    t[2000:] += 60.0
    u = np.sin(np.arange(4000) * 0.01)
    p = tmp_path / "gap.csv"
    np.savetxt(p, np.column_stack([t, u, 0.5 * u]), delimiter=",", header="t,u,y", comments="")
    with pytest.raises(ph.DataError, match=r"gap of 60\.\d* s .* split the file"):
        ph.load_dataset(p, resample=True)
    t2 = np.arange(4000) * 1e-3
    t2[2000:] += 3e-3  # a few missed samples: resampled as before
    np.savetxt(p, np.column_stack([t2, u, 0.5 * u]), delimiter=",", header="t,u,y", comments="")
    assert ph.load_dataset(p, resample=True).meta["resampled"]["samples_after"] == 4003


def test_an_hdf5_datasets_units_attribute_is_used(tmp_path):
    # found by fuzzing: y in nm and t in ms, said so by each dataset's "units" attribute, were read
    # as um and s ("no unit stated")
    h5py = pytest.importorskip("h5py")
    t = np.arange(2000) * 1e-3
    p = tmp_path / "stated.h5"
    with h5py.File(p, "w") as f:
        f["t"] = t * 1000.0
        f["u"] = 50.0 + 50.0 * np.sin(2 * np.pi * t)
        f["y"] = 2000.0 + 2000.0 * np.sin(2 * np.pi * t)
        f["t"].attrs["units"] = "ms"
        f["y"].attrs["units"] = "nm"
    ds = ph.load_dataset(p)
    assert ds.dt == pytest.approx(1e-3) and ds.y.max() == pytest.approx(4.0)
    assert ds.meta["units"]["y"]["unit"] == "nm"
    with h5py.File(p, "a") as f:
        f["u"].attrs["units"] = "furlongs"
    with pytest.raises(ph.DataError, match=r"'furlongs' of 'u'.*units=\{'u': 'V'\}"):
        ph.load_dataset(p)


def test_a_top_level_time_named_with_its_unit_in_brackets_is_found(tmp_path):
    # found by fuzzing: npz/HDF5 keys "Time [ms]", "Voltage [mV]", "Displacement [nm]" were refused
    # with "no time column" (a bracket in the key took it for a path into a struct)
    t = np.arange(2000) * 1e-3
    p = tmp_path / "bracketed.npz"
    np.savez(p, **{"Time [ms]": t * 1000.0, "Voltage [mV]": 5e4 + 5e4 * np.sin(2 * np.pi * t),
                   "Displacement [nm]": 2e3 + 2e3 * np.sin(2 * np.pi * t)})
    ds = ph.load_dataset(p)
    assert ds.dt == pytest.approx(1e-3) and ds.u.max() == pytest.approx(100.0) and ds.y.max() == pytest.approx(4.0)


def test_a_unit_spelt_mega_is_not_read_as_milli(tmp_path):
    # found by fuzzing: units were matched in any case, so "Mm" (megametres) was read as mm and "Ms"
    # as ms; all capitals ("MS", "MV", as loggers write headers) stay milli
    t = np.arange(200) * 1e-3
    p = tmp_path / "x.npz"
    np.savez(p, t=t, u=50 + 50 * np.sin(2 * np.pi * t), y=2 + 2 * np.sin(2 * np.pi * t))
    for units, wrong in (({"y": "Mm"}, "Mm"), ({"t": "Ms"}, "Ms")):
        with pytest.raises(ph.DataError, match=f"'{wrong}' .* reads as mega .* for milli write 'm{wrong[1]}'"):
            ph.load_dataset(p, units=units)
    assert ph.load_dataset(p, units={"u": "MV"}).u.max() == pytest.approx(1e-3 * float(np.max(50 + 50 * np.sin(2 * np.pi * t))))


@pytest.mark.parametrize("unit, factor", [("0.1 um", 0.1), ("x10 nm", 0.01), ("10^-6 m", 1.0)])
def test_a_scaled_unit_is_refused_with_its_factor_and_read_with_it(tmp_path, ref, unit, factor):
    """'Displacement [0.1 um]' was taken for a name without a unit, and its values for um (10 and
    100 times off when the column was named; found by fuzzing)."""
    p = tmp_path / "scaled.csv"
    pd.DataFrame({"Time [s]": T, "Voltage [V]": U, f"Displacement [{unit}]": Y / factor}).to_csv(p, index=False)
    for kw in ({}, {"y_col": 2}):
        with pytest.raises(DataError, match=rf"is a scaled unit.*units=\{{'y': {factor:g}\}}"):
            ph.load_dataset(p, **kw)
    same(ph.load_dataset(p, y_col=2, units={"y": factor}), ref)


_LVM_HEAD = """LabVIEW Measurement\t
Writer_Version\t2
Reader_Version\t2
Separator\tTab
Decimal_Separator\t,
Multi_Headings\tNo
X_Columns\tOne
Time_Pref\tRelative
Date\t2024/03/05
Time\t14:00:00,000
***End_of_Header***\t
\t
Channels\t2\t
Samples\t{n}\t{n}\t
Date\t2024/03/05\t2024/03/05\t
Time\t14:00:00,000\t14:00:00,000\t
Y_Unit_Label\tVolts\tmm\t
X_Dimension\tTime\tTime\t
X0\t0,0000000000000000E+0\t0,0000000000000000E+0\t
Delta_X\t{dt}\t{dt}\t
***End_of_Header***\t
X_Value\tVoltage\tDisplacement\tComment
"""


def _lvm_rows(t, u, y_mm, row_end="", x=True):
    return "".join(f"{a:.9e}\t{b:.12e}\t{c:.12e}{row_end}\n".replace(".", ",") if x else
                   f"\t{b:.12e}\t{c:.12e}{row_end}\n".replace(".", ",") for a, b, c in zip(t, u, y_mm))


def _lvm(n, dt, x_columns="One", x0=0.0):
    return (_LVM_HEAD.replace("X_Columns\tOne", f"X_Columns\t{x_columns}")
            .replace("X0\t0,0000000000000000E+0\t0,0000000000000000E+0", f"X0\t{x0:.6e}\t{x0:.6e}".replace(".", ","))
            .format(n=n, dt=f"{dt:.6f}".replace(".", ",")))


@pytest.mark.parametrize("row_end", ["", "\t"])
def test_labview_lvm_units_and_comment_column(tmp_path, ref, row_end):
    """LabVIEW states the units in its segment header (Y_Unit_Label) and names a Comment column
    its rows leave out (or end with a tab for): the mm were read as um, 1000 times off, and
    without the tab the columns could not be named (found by fuzzing)."""
    p = tmp_path / "run.lvm"
    dt = float(T[1] - T[0])
    p.write_text(_lvm(T.size, dt) + _lvm_rows(T, U, Y / 1000.0, row_end))
    ds = ph.load_dataset(p)
    assert ds.meta["columns"] == {"t": "X_Value", "u": "Voltage", "y": "Displacement"}
    assert ds.meta["units"]["y"]["unit"] == "mm" and ds.meta["format"] == "lvm"
    np.testing.assert_allclose(ds.y, Y, rtol=1e-9, atol=1e-9)
    same(ph.load_dataset(p, u_col="Voltage", y_col="Displacement"), ref)


def test_labview_lvm_without_x_values_and_with_segments(tmp_path, ref):
    """X_Columns No (no x values: the time is X0 + k Delta_X) found no table; a second segment
    was 'not a number' (found by fuzzing). Segments that continue in time are one record; one
    whose time restarts is refused with its line."""
    dt = float(T[1] - T[0])
    half = T.size // 2
    p = tmp_path / "nox.lvm"
    p.write_text(_lvm(T.size, dt, "No") + _lvm_rows(T, U, Y / 1000.0, x=False))
    ds = ph.load_dataset(p)
    np.testing.assert_allclose(ds.t, T - T[0], atol=1e-9)
    np.testing.assert_allclose(ds.y, Y, rtol=1e-9, atol=1e-9)
    body = _LVM_HEAD.split("***End_of_Header***\t\n\t\n", 1)[1]  # a segment header, as LabVIEW repeats it
    two = tmp_path / "two.lvm"
    two.write_text(_lvm(half, dt) + _lvm_rows(T[:half], U[:half], Y[:half] / 1000.0) + "\n"
                   + body.format(n=T.size - half, dt=f"{dt:.6f}".replace(".", ","))
                   + _lvm_rows(T[half:], U[half:], Y[half:] / 1000.0))
    ds = ph.load_dataset(two)
    assert ds.meta["lvm"]["segments"] == 2 and len(ds) == T.size
    np.testing.assert_allclose(ds.y, Y, rtol=1e-9, atol=1e-9)
    again = tmp_path / "restart.lvm"
    again.write_text(_lvm(half, dt) + _lvm_rows(T[:half], U[:half], Y[:half] / 1000.0) + "\n"
                     + body.format(n=half, dt=f"{dt:.6f}".replace(".", ","))
                     + _lvm_rows(T[:half], U[:half], Y[:half] / 1000.0))
    with pytest.raises(DataError, match=r"segment 2 \(rows from line \d+\) starts at t = 0 s.*separate records"):
        ph.load_dataset(again)


def test_a_header_written_as_a_comment_by_numpy_savetxt_and_one_with_a_trailing_delimiter(tmp_path, ref):
    """numpy.savetxt writes its header as '# ...': the file 'had no header line', and read by
    column number its nm were taken for um; a header line ending in a delimiter its rows do not
    have was refused the same way (found by fuzzing)."""
    p = tmp_path / "np.csv"
    np.savetxt(p, np.column_stack([T, U, Y * 1000.0]), delimiter=",", header="Time [s],Voltage [V],Displacement [nm]")
    ds = ph.load_dataset(p)
    assert ds.meta["columns"] == {"t": "Time [s]", "u": "Voltage [V]", "y": "Displacement [nm]"}
    same(ds, ref)
    q = tmp_path / "trailing.csv"
    q.write_text("Time [s],Voltage [V],Displacement [nm],\n"
                 + "".join(f"{a:.17g},{b:.17g},{c:.17g}\n" for a, b, c in zip(T, U, Y * 1000.0)))
    same(ph.load_dataset(q), ref)
    # a comment of numbers, or of one field, above headerless data is no header
    r = tmp_path / "nohead.csv"
    r.write_text("# 1,2,3\n" + "".join(f"{a:.17g},{b:.17g},{c:.17g}\n" for a, b, c in zip(T, U, Y)))
    with pytest.raises(DataError, match="no header line"):
        ph.load_dataset(r)


def test_clock_times_in_a_text_file_are_seconds_from_the_first_sample(tmp_path, ref):
    """A CSV's datetime column was "not a number" (a spreadsheet's or Parquet's were read), also
    with the sample rate given (found by fuzzing)."""
    when = pd.Timestamp("2024-03-05 14:00:00") + pd.to_timedelta(T - T[0], unit="s")
    p = tmp_path / "stamped.csv"
    p.write_text("Timestamp,Voltage [V],Displacement [um]\n" + "".join(
        f"{w.strftime('%Y-%m-%d %H:%M:%S.%f')},{b:.17g},{c:.17g}\n" for w, b, c in zip(when, U, Y)))
    ds = ph.load_dataset(p)
    assert ds.meta["clock_times"] == ["Timestamp"]
    np.testing.assert_allclose(ds.t, T - T[0], atol=1e-9)
    np.testing.assert_allclose(ds.u, U)
    q = tmp_path / "date_time.csv"  # a logger's date and clock time in columns of their own
    q.write_text("Date;Time;Voltage [V];Displacement [um]\n" + "".join(
        f"{w.strftime('%Y-%m-%d')};{w.strftime('%H:%M:%S.%f')};{b:.17g};{c:.17g}\n" for w, b, c in zip(when, U, Y)))
    np.testing.assert_allclose(ph.load_dataset(q).y, Y)
    lines = p.read_text().splitlines()
    lines[5] = "garbled" + lines[5][lines[5].index(","):]
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=r"line 6, 'garbled' in 'Timestamp' is not a clock time"):
        ph.load_dataset(p)


def test_a_units_row_in_brackets_under_the_header(tmp_path, ref):
    """'[s],[V],[mm]' under the header was taken for the header (found by fuzzing)."""
    p = tmp_path / "bracketed.csv"
    p.write_text("Time,Voltage,Displacement\n[s],[V],[mm]\n"
                 + "".join(f"{a:.17g},{b:.17g},{c:.17g}\n" for a, b, c in zip(T, U, Y / 1000.0)))
    ds = ph.load_dataset(p, u_col="Voltage")
    assert ds.meta["columns"] == {"t": "Time", "u": "Voltage", "y": "Displacement"}
    np.testing.assert_allclose(ds.y, Y, rtol=1e-12)


def test_a_single_precision_time_column(tmp_path):
    """float32 time at t ~ 1000 s with 1e-4 s steps: rounded to 6.1e-5 or 1.22e-4, 'not uniform',
    and resampled at that median step it lost 18 % of the record (found by fuzzing). A finer one
    was accepted with dt 0.14 % off (its first step)."""
    n = 20000

    def write(t0, step, drop=None):
        t = t0 + np.arange(n) * step
        if drop is not None:
            t = np.delete(t, drop)
        u = 50 + 50 * np.sin(2 * np.pi * 5 * (t - t0))
        p = tmp_path / f"f32_{t0}_{step}_{drop}.npz"
        np.savez(p, t=t.astype(np.float32), u=u, y=0.1 * u)
        return p

    for resample in (False, True):
        with pytest.raises(DataError, match=r"single-precision numbers, whose resolution .* is 6\.1e-05 s, 61 % of"):
            ph.load_dataset(write(1000.0, 1e-4), resample=resample)
    for t0, step in ((10.0, 1e-4), (1000.0, 1e-3)):
        ds = ph.load_dataset(write(t0, step))
        assert len(ds) == n and ds.dt == pytest.approx(step, rel=1e-5), (t0, step, ds.dt)
        assert ds.meta["time_single_precision"]["dt"] == pytest.approx(step, rel=1e-5)
    with pytest.raises(DataError, match="not uniformly sampled"):  # a dropped sample still shows
        ph.load_dataset(write(10.0, 1e-3, drop=n // 2))


def test_a_compressed_file_is_named_as_such(tmp_path):
    import gzip

    p = tmp_path / "run.csv.gz"
    p.write_bytes(gzip.compress(b"t,u,y\n0,1,2\n0.1,2,3\n"))
    with pytest.raises(DataError, match=r"run\.csv\.gz: a compressed file .* decompress it first"):
        ph.load_dataset(p)  # it was "not a text file (it contains NUL bytes)"


def test_a_decimal_comma_that_shows_only_after_the_first_rows(tmp_path):
    """250 rows of whole numbers, then '0,512': 'not a number' with no word of the decimal mark,
    and decimal=',' given alone then found no table at all (found by fuzzing)."""
    rows = ["voltage;y"] + ["0;0"] * 250 + [f"{0.5 + i / 100:.3f};{1 + i / 50:.3f}".replace(".", ",") for i in range(300)]
    p = tmp_path / "late.csv"
    p.write_text("\n".join(rows) + "\n")
    with pytest.raises(DataError, match=r"line 252, column 'voltage': '0,500' is not a number; the file writes a "
                                        r"decimal comma"):
        ph.load_dataset(p, fs=1000.0)
    ds = ph.load_dataset(p, decimal=",", fs=1000.0)
    assert ds.u[-1] == pytest.approx(0.5 + 299 / 100) and len(ds) == 550


def test_excel_serial_dates_in_a_time_column_without_a_unit(tmp_path):
    """A spreadsheet's date-time column saved as numbers (days since 1899-12-30) was read as
    seconds: a 1 kHz record became 86.4 MHz, silently, in every model file (found by fuzzing).
    Refused with the unit to state; in hours or in seconds from a late start it reads as before."""
    n, dt = 3000, 1e-3
    k = np.arange(n)
    u = 50 + 50 * np.sin(2 * np.pi * k * dt)

    def write(name, header, t):
        p = tmp_path / name
        np.savetxt(p, np.c_[t, u, 0.2 * u], delimiter=",", header=header, comments="", fmt="%.12f")
        return p

    days = write("days.csv", "Time,Voltage (V),Displacement (um)", 46354.5 + k * dt / 86400)
    with pytest.raises(DataError, match=r"days\.csv: the time column 'Time' states no unit and looks like Excel "
                                        r"serial dates .*46354\.5 is 2026-11-28 12:00:00.* 8\.64e\+07 Hz; in days "
                                        r"they are 0\.001 s\. State its unit \(units=\{'t': 'day'\}"):
        ph.load_dataset(days)
    assert ph.load_dataset(days, units={"t": "day"}).dt == pytest.approx(dt, rel=1e-3)
    hours = write("hours.csv", "Time [h],Voltage (V),Displacement (um)", 0.5 + k * dt / 3600)
    assert ph.load_dataset(hours).dt == pytest.approx(dt, rel=1e-6)
    late = write("late.csv", "Time,Voltage (V),Displacement (um)", 30000.0 + k * 1e-4)  # 10 kHz, 8 h in
    assert ph.load_dataset(late).dt == pytest.approx(1e-4, rel=1e-6)
    # an hour stated as a suffix is a name: u_h, Position_h (a horizontal axis) read as before
    axis = write("axis.csv", "t,u_h,Position_h", k * dt)
    ds = ph.load_dataset(axis, u_col="u_h", y_col="Position_h")
    assert ds.meta["units"]["y"]["unit"] is None and ds.dt == pytest.approx(dt)


@pytest.mark.parametrize("late", [False, True])
def test_thousands_points_with_a_decimal_comma(tmp_path, late):
    """German Excel writes a cell formatted with thousands as ``1.010,2``: the comma was taken for
    the delimiter and the table for four columns of text (found by fuzzing lab files). Grouped
    numbers in the first rows, or only after the rows the sniffer reads (nm passing 1000 late)."""
    k = np.arange(2000)
    u = 50 + 50 * np.sin(2 * np.pi * k / 1000)
    y = 2.0 * k if late else 1000 + 1000 * np.sin(2 * np.pi * k / 1000)

    def de(v):
        return f"{v:,.3f}".replace(",", "X").replace(".", ",").replace("X", ".")

    p = tmp_path / "de.csv"
    p.write_text("\n".join(["Zeit [s];Spannung [V];Weg [nm]"]
                           + [f"{i / 1000:.3f}".replace(".", ",") + f";{de(u[i])};{de(y[i])}" for i in k]) + "\n",
                 encoding="utf-8")
    ds = ph.load_dataset(p)
    assert (ds.meta["delimiter"], ds.meta["decimal"], ds.meta["thousands"]) == ("semicolon", ",", ".")
    np.testing.assert_allclose(ds.y, np.round(y, 3) / 1000, atol=1e-12)
    np.testing.assert_allclose(ds.u, np.round(u, 3), atol=1e-12)
    assert ds.dt == pytest.approx(1e-3)


def test_three_decimals_with_a_point_stay_decimals(tmp_path):
    """A semicolon file with decimal points and three decimals (and a comma in its header) is not
    read as thousands: 1.250 stays 1.25."""
    p = tmp_path / "points.csv"
    p.write_text("t [s];u, drive [V];y [um]\n" + "".join(f"{i / 1000:.3f};{1 + i / 1000:.3f};{2 + i / 500:.3f}\n"
                                                          for i in range(300)))
    ds = ph.load_dataset(p, u_col=1, y_col=2)
    assert ds.meta["decimal"] == "." and "thousands" not in ds.meta
    assert ds.u[250] == pytest.approx(1.25) and ds.y[250] == pytest.approx(2.5)


def test_a_time_beyond_single_precisions_range_is_no_single_precision_number(tmp_path):
    """t = 3.4028235677973366e+38 (just above float32's largest) overflowed in the check for a
    single-precision time column, a RuntimeWarning (an error under -W error) instead of the
    reader's own answer (found by the readers' fuzz test)."""
    p = tmp_path / "big.csv"
    p.write_text("t,u,y\n0,0.841471,0.909297\n0.001,0.909297,0.141120\n3.4028235677973366e+38,0.141120,-0.756802\n")
    with pytest.raises(DataError, match="not uniformly sampled"):
        ph.load_dataset(p)
