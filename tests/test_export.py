"""Issue 12: the compensator as C99 and MATLAB, and the python-control bridge.

The C files are compiled with the system C compiler as the issue asks
(``-std=c99 -Wall -Wextra -Werror -O2 -ffp-contract=off``), driven by a program that calls
``compensator_reset()`` once and ``compensator_step(x)`` per sample, and compared with what
``piezohyst compensate --clip`` writes for the same model and range (to 1e-9 V).
"""

import hashlib
import math
import shutil
import subprocess
import sys

import numpy as np
import pytest

import piezohyst as ph
from piezohyst.cli import main
from piezohyst.models.base import kind_of, kinds

CC = shutil.which("cc")
needs_cc = pytest.mark.skipif(CC is None, reason="no system C compiler")
CFLAGS = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-O2", "-ffp-contract=off"]
DT = 1e-4

DRIVER = r"""
#include <stdio.h>
#include <stdlib.h>
#include "compensator.h"
int main(int argc, char **argv)
{
    FILE *in = argc > 3 ? fopen(argv[1], "rb") : NULL;
    FILE *out = argc > 3 ? fopen(argv[2], "wb") : NULL;
    int fb = argc > 3 ? atoi(argv[3]) : 0;
    double x[2];
    if (argc < 4 || !in || !out) return 3;
    compensator_reset();
    while (fread(x, sizeof(double), fb ? 2 : 1, in) == (size_t)(fb ? 2 : 1)) {
        double u = fb ? compensator_step_fb(x[0], x[1]) : compensator_step(x[0]);
        fwrite(&u, sizeof(double), 1, out);
    }
    fclose(in);
    fclose(out);
    return 0;
}
"""


def _pi():
    w = np.array([0.02, 0.004, 0.003, -0.001, 0.002, 0.001, 0.0015, -0.0005, 0.001, 0.0008])
    return ph.PrandtlIshlinskii(ph.equal_thresholds(10, 100.0), w, offset=0.05, input_offset=1.5)


def _preisach():
    rng = np.random.default_rng(7)
    return ph.Preisach(lo=-10.0, hi=110.0, weights=rng.uniform(0.0, 0.0015, 36 + 16), slope=0.012, offset=-0.03)


def example_models():
    """One model of every kind that has a compensator (and the wrappers around each static kind)."""
    pi, pre = _pi(), _preisach()
    rate_pi = ph.RateDependent(static=pi, taus=[0.002, 0.03, 0.4], lag_weights=[0.003, 0.0015, -0.0004],
                               dt=DT, input_tau=4e-4)
    out_map = ph.OutputMap(knots=[0.4, 1.9], coefficients=[0.5, 0.8], centre=1.0)
    duhem_knots = np.linspace(0.0, 100.0, 6)
    return {
        "prandtl-ishlinskii": pi,
        "preisach": pre,
        "rate-dependent (P-I)": rate_pi,
        "rate-dependent (Preisach)": ph.RateDependent(static=pre, taus=[0.005], lag_weights=[0.002], dt=DT),
        # a long input lag whose lead's gain is limited (model selection sets it where the exact
        # lead's steps are too large): the C code runs the same filter before the lead
        "rate-dependent (P-I, lead limited)": ph.RateDependent(static=pi, taus=[0.002, 0.03, 0.4],
                                                              lag_weights=[0.003, 0.0015, -0.0004], dt=DT,
                                                              input_tau=4e-3, input_lead_gain=8.0),
        "asymmetric-pi": ph.AsymmetricPI(inner=pi, output_map=out_map),
        "asymmetric-pi (rate)": ph.AsymmetricPI(inner=rate_pi, output_map=out_map),
        "bouc-wen": ph.BoucWen(m=0.75, b=27.96, k=8.54e7, d1=2.15e-8, alpha=0.472, beta=0.072, gamma=0.02,
                               offset=3e-8),
        "bouc-wen-hysteresis": ph.BoucWenHysteresis(d1=0.021, alpha=0.3, beta=0.035, gamma=-0.01, offset=0.02),
        # invertible within its operating range only (alpha M = 1.13 over every state, 0.94 within)
        "bouc-wen-hysteresis (operating range)": ph.BoucWenHysteresis(d1=0.021, alpha=0.31, beta=0.02, gamma=-0.009,
                                                                      offset=0.02, v_range=(-15.0, 115.0)),
        "generalized-duhem": ph.GeneralizedDuhem(duhem_knots, f=0.04 * 0.6 * np.tanh(duhem_knots / 80.0),
                                                 g=0.006 * (1.0 - 0.4 * (duhem_knots / 100.0) ** 2), lam=0.04,
                                                 offset=0.03),
        "rate-dependent (generalized Duhem)": ph.RateDependent(
            static=ph.GeneralizedDuhem([-30.0, 0.0, 40.0, 100.0], f=[-0.004, 0.0, 0.003, 0.005],
                                       g=[0.012, 0.01, 0.009, 0.006], lam=0.02, offset=-0.2, v_range=(-30.0, 100.0)),
            taus=[0.003, 0.2], lag_weights=[0.001, -0.0003], dt=DT, input_tau=5e-4),
        "rate-dependent (Bouc-Wen hysteresis)": ph.RateDependent(
            static=ph.BoucWenHysteresis(d1=0.021, alpha=0.4, beta=0.035, gamma=0.01), taus=[0.003, 0.2],
            lag_weights=[0.002, -0.0007], dt=DT, input_tau=5e-4),
        # a stage that rests after coming down from the top of its range: the C reset replays the
        # model's output along that history through the inverse, as the Python compensator does
        "after-history (P-I)": ph.AfterHistory(pi, (0.0, 100.0, 0.0), 30),
        "after-history (rate-dependent Preisach)": ph.AfterHistory(
            ph.RateDependent(static=pre, taus=[0.005], lag_weights=[0.002], dt=DT), (0.0, -10.0, 0.0), 200, 100),
    }


MODELS = example_models()


def test_every_kind_with_a_compensator_is_exported():
    # a new kind must add its model here (and its to_c piece), or this fails
    assert {kind_of(m) for m in MODELS.values()} == set(kinds())
    assert all(m.is_invertible for m in MODELS.values())


def references(model, n=20000, seed=0):
    """A long random walk over the model's output range (reversals of every size) and a sum of
    sinusoids, both as desired displacement, µm."""
    rng = np.random.default_rng(seed)
    u = np.clip(50.0 + np.cumsum(rng.normal(0.0, 0.8, n)), -15.0, 115.0)
    walk = np.asarray(model.predict(u, DT), dtype=float)
    t = np.arange(n) * DT
    lo, hi = float(walk.min()), float(walk.max())
    mid, amp = 0.5 * (lo + hi), 0.5 * (hi - lo)
    sines = mid + amp * (0.6 * np.sin(2 * np.pi * 3.0 * t) + 0.35 * np.sin(2 * np.pi * 17.0 * t + 1.0))
    return {"random walk": walk, "sinusoids": sines}


@pytest.fixture(scope="module")
def driver_obj(tmp_path_factory):
    if CC is None:
        pytest.skip("no system C compiler")
    d = tmp_path_factory.mktemp("driver")
    (d / "driver.c").write_text(DRIVER)
    return d / "driver.c"


def build(directory, driver):
    exe = directory / "drive"
    res = subprocess.run([CC, *CFLAGS, "-I", str(directory), "-o", str(exe), str(directory / "compensator.c"),
                          str(driver), "-lm"], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr  # no warning: -Werror
    return exe


def run_c(exe, x, measured=None):
    d = exe.parent
    data = np.asarray(x, dtype="<f8") if measured is None else np.column_stack([x, measured]).astype("<f8")
    data.tofile(d / "in.bin")
    subprocess.run([str(exe), str(d / "in.bin"), str(d / "out.bin"), "0" if measured is None else "1"], check=True)
    return np.fromfile(d / "out.bin", dtype="<f8")


@needs_cc
@pytest.mark.parametrize("name", list(MODELS))
def test_c_equals_piezohyst_compensate(name, tmp_path, driver_obj, capsys):
    # the acceptance: export --to c and compensate --clip with the same model and range
    model = MODELS[name]
    path = tmp_path / "model.json"
    ph.save_model(model, path)
    out = tmp_path / "c"
    assert main(["export", str(path), "--to", "c", "--u-min", "-20", "--u-max", "120", "--out", str(out)]) == 0
    exe = build(out, driver_obj)
    src = (out / "compensator.c").read_text()
    # what produced it: the producer line and the model file's SHA-256
    assert "piezohyst" in src and "command: " in src
    assert hashlib.sha256(path.read_bytes()).hexdigest() in src
    assert "malloc" not in src and "#include <math.h>" in src
    # one reference, driven from one reset: a random walk (4000 reversals of every size), then sinusoids
    refs = references(model)
    ref = np.concatenate([refs["random walk"], refs["sinusoids"]])
    ref_csv = tmp_path / "ref.csv"
    np.savetxt(ref_csv, np.column_stack([np.arange(ref.size) * DT, ref]), delimiter=",", header="t,x",
               comments="", fmt="%.17g")
    cmd_csv = tmp_path / "cmd.csv"
    assert main(["compensate", "--model", str(path), "--reference", str(ref_csv), "--u-min", "-20",
                 "--u-max", "120", "--clip", "-o", str(cmd_csv)]) == 0
    expected = np.loadtxt(cmd_csv, delimiter=",", comments="#", skiprows=4)[:, 2]
    got = run_c(exe, ref)
    assert got.size == expected.size == ref.size
    assert np.max(np.abs(got - expected)) <= 1e-9, name
    assert expected.min() >= -20.0 and expected.max() <= 120.0
    capsys.readouterr()


@needs_cc
def test_c_clip_and_step_limit_equal_python(tmp_path, driver_obj):
    from piezohyst.export import export_c

    model = MODELS["rate-dependent (P-I)"]
    export_c(model, tmp_path, u_range=(5.0, 60.0), max_slew=0.05)
    exe = build(tmp_path, driver_obj)
    ref = references(model, n=20000, seed=3)["random walk"]
    py = model.compensator(DT, u_range=(5.0, 60.0), max_slew=0.05)
    expected = py.command(ref)
    assert py.limited > 100  # both limits act on this reference
    assert np.max(np.abs(run_c(exe, ref) - expected)) <= 1e-9


@needs_cc
def test_c_keeps_the_operating_range_as_python_does(tmp_path, driver_obj):
    """A Bouc-Wen hysteresis with an operating range: targets beyond what the range reaches give
    the range's end, in C as in Python."""
    from piezohyst.export import export_c

    model = MODELS["bouc-wen-hysteresis (operating range)"]
    export_c(model, tmp_path)
    exe = build(tmp_path, driver_obj)
    walk = references(model, n=20000, seed=4)["random walk"]
    lo, hi = float(walk.min()), float(walk.max())
    ref = np.concatenate([walk, np.linspace(walk[-1], hi + 2.0 * (hi - lo), 500), np.linspace(hi, lo - 2.0 * (hi - lo), 900),
                          np.linspace(lo, 0.5 * (lo + hi), 300)])
    expected = model.compensator().command(ref)
    assert expected.max() == 115.0 and expected.min() == -15.0  # the range's ends, reached
    assert np.max(np.abs(run_c(exe, ref) - expected)) <= 1e-9


@needs_cc
def test_c_integral_feedback_equals_python_pid(tmp_path, driver_obj):
    from piezohyst.export import export_c

    model = MODELS["prandtl-ishlinskii"]
    kp, ki, delay, rng_u = 5.0, 400.0, 2, (0.0, 60.0)
    export_c(model, tmp_path, u_range=rng_u, kp=kp, ki=ki, fb_delay=delay, fb_dt=DT)
    exe = build(tmp_path, driver_obj)
    gen = np.random.default_rng(5)
    x = references(model, n=20000, seed=4)["sinusoids"]
    meas = x + gen.normal(0.0, 0.05, x.size) + 0.3 * np.sin(np.arange(x.size) * 0.001)
    # the documented semantics in Python: PID at the command, e = desired[k - delay] - measured,
    # the integral held in the direction of a clipped command
    ff = model.compensator(None)
    ff.reset()
    pid = ph.PID(kp, ki, 0.0, DT)
    sat, out = 0, np.empty(x.size)
    for k in range(x.size):
        e = x[max(k - delay, 0)] - meas[k]
        u = ff.step(x[k]) + pid.step(e, sat)
        v = min(max(u, rng_u[0]), rng_u[1])
        sat = 1 if u > rng_u[1] else (-1 if u < rng_u[0] else 0)
        out[k] = v
    got = run_c(exe, x, meas)
    assert np.sum(out == rng_u[1]) + np.sum(out == rng_u[0]) > 10  # the anti-windup is exercised
    assert np.max(np.abs(got - out)) <= 1e-9


def test_export_refuses_bad_options(tmp_path, capsys):
    path = tmp_path / "m.json"
    ph.save_model(MODELS["prandtl-ishlinskii"], path)
    for extra in (["--u-min", "nan"], ["--u-min", "10", "--u-max", "10"], ["--max-slew", "0"], ["--ki", "inf"]):
        assert main(["export", str(path), "--to", "c", "--out", str(tmp_path / "o"), *extra]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "error" in err
    (tmp_path / "o2").mkdir()
    (tmp_path / "o2" / "compensator.c").write_text("mine")
    assert main(["export", str(path), "--to", "c", "--out", str(tmp_path / "o2")]) == 2
    assert (tmp_path / "o2" / "compensator.c").read_text() == "mine"  # never overwritten without --force
    capsys.readouterr()


# -- MATLAB ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["prandtl-ishlinskii", "rate-dependent (Preisach)", "asymmetric-pi (rate)", "bouc-wen"])
def test_matlab_file_loads_with_the_model_inverse_and_a_reference_table(name, tmp_path, capsys):
    from scipy.io import loadmat

    model = MODELS[name]
    path = tmp_path / "m.json"
    ph.save_model(model, path)
    args = ["export", str(path), "--to", "matlab", "--out", str(tmp_path / "m.mat"), "--u-min", "-5", "--u-max", "105"]
    if name == "bouc-wen":
        args += ["--fs", "10000"]
    assert main(args) == 0
    capsys.readouterr()
    s = loadmat(tmp_path / "m.mat", squeeze_me=True, struct_as_record=False)
    assert s["model"].kind == kind_of(model)
    assert s["model_sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()
    assert "piezohyst" in s["producer"]
    ref = s["reference"]
    dt = float(s["dt_s"])
    comp = model.compensator(dt if model.dynamic else None, u_range=(-5.0, 105.0))
    assert np.max(np.abs(comp.command(ref.x_d_um) - ref.u_V)) <= 1e-9
    assert len(ref.u_V) > 1000


def test_matlab_reader_note_reproduces_the_reference_commands(tmp_path):
    # the .m note in piezohyst.export.matlab's docstring, line by line in numpy
    from scipy.io import loadmat

    from piezohyst.export import export_matlab

    model = MODELS["prandtl-ishlinskii"]
    export_matlab(model, tmp_path / "pi.mat", u_range=(0.0, 100.0))
    s = loadmat(tmp_path / "pi.mat", squeeze_me=True, struct_as_record=False)
    p = s["inverse"]
    inv = model.inverse()
    assert np.allclose(p.thresholds, inv.thresholds) and np.allclose(p.weights, inv.weights)
    z, r, w = np.array(p.initial_state, float), np.array(p.thresholds, float), np.array(p.weights, float)
    x = s["reference"].x_d_um
    u = np.empty(x.size)
    for k in range(x.size):
        xs = x[k] - p.input_offset
        z = np.minimum(np.maximum(z, xs - r), xs + r)
        u[k] = w @ z + p.offset
    u = np.clip(u, s["u_range_V"][0], s["u_range_V"][1])
    assert np.max(np.abs(u - s["reference"].u_V)) < 1e-9


# -- python-control --------------------------------------------------------------------------------
@pytest.fixture
def control():
    return pytest.importorskip("control")  # the optional extra: only these tests need it


def test_bouc_wen_linear_part_as_transfer_function(control):
    from piezohyst.export.pycontrol import bouc_wen_linear_part

    bw = MODELS["bouc-wen"]
    g = bouc_wen_linear_part(bw)
    assert math.isclose(float(control.dcgain(g)), 1.0, rel_tol=1e-12)
    gu = bouc_wen_linear_part(bw, input="u")
    assert math.isclose(float(control.dcgain(gu)), 1e6 * bw.d1, rel_tol=1e-12)
    # its poles: the natural frequency sqrt(k/m) and damping b / (2 sqrt(k m)) of eq. (7)
    wn, zeta, _ = control.damp(g, doprint=False)
    assert math.isclose(wn[0], 2 * math.pi * bw.natural_frequency_hz, rel_tol=1e-9)
    assert math.isclose(zeta[0], bw.damping_ratio, rel_tol=1e-9)


def test_pid_transfer_function_is_what_the_pid_computes(control):
    from piezohyst.export.pycontrol import pid_transfer_function

    pid = ph.PID(0.3, 250.0, 2e-4, 1e-4)
    e = np.random.default_rng(2).normal(size=3000)
    e[0] = 0.0  # the PID takes no derivative kick on its first sample; a transfer function starts from e = 0
    y_pid = np.array([pid.step(v) for v in e])
    resp = control.forced_response(pid_transfer_function(pid), T=np.arange(e.size) * 1e-4, U=e)
    assert np.allclose(resp.outputs, y_pid, rtol=1e-9, atol=1e-9)


def _integrator_with_delay_controller(ki, delay, dt=1e-4):
    """A commissioned controller whose loop is ki dt z/(z-1) z^-(delay+1): the model is a pure gain
    (one play operator of threshold 0) and the output scale cancels it."""
    from piezohyst.control.tuning import TuningResult

    CommissionedController = ph.CommissionedController
    from piezohyst.identify import FitResult

    gain = 0.02
    model = ph.PrandtlIshlinskii([0.0], [gain])

    class Plant:
        dt = 1e-4
        u_range = (0.0, 100.0)

        def reset(self):
            pass

        def step(self, u):
            return gain * u

    u = np.linspace(0.0, 100.0, 50)
    ds = ph.Dataset(np.arange(50) * dt, u, gain * u)
    fit = FitResult(model=model, rmse=0.0, method="given", n_samples=50, time_s=0.0, delay=delay)
    return CommissionedController(plant=Plant(), fit=fit, tuning=TuningResult(0.0, ki, 0.0, 0.0, (), "given"),
                                  identification=ds)


def test_loop_margins_of_an_integrator_with_delay_match_the_closed_form(control):
    from piezohyst.export.pycontrol import loop_margins

    dt, ki, d = 1e-4, 600.0, 3
    ctl = _integrator_with_delay_controller(ki, d, dt)
    # closed form: |L| = ki dt / (2 sin(w dt / 2)) = 1 at the crossover; the phase there is
    # -90 deg + w dt / 2 (backward-Euler integrator) - w (d + 1) dt
    wc = 2.0 / dt * math.asin(ki * dt / 2.0)
    pm = 90.0 - math.degrees(wc * dt * (d + 0.5))
    m = loop_margins(ctl)
    for branch in m.values():
        assert branch["phase_margin_deg"] == pytest.approx(pm, abs=0.2)
        assert branch["gain_crossover_rad_s"] == pytest.approx(wc, rel=5e-3)


def test_bridge_says_how_to_install_python_control(monkeypatch):
    from piezohyst.export import pycontrol

    monkeypatch.setitem(sys.modules, "control", None)
    with pytest.raises(ImportError, match=r"pip install 'piezohyst\[control\]'"):
        pycontrol.pid_transfer_function(ph.PID(0.0, 1.0, 0.0, 1e-3))


def test_export_reads_negative_numbers_in_exponent_notation(tmp_path, capsys):
    # argparse before Python 3.13 took "-1e3" for an unknown option (found by fuzzing)
    path = tmp_path / "m.json"
    ph.save_model(MODELS["prandtl-ishlinskii"], path)
    assert main(["export", str(path), "--to", "c", "--out", str(tmp_path / "o"), "--u-min", "-1e2",
                 "--u-max", "1.2e2", "--json"]) == 0
    assert '"amplifier_range_V": [\n    -100.0,\n    120.0\n  ]' in capsys.readouterr().out


def test_feedback_gains_that_diverge_on_the_model_are_refused_and_those_below_converge():
    # a linear stage (one play operator of threshold 0: y = w u) behind its exact feedforward, the
    # PI of compensator_step_fb measuring one sample after each command, a constant disturbance
    # for the integral to remove: Jury's test says stable only for 2 kp w + ki dt w < 2; the
    # exporter refuses the gains at or beyond that bound and takes those below it
    from piezohyst.export.c import generate_c

    w, dt, rng_u = 0.2, 1e-4, (-1000.0, 1000.0)
    model = ph.PrandtlIshlinskii(np.array([0.0]), np.array([w]))

    def final_error(kp, ki, n=3000):
        ff = model.compensator(None)
        ff.reset()
        pid = ph.PID(kp, ki, 0.0, dt)
        y, e = 0.0, 0.0
        for _ in range(n):
            e = 5.0 - y
            y = w * (ff.step(5.0) + pid.step(e, 0)) + 0.5  # what the stage shows at the next sample
            if not abs(y) < 1e6:
                return math.inf
        return abs(e)

    a = 0.3  # kp w
    for share, converges in ((0.9, True), (1.1, False)):
        kp, ki = a / w, share * (2.0 - 2.0 * a) / (w * dt)
        assert (final_error(kp, ki) < 1e-6) is converges, (share, final_error(kp, ki))
        if converges:
            generate_c(model, u_range=rng_u, kp=kp, ki=ki, fb_dt=dt)
        else:
            with pytest.raises(ValueError, match="diverge on this model"):
                generate_c(model, u_range=rng_u, kp=kp, ki=ki, fb_dt=dt)


@needs_cc
def test_generated_c_compiles_whatever_the_paths_and_table_names(tmp_path):
    """Found by fuzzing: a path holding ``*/`` (or ``/*``) in the provenance comment ended it (or
    failed -Werror=comment); tables named exp.h, NAN.h, main.h clashed with <math.h>/<stdlib.h>,
    class.h and new.h with C++."""
    from piezohyst.export.c import export_c
    from piezohyst.export.tables import write_table

    model = _pi()
    out = tmp_path / "fw"
    export_c(model, out, u_range=(0.0, 100.0), provenance=["model file: odd/evil*/m.json", "out: fw/*x */ /*"])
    res = subprocess.run([CC, *CFLAGS, "-c", "-o", str(tmp_path / "c.o"), str(out / "compensator.c")],
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    n = 50
    t = np.arange(n) * 1e-3
    names = ["exp", "NAN", "main", "class", "new", "int", "9lives"]
    for name in names:
        write_table(tmp_path / f"{name}.h", t, np.linspace(0, 1, n), np.linspace(0, 10, n), dt=1e-3,
                    comments=["from odd/evil*/m.json", "to tbl/*.h"])
    includes = "".join(f'#include "{name}.h"\n' for name in names)
    prog = tmp_path / "use.c"
    prog.write_text("#include <math.h>\n#include <stdlib.h>\n#include <stdio.h>\n#include <string.h>\n" + includes
                    + "int main(void) { return 0; }\n")
    res = subprocess.run([CC, *CFLAGS, "-I", str(tmp_path), "-o", str(tmp_path / "use"), str(prog), "-lm"],
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    cxx = shutil.which("g++") or shutil.which("c++")
    if cxx:
        res = subprocess.run([cxx, "-x", "c++", "-Wall", "-Wextra", "-Werror", "-I", str(tmp_path), "-fsyntax-only",
                              str(prog)], capture_output=True, text=True)
        assert res.returncode == 0, res.stderr


def test_c_export_refuses_a_file_name_and_checks_gains_without_a_range(tmp_path):
    from piezohyst.export.c import export_c, generate_c

    model = _pi()
    with pytest.raises(ValueError, match="writes a folder"):
        export_c(model, tmp_path / "comp.c")
    assert not (tmp_path / "comp.c").exists()
    # without u_range the gains were not checked at all (the command line always gives a range)
    with pytest.raises(ValueError, match="diverge on this model"):
        generate_c(model, kp=1e6, fb_dt=1e-4)
    with pytest.raises(ValueError, match="diverge") as info:
        generate_c(model, u_range=(0.0, 100.0), kp=1e6)
    assert "sample period" not in str(info.value)  # none was given: it said "0 s"


def test_the_header_and_the_source_are_published_together(tmp_path, monkeypatch):
    """Found by a helper: an interrupt (or a full disk) between the two files left compensator.h
    alone, a rerun then refused; with force, a new header beside the old source, which compiled.
    Now both are written first and moved into place together: an interrupt at the second move
    leaves the old pair (or none), and a full disk writes neither."""
    import errno

    import piezohyst._fileio as fio
    from piezohyst.export.c import export_c

    out = tmp_path / "fw"
    real = fio._publish_file
    calls = []

    def interrupted_at_the_second(tmp, p, force):
        calls.append(p.name)
        if len(calls) == 2:
            raise KeyboardInterrupt
        real(tmp, p, force)

    monkeypatch.setattr(fio, "_publish_file", interrupted_at_the_second)
    with pytest.raises(KeyboardInterrupt):
        export_c(_pi(), out)
    assert calls == ["compensator.h", "compensator.c"] and sorted(p.name for p in out.iterdir()) == []

    monkeypatch.setattr(fio, "_publish_file", real)
    export_c(_pi(), out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    calls.clear()
    monkeypatch.setattr(fio, "_publish_file", interrupted_at_the_second)
    other = ph.PrandtlIshlinskii(ph.equal_thresholds(5, 80.0), [0.03, 0.02, 0.01, 0.01, 0.005])
    with pytest.raises(KeyboardInterrupt):
        export_c(other, out, force=True)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # the old pair, whole, nothing else

    monkeypatch.setattr(fio, "_publish_file", real)
    real_write = fio.Path.write_text

    def full_at_the_source(self, text, *a, **k):
        if ".compensator.c." in self.name:
            raise OSError(errno.ENOSPC, "No space left on device", str(self))
        return real_write(self, text, *a, **k)

    monkeypatch.setattr(fio.Path, "write_text", full_at_the_source)
    with pytest.raises(OSError, match=r"cannot write .*fw2/compensator.c: No space left"):
        export_c(_pi(), tmp_path / "fw2")
    assert sorted(p.name for p in (tmp_path / "fw2").iterdir()) == []
