"""batch_filter (squkf.batch): equal to the step loop, and its inputs.

Any iterable of measurements, progress, per-step arguments, an error at step k (nothing changed),
missing measurements against filterpy's batch_filter.
"""

from __future__ import annotations

import copy
import io
import pickle
import subprocess
import sys

import numpy as np
import pytest
from filterpy.kalman import UnscentedKalmanFilter
from hypothesis import given, settings
from hypothesis import strategies as st
from models import (
    DRIFT_Q,
    DRIFT_R,
    assert_results_equal,
    assert_same_filter,
    counting,
    ct_merwe_filter,
    ct_simulate,
    drift_filter,
    drift_fx,
    drift_measurements,
)

import squkf.batch
from squkf import (
    GainError,
    MerweScaledWeights,
    NonFiniteError,
    ParameterError,
    ShapeError,
    SquareRootUKF,
    SqukfError,
)

# == the step loop and filterpy ====================================================================


def test_batch_equals_loop_exactly():
    zs, _ = ct_simulate()
    a, b = ct_merwe_filter(SquareRootUKF), ct_merwe_filter(SquareRootUKF)
    means, covs = a.batch_filter(zs)
    for k, z in enumerate(zs):
        b.predict()
        b.update(z)
        np.testing.assert_array_equal(means[k], b.x)
        np.testing.assert_array_equal(covs[k], b.P)


def test_batch_equals_filterpy_with_missing_measurements():
    zs, _ = ct_simulate()
    nan_zs = [np.full(2, np.nan) if z is None else z for z in zs]
    m_fp, P_fp = ct_merwe_filter(UnscentedKalmanFilter).batch_filter(zs)
    for data in (zs, nan_zs):
        m, P = ct_merwe_filter(SquareRootUKF).batch_filter(data)
        # same algorithm, different arithmetic: O(eps cond) per step, contracted by updates
        assert np.max(np.abs(m - m_fp)) / np.max(np.abs(m_fp)) < 1e-8
        assert np.max(np.abs(P - P_fp) / np.abs(P_fp).max(axis=(1, 2))[:, None, None]) < 1e-8


def test_batch_is_transactional():
    zs, _ = ct_simulate(10)
    zs[6] = np.array([1.0, 2.0, 3.0])  # wrong length
    f = ct_merwe_filter(SquareRootUKF)
    x, S = f.x.copy(), np.array(f.P1_2)
    with pytest.raises(ShapeError, match="length 3"):
        f.batch_filter(zs)
    np.testing.assert_array_equal(f.x, x)
    np.testing.assert_array_equal(f.P1_2, S)


# == batch_filter's inputs =========================================================================

tqdm = pytest.importorskip("tqdm").tqdm


def loop(f, zs, Rs=None, dts=None, Qs=None, fx_args=None, hx_args=None):
    """The reference: predict and update by hand, one step at a time."""
    T = len(zs)

    def at(v, k):
        return v[k] if isinstance(v, list) else v

    means, covs = np.zeros((T, 2)), np.zeros((T, 2, 2))
    for k, z in enumerate(zs):
        f.predict(dt=at(dts, k), Q=at(Qs, k), **(at(fx_args, k) or {}))
        f.update(z, R=at(Rs, k), **(at(hx_args, k) or {}))
        means[k], covs[k] = f.x, f.P
    return means, covs


# -- any iterable of measurements ---------------------------------------------


CONTAINERS = {
    "list": list,
    "tuple": tuple,
    "array": lambda zs: np.array(zs),
    "generator": lambda zs: (z for z in zs),
    "map": lambda zs: map(np.asarray, zs),
    "tqdm": lambda zs: tqdm(zs, disable=True),
    "tqdm over a generator": lambda zs: tqdm((z for z in zs), disable=True),
}


@settings(max_examples=40, deadline=None)
@given(
    T=st.integers(0, 12),
    seed=st.integers(0, 2**16),
    kind=st.sampled_from(sorted(CONTAINERS)),
    split=st.integers(0, 12),
)
def test_every_kind_of_iterable_gives_the_loops_results(T, seed, kind, split):
    zs = drift_measurements(T, seed)
    expected = loop(drift_filter(), zs)
    assert_results_equal(drift_filter().batch_filter(CONTAINERS[kind](zs)), expected)
    # and the batch keeps no state of its own: two batches in a row are one batch
    f = drift_filter()
    split = min(split, T)
    first = f.batch_filter(CONTAINERS[kind](zs[:split]))
    second = f.batch_filter(CONTAINERS[kind](zs[split:]))
    assert_results_equal([np.concatenate([a, b]) for a, b in zip(first, second)], expected)


def test_missing_measurements_in_a_generator():
    zs = drift_measurements(15, missing=(3, 4, 11))
    assert_results_equal(drift_filter().batch_filter(z for z in zs), loop(drift_filter(), zs))


def test_tqdm_of_the_measurements_shows_its_bar(capsys):
    zs = drift_measurements(40)
    result = drift_filter().batch_filter(tqdm(zs))
    assert_results_equal(result, loop(drift_filter(), zs))
    assert "40/40" in capsys.readouterr().err


def test_a_generator_is_read_lazily():
    seen = []

    def source():
        for k, z in enumerate(drift_measurements(10)):
            seen.append(k)
            yield z

    def progress(k):
        assert seen[-1] == k  # step k ran when only measurements 0..k had been read

    drift_filter().batch_filter(source(), progress=progress)
    assert seen == list(range(10))


def test_the_module_function_and_the_method_agree():
    zs = drift_measurements(8)
    Rs = [DRIFT_R * s for s in np.linspace(0.5, 2, 8)]
    assert_results_equal(
        squkf.batch.batch_filter(drift_filter(), zs, Rs, 0.5), drift_filter().batch_filter(zs, Rs, 0.5)
    )
    assert_results_equal(drift_filter().batch_filter(zs, Rs, 0.5), loop(drift_filter(), zs, Rs=Rs, dts=0.5))


@pytest.mark.parametrize("zs", [3.0, None, "abc", b"ab", {"a": 1}, np.float64(2.0)])
def test_not_an_iterable_of_measurements(zs):
    f = drift_filter()
    before = copy.deepcopy(f)
    with pytest.raises(ShapeError, match="zs must be an iterable"):
        f.batch_filter(zs)
    assert_same_filter(f, before)


# -- empty input ----------------------------------------------------------------


@pytest.mark.parametrize("zs", [[], (), np.zeros((0, 2)), iter([]), (z for z in [])])
@pytest.mark.parametrize("return_factors", [False, True])
def test_no_measurements_give_empty_results_and_leave_the_filter(zs, return_factors):
    f = drift_filter()
    before = copy.deepcopy(f)
    means, covs = f.batch_filter(zs, return_factors=return_factors)
    assert means.shape == (0, 2) and covs.shape == (0, 2, 2)
    assert means.dtype == covs.dtype == np.float64
    assert_same_filter(f, before)


def test_no_measurements_with_per_step_arguments_of_the_wrong_length():
    with pytest.raises(ShapeError, match="Rs has 2 entries but zs has 0"):
        drift_filter().batch_filter([], Rs=[DRIFT_R, DRIFT_R])


# -- progress -------------------------------------------------------------------


def test_progress_true_shows_a_bar(capsys):
    zs = drift_measurements(25)
    assert_results_equal(drift_filter().batch_filter(zs, progress=True), loop(drift_filter(), zs))
    err = capsys.readouterr().err
    assert "batch_filter" in err and "25/25" in err


def test_progress_false_is_silent(capsys):
    drift_filter().batch_filter(drift_measurements(5))
    assert capsys.readouterr().err == ""


def test_progress_callable_is_called_after_each_step():
    zs = drift_measurements(12, missing=(4,))
    means, _ = loop(drift_filter(), zs)
    f = drift_filter()
    calls = []

    def progress(k):
        calls.append(k)
        np.testing.assert_array_equal(f.x, means[k])  # step k is complete

    f.batch_filter(zs, progress=progress)
    assert calls == list(range(12))


def test_progress_true_without_tqdm_is_an_error_before_any_step(monkeypatch):
    monkeypatch.setitem(sys.modules, "tqdm", None)  # makes "import tqdm" fail
    monkeypatch.setitem(sys.modules, "tqdm.auto", None)
    counted, calls = counting(drift_fx)
    f = drift_filter(fx=counted)
    before = copy.deepcopy(f)
    with pytest.raises(ParameterError, match="tqdm"):
        f.batch_filter(drift_measurements(5), progress=True)
    assert calls == []
    assert_same_filter(f, before)


@pytest.mark.parametrize("progress", [1, "yes", 0.5, [print]])
def test_progress_must_be_a_bool_or_a_callable(progress):
    with pytest.raises(ParameterError, match="progress"):
        drift_filter().batch_filter(drift_measurements(3), progress=progress)


def test_importing_squkf_does_not_import_tqdm():
    code = "import sys, squkf, squkf.batch, squkf.smoother; print('tqdm' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


# -- an error at step k -----------------------------------------------------------


@pytest.mark.parametrize("kind", ["list", "array", "generator", "tqdm"])
@pytest.mark.parametrize("k", [0, 1, 7, 19])
def test_error_at_step_k_names_the_step_and_carries_the_results_before_it(kind, k):
    zs = drift_measurements(20)
    zs[k] = np.array([np.inf, 0.0])
    f = drift_filter()
    before, clean = copy.deepcopy(f), copy.deepcopy(f)
    with pytest.raises(NonFiniteError, match=f"^at step {k}: ") as info:
        f.batch_filter(CONTAINERS[kind](zs))
    exc = info.value
    assert exc.step == k and exc.errno is None
    assert exc.partial[0].shape == (k, 2) and exc.partial[1].shape == (k, 2, 2)
    assert_results_equal(exc.partial, clean.batch_filter(zs[:k]))
    assert_same_filter(f, before)


def test_error_keeps_its_type_and_errno_and_pickles_with_the_step():
    T, k = 10, 6
    hx_args = [{}] * T
    hx_args[k] = {"flat": True}  # a constant measurement function ...
    Rs = [DRIFT_R] * T
    Rs[k] = np.zeros((2, 2))  # ... and no noise: the innovation factor is singular
    f = drift_filter()
    before = copy.deepcopy(f)
    with pytest.raises(GainError) as info:
        f.batch_filter(drift_measurements(T), Rs=Rs, hx_args=hx_args, return_factors=True)
    exc = info.value
    assert exc.errno == 302 and str(exc).startswith(f"at step {k}: ")
    assert_results_equal(
        exc.partial, copy.deepcopy(before).batch_filter(drift_measurements(k), return_factors=True)
    )
    again = pickle.loads(pickle.dumps(exc))
    assert type(again) is GainError and again.errno == 302 and str(again) == str(exc)
    assert_same_filter(f, before)


class ModelFailureError(Exception):
    pass


def test_an_exception_from_fx_keeps_its_message_and_gets_the_partial_results():
    k = 5

    def failing_fx(x, dt, drift=0.0):
        if failing_fx.calls >= k * 5:  # five sigma points per prediction
            raise ModelFailureError("model diverged")
        failing_fx.calls += 1
        return drift_fx(x, dt)

    failing_fx.calls = 0
    f = drift_filter(fx=failing_fx)
    before = copy.deepcopy(drift_filter())
    with pytest.raises(ModelFailureError) as info:
        f.batch_filter(drift_measurements(9))
    exc = info.value
    assert str(exc) == "model diverged" and exc.step == k
    if sys.version_info >= (3, 11):
        assert any(f"at step {k}" in note for note in exc.__notes__)
    assert_results_equal(exc.partial, before.batch_filter(drift_measurements(k)))
    np.testing.assert_array_equal(f.x, drift_filter().x)
    np.testing.assert_array_equal(f.P1_2, drift_filter().P1_2)


def test_an_interrupt_restores_the_filter_and_keeps_the_results_so_far():
    def progress(k):
        if k == 3:
            raise KeyboardInterrupt

    f = drift_filter()
    before = copy.deepcopy(f)
    with pytest.raises(KeyboardInterrupt) as info:
        f.batch_filter(drift_measurements(10), progress=progress)
    # step 3 was complete, but the call failed there: the results before it are kept
    assert info.value.step == 3
    assert_results_equal(info.value.partial, copy.deepcopy(before).batch_filter(drift_measurements(3)))
    assert_same_filter(f, before)


def test_a_failing_saver_fails_its_step():
    class Saver:
        def __init__(self):
            self.n = 0

        def save(self):
            self.n += 1
            if self.n == 4:
                raise ShapeError("disk full")

    f = drift_filter()
    before = copy.deepcopy(f)
    with pytest.raises(ShapeError, match="^at step 3: disk full$") as info:
        f.batch_filter(drift_measurements(6), saver=Saver())
    assert info.value.partial[0].shape == (3, 2)
    assert_same_filter(f, before)


@settings(max_examples=25, deadline=None)
@given(T=st.integers(1, 15), data=st.data(), seed=st.integers(0, 1000))
def test_partial_results_are_a_prefix_of_the_clean_run(T, data, seed):
    k = data.draw(st.integers(0, T - 1))
    zs = drift_measurements(T, seed)
    clean = drift_filter().batch_filter(zs)
    bad = list(zs)
    bad[k] = np.array([0.0, 1.0, 2.0])[: data.draw(st.sampled_from([1, 3]))]  # wrong length
    with pytest.raises(ShapeError, match=f"^at step {k}: ") as info:
        drift_filter().batch_filter(bad)
    assert_results_equal(info.value.partial, (clean[0][:k], clean[1][:k]))


# -- per-step arguments -------------------------------------------------------------


def test_scalar_Rs_and_Qs_mean_that_multiple_of_the_identity_at_every_step():
    zs = drift_measurements(10)
    expected = loop(drift_filter(), zs, Rs=[0.7 * np.eye(2)] * 10, Qs=[0.03 * np.eye(2)] * 10)
    for r, q in [(0.7, 0.03), (np.float64(0.7), np.array(0.03))]:
        assert_results_equal(drift_filter().batch_filter(zs, Rs=r, Qs=q), expected)
    g = drift_filter()
    g.R, g.Q = 0.7 * np.eye(2), 0.03 * np.eye(2)
    assert_results_equal(g.batch_filter(zs), expected)


def test_the_forms_of_a_per_step_noise_argument():
    zs = drift_measurements(6)
    scales = np.linspace(0.5, 3.0, 6)
    per_step = [DRIFT_R * s for s in scales]
    expected = loop(drift_filter(), zs, Rs=per_step)
    for Rs in (per_step, tuple(per_step), np.array(per_step), iter(per_step), (R for R in per_step)):
        assert_results_equal(drift_filter().batch_filter(zs, Rs=Rs), expected)
    # one matrix for every step
    assert_results_equal(
        drift_filter().batch_filter(zs, Rs=DRIFT_R * 2), loop(drift_filter(), zs, Rs=DRIFT_R * 2)
    )
    # one scalar per step
    assert_results_equal(
        drift_filter().batch_filter(zs, Rs=scales),
        loop(drift_filter(), zs, Rs=[s * np.eye(2) for s in scales]),
    )


def test_per_step_dts_fx_args_hx_args():
    zs = drift_measurements(7)
    dts = [0.5, 1.0, 2.0, 0.25, 1.0, 1.5, 0.75]
    fx_args = [{"drift": 0.01 * k} for k in range(7)]
    hx_args = [None, {"scale": 1.1}, {}, None, {"scale": 0.9}, None, {}]
    expected = loop(drift_filter(), zs, dts=dts, fx_args=fx_args, hx_args=hx_args)
    got = drift_filter().batch_filter(zs, dts=dts, fx_args=fx_args, hx_args=hx_args)
    assert_results_equal(got, expected)
    # the same through generators
    got = drift_filter().batch_filter(
        iter(zs), dts=iter(dts), fx_args=iter(fx_args), hx_args=(h for h in hx_args)
    )
    assert_results_equal(got, expected)
    # one dict for every step
    expected = loop(drift_filter(), zs, fx_args={"drift": 0.1}, hx_args={"scale": 1.2})
    assert_results_equal(
        drift_filter().batch_filter(zs, fx_args={"drift": 0.1}, hx_args={"scale": 1.2}), expected
    )


@pytest.mark.parametrize("name", ["Rs", "Qs", "dts", "fx_args", "hx_args"])
@pytest.mark.parametrize("length", [4, 9])
def test_lengths_must_match_the_measurements(name, length):
    entry = {"Rs": DRIFT_R, "Qs": DRIFT_Q, "dts": 1.0, "fx_args": {}, "hx_args": {}}[name]
    counted, calls = counting(drift_fx)
    f = drift_filter(fx=counted)
    before = copy.deepcopy(f)
    # a list of measurements: found before any step
    with pytest.raises(ShapeError, match=f"^{name} has {length} entries but zs has 6$"):
        f.batch_filter(drift_measurements(6), **{name: [entry] * length})
    assert calls == []
    assert_same_filter(f, before)
    # a generator: found when one of them runs out
    with pytest.raises(ShapeError, match=name) as info:
        f.batch_filter((z for z in drift_measurements(6)), **{name: [entry] * length})
    assert info.value.partial[0].shape == (min(length, 6), 2)
    assert info.value.step == (4 if length == 4 else None)
    assert_same_filter(f, before)


def test_a_generator_of_dts_longer_than_the_measurements():
    f = drift_filter()
    before = copy.deepcopy(f)
    with pytest.raises(ShapeError, match="dts has more entries than the 3 in zs"):
        f.batch_filter(drift_measurements(3), dts=(1.0 for _ in range(4)))
    assert_same_filter(f, before)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"hx_args": 5}, "hx_args must be None, a dict"),
        ({"fx_args": "drift"}, "fx_args must be None, a dict"),
        ({"hx_args": [1, 2, 3]}, r"hx_args\[0\] must be a dict"),
        ({"fx_args": [{}, {"drift": 1}, ("drift", 1)]}, r"fx_args\[2\] must be a dict"),
        ({"fx_args": {1: 2}}, "fx_args has the key 1"),
        ({"fx_args": {"dt": 2.0}}, "fx_args has the key 'dt'"),
        ({"fx_args": [{}, {"Q": DRIFT_Q}, {}]}, r"fx_args\[1\] has the key 'Q'"),
        ({"hx_args": {"R": DRIFT_R}}, "hx_args has the key 'R'"),
        ({"hx_args": {"z": 1}}, "hx_args has the key 'z'"),
        ({"dts": [1.0, "1.0", 1.0]}, r"dts\[1\] must be a finite number"),  # a negative dt is a step
        ({"dts": [1.0, 1.0, np.nan]}, r"dts\[2\]"),
        ({"dts": np.inf}, "dts must be a finite number"),
        ({"dts": [1.0, "a", 1.0]}, r"dts\[1\]"),
        ({"dts": {"a": 1}}, "dts must be None, a number"),
        ({"Rs": {0: DRIFT_R}}, "Rs must be None, a scalar"),
        ({"Qs": object()}, "Qs must be None, a scalar"),
        ({"UT": 3}, "UT must be a callable"),
        ({"saver": object()}, "saver must have a save"),
        ({"return_factors": "yes"}, "return_factors"),
    ],
)
def test_bad_options_are_named_before_any_step(kwargs, match):
    counted, calls = counting(drift_fx)
    f = drift_filter(fx=counted)
    before = copy.deepcopy(f)
    with pytest.raises(ParameterError, match=match):
        f.batch_filter(drift_measurements(3), **kwargs)
    assert calls == []
    assert_same_filter(f, before)


def test_noise_arrays_of_the_wrong_rank():
    with pytest.raises(ShapeError, match=r"Rs has shape \(3, 2, 2, 1\)"):
        drift_filter().batch_filter(drift_measurements(3), Rs=np.zeros((3, 2, 2, 1)))
    with pytest.raises(ShapeError, match=r"dts has shape \(3, 1\)"):
        drift_filter().batch_filter(drift_measurements(3), dts=np.ones((3, 1)))


def test_a_bad_noise_entry_fails_its_step():
    Rs = [DRIFT_R, DRIFT_R, np.eye(3), DRIFT_R]
    f = drift_filter()
    before = copy.deepcopy(f)
    with pytest.raises(ShapeError, match="^at step 2: ") as info:
        f.batch_filter(drift_measurements(4), Rs=Rs)
    assert info.value.partial[0].shape == (2, 2)
    assert_same_filter(f, before)


def test_filterpy_positional_order_and_keyword_only_extras():
    zs = drift_measurements(5)
    Rs, dts = [DRIFT_R] * 5, [1.0] * 5
    assert_results_equal(
        drift_filter().batch_filter(zs, Rs, dts, None, None), loop(drift_filter(), zs, Rs=Rs, dts=dts)
    )
    with pytest.raises(TypeError):
        squkf.batch.batch_filter(drift_filter(), zs, Rs, dts, None, None, [DRIFT_Q] * 5)


# -- a long run through tqdm ----------------------------------------------------------


@pytest.mark.slow  # about 45 s: two runs of ~10^5 steps (measured on the 2-core test machine)
def test_tqdm_over_a_long_random_walk_fails_at_the_bad_step(capsys):
    T, bad = 100_000, 99_990
    rng = np.random.default_rng(12)
    zs = np.cumsum(rng.normal(0.0, 0.1, T)) + rng.normal(0.0, 1.0, T)
    zs[bad] = np.inf
    f = SquareRootUKF(1, 1, 1.0, lambda x: x, lambda x, dt: x, MerweScaledWeights(0.5))
    f.x, f.P, f.Q, f.R = np.zeros(1), 1.0, 0.01, 1.0
    clean = copy.deepcopy(f)
    before = copy.deepcopy(f)
    with pytest.raises(NonFiniteError, match=f"^at step {bad}: ") as info:
        f.batch_filter(tqdm(zs))
    assert "/100000" in capsys.readouterr().err  # the bar was shown
    means, covs = info.value.partial
    assert means.shape == (bad, 1) and covs.shape == (bad, 1, 1)
    assert_results_equal((means, covs), clean.batch_filter(zs[:bad]))
    for name in ("x", "P1_2", "x_prior", "P1_2_prior", "x_post", "P1_2_post"):
        np.testing.assert_array_equal(getattr(f, name), getattr(before, name), err_msg=name)
    f.predict()
    f.update(0.5)
    before.predict()
    before.update(0.5)
    np.testing.assert_array_equal(f.x, before.x)
    np.testing.assert_array_equal(f.P1_2, before.P1_2)


def test_squkf_errors_are_value_errors_too():
    # a caller's ``except ValueError`` still catches the annotated errors
    with pytest.raises(ValueError, match="at step 0"):
        drift_filter().batch_filter([np.array([np.inf, 1.0])])
    assert issubclass(ShapeError, SqukfError)


def test_a_failed_run_leaves_a_tqdm_bar_closed_where_it_stopped():
    zs = drift_measurements(20)
    zs[7] = np.array([np.inf, 0.0])
    out = io.StringIO()
    with pytest.raises(NonFiniteError) as info:
        drift_filter().batch_filter(tqdm(zs, file=out, mininterval=1e9))  # drawn only when opened and closed
    # closed by batch_filter, not later when the exception (and its traceback) is freed
    assert info.value.step == 7
    assert "7/20" in out.getvalue() and out.getvalue().endswith("\n")
