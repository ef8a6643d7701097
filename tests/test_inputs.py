"""Promises at the boundary of the front ends (issue 20), one test (or more) per promise.

Each test failed on the code before its fix. Errors are squkf's own exceptions naming the
argument; a call that fails leaves the filter or fleet as it was.
"""

from __future__ import annotations

import copy
import warnings

import numpy as np
import pytest
from filterpy.common import Saver
from models import (
    CV3_K,
    CV3_NX,
    CV3_NZ,
    assert_filter_state,
    assert_fleet_state,
    ct_fx,
    ct_hx,
    cv3_zs,
    cv_fx_nudged,
    filter_state,
    fleet_state,
    make_cv3_fleet,
    near_filter,
    near_measurements,
    one_d,
    one_d_filterpy,
    positions_hx,
)

from squkf import Fleet, MerweScaledWeights, ParameterError, ShapeError, SquareRootUKF, SqukfError

# -- 1. K is a fresh array on each read -------------------------------------------------------


def test_K_is_a_fresh_array_on_each_read():
    f = near_filter()
    f.predict()
    f.update(near_measurements(1)[0])
    first = f.K
    expected = first.copy()
    first[:] = 123.0
    np.testing.assert_array_equal(f.K, expected)
    assert f.K is not f.K


def test_a_savers_K_history_is_never_rewritten():
    f = near_filter()
    saver = Saver(f)
    for z in near_measurements(4):
        f.predict()
        saver.save()  # K of the previous update, read twice: two entries
        f.update(z)
        saver.save()
    Ks = saver["K"]
    assert len({id(k) for k in Ks}) == len(Ks)
    kept = [k.copy() for k in Ks]
    Ks[1][:] = np.nan  # editing one saved entry changes no other, nor the filter's K
    for j in (0, 2, 3):
        np.testing.assert_array_equal(Ks[j], kept[j])
    np.testing.assert_array_equal(f.K, kept[-1])
    f.predict()
    f.update(near_measurements(5)[4])
    for j in range(2, len(Ks)):
        np.testing.assert_array_equal(Ks[j], kept[j])


# -- 2. one rule for dt on every route: any finite real number; strings are refused ----------
#
# The rule is filterpy's (and ``SquareRootUKF.predict``'s since tests/test_filterpy_habits.py's
# test_dt_conventions): a negative dt is a step backwards in time, passed to fx as it is.


def single_loop(f: SquareRootUKF, zs, dts) -> tuple[np.ndarray, np.ndarray]:
    means, covs = [], []
    for z, dt in zip(zs, dts):
        f.predict(dt=dt)
        f.update(z)
        means.append(f.x)
        covs.append(f.P)
    return np.array(means), np.array(covs)


def fleet_loop(fl: Fleet, zs, dts) -> np.ndarray:
    means = []
    for t, dt in enumerate(dts):
        fl.predict(dt)
        fl.update(zs[:, t])
        means.append(fl.x)
    return np.stack(means, axis=1)


NEGATIVE_DTS = [1.0, -0.5, 0.0, -1.0, 0.5]


def test_negative_dts_run_the_same_on_every_single_filter_route():
    zs = near_measurements(5)
    expected = single_loop(near_filter(), zs, NEGATIVE_DTS)
    for dts in (NEGATIVE_DTS, np.array(NEGATIVE_DTS), iter(NEGATIVE_DTS)):
        means, covs = near_filter().batch_filter(zs, dts=dts)
        np.testing.assert_array_equal(means, expected[0])
        np.testing.assert_array_equal(covs, expected[1])
    means, covs = near_filter().batch_filter(zs, dts=-0.5)
    loop = single_loop(near_filter(), zs, [-0.5] * 5)
    np.testing.assert_array_equal(means, loop[0])
    f = near_filter()
    xs, Ps, Ks = f.rts_smoother(*expected, dts=NEGATIVE_DTS)
    assert xs.shape == (5, 5) and np.all(np.isfinite(Ps))


def test_negative_dts_run_the_same_on_every_fleet_route():
    zs = cv3_zs(5)
    expected = fleet_loop(make_cv3_fleet(), zs, NEGATIVE_DTS)
    fl = make_cv3_fleet()
    res = fl.batch_filter(zs, dts=NEGATIVE_DTS)
    np.testing.assert_array_equal(res.means, expected)
    np.testing.assert_array_equal(
        make_cv3_fleet().batch_filter(zs, dts=-0.5).means, fleet_loop(make_cv3_fleet(), zs, [-0.5] * 5)
    )
    sm = make_cv3_fleet().rts_smoother(res, dts=NEGATIVE_DTS)
    assert not sm.failed.any() and np.all(np.isfinite(sm[0]))
    # the smoother of one filter of the fleet, on the same data and dts
    f = make_cv3_fleet()[1]
    xs, _, _ = f.rts_smoother_factors(res.means[1], res.P1_2s[1], dts=NEGATIVE_DTS)
    np.testing.assert_allclose(sm[0][1], xs, rtol=1e-10, atol=1e-12)


def test_negative_dts_on_dask_as_in_one_process():
    sd = pytest.importorskip("squkf.dask")
    zs = cv3_zs(5)
    res = sd.compute(sd.batch_filter(make_cv3_fleet(), zs, dts=NEGATIVE_DTS), scheduler="synchronous")
    np.testing.assert_array_equal(res.means, make_cv3_fleet().batch_filter(zs, dts=NEGATIVE_DTS).means)


@pytest.mark.parametrize("bad", ["0.1", b"0.1", np.str_("0.1"), np.array("0.1"), "nan", "one"])
def test_a_string_dt_is_an_error_naming_it(bad):
    f = near_filter()
    f.predict()
    snap = filter_state(f)
    with pytest.raises(ParameterError, match="dt"):
        f.predict(dt=bad)
    assert_filter_state(f, snap)
    fl = make_cv3_fleet()
    snap = fleet_state(fl)
    with pytest.raises(ParameterError, match="dt"):
        fl.predict(dt=bad)
    assert_fleet_state(fl, snap)
    with pytest.raises(ParameterError):
        SquareRootUKF(5, 2, bad, ct_hx, ct_fx, MerweScaledWeights())
    with pytest.raises(ParameterError):
        Fleet(CV3_K, CV3_NX, CV3_NZ, bad, positions_hx, cv_fx_nudged, MerweScaledWeights())


def test_string_dts_are_errors_on_every_route():
    zs, fzs = near_measurements(5), cv3_zs(5)
    dts = [1.0, 1.0, "0.1", 1.0, 1.0]
    f = near_filter()
    snap = filter_state(f)
    with pytest.raises(ParameterError, match=r"dts\[2\]"):
        f.batch_filter(zs, dts=dts)
    assert_filter_state(f, snap)
    means, covs = f.batch_filter(zs)
    with pytest.raises(ParameterError, match=r"dts\[2\]"):
        f.rts_smoother(means, covs, dts=dts)
    fl = make_cv3_fleet()
    snap = fleet_state(fl)
    with pytest.raises(ParameterError, match=r"dts\[2\]"):
        fl.batch_filter(fzs, dts=dts)
    with pytest.raises(ParameterError, match="dts"):
        fl.batch_filter(fzs, dts=np.array(dts))
    assert_fleet_state(fl, snap)
    res = fl.batch_filter(fzs)
    with pytest.raises(ParameterError, match=r"dts\[2\]"):
        fl.rts_smoother(res, dts=dts)
    sd = pytest.importorskip("squkf.dask")
    with pytest.raises(ParameterError, match=r"dts\[2\]"):  # before anything is scheduled
        sd.batch_filter(make_cv3_fleet(), fzs, dts=dts)


# -- 3. a 1-element covariance reads back as assigned (filterpy stores what it is given) ----------


@pytest.mark.parametrize("name", ["R", "Q", "P"])
def test_a_one_element_covariance_reads_back_as_assigned(name):
    ours, theirs = one_d(SquareRootUKF), one_d_filterpy()
    for f in (ours, theirs):
        setattr(f, name, np.array([0.25]))
    assert getattr(ours, name).shape == getattr(theirs, name).shape == (1,)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "conversion of an array with ndim > 0 to a scalar"
        value = getattr(ours, name)[0]
        assert np.ndim(value) == 0 and value == 0.25
        if name == "R":
            ours.P[0, 0] = ours.R[0]  # a client program's line
            theirs.P[0, 0] = theirs.R[0]
    # an edit in place takes effect, as for a matrix
    getattr(ours, name)[0] = 0.5
    getattr(theirs, name)[0] = 0.5
    for f in (ours, theirs):
        f.predict()
        f.update(np.array([1.0]))
    np.testing.assert_allclose(ours.x, theirs.x, rtol=1e-12)
    np.testing.assert_allclose(np.atleast_2d(ours.P), np.atleast_2d(theirs.P), rtol=1e-12)
    # as filterpy, a step assigns P a matrix; Q and R keep what was assigned
    assert ours.P.shape == theirs.P.shape == (1, 1)
    if name != "P":
        assert getattr(ours, name).shape == (1,)


def test_a_one_element_covariance_survives_copies_and_pickles():
    import pickle

    f = one_d(SquareRootUKF)
    f.R = np.array([0.25])
    for g in (copy.copy(f), copy.deepcopy(f), pickle.loads(pickle.dumps(f))):
        assert g.R.shape == (1,) and g.R[0] == 0.25
        g.R[0] = 4.0
        assert f.R[0] == 0.25
        np.testing.assert_array_equal(g.R1_2, [[2.0]])


# -- 4. fx_args / hx_args reach the model functions and nothing else -------------------------

CLASHES = [
    ("hx_args", {"R": 100.0 * np.eye(CV3_NZ)}, "R"),
    ("hx_args", {"z": 1.0}, "z"),
    ("fx_args", {"dt": 2.0}, "dt"),
]


@pytest.mark.parametrize("arg, value, key", CLASHES)
def test_a_model_argument_named_like_a_step_argument_is_an_error_for_one_filter(arg, value, key):
    f = near_filter()
    snap = filter_state(f)
    with pytest.raises(ParameterError, match=f"{arg} has the key '{key}'"):
        f.batch_filter(near_measurements(3), **{arg: value})
    assert_filter_state(f, snap)
    if arg == "fx_args":
        means, covs = f.batch_filter(near_measurements(3))
        with pytest.raises(ParameterError, match=f"{arg} has the key '{key}'"):
            f.rts_smoother(means, covs, fx_args=value)


@pytest.mark.parametrize("arg, value, key", CLASHES)
def test_a_model_argument_named_like_a_step_argument_is_an_error_for_a_fleet(arg, value, key):
    fl = make_cv3_fleet()
    snap = fleet_state(fl)
    with pytest.raises(ParameterError, match=f"{arg} has the key '{key}'"):
        fl.batch_filter(cv3_zs(3), **{arg: value})
    assert_fleet_state(fl, snap)
    if arg == "fx_args":
        res = fl.batch_filter(cv3_zs(3))
        with pytest.raises(ParameterError, match=f"{arg} has the key '{key}'"):
            fl.rts_smoother(res, fx_args=value)
    sd = pytest.importorskip("squkf.dask")
    with pytest.raises(ParameterError, match=f"{arg} has the key '{key}'"):  # before scheduling
        sd.batch_filter(make_cv3_fleet(), cv3_zs(3), **{arg: value})


def test_hx_args_are_given_to_hx_only():
    """A fleet's ``hx_args`` reach ``hx`` as a loop of ``update(z, **hx_args)`` gives them."""
    zs = cv3_zs(4)
    res = make_cv3_fleet().batch_filter(zs, hx_args={"scale": 2.0}, fx_args={"u": 0.1})
    loop = make_cv3_fleet()
    for t in range(4):
        loop.predict(u=0.1)
        loop.update(zs[:, t], scale=2.0)
    np.testing.assert_array_equal(res.x, loop.x)


# -- 5. what a zs iterable yields is checked, naming the step; zs itself must be array-like ------


def test_a_generator_yielding_a_bad_step_is_named_for_a_fleet():
    good = cv3_zs(4)
    cases = [
        ([good[:, 0], good[:, 1, :1], good[:, 2]], ShapeError, r"zs\[1\] has shape \(3, 1\)"),
        ([good[:, 0], good[:, 1], None], ShapeError, r"zs\[2\] is None"),
        ([good[:2, 0], good[:2, 1]], ShapeError, r"zs\[0\] has shape \(2, 2\)"),
        ([good[:, 0], "1.0"], ShapeError, r"zs\[1\]"),
        ([good[:, 0], np.full((CV3_K, CV3_NZ), np.inf)], SqukfError, r"zs\[1\]"),
    ]
    for steps, error, match in cases:
        fl = make_cv3_fleet()
        snap = fleet_state(fl)
        with pytest.raises(error, match=match):
            fl.batch_filter(z for z in steps)
        assert_fleet_state(fl, snap)


def test_a_generator_yielding_a_bad_step_is_named_for_one_filter():
    good = near_measurements(3)
    cases = [
        ([good[0], good[1][:1].reshape(1, 1, 1), good[2]], ShapeError, r"at step 1: z has shape"),
        ([good[0], "1.0"], ShapeError, r"at step 1: z"),
        ([good[0], object()], ShapeError, r"at step 1: z"),
    ]
    for steps, error, match in cases:
        f = near_filter()
        snap = filter_state(f)
        with pytest.raises(error, match=match):
            f.batch_filter(z for z in steps)
        assert_filter_state(f, snap)


@pytest.mark.parametrize(
    "zs", [5.0, object(), {0: [1.0, 2.0]}, {1.0, 2.0}, frozenset({(1.0, 2.0)}), "zs", b"zs"], ids=repr
)
def test_zs_that_is_not_array_like_is_an_error_naming_zs(zs):
    f = near_filter()
    snap = filter_state(f)
    with pytest.raises(ShapeError, match="zs"):
        f.batch_filter(zs)
    assert_filter_state(f, snap)
    fl = make_cv3_fleet()
    snap = fleet_state(fl)
    with pytest.raises(ShapeError, match="zs"):
        fl.batch_filter(zs)
    assert_fleet_state(fl, snap)


# -- 6. masked measurements are missing where masked, on every route ----------------------------


def masked_fleet_zs(T: int = 5) -> tuple[np.ma.MaskedArray, np.ndarray]:
    zs = cv3_zs(T)
    mask = np.zeros(zs.shape, dtype=bool)
    mask[0, 1] = True  # a whole row
    mask[2, 3, 1] = True  # one component
    data = zs.copy()
    data[mask] = 1e6  # what a masked entry holds must never be read
    return np.ma.masked_array(data, mask=mask), np.where(mask, np.nan, zs)


def test_a_masked_zs_is_missing_where_masked_for_a_fleet():
    masked, nan = masked_fleet_zs()
    expected = make_cv3_fleet().batch_filter(nan)
    got = make_cv3_fleet().batch_filter(masked)
    np.testing.assert_array_equal(got.means, expected.means)
    np.testing.assert_array_equal(got.log_likelihood, expected.log_likelihood)
    steps = make_cv3_fleet().batch_filter(masked[:, t] for t in range(masked.shape[1]))
    np.testing.assert_array_equal(steps.means, expected.means)


def test_a_masked_zs_is_missing_where_masked_on_dask():
    sd = pytest.importorskip("squkf.dask")
    da = pytest.importorskip("dask.array")
    masked, nan = masked_fleet_zs()
    expected = make_cv3_fleet().batch_filter(nan)
    for zs in (masked, da.ma.masked_array(da.from_array(masked.data, chunks=(2, -1, -1)), mask=masked.mask)):
        got = sd.compute(sd.batch_filter(make_cv3_fleet(), zs), scheduler="synchronous")
        np.testing.assert_array_equal(got.means, expected.means)


# -- 7. a subset of no filters is an error ---------------------------------------------------------


NO_ROWS = [[], np.array([], dtype=int), np.zeros(CV3_K, dtype=bool), slice(0, 0)]


@pytest.mark.parametrize("rows", NO_ROWS, ids=repr)
def test_a_subset_of_no_filters_is_an_error_naming_rows(rows):
    fl = make_cv3_fleet()
    snap = fleet_state(fl)
    with pytest.raises(ParameterError, match="rows"):
        fl.subset(rows)
    assert_fleet_state(fl, snap)
    assert len(fl.subset([2])) == 1


# -- 8. the fleet's smoother of a zero-step result: empty arrays ----------------------------------


def test_the_fleet_smoother_of_no_steps_returns_empty_arrays():
    fl = make_cv3_fleet()
    res = fl.batch_filter(np.zeros((CV3_K, 0, CV3_NZ)))
    means, P1_2s, Gs = out = fl.rts_smoother(res)
    assert means.shape == (CV3_K, 0, CV3_NX) and P1_2s.shape == Gs.shape == (CV3_K, 0, CV3_NX, CV3_NX)
    assert out.failed.shape == (CV3_K,) and not out.failed.any()
    # as the single filter's smoother does
    f = near_filter()
    xs, Ps, Ks = f.rts_smoother(*f.batch_filter(np.zeros((0, 2))))
    assert xs.shape == (0, 5) and Ps.shape == Ks.shape == (0, 5, 5)


# -- 9. a flagged filter's failure describes its own values, as the single filter's error does ----


def single_error(f: SquareRootUKF, call) -> str:
    with pytest.raises(SqukfError) as info:
        call(f)
    return f"{type(info.value).__name__}: {info.value}"


def test_a_singular_innovation_is_described_by_the_failing_filters_own_values():
    fl = make_cv3_fleet()
    R = np.stack([0.1 * np.eye(CV3_NZ)] * CV3_K)
    R[1] = 0.0
    fl.R = R
    fl.predict()
    one = fl[1]  # filter 1 alone, as it is now
    scale = np.array([1.0, 0.0, 1.0])  # filter 1's hx is constant: with R = 0, Sy is singular
    z = cv3_zs(1)[:, 0]
    fl.update(z, scale=scale)
    assert fl.failed.tolist() == [False, True, False]
    expected = single_error(one, lambda f: f.update(z[1], scale=0.0))
    assert fl.failure[1] == expected


def test_non_finite_images_are_described_by_the_failing_filters_own_values():
    fl = make_cv3_fleet()
    one = fl[2]
    fl.predict(bad=np.array([False, False, True]))
    assert fl.failed.tolist() == [False, False, True]
    assert fl.failure[2] == single_error(one, lambda f: f.predict(bad=True))


# -- 10. an in-place edit of fleet.x, P, Q or R is never lost: taken at the next call --------------


def edited_pair(edit):
    """A fleet edited in place by ``edit``, and one given the same values by assignment."""
    fl, ref = make_cv3_fleet(), make_cv3_fleet()
    edit(fl)
    for name in ("x", "P", "Q", "R"):
        setattr(ref, name, np.array(getattr(fl, name)))
    return fl, ref


EDITS = {
    "x": lambda fl: fl.x.__setitem__((1, 0), 5.0),
    "P": lambda fl: fl.P.__setitem__((2, 0, 0), 4.0),
    "P *=": lambda fl: fl.P.__imul__(2.0),
    "Q": lambda fl: fl.Q.__setitem__((1, 1), 0.5),
    "R": lambda fl: fl.R.__setitem__((0, 0), 2.0),
}


@pytest.mark.parametrize("name", list(EDITS))
def test_an_edit_in_place_of_a_fleet_attribute_takes_effect(name):
    plain = make_cv3_fleet()
    fl, ref = edited_pair(EDITS[name])
    zs = cv3_zs(3)
    for f in (fl, ref, plain):
        f.predict()
        f.update(zs[:, 0])
    np.testing.assert_array_equal(fl.x, ref.x)
    np.testing.assert_array_equal(fl.P1_2, ref.P1_2)
    assert not np.array_equal(fl.P1_2, plain.P1_2) or not np.array_equal(fl.x, plain.x)


def test_several_edits_in_place_and_every_route_sees_them():
    zs = cv3_zs(3)
    fl = make_cv3_fleet()
    fl.R[0, 0] = 2.0  # two statements on the same attribute: both kept
    fl.R[1, 1] = 3.0
    fl.x[0] += 1.0
    assert fl.R[0, 0] == 2.0 and fl.R[1, 1] == 3.0
    ref = make_cv3_fleet()
    ref.R = np.diag([2.0, 3.0])
    x = np.array(ref.x)
    x[0] += 1.0
    ref.x = x
    np.testing.assert_array_equal(fl.batch_filter(zs).means, ref.batch_filter(zs).means)
    for route in (lambda f: f.subset(slice(None)).x, lambda f: f[0].x, lambda f: copy.copy(f).x):
        fl, ref = edited_pair(EDITS["x"])
        np.testing.assert_array_equal(route(fl), route(ref))
    sd = pytest.importorskip("squkf.dask")
    fl, ref = edited_pair(EDITS["P"])
    got = sd.compute(sd.batch_filter(fl, zs), scheduler="synchronous")
    np.testing.assert_array_equal(got.means, ref.batch_filter(zs).means)


def test_an_invalid_edit_in_place_raises_at_the_next_call_and_changes_nothing():
    fl = make_cv3_fleet()
    fl.predict()
    snap = fleet_state(fl)
    P = fl.P
    P[1, 0, 0] = -1.0  # not positive definite
    with pytest.raises(SqukfError, match=r"P\[1\]"):
        fl.update(cv3_zs(1)[:, 0])
    P[1, 0, 0] = snap["P1_2"][1, 0, 0] ** 2  # put back: nothing had changed
    assert_fleet_state(fl, snap)


def test_arrays_read_before_a_step_are_never_rewritten():
    fl = make_cv3_fleet()
    x, P = fl.x, fl.P
    kept = x.copy(), P.copy()
    fl.predict()
    fl.update(cv3_zs(1)[:, 0])
    np.testing.assert_array_equal(x, kept[0])
    np.testing.assert_array_equal(P, kept[1])
    assert fl.x is not x and not np.array_equal(fl.x, x)


# -- 11. text measurements are errors on every batch route, before anything runs -----------------


def text_versions(zs: np.ndarray) -> dict:
    text = zs.astype(str)
    mixed = zs.astype(object)
    mixed.flat[1] = "1.0"
    return {
        "list of str": text.tolist(),
        "str array": text,
        "object array of str": text.astype(object),
        "one str among numbers": mixed,
        "masked str": np.ma.masked_array(text, mask=np.zeros(zs.shape, dtype=bool)),
    }


@pytest.mark.parametrize("what", list(text_versions(np.zeros((2, 2)))))
def test_text_measurements_are_errors_for_one_filter(what):
    zs = text_versions(near_measurements(3))[what]
    f = near_filter()
    snap = filter_state(f)
    with pytest.raises(ShapeError, match="z"):
        f.batch_filter(zs)
    assert_filter_state(f, snap)
    with pytest.raises(ShapeError, match="z"):
        f.update(zs[0])
    assert_filter_state(f, snap)


@pytest.mark.parametrize("what", list(text_versions(np.zeros((2, 2)))))
def test_text_measurements_are_errors_for_a_fleet_and_on_dask(what):
    zs = text_versions(cv3_zs(3))[what]
    fl = make_cv3_fleet()
    snap = fleet_state(fl)
    with pytest.raises(ShapeError, match="zs"):
        fl.batch_filter(zs)
    with pytest.raises(ShapeError, match="z"):
        fl.update(np.asarray(zs)[:, 0])
    assert_fleet_state(fl, snap)
    sd = pytest.importorskip("squkf.dask")
    with pytest.raises(ShapeError, match="zs"):  # raised by batch_filter itself: nothing scheduled
        sd.batch_filter(make_cv3_fleet(), zs)
    da = pytest.importorskip("dask.array")
    if np.asarray(zs).dtype.kind in "UO":
        with pytest.raises(ShapeError, match="zs"):
            sd.batch_filter(make_cv3_fleet(), da.from_array(np.asarray(zs), chunks=(1, -1, -1)))
