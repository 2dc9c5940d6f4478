"""The README's table of the plant zoo: ``python benchmarks/zoo_table.py`` prints it (markdown).

For each stage of ``tests/plants/zoo.py``: ``commission()`` (model chosen on the stage's own
data, integral gain tuned by the bounded experiments), then 1, 3 and 5 Hz sinusoids over 10-90 %
of the stage's steady stroke, as ``tests/test_zoo.py`` runs them: e_max in % of span with the
feedforward alone (3 cycles, the first left out) and with integral feedback and learning
(12 cycles, the last 3 scored); and the floor the stage's sensor noise puts under the
feedforward's e_max (:meth:`~piezohyst.commissioning.CommissionedController.noise_floor`: the
e_max the noise alone reaches, with probability one half, over those scored samples; the noise's
RMS estimated from the identification run). A few minutes; nothing here is tuned on the zoo.
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import piezohyst as ph  # noqa: E402
from tests.plants.zoo import zoo  # noqa: E402
from tests.test_zoo import FBL_CYCLES, FBL_READ, steady_range  # noqa: E402


def row(stage) -> str:  # noqa: ANN001 - a zoo Stage
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ph.ClippingWarning)
        ctl = ph.commission(stage)
    a, b = steady_range(stage)
    ff, fbl, floor = [], [], []
    for f in (1.0, 3.0, 5.0):
        per = int(round(1.0 / (f * stage.dt)))
        run = ctl.track(ph.sinusoid(f, 3, a, b, stage.dt), feedback=False, learning=False, period=per)
        ff.append(run.e_max_percent)
        floor.append(run.info.get("noise_floor_percent", float("nan")))
        ref = ph.sinusoid(f, FBL_CYCLES, a, b, stage.dt)
        try:
            out = ctl.track(ref, period=per)
            last = slice((FBL_CYCLES - FBL_READ) * per, FBL_CYCLES * per)
            fbl.append(100.0 * float(np.abs(out.error[last]).max()) / float(np.ptp(ref)))
        except ph.UnstableLoopError:
            fbl.append(float("nan"))
    name = stage.name.split(",")[0]
    st = ctl.fit.info.get("structure", {})
    kind = {"pi": "P-I", "preisach": f"Preisach {st.get('size')}", "bouc-wen": "Bouc-Wen hysteresis",
            "duhem": f"generalized Duhem {st.get('size')}"}.get(
        st.get("static"), ctl.model.kind)
    if st.get("map_knots"):
        kind = "asymmetric P-I"
    if st.get("taus_s"):
        kind += ", lags"
    start = ctl.fit.info.get("history")
    if start:  # fit_model's initial state: after a history down to the bottom or up to the top
        pts = start["waypoints_v"]
        kind += ", from below" if pts[1] < pts[0] else ", from above"
    return (f"| {name} ({kind}; ki {ctl.tuning.ki:.3g} 1/s) | {' / '.join(f'{v:.2f}' for v in ff)} | "
            f"{' / '.join(f'{v:.2f}' for v in fbl)} | {' / '.join(f'{v:.2f}' for v in floor)} |")


def main(stages=None) -> None:  # noqa: ANN001 - zoo Stages; default: the zoo's
    print("| stage (chosen model; integral gain) | FF 1 / 3 / 5 Hz | FF+FB+learning 1 / 3 / 5 Hz | noise floor (FF) 1 / 3 / 5 Hz |")
    print("|---|---|---|---|")
    for stage in zoo(seed=0) if stages is None else stages:
        print(row(stage), flush=True)


if __name__ == "__main__":
    main()
