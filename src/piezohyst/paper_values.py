"""Numbers printed in the paper (``shared/paper/pi-pso-piezo-control.txt``), with where they are.

They are used as the paper's side of every comparison the tool prints, and as reference values in
tests. Nothing here is used to *produce* a result.
"""

from __future__ import annotations

#: Section III-B: the identified Bouc-Wen parameters (SI units: kg, N s/m, N/m, m/V, -, 1/V, 1/V).
BOUC_WEN = {
    "m": 0.75,
    "b": 27.96,
    "k": 8.54e7,
    "alpha": 0.472,
    "beta": 0.072,
    "gamma": 0.0,
    "d1": 2.15e-8,
}

#: Section III-C: the twenty identified P-I weights (thresholds by eq. (4) over [0, 100] V).
PI_WEIGHTS = (
    0.616, 0.285, -0.177, 0.221, 0.130, 0.044,
    -0.238, 0.220, 0.085, 0.175, -0.203, -0.271,
    0.115, -0.167, 0.380, -0.681, 0.500, -0.098,
    0.364, -0.266,
)
PI_N = 20
PI_U_MAX = 100.0

#: Section IV-B: the inverse weights *as printed*. They do not follow from PI_WEIGHTS by the
#: paper's own eqs. (13)-(15) (1/0.616 = 1.623, not 1.834); kept only to show that.
PI_INVERSE_WEIGHTS_PRINTED = (
    1.834, -0.822, 0.148, 0.599, -0.525,
    -0.276, -0.046, 0.130, 0.324, 0.035,
    -0.443, -0.138, 0.271, -0.243, 0.070,
    0.034, -0.171, 0.306, -0.349, -0.110,
)

#: Table I (Bouc-Wen hysteresis-estimate feedforward): (freq Hz, feedback?) -> (e_max um, %, RMSE um)
TABLE_I = {
    (1, False): (0.198, 8.8, 0.0577),
    (1, True): (0.090, 4.4, 0.0191),
    (3, False): (0.337, 15.0, 0.0949),
    (3, True): (0.114, 5.1, 0.0258),
    (5, False): (0.459, 20.4, 0.1472),
    (5, True): (0.182, 8.1, 0.0427),
}

#: Table II (inverse P-I feedforward): (freq Hz, feedback?) -> (e_max um, %, RMSE um)
TABLE_II = {
    (1, False): (0.124, 5.5, 0.0253),
    (1, True): (0.074, 3.3, 0.0162),
    (3, False): (0.164, 7.3, 0.0378),
    (3, True): (0.133, 5.9, 0.0243),
    (5, False): (0.204, 9.1, 0.0533),
    (5, True): (0.155, 6.9, 0.0292),
}

#: Section I: open-loop hysteresis error "as high as 10-15% of the span of the motion".
OPEN_LOOP_HYSTERESIS_PERCENT = (10.0, 15.0)


def bouc_wen_model():  # type: ignore[no-untyped-def]
    """The paper's Bouc-Wen model as a :class:`~piezohyst.models.BoucWen`."""
    from .models.bouc_wen import BoucWen

    return BoucWen(**BOUC_WEN)


def pi_model():  # type: ignore[no-untyped-def]
    """The paper's P-I model: its weights on ``equal_thresholds(20, 100)``."""
    from .models.pi import PrandtlIshlinskii, equal_thresholds

    return PrandtlIshlinskii(equal_thresholds(PI_N, PI_U_MAX), PI_WEIGHTS)
