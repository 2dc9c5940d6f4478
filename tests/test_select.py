"""Model selection on held-out data (issue 11, items 4 and 6): ranges from the data, the choice,
the refit, the table of candidates, and the warnings."""

import math
import warnings

import numpy as np
import pytest

import piezohyst as ph
from piezohyst.identify.select import excitation_band, search_ranges

DT = 1e-3


def record(freq=1.0, seconds=8.0, lo=0.0, hi=100.0):
    """Two full-range cycles, then cycles of decaying amplitude (nested minor loops)."""
    n = int(seconds / DT)
    t = np.arange(n) * DT
    full = int(round(2.0 / (freq * DT)))
    amp = np.concatenate([np.ones(full), np.linspace(1.0, 0.4, max(n - full, 0))])[:n]
    return 0.5 * (lo + hi) - 0.5 * (hi - lo) * np.cos(2 * np.pi * freq * t) * amp


def test_ranges_follow_the_data_not_a_stage():
    u = record(freq=2.0)
    f_lo, f_hi = excitation_band(u, DT)
    assert 1.0 <= f_lo <= 2.0 <= f_hi <= 4.0
    r = search_ranges(u, DT, n_fit=u.size, one_rate_rule=False)  # (the ranges of a record of several rates)
    # lags from a few samples up to half the record, two per decade; delays up to 5 % of the
    # fastest period; input lags up to 1 / (2 pi f_hi), in octaves from two samples
    assert r.creep_taus[0] >= 2 * DT and r.creep_taus[-1] <= 0.5 * u.size * DT
    assert all(b / a == pytest.approx(np.sqrt(10)) for a, b in zip(r.creep_taus, r.creep_taus[1:]))
    assert r.max_delay >= 5 and r.max_delay * DT <= max(0.05 / f_hi, 5 * DT) + DT
    assert all(t <= 1.0 / (2 * np.pi * f_hi) for t in r.input_taus)
    assert r.input_taus[0] == 2 * DT and r.input_taus[-1] > 0.5 / (2 * np.pi * f_hi)
    # the same record at 10x the sample rate: the same ranges in seconds
    r10 = search_ranges(np.repeat(u, 10), DT / 10, n_fit=u.size * 10, one_rate_rule=False)
    assert r10.creep_taus[-1] == pytest.approx(r.creep_taus[-1], rel=1e-6)
    # where two per decade stop more than a quarter decade short of half the fitting part, that
    # half is the last lag (a creep of a few seconds is what such a record identifies)
    for n_fit in (2500, 5000, 6000, 8000):
        taus = search_ranges(u, DT, n_fit=n_fit, one_rate_rule=False).creep_taus
        half = 0.5 * n_fit * DT
        assert taus[-1] <= half * (1 + 1e-9) and taus[-1] >= half / 10 ** 0.25
        assert all(b / a == pytest.approx(np.sqrt(10)) for a, b in zip(taus[:-2], taus[1:-1]))


def test_exact_model_is_found_and_refitted_on_everything():
    true = ph.PrandtlIshlinskii(ph.equal_thresholds(10, 100.0), np.linspace(0.02, 0.002, 10), offset=0.4)
    u = record()
    y = true.simulate(u)
    fit = ph.fit_model(u, y, DT)
    assert fit.rmse < 1e-9 * np.ptp(y)
    assert fit.n_samples == u.size  # refitted on the whole record
    table = fit.info["candidates"]
    assert sum(c["chosen"] for c in table) == 1
    assert fit.info["holdout"]["rmse"] == min(c["holdout_rmse"] for c in table) or fit.info["holdout"]["rmse"] < 1e-9
    # the record is of one rate (1 Hz, decaying): that, and nothing else, is said
    assert len(fit.warnings) == 1 and "has one rate (1.07 Hz" in fit.warnings[0], fit.warnings


def _two_rates(seconds=8.0):
    """A record of two rates: full-range cycles at 1 Hz, then at 5 Hz, decaying."""
    return np.concatenate([record(freq=1.0, seconds=seconds / 2), record(freq=5.0, seconds=seconds / 2)])


def test_one_rate_records_are_told_apart_and_searched_for_what_they_show():
    u1 = record(freq=2.0)
    r1 = search_ranges(u1, DT, n_fit=u1.size)
    assert r1.single_rate_hz == pytest.approx(2.0, rel=0.05)
    # no input lag and no lag within a decade of the excitation: nothing one rate can identify
    assert r1.input_taus == () and all(t >= 10 / (2 * np.pi * 2.0) for t in r1.rate_taus + r1.creep_taus)
    assert search_ranges(u1, DT, n_fit=u1.size, one_rate_rule=False).single_rate_hz is None
    r2 = search_ranges(_two_rates(), DT, n_fit=8000)
    assert r2.single_rate_hz is None and r2.input_taus
    one_then_two = np.concatenate([record(freq=1.0, seconds=4.0), record(freq=2.0, seconds=4.0)])  # half an octave apart
    assert search_ranges(one_then_two, DT, n_fit=8000).single_rate_hz is None


def test_a_rate_dependent_model_asked_for_on_one_rate_is_given_and_qualified():
    true = ph.PrandtlIshlinskii(ph.equal_thresholds(10, 100.0), np.linspace(0.02, 0.002, 10))
    u = ph.sinusoid(1.0, 3, 0.0, 100.0, DT)
    fit = ph.fit_model(u, true.simulate(u), DT, kind="rate-dependent")
    # lags slower than the excitation (1 / (2 pi f)), and a word on what they rest on
    assert fit.model.kind == "rate-dependent" and min(fit.model.taus) >= 1 / (2 * np.pi * 1.05)
    assert any("no lag faster than the excitation; the lags and delay kept are fitted to that rate" in w
               for w in fit.warnings), fit.warnings
    auto = ph.fit_model(u, true.simulate(u), DT)  # the automatic choice: none within a decade
    assert all(t >= 10 / (2 * np.pi * 1.05) for t in auto.info["search"]["rate_taus_s"] + auto.info["search"]["creep_taus_s"])
    assert not auto.info["search"]["input_taus_s"]


def test_delay_is_found_on_held_out_data():
    true = ph.PrandtlIshlinskii(ph.equal_thresholds(10, 100.0), np.linspace(0.02, 0.002, 10))
    u = record(freq=3.0)
    y = np.concatenate([np.zeros(7), true.simulate(u)[:-7]])
    fit = ph.fit_model(u, y, DT, kind="pi")
    assert fit.delay == 7


def test_validation_sets_choose_and_are_reported():
    true = ph.PrandtlIshlinskii(ph.equal_thresholds(10, 100.0), np.linspace(0.02, 0.002, 10))
    u = record()
    y = true.simulate(u)
    uv = record(freq=2.5, seconds=2.0)
    fit = ph.fit_model(u, y, DT, kind="pi", validation=[(uv, true.simulate(uv)), (u, y, u.size // 2)])
    assert fit.info["holdout"]["on"] == "validation data"
    assert len(fit.info["holdout"]["per_set_rmse"]) == 2
    with pytest.raises(ValueError, match="first scored sample"):
        ph.fit_model(u, y, DT, kind="pi", validation=[(u, y, u.size + 5)])


def test_kind_names_and_refusals():
    u = record(seconds=3.0)
    y = 0.02 * u
    for kind in ("pi", "preisach", "asymmetric-pi", "rate-dependent", "bouc-wen-hysteresis"):
        assert ph.fit_model(u, y + 0.001 * np.sin(u), DT, kind=kind).model.is_invertible
    with pytest.raises(ValueError, match="unknown model kind"):
        ph.fit_model(u, y, DT, kind="maxwell")
    with pytest.raises(ValueError, match="sample period"):
        ph.fit_model(u, y, None, kind="rate-dependent")
    with pytest.raises(ValueError, match="negate y"):
        ph.fit_model(u, -y, DT)
    # a falling output is also what a loop that falls after each reversal gives on small swings:
    # the message names both causes, with the record's correlation and input range
    with pytest.raises(ValueError, match=r"correlation -1\.00; input 0 to .*excite a wider range"):
        ph.fit_model(u, -y, DT)
    # an output that does not follow the input at all (swings inside a dead zone: found by fuzzing
    # with correlations of -0.01 to -0.26) is not said to fall as the input rises
    noise = np.random.default_rng(4).normal(0.0, 1e-3, u.size) - 1e-4 * (u - u.mean()) / np.std(u)
    assert -0.3 < np.corrcoef(u, noise)[0, 1] < 0
    with pytest.raises(ValueError, match=r"hardly follows the input.*dead band or play"):
        ph.fit_model(u, noise, DT)
    with pytest.raises(ValueError, match="holdout"):
        ph.fit_model(u, y, DT, holdout=0.9)


def test_a_loop_that_falls_after_reversals_is_flagged():
    # first partial sum negative: right after each reversal the output moves against the input
    pi = ph.PrandtlIshlinskii(np.arange(8) / 8 * 50.0, np.array([-0.3, 1, 1, 1, 1, 1, 1, 1]) * 0.004)
    u = record(freq=1.0, seconds=8.0)
    fit = ph.fit_model(u, pi.simulate(u), DT, kinds=["prandtl-ishlinskii", "rate-dependent"])
    text = " ".join(fit.warnings)
    assert "falling" in text or "against" in text or "old way" in text, fit.warnings
    # and its compensator stays bounded: the inverse's gain is at most 1 / margin
    x = ph.sinusoid(1.0, 2, 5.0, 15.0, DT)
    cmd = fit.model.compensator(DT).command(x)
    assert np.all(np.isfinite(cmd)) and np.abs(np.diff(cmd[10:])).max() < 5.0


def test_a_model_that_misses_the_loop_shape_is_flagged():
    # a strongly asymmetric stage seen through a plain P-I model: large, direction-dependent error
    u = record(freq=1.0, seconds=6.0)
    y = 0.02 * u + 0.6 * np.tanh((u - 50.0) / 20.0) + 0.3 * np.sign(np.gradient(u)) * (u / 100.0) ** 3
    fit = ph.fit_model(u, y, DT, kind="pi", n=5)
    assert any("direction" in w or "hold-out error" in w for w in fit.warnings), fit.warnings


def search_outcome(u, y, dt):
    """What a search decides and lists: the choice, the candidates with their hold-out errors, the model."""
    fit = ph.fit_model(u, y, dt)
    return fit.info["chosen"], [(c["label"], c["holdout_rmse"]) for c in fit.info["candidates"]], fit.model.to_dict()


def assert_same_search(a, b):
    assert len(a[1]) > 50
    assert a[0] == b[0] and a[1] == b[1]
    assert repr(a[2]) == repr(b[2])


def recorded_siblings(monkeypatch):
    """The scorers that fit_model's threaded searches make, as they are made."""
    import piezohyst.identify.select as sel

    siblings = []
    make = sel._Scorer.sibling
    monkeypatch.setattr(sel._Scorer, "sibling", lambda self: siblings.append(make(self)) or siblings[-1])
    return siblings


def test_the_search_keeps_few_designs_and_chooses_exactly_as_with_all(monkeypatch):
    # the search keeps only the last few designs and static parts (memory: 1.28 GB -> 0.56 GB
    # peak on the VirtualRig's commissioning record); one it dropped is built again bit for bit,
    # with the Gram matrices it had, so every candidate scores exactly as when all are kept
    import piezohyst.identify.select as sel

    rng = np.random.default_rng(3)
    true = ph.Preisach(lo=0.0, hi=100.0, weights=rng.random(ph.models.preisach.grid_size(6)) * 0.01, slope=0.02)
    u = record(freq=2.0)
    y = true.simulate(u) + 0.01 * np.convolve(rng.standard_normal(u.size), np.ones(20) / 20, "same")

    monkeypatch.setattr(sel, "PREPARED_KEPT", 1)
    monkeypatch.setattr(sel, "STATIC_KEPT", 1)
    few = search_outcome(u, y, DT)
    monkeypatch.setattr(sel, "PREPARED_KEPT", 10**6)
    monkeypatch.setattr(sel, "STATIC_KEPT", 10**6)
    assert_same_search(few, search_outcome(u, y, DT))


def test_the_threaded_searches_choose_and_list_exactly_as_one_after_the_other(monkeypatch):
    # the two P-I threshold rules' searches run on two threads, each with a scorer of its own;
    # the candidates (labels, order, hold-out errors), the choice and the model are those of
    # the serial search, bit for bit
    import piezohyst.identify.select as sel

    rig = ph.VirtualRig(seed=2)
    d = rig.excite(record(freq=3.0))
    monkeypatch.setattr(sel, "_more_threads_wanted", lambda: True)  # whatever this machine's numba says
    monkeypatch.setattr(sel, "PARALLEL_SEARCHES", False)
    serial = search_outcome(d.u, d.y, rig.dt)
    monkeypatch.setattr(sel, "PARALLEL_SEARCHES", True)
    assert_same_search(serial, search_outcome(d.u, d.y, rig.dt))


def test_an_interrupted_search_stops_the_other_thread_at_its_next_candidate(monkeypatch):
    # Ctrl-C in the first search (here: raised by the progress callback as the search starts)
    # reaches the caller, and the search on the other thread stops at its next candidate instead
    # of running to its end (a whole search tries dozens)
    import piezohyst.identify.select as sel

    # (what the sibling had tried when it was told to stop is recorded as the flag is set: a
    # count of candidates alone, "< 10", failed under load, where the first thread waited for a
    # core while the other fitted)
    class Watched(sel._Scorer):
        @property
        def cancelled(self):
            return self.__dict__.get("_told", False)

        @cancelled.setter
        def cancelled(self, value):
            if value and not self.__dict__.get("_told"):
                self.tried_when_told = len(self.tried)
            self.__dict__["_told"] = value

    rig = ph.VirtualRig(seed=2)
    d = rig.excite(record(freq=3.0))
    siblings = []
    make = sel._Scorer.sibling

    def watched_sibling(self):
        s = make(self)
        s.__class__ = Watched
        siblings.append(s)
        return s

    monkeypatch.setattr(sel._Scorer, "sibling", watched_sibling)
    monkeypatch.setattr(sel, "_more_threads_wanted", lambda: True)  # whatever this machine's numba says

    def progress(text):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        ph.fit_model(d.u, d.y, rig.dt, progress=progress)
    assert len(siblings) == 1 and siblings[0].cancelled
    # at most the candidate it was fitting when told: not the dozens of a whole search
    assert len(siblings[0].tried) <= siblings[0].tried_when_told + 1, [c.label for c in siblings[0].tried]


def test_one_numba_thread_means_one_search_thread(monkeypatch):
    # a fleet's worker (one per core) sets numba to one thread: its fits start no thread either
    import numba

    rig = ph.VirtualRig(seed=2)
    d = rig.excite(record(freq=3.0))
    siblings = recorded_siblings(monkeypatch)
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = ph.fit_model(d.u, d.y, rig.dt)
    finally:
        numba.set_num_threads(before)
    assert siblings == []
    if before > 1:
        two = ph.fit_model(d.u, d.y, rig.dt)
        assert len(siblings) == 1
        assert one.info["chosen"] == two.info["chosen"]


def test_designs_of_one_static_block_share_its_gram_and_agree_with_the_whole_design():
    # the Gram matrix is formed block by block, S'S once per static block and number of rows
    # (most of the work on a wide Preisach grid), E'[S | E] per design: the same matrix as the
    # whole design's B'B, to rounding, for any number of rows (also those derived from a longer one)
    from piezohyst.identify.linear import Structure, prepare

    u = record(freq=2.0)
    cache: dict = {}
    a = prepare(u, DT, Structure(static="preisach", size=8, taus=(0.01, 0.3)), cache=cache)
    b = prepare(u, DT, Structure(static="preisach", size=8, taus=(0.05,)), cache=cache)
    assert a.static is b.static and a.static_grams is b.static_grams
    for pre in (a, b):
        for rows in (u.size, u.size - 7, int(0.9 * u.size), u.size // 3):
            whole = np.hstack([pre.static, pre.extra])[: pre.n_rows(rows)]
            want = whole.T @ whole
            np.testing.assert_allclose(pre.gram(rows), want, rtol=1e-12, atol=1e-12 * np.abs(want).max())
    assert sorted(a.static_grams) == sorted({a.n_rows(r) for r in (u.size, u.size - 7, int(0.9 * u.size), u.size // 3)})


def test_warmup_makes_the_fit_independent_of_the_stage_past():
    # a Preisach stage in two different states (what it did before nobody recorded), swept over
    # its whole range and then excited: after the sweep both records are the same. With the sweep
    # as warm-up (run through, not fitted) the fits are identical; fitted from the model's
    # demagnetised state, each fits its own past into the model
    rng = np.random.default_rng(3)
    true = ph.Preisach(lo=0.0, hi=100.0, weights=rng.random(ph.models.preisach.grid_size(6)) * 0.01, slope=0.02)

    def rc(a, b, n):
        return a + (b - a) * 0.5 * (1 - np.cos(np.pi * np.arange(1, n + 1) / n))

    sweep = np.concatenate([rc(40.0, 100.0, 400), rc(100.0, 0.0, 600)])
    t = np.arange(6000) * DT
    u = np.concatenate([sweep, 50.0 - 50.0 * np.cos(2 * np.pi * t) * np.linspace(1.0, 0.3, t.size)])
    noise = 0.002 * rng.standard_normal(u.size)
    fits = {}
    for name, past in (("high", np.concatenate([rc(0.0, 90.0, 500), rc(90.0, 40.0, 400)])),
                       ("low", np.concatenate([rc(0.0, 60.0, 500), rc(60.0, 40.0, 400)]))):
        y = true.simulate(np.concatenate([past, u]))[past.size:] + noise
        fits[name, 0] = ph.fit_model(u, y, DT, kind="preisach", delay=0)
        fits[name, sweep.size] = ph.fit_model(u, y, DT, kind="preisach", delay=0, warmup=sweep.size)
    a, b = fits["high", sweep.size], fits["low", sweep.size]
    assert a.info["warmup"] == sweep.size
    assert repr(a.model.to_dict()) == repr(b.model.to_dict()) and a.rmse == b.rmse
    assert repr(fits["high", 0].model.to_dict()) != repr(fits["low", 0].model.to_dict())
    # and the model predicts a new run after the same sweep better than the one fitted through it
    test = np.concatenate([sweep, 50.0 - 30.0 * np.sin(2 * np.pi * 2.0 * np.arange(3000) * DT)])
    truth = true.simulate(np.concatenate([u, test]))[-test.size:][sweep.size:]
    err = {w: float(np.sqrt(np.mean((truth - fits["high", w].model.predict(test, DT)[sweep.size:]) ** 2)))
           for w in (0, sweep.size)}
    assert err[sweep.size] < err[0]


def test_warmup_is_checked():
    u = record()
    y = 0.2 * u
    with pytest.raises(ValueError, match="warmup"):
        ph.fit_model(u, y, DT, kind="pi", warmup=u.size)


def test_an_output_that_dwells_on_one_value_still_gets_output_maps():
    """A noise-free stage with a dead zone rests at exactly the same output for a third of the
    record: two quantiles of the output coincide. The map's knots come from the distinct values
    then (commission() had stopped with "too few distinct values" on such a stage)."""
    from piezohyst.identify.linear import map_knots_for

    dt = 1e-3
    u = ph.sinusoid(1.0, 6, -50.0, 100.0, dt) * np.linspace(1.0, 0.6, 6000)
    pi = ph.PrandtlIshlinskii(np.arange(6) / 6 * 60.0, np.full(6, 0.004))
    h = pi.simulate(u)
    y = np.maximum(h - np.quantile(h, 0.4), 0.0)  # a dead zone of the output: 40 % of the samples at 0
    assert np.mean(y == 0.0) >= 0.4
    knots, centre = map_knots_for(y, 8)
    assert knots.size == 8 and np.all(np.diff(knots) > 0) and knots[0] >= y.min()
    # where the quantiles are distinct the knots are what they always were
    noisy = y + np.random.default_rng(0).normal(0.0, 1e-6, y.size)
    assert np.array_equal(map_knots_for(noisy, 8)[0], np.quantile(noisy, np.arange(1, 9) / 9))
    fit = ph.fit_model(u, y, dt, kind="asymmetric-pi", delay=0)
    assert fit.model.kind == "asymmetric-pi"
    # a flat output is beyond the map's slope bound (its inverse's slope is bounded): a rough fit,
    # but a fit (7.8 % of span measured), where the search had stopped with an error
    assert fit.info["holdout"]["percent_of_span"] < 15.0


@pytest.mark.slow
def test_a_model_fitted_on_one_rate_carries_over_to_another():
    """The zoo's asymmetric Bouc-Wen stage (10 kHz, amplifier lag, creep, 800 Hz resonance, delay 3),
    identified from three cycles of a 1 Hz full-range sinusoid, predicting a 5 Hz one: the model
    chosen on the record's own later part was 16.1 % of span off (lags that made up the loop's
    shape at 1 Hz), a plain P-I model without delay 1.79 %."""
    from tests.plants.zoo import zoo

    stage = zoo(seed=0)[4]
    lo, hi = stage.u_range

    def record_at(freq, cycles):
        u = ph.sinusoid(freq, cycles, lo, hi, stage.dt)
        n = int(0.2 / stage.dt)  # from rest (0 V) to the first sample, smoothly
        return stage.excite(np.concatenate([u[0] * 0.5 * (1 - np.cos(np.pi * np.arange(n) / n)), u]))

    train, test = record_at(1.0, 3), record_at(5.0, 15)
    fit = ph.fit_model(train)
    assert any("has one rate" in w for w in fit.warnings)
    assert not fit.info["search"]["input_taus_s"]
    pred = fit.model.predict(test.u, test.dt if getattr(fit.model, "dynamic", False) else None)
    d = fit.delay
    pred = np.concatenate([np.full(d, pred[0]), pred[: pred.size - d]]) if d else pred
    k0 = test.u.size // 3
    rms = 100 * np.sqrt(np.mean((test.y[k0:] - pred[k0:]) ** 2)) / np.ptp(test.y)
    assert rms < 3.0, (rms, fit.info["chosen"])


def test_one_rate_keeps_no_delay_against_a_ruled_out_undelayed_candidate():
    """The tutorial's path (docs/tutorial.md): four 1 Hz full-range cycles of the VirtualRig
    (one sample of sensor delay). The generalized Duhem model without delay is ruled out (its
    branches would not rise), and its infinite hold-out error was "halved" by any delay: the
    search kept a Duhem model with 350 samples (35 ms) of delay, whose feedforward then missed a
    2 Hz reference by 21 % of span. The best undelayed candidate stands in for a ruled-out one."""
    rig = ph.VirtualRig(seed=0)
    train = rig.excite(ph.sinusoid(1.0, 4, 0.0, 100.0, rig.dt))
    fit = ph.fit_model(train, kind="auto")
    assert any("has one rate" in w for w in fit.warnings)
    assert fit.delay <= 5, fit.info["chosen"]
    # the rule held: what was kept is no worse than half the best undelayed candidate, or is one
    undelayed = [c["holdout_rmse"] for c in fit.info["candidates"]
                 if "delay 0" in c["label"] and "history" not in c["label"] and np.isfinite(c["holdout_rmse"])]
    assert fit.delay == 0 or fit.info["holdout"]["rmse"] < 0.5 * min(undelayed)


def test_a_record_of_major_loops_only_is_said_to_leave_the_inner_loops_unidentified():
    true = ph.PrandtlIshlinskii(ph.equal_thresholds(10, 100.0), np.linspace(0.02, 0.002, 10))
    full = ph.sinusoid(1.0, 4, 0.0, 100.0, DT)
    fit = ph.fit_model(full, true.simulate(full), DT, kind="pi")
    assert any("reverses only at the ends of its range (7 reversals)" in w for w in fit.warnings), fit.warnings
    nested = record()  # two full cycles, then decaying ones: inner loops are there
    fit = ph.fit_model(nested, true.simulate(nested), DT, kind="pi")
    assert not any("reverses only at the ends" in w for w in fit.warnings), fit.warnings


def test_a_record_that_never_reverses_is_said_to_show_no_loop():
    true = ph.PrandtlIshlinskii(ph.equal_thresholds(10, 100.0), np.linspace(0.02, 0.002, 10))
    ramp = np.linspace(0.0, 100.0, 4000) + 0.2 * np.sin(np.arange(4000))  # dither does not count
    fit = ph.fit_model(ramp, true.simulate(ramp), DT, kind="pi")
    assert any("never reverses" in w for w in fit.warnings), fit.warnings
    once = np.concatenate([ramp, ramp[::-1]])  # up and down once: the descending branch is there
    fit = ph.fit_model(once, true.simulate(once), DT, kind="pi")
    assert not any("never reverses" in w for w in fit.warnings), fit.warnings


@pytest.mark.parametrize("samples", [120, 300, 440])
def test_a_preisach_model_on_a_short_record(samples):
    """Found by fuzzing: fit_model(kind="preisach") with fewer than 360 samples to fit on (the
    8-level grid's 36 weights at 10 samples each) stopped at an AssertionError. It now fits as
    many levels as the record carries."""
    t = np.arange(samples) * 1e-3
    u = 50.0 - 50.0 * np.cos(2 * np.pi * 4.0 * t)
    y = 0.2 * u + 2.0 * np.sin(2 * np.pi * 4.0 * t)
    fit = ph.fit_model(u, y, 1e-3, kind="preisach")
    assert fit.model.kind == "preisach" and np.all(np.isfinite(fit.predict(u, 1e-3)))


@pytest.mark.parametrize("start", [-90.0, -40.0, 30.0])
def test_a_preisach_fit_predicts_a_record_that_starts_elsewhere(start):
    """Found probing prediction across records: fitted on cycles that start at the bottom of the
    range, a Preisach model predicted a record starting 10 V above it (zoo's relay-Preisach stage)
    at 2.9e6 µm. The strip of down-only hysterons beyond the grid is never moved by such a record
    (the first sample sets it down and nothing lifts it), its column is constant, the offset's twin,
    and its weight came out at 4.6e6; a record that starts higher leaves it partly up. A strip the
    record does not move now keeps weight zero; the prediction is as good as on the record's own
    range (0.6-0.8 % of span RMS on this stage at 1, 3 and 5 Hz)."""
    from tests.plants.zoo import zoo

    stage = next(s for s in zoo(seed=0) if s.name.startswith("relay Preisach"))
    lo, hi = stage.u_range
    dt = stage.dt
    t = np.arange(int(round(3.0 / dt))) * dt  # (fitted on 2 s, the weight happened to come out small)
    u = lo + (hi - lo) * 0.5 * (1 - np.cos(2 * np.pi * 1.0 * t) * np.linspace(1.0, 0.3, t.size))
    fit = ph.fit_model(u, stage.excite(u).y, dt, kind="preisach", delay=0)
    mid = 0.5 * (lo + hi)
    ut = mid + (start - mid) * np.cos(2 * np.pi * 2.0 * t[: t.size // 2])
    yt = stage.excite(ut).y
    rms = float(np.sqrt(np.mean((yt - fit.predict(ut, dt)) ** 2)))
    assert rms < 0.05 * float(np.ptp(yt)), (rms, float(np.ptp(yt)), fit.model.weights.max())


def test_predicting_beyond_the_identified_input_range_warns():
    """FitResult.predict says when the input leaves the range the model was fitted on by more than
    2 % of it (every fit records that range: fit_model's kinds, fit_pi, fit_bouc_wen); inside it
    nothing is said."""
    true = ph.PrandtlIshlinskii(ph.equal_thresholds(10, 100.0), np.linspace(0.02, 0.002, 10))
    t = np.arange(20000) * 1e-4
    u = 25.0 - 25.0 * np.cos(2 * np.pi * t)
    y = true.simulate(u)
    fits = [ph.fit_model(u, y, 1e-4, kind=k) for k in ("pi", "preisach")] + [ph.fit_pi(u, y)]
    fits.append(ph.fit_bouc_wen(u[::10], y[::10], 1e-3, max_iter=3, n_particles=6, polish=False))
    for fit in fits:
        assert fit.input_range == (0.0, 50.0)
        assert fit.summary()["input_range_V"] == [0.0, 50.0]
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            fit.predict(25.0 - 25.5 * np.cos(2 * np.pi * t), 1e-4)  # 1 % beyond: within the tolerance
        with pytest.warns(ph.ExtrapolationWarning, match="up to 100 V, beyond the 0 .. 50 V"):
            fit.predict(50.0 - 50.0 * np.cos(2 * np.pi * t), 1e-4)


def _small_signal_record():
    """A P-I stage ramped from rest to 126 V, then recorded swinging +-0.5 V about it (a small-signal
    record at an operating point, as an AFM scanner's is)."""
    t = np.arange(4000) * 1e-4
    u = 126.0 - 0.5 * np.cos(2 * np.pi * 3.0 * t)
    true = ph.PrandtlIshlinskii(ph.equal_thresholds(10, 200.0), np.linspace(0.02, 0.002, 10))
    return u, true.simulate(np.concatenate([np.linspace(0.0, 126.0, 2000), u]))[2000:]


def test_a_small_signal_record_far_from_rest():
    """Found by fuzzing every kind: on a record covering 125.5-126.5 V, kind="auto" (and
    "rate-dependent") stopped with the generalized Duhem model's "v_range 0..126.5 V reaches more than
    100 times the knots' span" (its state runs from rest, 0 V, which such a record never shows). The
    Duhem candidates are now left out there, and asked for by name the refusal says why. And the
    P-I stages' delay (61 samples, a long delay standing in for P-I's misfit) no longer holds the
    other kinds: the Preisach model, which follows this record, is also tried without it and chosen
    (hold-out 0.006 % of span, against a Bouc-Wen model's 0.66 % chosen before)."""
    u, y = _small_signal_record()
    fit = ph.fit_model(u, y, 1e-4, kind="auto")
    assert fit.model.kind == "preisach" and fit.info["holdout"]["percent_of_span"] < 0.1, fit.info["chosen"]
    # asked for by name, the rate-dependent kind follows it too: measured 0.0064 % of span (a
    # Preisach static part with lags); a rate-dependent model without the Preisach candidates
    # scored 0.86 % (Bouc-Wen, delay 61). 0.05 % leaves the run a margin of 8
    rate = ph.fit_model(u, y, 1e-4, kind="rate-dependent")
    assert rate.model.kind == "rate-dependent"
    assert rate.info["holdout"]["percent_of_span"] < 0.05, rate.info["chosen"]
    with pytest.raises(ValueError, match=r"more than 100 times its span from 0 V \(rest\)"):
        ph.fit_model(u, y, 1e-4, kind="generalized-duhem")


def _slew_limited(u, max_step):
    """The voltage an amplifier that slews by at most ``max_step`` per sample delivers."""
    v = np.empty_like(u)
    last = u[0]
    for k, x in enumerate(u):
        last += min(max(x - last, -max_step), max_step)
        v[k] = last
    return v


def test_a_model_that_misses_the_fast_parts_says_the_amplifier_may_not_follow():
    """A P-I stage behind an amplifier limited to 2000 V/s (a current limit into the stack's
    capacitance), fitted on the commissioning excitation (up to 7850 V/s on 0-100 V): the residual
    concentrates where the input moves fastest, and the fit says so and what to declare; the
    same stage with an amplifier that follows gets no such warning."""
    from piezohyst.commissioning import commissioning_excitation

    dt = 1e-4
    u = np.asarray(commissioning_excitation(dt, (0.0, 100.0)))
    pi = ph.PrandtlIshlinskii(ph.equal_thresholds(10, 100.0), np.linspace(0.04, 0.01, 10))
    rng = np.random.default_rng(3)
    for limited in (True, False):
        v = _slew_limited(u, 2000.0 * dt) if limited else u
        y = pi.predict(v) + 0.002 * rng.standard_normal(u.size)
        fit = ph.fit_model(u, y, dt, kind="pi", delay=0)
        said = [w for w in fit.warnings if "moves fastest" in w]
        assert bool(said) == limited, (limited, fit.warnings)
        assert all("max_step_fraction" in w for w in said)


def test_an_input_lag_is_kept_where_its_lead_only_wiggles_the_command_the_lag_smooths():
    """A stage behind an 8 ms amplifier lag (a probe of structures outside the zoo, not tuned on).
    The input lag's exact inverse, a lead of gain tau / dt, turns the kinks of a Preisach inverse
    into one- or two-sample wiggles of the command (1 V of 100); the chatter check counted them as
    turns and refused every candidate with an input lag, and the rate-independent fallback left
    the feedforward 4.2 / 4.2 / 5.5 % e_max at 1 / 3 / 5 Hz. The check now judges the command as
    the model's own input lag passes it on (an oscillating inverse still shows there: at the
    Nyquist frequency the lag passes (1 - b) / (1 + b) of it): 1.0 / 0.6 / 1.4 %; with input lags
    searched up to 1 / (2 pi f_hi) (0.2 / (2 pi f_hi) before), 0.44 / 0.42 / 0.56 %."""
    from piezohyst.identify.select import _chatters, _input_lag_factor

    from .plants.zoo import AsymmetricMaxwellSlip, Stage
    from .test_zoo import steady_range

    stage = Stage("Maxwell-slip behind an 8 ms amplifier lag", AsymmetricMaxwellSlip(100.0, 20.0), 1e-4, (0.0, 100.0),
                  tau_amp=8e-3, kv=((0.05, 0.02),), fn_hz=2000.0, zeta=0.05, noise_um=0.005, delay_samples=1, seed=51)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ctl = ph.commission(stage, tune=False)
    assert _input_lag_factor(ctl.model) > 0, ctl.fit.info["structure"]
    a, b = steady_range(stage)
    for f in (1.0, 3.0, 5.0):
        ref = ph.sinusoid(f, 3, a, b, stage.dt)
        period = int(round(1.0 / (f * stage.dt)))
        out = ctl.track(ref, feedback=False, learning=False, period=period)
        assert out.e_max_percent < 1.0, (f, out.e_max_percent)
        cmd = out.command[period:]  # and the zoo's test of a command free of chatter
        assert np.abs(np.diff(cmd)).max() <= 20 * (np.ptp(cmd) / np.ptp(ref)) * np.abs(np.diff(ref)).max()

    class Oscillating:  # a compensator whose command swings at the Nyquist frequency
        dynamic = True

        def __init__(self, model):
            self.model, self.input_lag_factor = model, _input_lag_factor(model)

        def compensator(self, dt):
            inner = self.model.compensator(dt)

            class C:
                def command(self, x):
                    u = np.asarray(inner.command(x))
                    return u + 20.0 * (-1.0) ** np.arange(u.size)
            return C()

    ranges = search_ranges(ctl.identification.u, stage.dt, ctl.identification.u.size)
    assert not _chatters(ctl.model, stage.dt, ctl.identification.y, ranges)
    assert _chatters(Oscillating(ctl.model), stage.dt, ctl.identification.y, ranges)


def test_an_output_on_two_levels_rules_out_the_output_map_not_the_fit():
    """Steps between two commands, noise free: the output takes two values, and the asymmetric
    P-I model's 8-knot map could not be placed; the error ("too few distinct values for an output
    map") ended ``fit_model(kind="auto")`` for every kind (found by fuzzing). Those candidates are
    now ruled out; the P-I model fits the two points exactly, and asked for by name the
    asymmetric P-I model takes the map it can place."""
    dt = 1e-3
    t = np.arange(4000) * dt
    u = np.where(np.sin(2 * np.pi * 2 * t) > 0, 90.0, 10.0)
    y = ph.PrandtlIshlinskii(np.linspace(0, 40, 8), np.linspace(0.06, 0.01, 8)).simulate(u)
    fit = ph.fit_model(u, y, dt)
    assert fit.info["holdout"]["percent_of_span"] < 1e-6
    ruled_out = [c for c in fit.info["candidates"] if "8 map knots" in c["label"]]
    assert ruled_out and all(c["holdout_rmse"] == float("inf") for c in ruled_out)
    named = ph.fit_model(u, y, dt, kind="asymmetric-pi")
    assert "map knot" in named.info["chosen"] and "8 map knots" not in named.info["chosen"]


def _came_from(lo, seed):
    """A stage of 60 play operators of random thresholds and a saturating, asymmetric output
    (no kind here is exact for it), at rest at 0 V in a range of ``lo`` .. 100 V, whose last move
    before each record was down to ``lo`` and back (``lo = 0``: a demagnetised stage)."""
    from piezohyst.models.play import play_operator

    rng = np.random.default_rng(seed)
    r = np.sort(rng.uniform(0.0, 70.0, 60))
    w = rng.uniform(0.2, 1.0, 60) * np.exp(-r / 30.0)

    def stage(u):
        noise = np.random.default_rng(seed + u.size)  # the same record, the same noise
        past = np.concatenate([np.linspace(0.0, lo, 50), np.linspace(lo, 0.0, 50)])
        x = np.concatenate([past, u])
        p = 0.01 * sum(wi * play_operator(x, ri) for wi, ri in zip(w, r)) + 0.004 * x
        return 12.0 * np.tanh(p / 3.0 + 0.1)[past.size:] + noise.normal(0.0, 2e-3, u.size)

    return stage


@pytest.mark.parametrize("seed", [2, 4])
def test_a_stage_that_came_up_from_the_bottom_is_fitted_from_there(seed):
    """Issue 11, fit any stage: every kind starts de-energised, but a stage resting above the
    bottom of its range after coming up from it sits on its rising branch, and a model started
    elsewhere mispredicts whatever the record does first. ``history="auto"`` tries the two
    histories the record's range allows and keeps the one the held-out part prefers: here the
    one from below, and a new record that starts by rising from rest is predicted 3x better;
    on the same stage demagnetised the start stays de-energised (or changes nothing)."""
    lo, hi = -60.0, 100.0
    t = np.arange(6000)
    amp = np.interp(t, [0, 1500, 6000], [1.0, 1.0, 0.3])
    u = np.concatenate([np.linspace(0.0, hi, 200), 0.5 * (lo + hi) + 0.5 * (hi - lo) * np.cos(2 * np.pi * t / 750) * amp])
    v = np.concatenate([np.linspace(0.0, 80.0, 300), 20.0 + 40.0 * np.cos(2 * np.pi * np.arange(3000) / 1000)])
    kinds = ["prandtl-ishlinskii", "asymmetric-pi"]

    def fitted(stage, history):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            f = ph.fit_model(u, stage(u), kinds=kinds, history=history)
        yv = stage(v)
        return f, float(np.sqrt(np.mean((yv - f.model.predict(v)) ** 2)))

    stage = _came_from(lo, seed)
    plain, e_plain = fitted(stage, "none")
    found, e_found = fitted(stage, "auto")
    assert not isinstance(plain.model, ph.AfterHistory) and isinstance(found.model, ph.AfterHistory)
    assert found.model.waypoints == (0.0, lo, 0.0) and "from below" in found.info["chosen"]
    assert [r["chosen"] for r in found.info["initial_state"]].count(True) == 1
    assert e_found < e_plain / 3
    assert found.info["holdout"]["rmse"] < plain.info["holdout"]["rmse"]
    # the file keeps the history
    back = ph.models.base.model_from_dict("after-history", found.model.to_dict())
    assert np.array_equal(back.predict(v), found.model.predict(v))
    # chosen on a validation record (which starts at rest too, and is simulated after the history)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        on_v = ph.fit_model(u, stage(u), kinds=kinds, validation=[(v, stage(v))])
    assert isinstance(on_v.model, ph.AfterHistory) and on_v.model.waypoints == (0.0, lo, 0.0)
    scores = {r["start"].split(" (")[0]: r["holdout_rmse"] for r in on_v.info["initial_state"]}
    assert scores["after a history from below"] < scores["de-energised"] / 2, scores
    demag = _came_from(0.0, seed)
    _, e_plain = fitted(demag, "none")
    f, e_auto = fitted(demag, "auto")
    assert not isinstance(f.model, ph.AfterHistory) and e_auto == e_plain, f.info["chosen"]


def test_the_command_line_fits_the_start_and_the_file_keeps_it(tmp_path, capsys):
    """``piezohyst identify --model auto`` on the record of a stage that came up from the bottom
    writes an after-history model (schema 6) whose compensator the C export replays at reset;
    ``--history none`` fits from the de-energised state; ``--model after-history`` forces it."""
    import json

    from piezohyst.cli import main

    lo, hi = -60.0, 100.0
    t = np.arange(6000)
    amp = np.interp(t, [0, 1500, 6000], [1.0, 1.0, 0.3])
    u = np.concatenate([np.linspace(0.0, hi, 200), 0.5 * (lo + hi) + 0.5 * (hi - lo) * np.cos(2 * np.pi * t / 750) * amp])
    ph.save_dataset(tmp_path / "came.csv", ph.Dataset(t=np.arange(u.size) * DT, u=u, y=_came_from(lo, 2)(u)))
    out = {}
    for name, extra in (("auto", []), ("none", ["--history", "none"]), ("forced", ["--model", "after-history"])):
        args = ["identify", str(tmp_path / "came.csv"), "--json", "-o", str(tmp_path / f"{name}.json")]
        assert main(args + (extra if extra[:1] == ["--model"] else ["--model", "auto", *extra])) == 0
        out[name] = json.loads(capsys.readouterr().out)
    assert out["auto"]["model"] == "after-history" and out["forced"]["model"] == "after-history"
    assert out["none"]["model"] != "after-history"
    assert out["auto"]["parameters"]["waypoints"] == [0.0, lo, 0.0]
    doc = json.loads((tmp_path / "auto.json").read_text())
    assert doc["schema"] == "piezohyst.model/6"
    model = ph.load_model(tmp_path / "auto.json")
    assert isinstance(model, ph.AfterHistory) and model.is_invertible
    # the compensator starts where the history left the model: it inverts the model's own output
    y = model.predict(u, DT)
    assert np.abs(model.predict(model.compensator(DT).command(y), DT) - y).max() < 1e-6 * np.ptp(y)


def test_fit_model_takes_progress_true_and_refuses_what_is_not_a_callback():
    """progress=True failed deep in the search ("'bool' object is not callable"), as fit_pi and
    fit_bouc_wen take it (found by a helper); a string is refused up front, naming the argument."""
    rig = ph.VirtualRig(seed=0)
    ds = rig.excite(ph.sinusoid(1.0, 3, 0.0, 100.0, rig.dt))
    quiet = ph.fit_model(ds, kind="preisach")
    shown = ph.fit_model(ds, kind="preisach", progress=True)
    assert shown.model == quiet.model
    # the display opens before the arguments are worked on: kind="after-history" turned history
    # into "force", which the call under the display then refused
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert ph.fit_model(ds, kind="after-history", progress=True).model.kind == "after-history"
    with pytest.raises(TypeError, match="progress must be True, False, None or a function of one str, got str"):
        ph.fit_model(ds, kind="preisach", progress="yes")


def test_long_records_keep_the_bouc_wen_candidate_and_the_refits_bounded(monkeypatch):
    """On 3 million samples the Bouc-Wen candidate's swarm took 129 of fit_model's 146 s, and a
    30-level Preisach refit on 10^6 samples held 4.3 GiB (found by a helper timing records the
    benchmarks do not use): the candidate is fitted on the first BOUC_WEN_SAMPLES samples, and a
    refit's design matrix keeps within REFIT_BYTES (fewer rows for more columns)."""
    from piezohyst.identify import linear, select

    pi_like = linear.Structure("pi", 20, 0, (), 0.0, 0)
    grid = linear.Structure("preisach", 30, 0, (), 0.0, 0)
    assert linear._row_cap(pi_like, linear.REFIT_ROWS) == linear.REFIT_ROWS
    rows = linear._row_cap(grid, linear.REFIT_ROWS)
    assert rows < linear.REFIT_ROWS and 8 * rows * (linear._static_width(grid) + 2) <= linear.REFIT_BYTES
    monkeypatch.setattr(select, "BOUC_WEN_SAMPLES", 4000)
    rig = ph.VirtualRig(seed=0)
    ds = rig.excite(ph.sinusoid(2.0, 4, 0.0, 100.0, rig.dt))  # 20,000 samples
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = ph.fit_model(ds, kind="bouc-wen", bouc_wen_options={"max_iter": 5, "n_particles": 8, "polish": False})
    assert fit.n_samples <= 4000 and fit.info["fitted_samples"] == "the first 4000 of 20000 samples (BOUC_WEN_SAMPLES)"


def _candidate(score, structure):
    from piezohyst.identify.select import _Candidate

    return _Candidate(structure=structure, label=f"{structure} at {score}", kind="prandtl-ishlinskii", score=score,
                      fit_rmse=score, n_parameters=structure.size, time_s=0.0)


def test_the_choice_is_the_candidate_with_the_lowest_hold_out_score():
    """The selection rules of piezohyst.identify.select on constructed candidates: _best takes the
    lowest hold-out score (``max`` in its place passed every other test here); _prefer lets a
    more complex challenger in only when better by more than MIN_GAIN; _choose keeps a simpler
    structure unless worse by more than MIN_GAIN, and of two as complex the lower score."""
    from piezohyst.identify.linear import Structure
    from piezohyst.identify.select import MIN_GAIN, _best, _choose, _prefer

    assert MIN_GAIN == 0.02  # the margins below are a fraction of it either side
    # the delay search's candidates: same structure, several delays, one ruled out (inf)
    cands = [_candidate(s, Structure("pi", 10, delay=d)) for d, s in enumerate([0.3, 0.1, 0.2, math.inf, 0.25])]
    assert _best(cands) is cands[1]
    assert _best(cands[::-1]) is cands[1]  # whatever the order
    assert _best([cands[3], cands[0]]) is cands[0]  # a ruled-out candidate loses to any scored one
    # a more complex challenger: in only when better by more than MIN_GAIN
    small = _candidate(1.0, Structure("pi", 10))
    assert _prefer(small, _candidate(1.0 - 0.5 * MIN_GAIN, Structure("pi", 20))) is small
    big = _candidate(1.0 - 1.5 * MIN_GAIN, Structure("pi", 20))
    assert _prefer(small, big) is big
    assert _prefer(small, _candidate(1.2, Structure("pi", 20))) is small
    # _choose, from a complex incumbent: a simpler one wins even slightly worse, not much worse
    best = _candidate(1.0, Structure("pi", 20))
    near = _candidate(1.0 + 0.5 * MIN_GAIN, Structure("pi", 10))
    assert _choose(best, near) is near
    assert _choose(best, _candidate(1.0 + 2 * MIN_GAIN, Structure("pi", 10))) is best
    # a more complex one by more than the margin only
    assert _choose(small, _candidate(1.0 - 0.5 * MIN_GAIN, Structure("pi", 20))) is small
    assert _choose(small, big) is big
    # as complex (another delay): the lower score, by any margin
    lower = _candidate(0.999, Structure("pi", 20, delay=3))
    assert _choose(best, lower) is lower
    assert _choose(best, _candidate(1.001, Structure("pi", 20, delay=3))) is best
