"""Commissioning, model selection and feedforward across the plant zoo (issue 11, items 5 and 7).

The zoo (:mod:`tests.plants.zoo`) holds seven piezo-like stages of structures the project's models
do not share, 2-20 kHz, delays 0-5 samples, unipolar and bipolar, strokes 1.5-100 µm. Nothing is
tuned on them. For each: ``commission`` chooses and fits a model on its own data, and the
feedforward alone (``ctl.track(ref, feedback=False, learning=False)``) tracks 1, 3 and 5 Hz
sinusoids over 10-90 % of the stage's steady stroke (the range a user would read off a full-range
open-loop loop) to within 2 % of the span (issue 11's goal), with a command free of chatter; with
the feedback tuned on the stage and learning, to within 1 % once learning has converged (e_max over
the last 3 of 12 cycles).
"""

import warnings

import numpy as np
import pytest

import piezohyst as ph

from .plants.zoo import zoo

STAGES = zoo(seed=0)
NAMES = [s.name.split(",")[0] for s in STAGES]

#: (stage, frequency) pairs that miss the 2 % goal today, with the reason; strict, so a fix shows
KNOWN_SHORT: dict[tuple[str, float], str] = {}


def steady_range(stage):
    """10-90 % of the output span of the second cycle of a full-range 1 Hz open-loop loop."""
    lo_u, hi_u = stage.u_range
    d = stage.excite(ph.sinusoid(1.0, 2, lo_u, hi_u, stage.dt))
    y = d.y[d.y.size // 2:]
    lo, hi = float(y.min()), float(y.max())
    return lo + 0.1 * (hi - lo), lo + 0.9 * (hi - lo)


@pytest.fixture(scope="module", params=range(len(STAGES)), ids=NAMES)
def commissioned(request):
    stage = zoo(seed=0)[request.param]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ph.ClippingWarning)
        ctl = ph.commission(stage, tune=False)
    return stage, ctl, steady_range(stage)


@pytest.mark.slow
def test_selection_predicts_held_out_data(commissioned):
    stage, ctl, _ = commissioned
    hold = ctl.fit.info["holdout"]
    # the chosen model predicts the commissioning run's validation part to within 1.5 % of span
    assert hold["percent_of_span"] < 1.5, (stage.name, ctl.fit.info["chosen"], hold)
    assert ctl.model.is_invertible
    # it is the best candidate or a simpler one within the selection's margin
    best = min(c["holdout_rmse"] for c in ctl.fit.info["candidates"])
    assert hold["rmse"] <= best / (1.0 - 0.02) ** 3 + 1e-12


@pytest.mark.slow
@pytest.mark.parametrize("freq", [1.0, 3.0, 5.0])
def test_feedforward_alone_within_2_percent(commissioned, freq, request):
    stage, ctl, (a, b) = commissioned
    key = (stage.name.split(",")[0], freq)
    if key in KNOWN_SHORT:
        request.applymarker(pytest.mark.xfail(reason=KNOWN_SHORT[key], strict=True))
    ref = ph.sinusoid(freq, 3, a, b, stage.dt)
    period = int(round(1.0 / (freq * stage.dt)))
    out = ctl.track(ref, feedback=False, learning=False, period=period)
    cmd = out.command[period:]
    # no chatter: the command moves no more per sample than the reference does, scaled by the
    # stage's mean gain, with room for the inverse's steeper slope just after reversals
    gain = np.ptp(cmd) / np.ptp(ref)
    assert np.abs(np.diff(cmd)).max() <= 20 * gain * np.abs(np.diff(ref)).max()
    assert out.e_max_percent <= 2.0, (stage.name, ctl.fit.info["chosen"], out.e_max_percent)


#: (stage, frequency) pairs whose feedback + learning misses 1 % today, with the reason; strict
_STAIRS = ("hard relays: the output climbs in stairs (up to 0.6 % of the stroke) that, swept at 1-5 Hz, "
           "ring the 1.5 kHz resonance; the feedforward alone leaves a repeatable error of 0.84/0.68/1.28 % "
           "of span (1/3/5 Hz) of which 0.65/0.73/1.22 % lies above 500 Hz, beyond any learning band or "
           "feedback loop, and the integral loop hunts on the stairs (e_max varies 0.88-1.46 % from cycle to "
           "cycle; at 1 Hz it stays within 1 %, at 0.96 %)")
KNOWN_SHORT_FBL = {
    ("relay Preisach", 3.0): _STAIRS + "; at 3 Hz the period (1666.7 samples) is not whole, so the stair "
                             "pattern shifts from cycle to cycle and cannot be learnt; 1.10 % measured",
    ("relay Preisach", 5.0): _STAIRS + "; 1.45 % measured",
}

#: cycles of a feedback + learning run, and the last ones read: the error once learning has converged
FBL_CYCLES, FBL_READ = 12, 3


@pytest.mark.slow
@pytest.mark.parametrize("freq", [1.0, 3.0, 5.0])
def test_feedback_and_learning_within_1_percent(commissioned, freq, request):
    """Issue 11's goal with the whole controller: integral feedback (tuned on the stage by the
    bounded experiments) and iterative learning, over 12 cycles; the error a user reads once
    learning has converged, e_max over the last three cycles, within 1 % of the span, and the
    command as free of chatter as the feedforward's test asks."""
    stage, ctl, (a, b) = commissioned
    key = (stage.name.split(",")[0], freq)
    if key in KNOWN_SHORT_FBL:
        request.applymarker(pytest.mark.xfail(reason=KNOWN_SHORT_FBL[key], strict=True))
    if ctl.tuning is None:  # the fixture commissions with tune=False; tune once per stage
        ctl.tune()
    ref = ph.sinusoid(freq, FBL_CYCLES, a, b, stage.dt)
    period = int(round(1.0 / (freq * stage.dt)))
    out = ctl.track(ref, period=period)
    assert out.info["feedback"] and out.info["learning"] and ctl.tuning.ki > 0
    if ctl.fit.info.get("floor_at_margin"):  # flat after reversals: the learning band stays where it starts
        assert out.info["learning_cutoff_hz"] == max(50.0, 15.0 * freq)
    last = slice((FBL_CYCLES - FBL_READ) * period, FBL_CYCLES * period)
    e_max = 100.0 * float(np.abs(out.error[last]).max()) / float(np.ptp(ref))
    cmd = out.command[period:]
    gain = np.ptp(cmd) / np.ptp(ref)
    assert np.abs(np.diff(cmd)).max() <= 20 * gain * np.abs(np.diff(ref)).max()
    per_cycle = [round(100.0 * float(np.abs(out.error[k * period:(k + 1) * period]).max()) / float(np.ptp(ref)), 2)
                 for k in range(FBL_CYCLES)]
    assert e_max <= 1.0, (stage.name, e_max, per_cycle, ctl.tuning.ki)


@pytest.mark.slow
def test_identify_auto_then_compensate_on_a_bipolar_long_stroke_stage(tmp_path, capsys):
    """Issue 11's goal: a record of a bipolar long-stroke stage (the zoo's Duhem stage, +-150 V,
    100 µm), ``identify --model auto`` on it, then ``compensate`` with the chosen model: <= 2 %
    e_max at 1 Hz when the command table is played on the stage; the plain P-I model, identified
    and used the same way, is shown beside it."""
    from piezohyst.cli import main

    stage = zoo(seed=1)[2]
    lo_u, hi_u = stage.u_range
    # a lab's identification record: full-range 1 Hz loops, then decaying ones (minor loops)
    u = np.concatenate([ph.sinusoid(1.0, 2, lo_u, hi_u, stage.dt),
                        ph.sinusoid(2.0, 4, lo_u, hi_u, stage.dt) * np.linspace(1.0, 0.3, int(2 / stage.dt)) +
                        np.linspace(0.0, 0.7, int(2 / stage.dt)) * 0.5 * (lo_u + hi_u)])
    rec = stage.excite(u)
    data = ph.save_dataset(tmp_path / "stage.csv", rec)
    a, b = steady_range(stage)
    ref = ph.sinusoid(1.0, 3, a, b, stage.dt)
    np.savetxt(tmp_path / "ref.csv", np.column_stack([np.arange(ref.size) * stage.dt, ref]), delimiter=",",
               header="t_s,x_um", comments="")
    results = {}
    for kind in ("auto", "pi"):
        m = tmp_path / f"{kind}.json"
        assert main(["identify", str(data), "--model", kind, "-o", str(m), "--json"]) == 0
        chosen = __import__("json").loads(capsys.readouterr().out)["model"]
        cmd = tmp_path / f"cmd_{kind}.csv"
        assert main(["compensate", "--model", str(m), "--reference", str(tmp_path / "ref.csv"),
                     "--u-min", str(lo_u), "--u-max", str(hi_u), "--clip", "-o", str(cmd)]) == 0
        capsys.readouterr()  # compensate's summary
        table = np.loadtxt(cmd, delimiter=",", comments="#", skiprows=4)
        out = stage.excite(table[:, 2]).y
        period = int(round(1.0 / stage.dt))
        e = out[period:] - ref[period:]
        results[kind] = (chosen, 100 * np.abs(e).max() / np.ptp(ref))
    capsys.readouterr()
    assert results["auto"][1] <= 2.0, results
    assert results["auto"][1] < results["pi"][1], results
