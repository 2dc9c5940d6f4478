"""The paper's whole experiment, end to end, on a plant (by default the :class:`VirtualRig`).

1. Open-loop loops at several frequencies (Fig. 2).
2. Excite the plant with the paper's 1 Hz, 0-100 V sinusoid and identify, from that record and
   with PSO as the paper does, the Bouc-Wen model (seven parameters within bounds, Sec. III-B)
   and the P-I weights (twenty, thresholds by eq. (4), Sec. III-C); Figs. 3 and 4.
3. Build both feedforward controllers: inverse P-I (eqs. 12-15) and the Bouc-Wen
   hysteresis estimate (eq. 10).
4. Tune the PID around each feedforward on the plant (:mod:`piezohyst.control.tuning`: ultimate
   integral gain by experiment, ``ki = ki_u / 3``).
5. Track 1, 3 and 5 Hz sinusoids with feedforward alone and with feedforward + feedback;
   the paper's figures of merit over the cycles after the first (Tables I and II, Figs. 6-9).
6. Check the paper's three claims against what was measured.

Choices the paper leaves open, and what is used here:

* the desired trajectory: a sinusoid from 0.25 to 2.25 µm (span 2.0 µm; the paper's e_max
  and % columns imply a span of about 2.25 µm). It stays inside what the rig reaches with
  0-100 V: at 0 V on the descending branch the hysteresis leaves the stage about 0.15 µm out;
* PSO budgets: Bouc-Wen 40 particles x 200 iterations (fitness eq. 9 on the whole record);
  P-I 100 particles x 3000 iterations (20 dimensions need more than the 7 of Bouc-Wen; the
  report prints how far that lands from the least-squares optimum on the same data);
* four cycles per frequency, the first discarded (start-up transient).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from .. import paper_values as pv
from ..analysis import LoopFigures, loop_figures
from ..control.feedforward import BoucWenFeedforward, InversePIFeedforward
from ..control.tracking import TrackingResult, track
from ..control.tuning import TuningResult, tune_integral_feedback
from ..data import Dataset
from ..identify import FitResult, fit_bouc_wen, fit_pi
from ..plant import open_loop
from ..rig import VirtualRig
from ..signals import sinusoid

MODELS = ("bouc-wen", "pi")
#: The ablation of ``piezohyst reproduce``: each configuration adds one means to the one before.
ABLATION = {
    "paper_pso_pi_ff": "paper: PSO P-I (eq. 4), inverse feedforward",
    "lsq_pi_ff": "+ least-squares P-I (global optimum), same 1 Hz record",
    "rate_pi_ff": "+ model chosen on held-out data from the commissioning run (lags, input lag, delay preview)",
    "rate_pi_ff_fb": "+ integral feedback tuned on the plant",
    "rate_pi_ff_fb_ilc": "+ iterative learning (repeating reference)",
}
MODEL_TITLES = {"bouc-wen": "Table I - Bouc-Wen hysteresis-estimate feedforward (eq. 10)",
                "pi": "Table II - inverse P-I feedforward (eqs. 12-15)"}
PAPER_TABLES = {"bouc-wen": pv.TABLE_I, "pi": pv.TABLE_II}


@dataclass
class PaperExperiment:
    """Everything the paper's experiment produced on the plant."""

    seed: int
    plant_description: str
    freqs: tuple[float, ...]
    reference_range: tuple[float, float]
    loops: dict[float, tuple[Dataset, LoopFigures]]
    identification_data: Dataset
    bw_fit: FitResult
    pi_fit: FitResult
    pi_lsq_rmse: float
    tuning: dict[str, TuningResult]
    runs: dict[tuple[str, float, bool], TrackingResult]
    time_s: float = 0.0
    timings: dict[str, float] = field(default_factory=dict)
    #: beyond the paper: config -> freq -> run (see ABLATION)
    ablation: dict[str, dict[float, TrackingResult]] = field(default_factory=dict)
    commissioned: Any = None

    def table_piezohyst(self) -> list[dict[str, Any]]:
        """Table III: piezohyst's best feedforward alone and with feedback, against its targets."""
        rows = []
        for f in self.freqs:
            for fb, key, target in ((False, "rate_pi_ff", (2.0, 0.6)), (True, "rate_pi_ff_fb_ilc", (1.0, 0.3))):
                run = self.ablation[key][f]
                paper = pv.TABLE_II.get((int(f), fb)) if float(f).is_integer() else None
                rows.append({
                    "excitation": f"{f:g}-Hz ({'feedforward+feedback' if fb else 'feedforward'})", "freq_hz": f,
                    "feedback": fb, "e_max_um": run.e_max, "e_max_percent": run.e_max_percent, "rmse_um": run.rmse,
                    "rmse_percent": run.rmse_percent, "target_e_max_percent": target[0],
                    "target_rmse_percent": target[1],
                    "meets_target": run.e_max_percent <= target[0] and run.rmse_percent <= target[1],
                    "paper_e_max_percent": paper[1] if paper else None, "clipped_samples": run.clipped,
                    "noise_floor_percent": run.info.get("noise_floor_percent"),
                })
        return rows

    def table(self, model: str) -> list[dict[str, Any]]:
        """Rows of Table I (``"bouc-wen"``) or II (``"pi"``), ours beside the paper's."""
        rows = []
        for f in self.freqs:
            for fb in (False, True):
                run = self.runs[(model, f, fb)]
                paper = PAPER_TABLES[model].get((int(f), fb)) if float(f).is_integer() else None
                rows.append({
                    "excitation": f"{f:g}-Hz ({'feedforward+feedback' if fb else 'feedforward'})",
                    "freq_hz": f, "feedback": fb,
                    "e_max_um": run.e_max, "e_max_percent": run.e_max_percent, "rmse_um": run.rmse,
                    "paper_e_max_um": paper[0] if paper else None,
                    "paper_e_max_percent": paper[1] if paper else None,
                    "paper_rmse_um": paper[2] if paper else None,
                    "clipped_samples": run.clipped,
                })
        return rows

    def claims(self) -> list[dict[str, Any]]:
        """The paper's three claims, each checked against the measured runs."""
        out = []
        # 1. inverse P-I feedforward beats Bouc-Wen feedforward at every frequency
        ev = []
        holds = True
        for f in self.freqs:
            a, b = self.runs[("pi", f, False)], self.runs[("bouc-wen", f, False)]
            better = a.rmse < b.rmse and a.e_max < b.e_max
            holds &= better
            ev.append(f"{f:g} Hz: RMSE {a.rmse * 1e3:.1f} vs {b.rmse * 1e3:.1f} nm, e_max {a.e_max * 1e3:.0f} vs {b.e_max * 1e3:.0f} nm")
        out.append({"claim": "inverse-P-I feedforward beats Bouc-Wen-estimate feedforward at every frequency "
                             "(lower RMSE and lower e_max; P-I vs Bouc-Wen)", "holds": bool(holds), "evidence": ev})
        # 2. feedback improves both
        ev = []
        holds = True
        for m in MODELS:
            for f in self.freqs:
                a, b = self.runs[(m, f, True)], self.runs[(m, f, False)]
                better = a.rmse < b.rmse and a.e_max < b.e_max
                holds &= better
                ev.append(f"{m} {f:g} Hz: RMSE {b.rmse * 1e3:.1f} -> {a.rmse * 1e3:.1f} nm, e_max {b.e_max * 1e3:.0f} -> {a.e_max * 1e3:.0f} nm")
        out.append({"claim": "adding PID feedback improves both feedforward schemes (lower RMSE and e_max)",
                    "holds": bool(holds), "evidence": ev})
        # 3. errors grow with frequency
        ev = []
        holds = True
        for m in MODELS:
            for fb in (False, True):
                r = [self.runs[(m, f, fb)].rmse for f in self.freqs]
                grows = all(x < y for x, y in zip(r, r[1:]))
                holds &= grows
                ev.append(f"{m} {'FF+FB' if fb else 'FF'}: RMSE " + " < ".join(f"{x * 1e3:.1f}" for x in r) + " nm"
                          + ("" if grows else " (does not grow throughout)"))
        out.append({"claim": "tracking errors (RMSE) grow with the frequency", "holds": bool(holds), "evidence": ev})
        return out

    def to_dict(self) -> dict[str, Any]:
        """Everything measured as plain data: what ``piezohyst reproduce`` writes to results.json."""
        return {
            "seed": self.seed, "plant": self.plant_description, "freqs_hz": list(self.freqs),
            "reference_um": list(self.reference_range),
            "loops": [{"freq_hz": f, "span_um": lf.span, "width_um": lf.width, "width_percent": lf.width_percent}
                      for f, (_, lf) in self.loops.items()],
            "identification": {
                "bouc_wen": {"parameters": self.bw_fit.model.parameters(), "paper": dict(pv.BOUC_WEN),
                             **self.bw_fit.summary()},
                "pi": {"weights": self.pi_fit.model.weights.tolist(), "thresholds": self.pi_fit.model.thresholds.tolist(),
                       "offset": self.pi_fit.model.offset, "paper_weights": list(pv.PI_WEIGHTS),
                       "lsq_optimum_rmse": self.pi_lsq_rmse, **self.pi_fit.summary()},
            },
            "pid": {m: {"kp": t.kp, "ki": t.ki, "kd": t.kd, "ki_ultimate": t.ki_ultimate, "method": t.method}
                    for m, t in self.tuning.items()},
            "table_I": self.table("bouc-wen"), "table_II": self.table("pi"),
            "claims": self.claims(), "time_s": self.time_s,
            **({"table_piezohyst": self.table_piezohyst(),
                "ablation": {k: {f"{f:g}": r.summary() for f, r in v.items()} for k, v in self.ablation.items()},
                "commissioned": self.commissioned.describe() if self.commissioned is not None else None}
               if self.ablation else {}),
        }


def run_paper_experiment(
    plant: Any = None, *, seed: int = 0, freqs: tuple[float, ...] = (1.0, 3.0, 5.0), cycles: int = 4,
    reference_range: tuple[float, float] = (0.25, 2.25), u_range: tuple[float, float] = (0.0, 100.0),
    pso_bw: tuple[int, int] = (40, 200), pso_pi: tuple[int, int] = (100, 3000),
    on_step: Callable[[str], None] | None = None, beyond: bool = True,
    on_paper_part: Callable[[PaperExperiment], None] | None = None,
) -> PaperExperiment:
    """Run the paper's experiment (module docstring) and return everything it measured.

    Parameters
    ----------
    plant : Plant, optional
        Default ``VirtualRig(seed=seed)``. Open-loop excitation uses ``plant.excite`` when the
        plant has it, else a loop over ``plant.step``.
    seed : int
        Seeds the rig's noise and both PSO runs: the same seed gives the same tables.
    on_step : callable, optional
        Called with a short description before each stage (progress reporting).
    on_paper_part : callable, optional
        Called, before the part beyond the paper, with the experiment as measured so far (the
        paper's part: loops, identification, tuning, runs; no ablation): what the paper's figures
        need, e.g. to draw them in another process while the rest runs (``piezohyst reproduce``).
    """
    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    plant = plant if plant is not None else VirtualRig(seed=seed)
    say = on_step or (lambda s: None)
    dt = plant.dt

    lo_u, hi_u = u_range
    loops = {}
    for f in freqs:
        say(f"open loop, {f:g} Hz (Fig. 2)")
        ds = open_loop(plant, sinusoid(f, 3, lo_u, hi_u, dt))
        loops[f] = (ds, loop_figures(ds.u, ds.y, period=int(round(1 / (f * dt)))))

    say("identification record: 1 Hz, 0-100 V")
    ident = open_loop(plant, sinusoid(1.0, 3, lo_u, hi_u, dt))
    t0 = time.perf_counter()
    say(f"PSO: Bouc-Wen, 7 parameters ({pso_bw[0]} x {pso_bw[1]})")
    bw_fit = fit_bouc_wen(ident.u, ident.y, dt, seed=seed, n_particles=pso_bw[0], max_iter=pso_bw[1], polish=False)
    timings["identify_bouc_wen_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    say(f"PSO: P-I, 20 weights ({pso_pi[0]} x {pso_pi[1]})")
    pi_fit = fit_pi(ident.u, ident.y, n=20, method="pso", seed=seed, n_particles=pso_pi[0], max_iter=pso_pi[1],
                    u_max=hi_u)
    timings["identify_pi_s"] = time.perf_counter() - t0
    pi_lsq = fit_pi(ident.u, ident.y, n=20, method="lsq", u_max=hi_u)

    ffs = {"bouc-wen": BoucWenFeedforward(bw_fit.model), "pi": InversePIFeedforward(pi_fit.model)}
    low, high = reference_range
    tuning = {}
    for m, ff in ffs.items():
        say(f"PID tuning around the {m} feedforward")
        tuning[m] = tune_integral_feedback(plant, ff, level=0.5 * (low + high))

    runs: dict[tuple[str, float, bool], TrackingResult] = {}
    t0 = time.perf_counter()
    for f in freqs:
        ref = sinusoid(f, cycles, low, high, dt)
        period = int(round(1 / (f * dt)))
        for m, ff in ffs.items():
            for fb in (False, True):
                say(f"tracking {f:g} Hz, {m}, {'feedforward + PID' if fb else 'feedforward'}")
                pid = tuning[m].pid(dt) if fb else None
                runs[(m, f, fb)] = track(plant, ref, ff, pid, period=period,
                                         label=f"{f:g} Hz, {m} {'feedforward + feedback' if fb else 'feedforward'}")
    timings["tracking_s"] = time.perf_counter() - t0

    def result(ablation: dict[str, dict[float, TrackingResult]], ctl: Any) -> PaperExperiment:
        return PaperExperiment(
            seed=seed, plant_description=repr(plant), freqs=tuple(freqs), reference_range=(low, high),
            loops=loops, identification_data=ident, bw_fit=bw_fit, pi_fit=pi_fit, pi_lsq_rmse=pi_lsq.rmse,
            tuning=tuning, runs=runs, time_s=time.perf_counter() - t_start, timings=dict(timings),
            ablation=ablation, commissioned=ctl,
        )

    if on_paper_part is not None:
        on_paper_part(result({}, None))
    ablation: dict[str, dict[float, TrackingResult]] = {}
    ctl = None
    if beyond:
        from ..commissioning import commission

        t0 = time.perf_counter()
        say("piezohyst: commissioning (identification run, fit, tuning)")
        ctl = commission(plant, seed=seed, u_range=u_range)
        lsq_ff = InversePIFeedforward(pi_lsq.model)
        for f in freqs:
            say(f"piezohyst: ablation at {f:g} Hz")
            ref = sinusoid(f, cycles, low, high, dt)
            period = int(round(1 / (f * dt)))
            ablation.setdefault("paper_pso_pi_ff", {})[f] = runs[("pi", f, False)]
            ablation.setdefault("lsq_pi_ff", {})[f] = track(plant, ref, lsq_ff, period=period)
            ablation.setdefault("rate_pi_ff", {})[f] = ctl.track(ref, feedback=False, learning=False, period=period)
            ablation.setdefault("rate_pi_ff_fb", {})[f] = ctl.track(ref, learning=False, period=period)
            ablation.setdefault("rate_pi_ff_fb_ilc", {})[f] = ctl.track(ref, period=period)
        timings["beyond_s"] = time.perf_counter() - t0
    return result(ablation, ctl)


# ------------------------------------------------------------------------------------------------
# figures and report
FIGURES = {
    "fig2": "fig2_loops.png", "fig3": "fig3_bouc_wen_vs_measured.png", "fig4": "fig4_pi_vs_measured.png",
    "fig6": "fig6_bouc_wen_ff_1hz.png", "fig7": "fig7_bouc_wen_ff_pid_1hz.png",
    "fig8": "fig8_pi_ff_1hz.png", "fig9": "fig9_pi_ff_pid_1hz.png",
}


def figure_files(formats: Any = ("png",)) -> list[str]:
    """The file names :func:`write_figures` writes for ``formats`` (to check before a run)."""
    from ..plots import check_formats

    fmts = check_formats(formats)
    return [name.rsplit(".", 1)[0] + "." + f for name in FIGURES.values() for f in fmts]


def figure_jobs(exp: PaperExperiment) -> list[Any]:
    """The paper's Figs. 2-4 and 6-9 of ``exp`` as :class:`~piezohyst._figures.FigureJob`
    (the data each plot needs, computed here; drawing them needs only :mod:`piezohyst.plots`).
    Only the paper's part of ``exp`` is read: its loops, identification, fits and runs."""
    from ..signals import cycles_after_first, estimate_period
    from .._figures import FigureJob

    jobs = []
    on_rig = exp.plant_description.startswith("VirtualRig")
    where = "the virtual rig" if on_rig else "the plant"
    data_label = "measured (virtual rig)" if on_rig else "measured"
    rig = exp.identification_data.meta.get("rig") or {}
    u_range = (rig["u_min"], rig["u_max"]) if "u_min" in rig and "u_max" in rig else None

    def job(key: str, plot: str, args: tuple[Any, ...], kwargs: dict[str, Any], title: str) -> None:
        jobs.append(FigureJob(key, FIGURES[key], plot, args, kwargs, note=f"{title}; {exp.plant_description}"))

    period = {f: int(round(1 / (f * exp.identification_data.dt))) for f in exp.freqs}
    runs = [(f"{f:g} Hz", ds.u[-period[f]:], ds.y[-period[f]:]) for f, (ds, _) in exp.loops.items()]
    title = f"Fig. 2 - open-loop hysteresis of {where}: the last cycle at each frequency"
    job("fig2", "plot_loops", (runs,), {"title": title}, title)
    ident = exp.identification_data
    p1 = int(round(1 / ident.dt))
    sl = slice(ident.u.size - p1, ident.u.size)
    t_last = ident.t[sl]
    for key, fit, name, num in (("fig3", exp.bw_fit, "Bouc-Wen", 3), ("fig4", exp.pi_fit, "P-I", 4)):
        y_model = fit.predict(ident.u, ident.dt)
        title = (f"Fig. {num} - identified {name} model against the 1 Hz record, last cycle "
                 f"(fit RMSE {fit.rmse * 1e3:.1f} nm on the whole record)")
        job(key, "plot_fit", (ident.u[sl], ident.y[sl], y_model[sl]),
            {"t": t_last, "model_name": f"identified {name}", "data_label": data_label, "title": title}, title)
    f1 = min(exp.freqs, key=lambda f: abs(f - 1.0))
    for key, (m, fb, name) in {"fig6": ("bouc-wen", False, "stand-alone Bouc-Wen feedforward"),
                               "fig7": ("bouc-wen", True, "Bouc-Wen feedforward + PID"),
                               "fig8": ("pi", False, "stand-alone inverse P-I feedforward"),
                               "fig9": ("pi", True, "inverse P-I feedforward + PID")}.items():
        run = exp.runs[(m, f1, fb)]
        title = (f"Fig. {key[3:]} - {f1:g} Hz tracking, {name}: e_max {run.e_max * 1e3:.1f} nm "
                 f"({run.e_max_percent:.1f} %), RMSE {run.rmse * 1e3:.1f} nm over the cycles after the first")
        # what TrackingResult.plot draws
        per = run.period if run.period is not None else estimate_period(run.reference)
        job(key, "plot_tracking", (run.t, run.reference, run.output),
            {"command": run.command, "scored": cycles_after_first(run.reference.size, per), "u_range": u_range,
             "title": title}, title)
    return jobs


def write_figures(exp: PaperExperiment, out: Any, *, force: bool = False, formats: Any = ("png",)) -> dict[str, Any]:
    """The paper's Figs. 2-4 and 6-9 from ``exp``, as files in ``out``.

    Parameters
    ----------
    exp : PaperExperiment
    out : path
        The folder (created if missing).
    force : bool
        Overwrite existing files.
    formats : str or sequence of str
        Any of ``"png"``, ``"pdf"``, ``"svg"`` (``"png,pdf"`` or a list): every figure is written
        in each. (The command line's ``--format`` flag is to pass this through.)

    Returns
    -------
    dict
        ``{key: path}`` with the file of the first format under ``"fig2"``, ... (the names in
        :data:`FIGURES` with that format's suffix), and each further format under
        ``"fig2.pdf"``, ... . Every file records what produced it in its metadata.
    """
    from ..plots import check_formats
    from .._figures import render

    return render(figure_jobs(exp), out, check_formats(formats), force=force)


def _fmt(v: Any, spec: str) -> str:
    return "-" if v is None else format(v, spec)


def report_markdown(exp: PaperExperiment) -> str:
    """A short report: tables beside the paper's, identified parameters, claims, figures."""
    from .._fileio import producer

    L = ["# The paper's experiment on the virtual rig", "",
         f"<!-- {producer()} -->", "",
         f"Plant: `{exp.plant_description}`. Seed {exp.seed}. Desired trajectory: sinusoids from "
         f"{exp.reference_range[0]:g} to {exp.reference_range[1]:g} µm; figures of merit over the cycles after the first. "
         f"Run time {exp.time_s:.1f} s.", ""]
    for m in MODELS:
        L += [f"## {MODEL_TITLES[m]}", "",
              f"PID: kp = {exp.tuning[m].kp:g}, ki = {exp.tuning[m].ki:.4g} 1/s, kd = {exp.tuning[m].kd:g} "
              f"({exp.tuning[m].method}; ultimate ki_u = {exp.tuning[m].ki_ultimate:.4g} 1/s).", "",
              "| Excitation | e_max (µm) rig | paper | % rig | paper | RMSE (µm) rig | paper |",
              "|---|---:|---:|---:|---:|---:|---:|"]
        for r in exp.table(m):
            L.append(f"| {r['excitation']} | {r['e_max_um']:.3f} | {_fmt(r['paper_e_max_um'], '.3f')} | "
                     f"{r['e_max_percent']:.1f} | {_fmt(r['paper_e_max_percent'], '.1f')} | {r['rmse_um']:.4f} | "
                     f"{_fmt(r['paper_rmse_um'], '.4f')} |")
        clipped = sum(r["clipped_samples"] or 0 for r in exp.table(m))
        L.append("")
        if clipped:
            L += [f"Commands clipped at the amplifier's range in these runs: {clipped} samples in all "
                  "(each run's count is in results.json).", ""]
    if exp.ablation:
        L += ["## Table III - piezohyst (beyond the paper)", "",
              "Best feedforward alone: the compensator of the model `piezohyst.commission()` chose on held-out data "
              "(every linear kind and structure, fitted by least squares on a 9.5 s commissioning run). With feedback: "
              "plus integral feedback tuned on the plant and iterative learning. Targets: piezohyst's own "
              "(e_max <= 2 % and RMSE <= 0.6 % of span with feedforward alone; 1 % and 0.3 % with feedback).", "",
              "| Excitation | e_max (µm) | e_max % | target % | paper % (Table II) | RMSE (µm) | RMSE % | target % | met |",
              "|---|---:|---:|---:|---:|---:|---:|---:|---|"]
        for r in exp.table_piezohyst():
            L.append(f"| {r['excitation']} | {r['e_max_um']:.4f} | {r['e_max_percent']:.2f} | {r['target_e_max_percent']:g} | "
                     f"{_fmt(r['paper_e_max_percent'], '.1f')} | {r['rmse_um']:.4f} | {r['rmse_percent']:.2f} | "
                     f"{r['target_rmse_percent']:g} | {'yes' if r['meets_target'] else 'NO'} |")
        d = exp.commissioned.describe()
        L += ["", f"Commissioning took {d['commissioning_time_s']:.1f} s; it chose a {d['model']} model "
              f"({d['structure']}), hold-out error {1e3 * d['holdout_rmse_um']:.1f} nm, a delay of {d['delay_samples']} "
              f"sample(s); ki = {d['ki']:.4g} 1/s.", "",
              "### Ablation: what each means contributes (e_max % of span / RMSE nm)", "",
              "| configuration | " + " | ".join(f"{f:g} Hz" for f in exp.freqs) + " |",
              "|---|" + "---:|" * len(exp.freqs)]
        for key, name in ABLATION.items():
            cells = [f"{exp.ablation[key][f].e_max_percent:.2f} % / {1e3 * exp.ablation[key][f].rmse:.1f}" for f in exp.freqs]
            L.append(f"| {name} | " + " | ".join(cells) + " |")
        floors = [r["noise_floor_percent"] for r in exp.table_piezohyst() if r["feedback"]]
        sigma = d.get("sensor_noise_um")
        if sigma is not None and all(f is not None for f in floors):
            L += ["", f"The commissioning estimated the sensor's noise at {1e3 * sigma:.2g} nm RMS (from what its model "
                  "leaves of the identification run), so an RMSE near it and an e_max near the noise floor (the e_max "
                  "that noise alone reaches with probability one half over a run's scored samples: "
                  + " / ".join(f"{f:.2f}" for f in floors) + f" % of span at {' / '.join(f'{f:g}' for f in exp.freqs)} "
                  "Hz with feedback) is what any controller reaches when judged by the same sensor. Where a means adds "
                  "nothing it is because the error is already at that floor.", ""]
    L += ["## The paper's claims, checked", ""]
    for c in exp.claims():
        L.append(f"- **{c['claim']}**: {'holds' if c['holds'] else 'does NOT hold'} on the rig.")
        for e in c["evidence"]:
            L.append(f"  - {e}")
    L += ["", "## Identified models", "", "Bouc-Wen (PSO, fitness eq. 9, "
          f"RMSE {exp.bw_fit.rmse * 1e3:.2f} nm, {exp.bw_fit.time_s:.1f} s):", "",
          "| parameter | identified | paper | constrained by 1 Hz data? |", "|---|---:|---:|---|"]
    for name in ("m", "b", "k", "d1", "alpha", "beta", "gamma"):
        s = (exp.bw_fit.sensitivity or {}).get(name, float("nan"))
        L.append(f"| {name} | {getattr(exp.bw_fit.model, name):.4g} | {pv.BOUC_WEN[name]:.4g} | "
                 f"{'barely' if s < 0.01 else 'yes'} ({100 * s:.2g} % RMSE rise for 10 %) |")
    w = exp.pi_fit.model.weights
    L += ["", f"P-I (PSO, 20 weights, thresholds by eq. 4; RMSE {exp.pi_fit.rmse * 1e3:.2f} nm, against "
          f"{exp.pi_lsq_rmse * 1e3:.2f} nm for the least-squares optimum on the same data; "
          f"{exp.pi_fit.time_s:.1f} s). The paper's P-I output is in unstated units (its weights map 0-100 V onto "
          "about 0-100), so the weights are compared normalised by their sum:", "",
          "| i | w_i / sum(w), identified | paper |", "|---:|---:|---:|"]
    for i, (a, b) in enumerate(zip(w / w.sum(), np.array(pv.PI_WEIGHTS) / sum(pv.PI_WEIGHTS)), 1):
        L.append(f"| {i} | {a:.3f} | {b:.3f} |")
    L += ["", "## Open-loop loops (Fig. 2)", "", "| freq (Hz) | span (µm) | width (µm) | width % of span |",
          "|---:|---:|---:|---:|"]
    for f, (_, lf) in exp.loops.items():
        L.append(f"| {f:g} | {lf.span:.3f} | {lf.width:.3f} | {lf.width_percent:.1f} |")
    L += ["", "## Figures", ""]
    captions = {"fig2": "Fig. 2 - loops at several frequencies", "fig3": "Fig. 3 - Bouc-Wen model vs measured",
                "fig4": "Fig. 4 - P-I model vs measured", "fig6": "Fig. 6 - 1 Hz, Bouc-Wen feedforward",
                "fig7": "Fig. 7 - 1 Hz, Bouc-Wen feedforward + PID", "fig8": "Fig. 8 - 1 Hz, inverse P-I feedforward",
                "fig9": "Fig. 9 - 1 Hz, inverse P-I feedforward + PID"}
    for key, fname in FIGURES.items():
        L += [f"![{captions[key]}]({fname})", ""]
    return "\n".join(L) + "\n"


#: The files of one run's output folder (written as one set with a ``manifest.json``).
RESULT_FILES = (*FIGURES.values(), "report.md", "results.json")


def results_folder(out: Any, *, force: bool = False, formats: Any = ("png",)) -> Any:
    """The :class:`~piezohyst._fileio.OutputFolder` a run's results go to; ``.check()`` it before
    the run to refuse a bad or occupied folder before the work, not after. ``formats``: the
    figures' formats (PNG is always among them: the report embeds it)."""
    from .._fileio import OutputFolder

    return OutputFolder(out, (*figure_files(_with_png(formats)), "report.md", "results.json"), force=force)


def _with_png(formats: Any) -> tuple[str, ...]:
    from ..plots import check_formats

    return tuple(dict.fromkeys(("png", *check_formats(formats))))


def write_results(exp: PaperExperiment, out: Any, *, force: bool = False, formats: Any = ("png",)) -> list[Any]:
    """Write the figures, ``report.md`` and ``results.json`` of ``exp`` into the folder ``out``,
    as one set: they appear together or not at all (an interrupted run leaves the previous set
    or nothing), and a previous set is replaced only with ``force``. The figures are written as
    PNG (embedded in the report) and in each further format of ``formats`` (``"pdf"``, ``"svg"``).

    Returns the paths written (in the final folder).
    """
    fmts = _with_png(formats)
    with results_folder(out, force=force, formats=fmts) as tmp:
        return write_results_into(exp, tmp, out, formats=fmts)


def write_results_into(exp: PaperExperiment, tmp: Any, out: Any, *, formats: Any = ("png",),
                       figures: dict[str, Any] | None = None) -> list[Any]:
    """The files of :func:`write_results` written into ``tmp``, the temporary folder of
    :func:`results_folder` ``(out, ...)`` (entered by the caller, which publishes the set);
    ``figures``: the ``{key: path}`` of :func:`write_figures` when the figures were already drawn
    into ``tmp`` (e.g. by a :class:`~piezohyst._figures.BackgroundFigures` worker while the
    experiment ran). Returns the paths the files will have in ``out``."""
    from pathlib import Path

    from .._fileio import atomic_write_text, dumps_strict, producer

    fmts = _with_png(formats)
    tmp = Path(tmp)
    paths = figures if figures is not None else write_figures(exp, tmp, force=True, formats=fmts)
    atomic_write_text(tmp / "report.md", report_markdown(exp), force=True)
    doc = {"producer": producer(), **exp.to_dict()}
    atomic_write_text(tmp / "results.json", dumps_strict(doc, indent=2) + "\n", force=True)
    final = Path(out)
    return [final / Path(p).name for p in paths.values()] + [final / "report.md", final / "results.json"]
