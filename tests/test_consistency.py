"""squkf.consistency: NEES, NIS, the chi-square bands of ``check`` and ``whiteness`` (issue 37, part 2).

Each function equals an oracle written here with ``numpy.linalg.inv`` and ``scipy.stats.chi2`` to a
relative 1e-12; with truly Gaussian errors (pure numpy, seeded, no filter) the bands hold at about
their level and the whiteness tests' p-values are about uniform; bad input is a squkf error naming
the argument; ``Consistency.plot`` draws the band and the mean.
"""

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from models import CV_Z, cv3_zs, cv_filter, lower_factors, make_cv3_fleet, tune_cv_filter, tune_cv_fx
from scipy.stats import chi2

from squkf import (
    Fleet,
    NonFiniteError,
    NotPositiveDefiniteError,
    ParameterError,
    ShapeError,
    consistency,
    simulate,
)
from squkf.consistency import Consistency, check, nees, nis, whiteness

seeds = st.integers(0, 2**32 - 1)


# -- oracles -------------------------------------------------------------------------------------


def nees_oracle(truth, means, S, idx=None):
    """``e^T inv(P) e`` one step at a time, ``P = S S^T`` (its ``idx`` block)."""
    e = np.broadcast_to(truth - means, np.broadcast_shapes(truth.shape, means.shape, S.shape[:-1]))
    S = np.broadcast_to(S, e.shape + e.shape[-1:])
    out = np.empty(e.shape[:-1])
    for i in np.ndindex(out.shape):
        P = S[i] @ S[i].T
        ei = e[i]
        if idx is not None:
            P, ei = P[np.ix_(idx, idx)], ei[idx]
        out[i] = ei @ np.linalg.inv(P) @ ei
    return out


def check_oracle(values, dof, level, normalised):
    """The bands of ``check``, step by step, with ``chi2.interval``."""
    v = np.atleast_2d(values)
    M, N = v.shape
    mean = np.array([sum(v[:, t]) / M for t in range(N)])
    lo, hi = np.array(chi2.interval(level, M * dof)) / M
    tlo, thi = np.array(chi2.interval(level, N * M * dof)) / (N * M)
    average = v.sum() / (N * M)
    verdict = "consistent" if tlo <= average <= thi else ("too large" if average > thi else "too small")
    scale = dof if normalised else 1.0
    inside = [lo <= m <= hi for m in mean]
    return dict(
        mean=mean / scale,
        band=(lo / scale, hi / scale),
        inside=np.array(inside),
        fraction_inside=sum(inside) / N,
        time_average=average / scale,
        time_band=(tlo / scale, thi / scale),
        verdict=verdict,
    )


def whiteness_oracle(y, S, L, level):
    """One series: whitened by ``inv(S_t)``, steps with a NaN deleted, the statistics by their sums."""
    w = np.array([np.linalg.inv(S[t]) @ y[t] for t in range(len(y)) if not np.isnan(y[t]).any()])
    T, m = w.shape
    c = w - w.mean(axis=0)
    C = [sum(np.outer(c[t], c[t - k]) for t in range(k, T)) / T for k in range(L + 1)]
    r = np.array(
        [[np.sum(c[k:, j] * c[: T - k, j]) / np.sum(c[:, j] ** 2) for j in range(m)] for k in range(1, L + 1)]
    )
    lb = T * (T + 2) * sum(r[k - 1] ** 2 / (T - k) for k in range(1, L + 1))
    C0inv = np.linalg.inv(C[0])
    hosking = T**2 * sum(np.trace(C[k].T @ C0inv @ C[k] @ C0inv) / (T - k) for k in range(1, L + 1))
    return dict(
        autocorrelation=r,
        bound=np.sqrt(chi2.ppf(level, 1) / T),  # z_{(1+level)/2} = sqrt of chi2(1)'s level quantile
        ljung_box=lb,
        ljung_box_pvalue=chi2.sf(lb, L),
        hosking=hosking,
        hosking_pvalue=chi2.sf(hosking, m * m * L),
        steps=T,
    )


def close(a, b, rtol=1e-12):
    """Equal to ``rtol`` relative to the largest entry (an autocorrelation near 0 is a difference of sums
    of the series' size: its rounding is relative to them, not to itself)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    scale = float(np.max(np.abs(b))) if b.size else 0.0
    np.testing.assert_allclose(a, b, rtol=rtol, atol=rtol * scale)


# -- nees ----------------------------------------------------------------------------------------


@settings(max_examples=40, deadline=None)
@given(seed=seeds, n=st.integers(1, 5), lead=st.sampled_from([(), (1,), (7,), (3, 4)]))
def test_nees_equals_the_inverse_of_the_covariance(seed, n, lead):
    rng = np.random.default_rng(seed)
    S = lower_factors(rng, lead, n)
    truth, means = rng.normal(0, 3, lead + (n,)), rng.normal(0, 3, lead + (n,))
    got = nees(truth, means, S)
    assert got.shape == lead
    close(got, nees_oracle(truth, means, S))


@settings(max_examples=40, deadline=None)
@given(seed=seeds, n=st.integers(1, 5), data=st.data())
def test_nees_of_a_subset_is_that_of_the_marginal_covariance(seed, n, data):
    idx = data.draw(st.lists(st.integers(0, n - 1), min_size=1, max_size=n, unique=True))
    rng = np.random.default_rng(seed)
    S = lower_factors(rng, (6,), n)
    truth, means = rng.normal(0, 3, (6, n)), rng.normal(0, 3, (6, n))
    got = nees(truth, means, S, idx=idx)
    close(got, nees_oracle(truth, means, S, idx=idx))
    # the order of the subset and negative indices change nothing
    close(nees(truth, means, S, idx=[i - n for i in idx[::-1]]), got)


@settings(max_examples=40, deadline=None)
@given(seed=seeds, n=st.integers(1, 5))
def test_nees_is_that_of_the_covariance_whatever_its_lower_factor(seed, n):
    rng = np.random.default_rng(seed)
    S = lower_factors(rng, (5,), n)
    flipped = S * rng.choice([-1.0, 1.0], (5, 1, n))  # another lower factor of each P
    truth, means = rng.normal(0, 3, (5, n)), rng.normal(0, 3, (5, n))
    np.testing.assert_array_equal(nees(truth, means, flipped), nees(truth, means, S))  # sign flips are exact
    idx = [n - 1, 0] if n > 1 else [0]
    close(nees(truth, means, flipped, idx=idx), nees(truth, means, S, idx=idx))
    # only the lower triangle is read
    upper = np.triu(rng.normal(size=(5, n, n)), 1)
    close(nees(truth, means, S + upper), nees(truth, means, S))
    close(nees(truth, means, S + upper, idx=idx), nees(truth, means, S, idx=idx))


def test_nees_broadcasts_one_truth_and_one_factor_over_runs():
    rng = np.random.default_rng(4)
    truth = rng.normal(size=(20, 3))  # (steps, n): the same truth for every run
    means = rng.normal(size=(8, 20, 3))  # (runs, steps, n)
    S_steps = lower_factors(rng, (20,), 3)
    got = nees(truth, means, S_steps)
    assert got.shape == (8, 20)
    close(got, nees_oracle(truth, means, S_steps))
    S_one = S_steps[0]  # one factor for all
    close(nees(truth, means, S_one), nees_oracle(truth, means, S_one))
    close(nees(truth, means, S_one, idx=[2]), nees_oracle(truth, means, S_one, idx=[2]))
    assert nees(truth[0], means[0, 0], S_one).shape == ()


# -- nis -----------------------------------------------------------------------------------------


def test_nis_of_a_filters_batch_run_is_y_inv_S_y_of_each_step():
    oracle = []
    stepped = cv_filter()
    for z in CV_Z:
        stepped.predict()
        stepped.update(z)
        oracle.append(stepped.y @ np.linalg.inv(stepped.S) @ stepped.y)
    result = cv_filter().batch_filter(CV_Z)
    got = nis(result)
    assert got.shape == (len(CV_Z),)
    close(got, oracle)
    got[:] = -1.0  # a new array: the result's record is untouched
    assert (result.nis >= 0).all()


def test_nis_of_a_fleet_run_is_each_filters_and_keep_final_is_refused():
    zs = cv3_zs(7)
    fleet = make_cv3_fleet()
    singles = [fleet[k] for k in range(len(zs))]
    got = nis(fleet.batch_filter(zs, keep="means"))
    assert got.shape == zs.shape[:2]
    for k, f in enumerate(singles):
        for t, z in enumerate(zs[k]):
            f.predict()
            f.update(z)
            close(got[k, t], f.y @ np.linalg.inv(f.S) @ f.y)
    with pytest.raises(ParameterError, match="keep="):
        nis(make_cv3_fleet().batch_filter(zs, keep="final"))


@pytest.mark.parametrize("thing", [None, np.zeros(3), cv_filter()])
def test_nis_of_anything_but_a_batch_result_is_refused(thing):
    with pytest.raises(ParameterError, match="^result must be what batch_filter returns"):
        nis(thing)


# -- check ---------------------------------------------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(
    seed=seeds,
    M=st.integers(1, 30),
    N=st.integers(1, 40),
    dof=st.one_of(st.integers(1, 6), st.floats(0.5, 6.0)),
    level=st.floats(0.5, 0.999),
    normalised=st.booleans(),
    scale=st.sampled_from([0.5, 1.0, 1.5]),
)
def test_check_equals_the_chi_square_bands(seed, M, N, dof, level, normalised, scale):
    values = scale * np.random.default_rng(seed).chisquare(dof, size=(M, N))
    got = check(values, dof, level=level, normalised=normalised)
    want = check_oracle(values, dof, level, normalised)
    for name in ("mean", "band", "time_average", "time_band", "fraction_inside"):
        close(getattr(got, name), want[name])
    np.testing.assert_array_equal(got.inside, want["inside"])
    assert got.verdict.startswith(want["verdict"])
    assert (got.runs, got.steps, got.dof, got.level, got.normalised) == (M, N, dof, level, normalised)
    assert got.target == (1.0 if normalised else dof)


def test_check_of_one_run_is_that_of_a_one_row_array():
    values = np.random.default_rng(3).chisquare(2, size=30)
    one = check(values, 2)
    assert one.runs == 1 and one.steps == 30
    close(one.mean, values)
    close(one.band, check(values[None], 2).band)


def test_the_per_step_nees_band_holds_at_its_level_for_gaussian_errors():
    rng = np.random.default_rng(537)
    n, runs, steps = 3, 400, 50
    S = lower_factors(rng, (steps,), n)  # a covariance per step, the same for every run
    truth = rng.normal(0, 5, (steps, n))
    errors = np.einsum("tij,rtj->rti", S, rng.standard_normal((runs, steps, n)))  # e ~ N(0, P_t)
    values = nees(truth, truth + errors, S)
    result = check(values, n)
    assert 0.90 <= result.fraction_inside <= 0.99
    assert result.verdict == "consistent"
    assert 0.90 <= check(nees(truth, truth + errors, S, idx=[0, 2]), 2).fraction_inside <= 0.99
    # a covariance too small or too large is found out
    too_large = check(nees(truth, truth + 1.3 * errors, S), n)
    too_small = check(nees(truth, truth + 0.75 * errors, S), n)
    assert too_large.verdict.startswith("too large") and too_large.fraction_inside < 0.2
    assert too_small.verdict.startswith("too small") and too_small.fraction_inside < 0.2


def test_the_time_average_band_of_white_innovations_holds_at_its_level():
    # 400 seeded studies of 4 runs x 50 steps of a 2-component NIS: the time average is in its band
    # in about 95% of them
    rng = np.random.default_rng(1)
    S = lower_factors(rng, (50,), 2)
    y = np.einsum("tij,srtj->srti", S, rng.standard_normal((400, 4, 50, 2)))
    values = nees(y, np.zeros(2), S)
    inside = np.mean([check(v, 2).verdict == "consistent" for v in values])
    assert 0.92 <= inside <= 0.98
    overconfident = np.mean([check(1.3 * v, 2).verdict == "consistent" for v in values])
    assert overconfident < 0.2


# -- whiteness -----------------------------------------------------------------------------------


def assert_whiteness(got, want):
    for name in ("autocorrelation", "bound", "ljung_box", "ljung_box_pvalue", "hosking", "hosking_pvalue"):
        close(getattr(got, name), want[name])
    assert got.steps == want["steps"]


@settings(max_examples=30, deadline=None)
@given(seed=seeds, m=st.integers(1, 3), T=st.integers(12, 80), level=st.floats(0.5, 0.999), data=st.data())
def test_whiteness_equals_the_sums_of_its_definition(seed, m, T, level, data):
    L = data.draw(st.one_of(st.none(), st.integers(1, T // 2)))
    rng = np.random.default_rng(seed)
    S = lower_factors(rng, (T,), m)
    y = rng.normal(size=(T, m)) + 0.3 * np.sin(np.arange(T))[:, None]  # white or not: the same sums
    got = whiteness(y, S, L, level=level)
    lags = max(1, min(10, T // 5)) if L is None else L
    assert got.lags == lags and got.autocorrelation.shape == (lags, m) and got.level == level
    assert_whiteness(got, whiteness_oracle(y, S, lags, level))


def test_whiteness_leaves_out_the_steps_with_a_nan():
    rng = np.random.default_rng(5)
    T, m = 60, 2
    S = lower_factors(rng, (T,), m)
    y = rng.normal(size=(T, m))
    y[[3, 4, 17]] = np.nan
    y[40, 1] = np.nan  # one component missing: the whole step is left out
    S[[3, 4]] = np.nan  # a factor of a step left out is not read
    got = whiteness(y, S, 6)
    assert got.steps == T - 4
    assert_whiteness(got, whiteness_oracle(y, S, 6, 0.95))


def test_whiteness_of_many_series_is_that_of_each():
    rng = np.random.default_rng(6)
    S = lower_factors(rng, (3, 30), 2)
    y = rng.normal(size=(3, 30, 2))
    y[1, :5] = np.nan  # series of different lengths: the default lags from the shortest
    got = whiteness(y, S)
    assert got.lags == 5 and got.autocorrelation.shape == (3, 5, 2) and got.hosking.shape == (3,)
    for b in range(3):
        assert_whiteness(
            type(got)(*(f[b] if isinstance(f, np.ndarray) and f.ndim else f for f in got)),
            whiteness_oracle(y[b], S[b], 5, 0.95),
        )
    # one factor for every step and series
    close(whiteness(y, S[0, 0]).ljung_box, whiteness(y, np.broadcast_to(S[0, 0], S.shape)).ljung_box)


def test_whiteness_p_values_are_about_uniform_for_white_innovations():
    rng = np.random.default_rng(5371)
    S = lower_factors(rng, (100,), 2)
    y = np.einsum("tij,stj->sti", S, rng.standard_normal((400, 100, 2)))  # 400 white series
    white = whiteness(y, S)
    assert white.lags == 10
    assert 0.02 <= np.mean(white.ljung_box_pvalue[:, 0] < 0.05) <= 0.09
    assert 0.02 <= np.mean(white.ljung_box_pvalue[:, 1] < 0.05) <= 0.09
    assert 0.02 <= np.mean(white.hosking_pvalue < 0.05) <= 0.09
    assert 0.4 <= np.mean(white.hosking_pvalue < 0.5) <= 0.6
    assert 0.9 <= np.mean(np.abs(white.autocorrelation) <= white.bound[:, None, None]) <= 0.99
    # correlated innovations (an AR(1) series, coefficient 0.6) are found out
    e = rng.standard_normal((400, 100, 2))
    ar = np.empty_like(e)
    ar[:, 0] = e[:, 0]
    for t in range(1, 100):
        ar[:, t] = 0.6 * ar[:, t - 1] + e[:, t]
    coloured = whiteness(np.einsum("tij,stj->sti", S, ar), S)
    assert np.mean(coloured.ljung_box_pvalue < 0.05) > 0.9
    assert np.mean(coloured.hosking_pvalue < 0.05) > 0.9


# -- Consistency: repr, html, plot ---------------------------------------------------------------


@pytest.fixture
def summary():
    values = np.random.default_rng(1).chisquare(2, size=(400, 50))
    return check(values, 2)


def test_consistency_repr_and_html_say_what_was_found(summary):
    text = repr(summary)
    assert text.startswith("Consistency(")
    for part in ("400 x 50", f"{int(summary.inside.sum())} of 50", "verdict", "consistent", "target 2"):
        assert part in text, part
    page = summary._repr_html_()
    assert page.startswith("<table>") and page.endswith("</table>")
    assert "consistent" in page and "time-average band" in page
    assert "&lt;" not in page
    with pytest.raises(dataclasses.FrozenInstanceError):
        summary.verdict = "consistent"  # type: ignore[misc]


def test_consistency_plot_draws_the_band_and_the_mean(summary):
    pytest.importorskip("matplotlib")
    from matplotlib.collections import PolyCollection
    from matplotlib.figure import Figure

    ax = Figure().add_subplot()
    assert summary.plot(ax) is ax
    (band,) = [c for c in ax.collections if isinstance(c, PolyCollection)]
    lo, hi = summary.band
    ys = band.get_paths()[0].vertices[:, 1]
    close([ys.min(), ys.max()], [lo, hi])
    means = [line for line in ax.lines if len(line.get_ydata()) == summary.steps]
    assert len(means) == 1
    close(means[0].get_ydata(), summary.mean)


def test_consistency_plot_makes_its_axes_and_names_the_extra_when_matplotlib_is_missing(summary, monkeypatch):
    matplotlib = pytest.importorskip("matplotlib")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ax = summary.plot()
    try:
        assert ax.collections and ax.lines
    finally:
        plt.close(ax.figure)
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # makes "import matplotlib" fail
    with pytest.raises(ImportError, match=r"squkf\[plot\]"):
        summary.plot()


# -- bad input -----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("truth", "means", "S", "named"),
    [
        ((5, 3), (4, 3), (5, 3, 3), "^means"),
        ((5, 3), (5, 2), (5, 3, 3), "^means"),
        ((5, 3), (5, 3), (4, 3, 3), "^P1_2s"),
        ((5, 3), (5, 3), (5, 2, 2), "^P1_2s"),
        ((5, 3), (5, 3), (3,), "^P1_2s"),
        ((), (3,), (3, 3), "^truth"),
        ((5, 0), (5, 0), (5, 0, 0), "^truth"),
    ],
)
def test_nees_of_mismatched_shapes_is_a_shape_error_naming_the_argument(truth, means, S, named):
    with pytest.raises(ShapeError, match=named):
        nees(
            np.zeros(truth), np.zeros(means), np.broadcast_to(np.eye(S[-1]), S) if len(S) > 1 else np.zeros(S)
        )


@pytest.mark.parametrize("name", ["truth", "means", "P1_2s"])
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_nees_of_a_nan_is_a_non_finite_error_naming_the_argument(name, bad):
    args = {
        "truth": np.ones((4, 2)),
        "means": np.zeros((4, 2)),
        "P1_2s": np.broadcast_to(np.eye(2), (4, 2, 2)).copy(),
    }
    args[name][2, 1 if name != "P1_2s" else (1, 0)] = bad
    with pytest.raises(NonFiniteError, match=f"^{name} is not finite"):
        nees(args["truth"], args["means"], args["P1_2s"])


def test_nees_of_text_or_a_singular_factor_is_refused():
    with pytest.raises(ShapeError, match="^truth"):
        nees(["a", "b"], np.zeros(2), np.eye(2))
    singular = np.array([[1.0, 0.0], [1.0, 0.0]])
    with pytest.raises(NotPositiveDefiniteError, match="P1_2s is singular"):
        nees(np.ones(2), np.zeros(2), singular)
    with pytest.raises(NotPositiveDefiniteError, match="marginal factor"):
        nees(np.ones(3), np.zeros(3), np.diag([1.0, 1.0, 1.0]) * [1.0, 0.0, 1.0], idx=[1])


@pytest.mark.parametrize("idx", [[], [3], [-4], [0, 0], [0, -3], [0.5], [[0, 1]], "0", [True]])
def test_nees_of_a_bad_idx_is_a_parameter_error_naming_idx(idx):
    with pytest.raises(ParameterError, match="^idx"):
        nees(np.ones(3), np.zeros(3), np.eye(3), idx=idx)


@pytest.mark.parametrize("level", [0, 1, 1.5, -0.1, np.nan, True, "0.95", None])
def test_a_level_outside_0_1_is_a_parameter_error_naming_level(level):
    with pytest.raises(ParameterError, match="^level"):
        check(np.ones((3, 4)), 1, level=level)
    with pytest.raises(ParameterError, match="^level"):
        whiteness(np.random.default_rng(0).normal(size=(30, 2)), np.eye(2), level=level)


@pytest.mark.parametrize(
    ("kwargs", "error", "named"),
    [
        ({"values": np.ones((2, 3, 4))}, ShapeError, "^values"),
        ({"values": np.ones((0, 3))}, ShapeError, "^values"),
        ({"values": [[1.0, np.nan]]}, NonFiniteError, "^values"),
        ({"values": [[1.0, -0.5]]}, ParameterError, "^values"),
        ({"dof": 0}, ParameterError, "^dof"),
        ({"dof": -2}, ParameterError, "^dof"),
        ({"dof": np.inf}, ParameterError, "^dof"),
        ({"dof": True}, ParameterError, "^dof"),
        ({"dof": "2"}, ParameterError, "^dof"),
        ({"normalised": 1}, ParameterError, "^normalised"),
    ],
)
def test_check_of_bad_input_names_the_argument(kwargs, error, named):
    args = {"values": np.ones((3, 4)), "dof": 2} | kwargs
    with pytest.raises(error, match=named):
        check(args.pop("values"), args.pop("dof"), **args)


@pytest.mark.parametrize("lags", [0, -1, 30, 31, 2.5, True, "3", np.float64(3.0)])
def test_whiteness_of_bad_lags_is_a_parameter_error_naming_lags(lags):
    with pytest.raises(ParameterError, match="^lags"):
        whiteness(np.random.default_rng(0).normal(size=(30, 2)), np.eye(2), lags)


def test_whiteness_of_bad_input_names_the_argument():
    y = np.random.default_rng(0).normal(size=(30, 2))
    with pytest.raises(ShapeError, match="^innovations"):
        whiteness(y[:, 0], np.eye(2))
    with pytest.raises(ShapeError, match="^S1_2s"):
        whiteness(y, np.eye(3))
    with pytest.raises(ShapeError, match="^S1_2s"):
        whiteness(y, np.broadcast_to(np.eye(2), (29, 2, 2)))
    with pytest.raises(NonFiniteError, match="^innovations"):
        whiteness(np.where(np.arange(30)[:, None] == 3, np.inf, y), np.eye(2))
    S = np.broadcast_to(np.eye(2), (30, 2, 2)).copy()
    S[7, 1, 0] = np.nan
    with pytest.raises(NonFiniteError, match="^S1_2s"):
        whiteness(y, S)
    S[7] = np.diag([1.0, 0.0])
    with pytest.raises(NotPositiveDefiniteError, match="^S1_2s"):
        whiteness(y, S)
    with pytest.raises(ShapeError, match="^innovations"):
        whiteness(np.full((30, 2), np.nan), np.eye(2))
    with pytest.raises(NotPositiveDefiniteError, match="constant"):
        whiteness(np.c_[y[:, 0], np.ones(30)], np.eye(2))


def test_consistency_is_a_submodule_of_squkf_that_imports_nothing_optional():
    import squkf

    assert squkf.consistency is consistency
    assert isinstance(check(np.ones(3), 1), Consistency)
    code = "import sys, squkf; print([m for m in ('matplotlib', 'scipy.stats') if m in sys.modules])"
    root = Path(__file__).resolve().parents[1]
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=root, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split("\n")[-2] == "[]"


# == Monte Carlo (issue 37): simulate, then every configuration's runs in one fleet =====================


def test_the_nis_time_average_and_the_per_step_nees_hold_their_bands_with_the_true_noise():
    """The 2-D constant-velocity model with its true Q and R: over 400 seeded simulations the time-averaged
    NIS is inside its band in 92-98% of them, and the per-step NEES band holds at 93-97% of the steps on
    average (5 studies of 400 runs of 100 steps: the fraction's spread is then about 0.01)."""
    template = tune_cv_filter()
    truth, zs = simulate(template, 100, 400, seed=21)
    result = Fleet.from_template(template, 400).batch_filter(zs)
    values = consistency.nis(result)
    inside = [check(values[r], 2).time_band[0] <= values[r].mean() <= check(values[r], 2).time_band[1]
              for r in range(400)]  # fmt: skip
    assert 0.92 <= np.mean(inside) <= 0.98
    fractions = []
    for seed in range(5):
        truth, zs = simulate(template, 100, 400, seed=100 + seed)
        mc = consistency.monte_carlo(template, truth, zs)
        fractions.append(mc["filter"].nees.fraction_inside)
        assert mc["filter"].nees.verdict == "consistent" and mc["filter"].diverged == 0.0
    assert 0.93 <= np.mean(fractions) <= 0.97


def test_monte_carlo_is_each_run_filtered_alone():
    truth, zs = simulate(tune_cv_filter(), 30, 12, seed=3)
    configs = {"true": tune_cv_filter(), "R too small": tune_cv_filter(r1=0.1, r2=0.4)}
    mc = consistency.monte_carlo(configs, truth, zs, level=0.9)
    assert list(mc) == ["true", "R too small"] and len(mc) == 2
    for name in configs:
        means, covs = [], []
        for r in range(12):
            f = tune_cv_filter(**({} if name == "true" else {"r1": 0.1, "r2": 0.4}))
            m, S = f.batch_filter(zs[r], return_factors=True)
            means.append(m)
            covs.append(S)
        means, covs = np.array(means), np.array(covs)
        np.testing.assert_array_equal(mc[name].rmse, np.sqrt(np.mean((means - truth) ** 2, axis=0)))
        want = check(nees(truth, means, covs), 4, level=0.9, white=False)
        np.testing.assert_array_equal(mc[name].nees.mean, want.mean)
        assert mc[name].nees.verdict == want.verdict and mc[name].nees.level == 0.9
    assert mc["R too small"].nis.verdict.startswith("too large")  # overconfident: S too small
    table = mc.table()
    assert list(table.index) == ["true", "R too small"]
    assert table.loc["true", "rmse"] == pytest.approx(float(np.sqrt(np.mean(mc["true"].rmse ** 2))))
    assert "R too small" in repr(mc)


def test_a_diverged_run_is_counted_with_its_wilson_interval():
    def fragile(X, dt):  # breaks where run 3's truth is pushed
        out = tune_cv_fx(X, dt)
        return np.where(np.abs(out) > 1e3, np.nan, out)

    truth, zs = simulate(tune_cv_filter(), 20, 10, seed=2)
    zs[3, 5:] = 5e3
    f = tune_cv_filter()
    f.fx = fragile
    mc = consistency.monte_carlo({"fragile": f}, truth, zs)
    run = mc["fragile"]
    assert list(run.failures) == [3] and run.diverged == 0.1
    # Wilson's score interval for 1 in 10 at 95%, written out
    z = 1.959963984540054
    p, n = 0.1, 10
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    np.testing.assert_allclose(run.diverged_interval, (centre - half, centre + half), rtol=1e-12)
    assert run.rmse.shape == (20, 4) and run.nees.runs == 9


def test_monte_carlo_refuses_bad_input_naming_it():
    truth, zs = simulate(tune_cv_filter(), 10, 4, seed=1)
    f = tune_cv_filter()
    bad_truth = truth.copy()
    bad_truth[1, 2, 0] = np.nan
    for args, kwargs, exc, match in [
        ((f, truth[:3], zs), {}, ShapeError, "truth"),
        ((f, truth[..., :3], zs), {}, ShapeError, "dim_x"),
        ((f, bad_truth, zs), {}, NonFiniteError, "truth"),
        ((f, truth, zs), {"level": 1.5}, ParameterError, "level"),
        (({}, truth, zs), {}, ParameterError, "filters"),
        (({"a": "filter"}, truth, zs), {}, ParameterError, "filters"),
    ]:
        with pytest.raises(exc, match=match):
            consistency.monte_carlo(*args, **kwargs)


def test_monte_carlo_plots_its_configurations():
    import matplotlib

    matplotlib.use("Agg")
    truth, zs = simulate(tune_cv_filter(), 10, 4, seed=1)
    mc = consistency.monte_carlo({"a": tune_cv_filter(), "b": tune_cv_filter(q=1.0)}, truth, zs)
    axes = mc.plot()
    assert [len(ax.get_lines()) for ax in axes] == [2, 2, 2]
