"""One rule per input on every route: SquareRootUKF, its batch_filter and smoother, Fleet, squkf.dask.

dt is any finite real number (negative: a step backwards), never a string; fx_args and hx_args
reach the model functions only and may not be named like a step argument; what a zs iterable
yields is checked naming the step, and zs must be array-like; text measurements are errors before
anything runs. Each test failed on the code before its fix (issue 20). Issue 35: a number beyond
float64's range (``10**400``) anywhere is refused naming its argument; a time step is never a bool,
a measurement never holds booleans, and ``vectorized`` is True or False.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from models import (
    CV3_K,
    CV3_NX,
    CV3_NZ,
    NEAR_SHAPES,
    DuckArray,
    assert_filter_state,
    assert_fleet_state,
    assert_same_estimate,
    ct_filter,
    ct_fx,
    ct_fx_rows,
    ct_hx,
    ct_measurements,
    cv3_zs,
    cv_fx_nudged,
    decay_fx,
    filter_state,
    fleet_state,
    gp_ukf_fx,
    gp_ukf_fx_row,
    half_hx,
    make_cv3_fleet,
    near_filter,
    near_measurements,
    near_shaped,
    one_d,
    positions_hx,
)

from squkf import (
    Fleet,
    MerweScaledWeights,
    NonFiniteError,
    ParameterError,
    ShapeError,
    SquareRootUKF,
    SqukfError,
)

# the paths here end in documented errors or decisions: no numpy RuntimeWarning may escape squkf
pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")


# -- 2. one rule for dt on every route: any finite real number; strings are refused ----------
#
# The rule is filterpy's (and ``SquareRootUKF.predict``'s since tests/test_ukf.py's
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


def test_an_array_like_zs_is_read_as_the_array_of_filters_steps_and_components():
    zs = cv3_zs(5)  # (K, T, dim_z): a duck array is read as it, not iterated over its filters
    want = make_cv3_fleet().batch_filter(zs)
    got = make_cv3_fleet().batch_filter(DuckArray(zs))
    np.testing.assert_array_equal(got.means, want.means)
    with pytest.raises(ShapeError, match=r"zs has shape \(5, 3, 2\)"):
        make_cv3_fleet().batch_filter(DuckArray(zs.transpose(1, 0, 2)))


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


# -- issue 29, 1. per point, a model value of a near shape is its row ------------------------------
#
# filterpy stores a per-point value with ``sigmas_f[i] = fx(...)``: any value numpy assigns into the
# row. squkf takes the same per point (fx and hx, and the lists told to tell_*), less numpy's
# broadcast of a single number into a longer row; the vectorised and fleet routes keep exact shapes.


def ct_run(f, zs):
    for z in zs:
        f.predict()
        f.update(z)
    return f


@settings(max_examples=25, deadline=None)
@given(
    fx_forms=st.lists(st.sampled_from(list(NEAR_SHAPES)), min_size=1, max_size=11),
    hx_forms=st.lists(st.sampled_from(list(NEAR_SHAPES)), min_size=1, max_size=11),
)
def test_per_point_values_of_a_near_shape_give_the_rows_numbers(fx_forms, hx_forms):
    """Any mix of shapes, one per sigma point (11 of them), is read as the rows, bit for bit."""
    zs = ct_measurements(3)
    want = ct_run(ct_filter(MerweScaledWeights()), zs)
    f = ct_filter(MerweScaledWeights())
    f.fx, f.hx = near_shaped(ct_fx, fx_forms), near_shaped(ct_hx, hx_forms)
    assert_same_estimate(ct_run(f, zs), want)


def test_a_gp_ukf_fx_of_shape_1_n_runs_as_its_row_on_every_per_point_route():
    zs = ct_measurements(6)
    row, gp = ct_filter(MerweScaledWeights()), ct_filter(MerweScaledWeights())
    row.fx, gp.fx = gp_ukf_fx_row, gp_ukf_fx
    want, got = row.batch_filter(zs), gp.batch_filter(zs)
    for a, b in zip(want, got):
        np.testing.assert_array_equal(a, b)
    for a, b in zip(row.rts_smoother(*want[:2]), gp.rts_smoother(*got[:2])):
        np.testing.assert_array_equal(a, b)
    # ask/tell: the lists of per-point values told
    row, told = ct_filter(MerweScaledWeights()), ct_filter(MerweScaledWeights())
    row.fx = gp_ukf_fx_row
    row.predict()
    told.tell_predict([gp_ukf_fx(x, 1.0) for x in told.ask_predict()])
    row.update(zs[0])
    told.tell_update([ct_hx(x)[None] for x in told.ask_update()], zs[0])
    assert_same_estimate(told, row)


@pytest.mark.parametrize("forms", [["number"], ["0-d array"], ["(1,)"], ["(1, 1, d)", "number"], ["list"]])
def test_one_number_is_the_value_of_a_one_dimensional_model(forms):
    want, f = one_d(SquareRootUKF), one_d(SquareRootUKF)
    f.fx, f.hx = near_shaped(decay_fx, forms), near_shaped(half_hx, forms)
    for z in (0.3, -0.2, 0.1):
        for g in (want, f):
            g.predict()
            g.update(z)
        assert_same_estimate(f, want)


NOT_A_ROW = [
    ("number", r"sigma point 0 has shape \(\), expected \({d},\).*not a single number"),
    ("0-d array", r"sigma point 0 has shape \(\), expected \({d},\)"),
    ("(1,)", r"sigma point 0 has shape \(1,\), expected \({d},\).*not a single number"),
]


@pytest.mark.parametrize("which", ["fx", "hx"])
@pytest.mark.parametrize("form, match", NOT_A_ROW, ids=[f for f, _ in NOT_A_ROW])
def test_one_number_for_a_longer_row_is_refused_not_broadcast(which, form, match):
    f = ct_filter(MerweScaledWeights())
    f.predict()
    f.update(ct_hx(f.x) + 1.0)
    snap = filter_state(f)
    with pytest.raises(ShapeError, match=f"{which} values at " + match.format(d=5 if which == "fx" else 2)):
        if which == "fx":
            f.predict(fx=near_shaped(ct_fx, [form]))
        else:
            f.update(ct_hx(f.x), hx=near_shaped(ct_hx, [form]))
    assert_filter_state(f, snap)


@pytest.mark.parametrize(
    "value, match",
    [
        (lambda v: np.stack([v, v]), r"sigma point 0 has shape \(2, 5\)"),
        (lambda v: v[:, None, None], r"sigma point 0 has shape \(5, 1, 1\)"),
        (lambda v: v[None].astype(complex), "complex"),
        (lambda v: [str(a) for a in v], "could not be read"),
    ],
    ids=["(2, n)", "(n, 1, 1)", "complex", "text"],
)
def test_other_per_point_values_are_refused_and_change_nothing(value, match):
    f = ct_filter(MerweScaledWeights())
    snap = filter_state(f)
    with pytest.raises(ShapeError, match=match):
        f.predict(fx=lambda x, dt: value(ct_fx(x, dt)))
    assert_filter_state(f, snap)
    X = f.ask_predict()
    with pytest.raises(ShapeError, match=match):
        f.tell_predict([value(ct_fx(x, 1.0)) for x in X])


def test_the_vectorised_and_fleet_routes_keep_exact_shapes():
    f = ct_filter(MerweScaledWeights(), vectorized=True)
    snap = filter_state(f)
    with pytest.raises(ShapeError, match=r"fx values has shape \(1, 11, 5\), expected \(11, 5\)"):
        f.predict(fx=lambda X, dt: ct_fx_rows(X, dt)[None])
    assert_filter_state(f, snap)
    fl = Fleet(
        CV3_K,
        CV3_NX,
        CV3_NZ,
        1.0,
        positions_hx,
        lambda X, dt: cv_fx_nudged(X, dt)[None],
        MerweScaledWeights(),
    )
    snap = fleet_state(fl)
    with pytest.raises(ShapeError, match=r"fx values have shape \(1, 3, 9, 4\), expected \(3, 9, 4\)"):
        fl.predict()
    assert_fleet_state(fl, snap)


# -- issue 35, 6. a number beyond float64's range is an error naming its argument ----------------
#
# A Python integer such as 10**400 has no float64: numpy and float() raise a bare OverflowError.
# Anywhere in an array (a list, nested lists, an object array) or as one number, it is refused as
# the infinity it would be: a NonFiniteError naming the argument (a ParameterError for a time
# step, as every other bad dt), and nothing changes.

HUGE = st.integers(min_value=2**1024, max_value=10**500) | st.integers(
    min_value=-(10**500), max_value=-(2**1024)
)
FORMS = ["list", "object array", "one number"]


def with_huge(value: np.ndarray, where: int, huge: int, form: str):
    """``value`` with entry ``where`` (modulo its size) made ``huge``, as nested lists or an object array."""
    if form == "one number":
        return huge
    out = np.asarray(value, dtype=float).astype(object)
    out.flat[where % out.size] = huge
    return out.tolist() if form == "list" else out


@settings(max_examples=80, deadline=None)
@given(
    target=st.sampled_from(["x", "P", "Q", "R", "Q per call", "R per call", "z", "z in tell_update"]),
    where=st.integers(0, 100),
    huge=HUGE,
    form=st.sampled_from(FORMS),
)
def test_a_huge_integer_is_refused_naming_its_argument_for_one_filter(target, where, huge, form):
    f = near_filter()
    z = near_measurements(1)[0]
    f.predict()
    f.update(z)
    name = target.split()[0]
    bad = with_huge({"x": f.x, "P": f.P, "Q": f.Q, "R": f.R, "z": z}[name], where, huge, form)
    snap = filter_state(f)
    with pytest.raises(NonFiniteError, match=rf"^{name} holds .*beyond float64's largest"):
        if target == "Q per call":
            f.predict(Q=bad)
        elif target == "R per call":
            f.update(z, R=bad)
        elif target == "z":
            f.update(bad)
        elif target == "z in tell_update":
            Y = f.ask_update()
            f.tell_update([ct_hx(y) for y in Y], bad)
        else:
            setattr(f, name, bad)
    if target == "z in tell_update":
        f.tell_update([ct_hx(y) for y in Y], z)  # the ask is still pending: the step completes
    else:
        assert_filter_state(f, snap)


@settings(max_examples=60, deadline=None)
@given(
    target=st.sampled_from(["x", "P", "Q", "R", "R per call", "z"]),
    per_filter=st.booleans(),
    where=st.integers(0, 100),
    huge=HUGE,
    form=st.sampled_from(FORMS),
)
def test_a_huge_integer_is_refused_naming_its_argument_for_a_fleet(target, per_filter, where, huge, form):
    fl = make_cv3_fleet()
    zs = cv3_zs(1)[:, 0]
    name = target.split()[0]
    one = {"x": fl.x[0], "P": fl.P[0], "Q": fl.Q, "R": fl.R, "z": zs}[name]  # Q and R are shared
    good = np.broadcast_to(one, (CV3_K,) + one.shape) if per_filter and name != "z" else one
    bad = with_huge(good, where, huge, form)
    snap = fleet_state(fl)
    with pytest.raises(NonFiniteError, match=rf"^{name} holds .*beyond float64's largest"):
        if target == "R per call":
            fl.update(zs, R=bad)
        elif target == "z":
            fl.update(bad)
        else:
            setattr(fl, name, bad)
    assert_fleet_state(fl, snap)


@pytest.mark.parametrize("huge", [10**400, -(10**400)], ids=["+10**400", "-10**400"])
def test_a_huge_integer_in_a_run_is_refused_naming_it(huge):
    zs = near_measurements(3).astype(object)
    zs[1, 0] = huge
    f = near_filter()
    snap = filter_state(f)
    with pytest.raises(NonFiniteError, match=r"at step 1: z holds"):
        f.batch_filter(zs.tolist())
    assert_filter_state(f, snap)
    fzs = cv3_zs(3).astype(object)
    fzs[2, 1, 1] = huge
    fl = make_cv3_fleet()
    snap = fleet_state(fl)
    with pytest.raises(NonFiniteError, match=r"^zs holds"):
        fl.batch_filter(fzs.tolist())
    assert_fleet_state(fl, snap)


# -- issue 35, 6. and 9. a time step is a number: not beyond float64's range, not a bool -----------


BAD_STEPS = [10**400, -(10**400), True, False, np.True_, np.array(True)]


@pytest.mark.parametrize(
    "bad", BAD_STEPS, ids=["+10**400", "-10**400", "True", "False", "np.True_", "0-d bool"]
)
def test_a_huge_or_boolean_dt_is_refused_naming_it_on_every_route(bad):
    with pytest.raises(ParameterError, match="^dt must be a finite number"):
        SquareRootUKF(5, 2, bad, ct_hx, ct_fx, MerweScaledWeights())
    with pytest.raises(ParameterError, match="^dt must be a finite number"):
        Fleet(CV3_K, CV3_NX, CV3_NZ, bad, positions_hx, cv_fx_nudged, MerweScaledWeights())
    f = near_filter()
    f.predict()
    snap = filter_state(f)
    with pytest.raises(ParameterError, match="^dt must be a finite number"):
        f.predict(dt=bad)
    with pytest.raises(ParameterError, match=r"dts\[1\] must be a finite number"):
        f.batch_filter(near_measurements(3), dts=[1.0, bad, 1.0])
    with pytest.raises(ParameterError, match="^dts must be"):
        f.batch_filter(near_measurements(3), dts=bad)
    assert_filter_state(f, snap)
    means, covs = near_filter().batch_filter(near_measurements(3))
    with pytest.raises(ParameterError, match=r"dts\[2\] must be a finite number"):
        near_filter().rts_smoother(means, covs, dts=[1.0, 1.0, bad])
    fl = make_cv3_fleet()
    snap = fleet_state(fl)
    with pytest.raises(ParameterError, match="^dt must be a finite number"):
        fl.predict(dt=bad)
    with pytest.raises(ParameterError, match=r"dts\[1\] must be a finite number"):
        fl.batch_filter(cv3_zs(3), dts=[1.0, bad, 1.0])
    assert_fleet_state(fl, snap)


def test_a_boolean_array_of_dts_is_refused_naming_the_step():
    f = near_filter()
    snap = filter_state(f)
    with pytest.raises(ParameterError, match=r"dts\[0\] must be a finite number, not a bool"):
        f.batch_filter(near_measurements(2), dts=np.array([True, True]))
    assert_filter_state(f, snap)


# -- issue 35, 9. a measurement is numbers, not booleans ------------------------------------------


def bool_versions(zs: np.ndarray) -> dict:
    """``zs`` (any shape) with booleans: a bool array, Python bools, one bool among numbers."""
    flags = zs > 0
    mixed = zs.astype(object)
    mixed.flat[0] = True
    return {
        "bool array": flags,
        "list of bools": flags.tolist(),
        "one bool among numbers (list)": mixed.tolist(),
        "one bool among numbers (object array)": mixed,
        "numpy bool among numbers": [np.True_] + zs.ravel()[1:].tolist() if zs.ndim == 1 else None,
        "masked bool array": np.ma.masked_array(flags, mask=np.zeros(zs.shape, dtype=bool)),
    }


@pytest.mark.parametrize("what", list(bool_versions(np.zeros(2))))
def test_a_boolean_measurement_is_refused_naming_z_for_one_filter(what):
    zs = near_measurements(3)
    z = bool_versions(zs[0])[what]
    f = near_filter()
    f.predict()
    snap = filter_state(f)
    with pytest.raises(ShapeError, match="^z holds booleans"):
        f.update(z)
    assert_filter_state(f, snap)
    Y = f.ask_update()
    with pytest.raises(ShapeError, match="^z holds booleans"):
        f.tell_update([ct_hx(y) for y in Y], z)
    f.tell_update([ct_hx(y) for y in Y], zs[0])  # the ask is still pending: the step completes
    f = near_filter()
    snap = filter_state(f)
    with pytest.raises(ShapeError, match=r"at step 1: z holds booleans"):
        f.batch_filter([zs[0], z, zs[2]])
    assert_filter_state(f, snap)


@pytest.mark.parametrize("what", [w for w in bool_versions(np.zeros(2)) if "numpy bool" not in w])
def test_a_boolean_measurement_is_refused_naming_z_for_a_fleet(what):
    z = bool_versions(cv3_zs(1)[:, 0])[what]
    zs = bool_versions(cv3_zs(3))[what]
    fl = make_cv3_fleet()
    fl.predict()
    snap = fleet_state(fl)
    with pytest.raises(ShapeError, match="^z holds booleans"):
        fl.update(z)
    assert_fleet_state(fl, snap)
    Y = fl.ask_update()
    with pytest.raises(ShapeError, match="^z holds booleans"):
        fl.tell_update(positions_hx(Y), z)
    fl.tell_update(positions_hx(Y), cv3_zs(1)[:, 0])  # the ask is still pending: the step completes
    fl = make_cv3_fleet()
    snap = fleet_state(fl)
    with pytest.raises(ShapeError, match="^zs holds booleans"):
        fl.batch_filter(zs)
    assert_fleet_state(fl, snap)
    sd = pytest.importorskip("squkf.dask")
    with pytest.raises(ShapeError, match="^zs holds booleans"):  # before anything is scheduled
        sd.batch_filter(make_cv3_fleet(), zs)


# -- issue 35, 9. vectorized is True or False -------------------------------------------------------


@pytest.mark.parametrize("bad", ["no", "False", "", 1, 0, 1.0, None, [True]], ids=repr)
def test_vectorized_that_is_not_a_bool_is_refused_naming_it(bad):
    with pytest.raises(ParameterError, match=r"^vectorized must be True or False"):
        SquareRootUKF(5, 2, 1.0, ct_hx, ct_fx, MerweScaledWeights(), vectorized=bad)
    # numpy's bools are bools
    assert near_filter(vectorized=np.False_).vectorized is False
    fl = SquareRootUKF(4, 2, 1.0, positions_hx, cv_fx_nudged, MerweScaledWeights(), vectorized=np.True_)
    assert fl.vectorized is True


@pytest.mark.parametrize("bad", ["no", 1, None], ids=repr)
def test_vectorized_assigned_that_is_not_a_bool_is_refused_and_changes_nothing(bad):
    f = near_filter()
    with pytest.raises(ParameterError, match=r"^vectorized must be True or False"):
        f.vectorized = bad
    assert f.vectorized is False
    f.vectorized = np.True_
    assert f.vectorized is True


@pytest.mark.parametrize("where", ["alpha", "gate"])
def test_a_huge_integer_as_a_points_parameter_or_a_gate_is_named(where):
    with pytest.raises(ParameterError, match=where):
        if where == "alpha":
            MerweScaledWeights(alpha=10**400)
        else:
            near_filter(gate=10**400)
