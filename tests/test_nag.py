"""squkf.nag: g13ej's calling sequence, its example, its documented errors, and bad input.

The example program prints NAG's published table; each documented IFAIL number is raised (as a
squkf exception carrying it as ``errno``) with the arguments left as they were; a corrupted comm,
non-numeric arguments, bad ROPT and any junk give a numbered error and change nothing.
"""

from __future__ import annotations

import copy
import os
import subprocess
import sys
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from models import at_exit, call, fill, first_entry

from squkf import (
    Augmented,
    CallSequenceError,
    JulierWeights,
    MerweScaledWeights,
    NonFiniteError,
    ParameterError,
    Redrawn,
    SimplexWeights,
    SqukfError,
    unscented_transform,
)
from squkf.examples import g13ej_example as ex

DATA = ex.load_data()


def test_example_program_prints_the_published_table():
    out = subprocess.run(
        [sys.executable, "-m", "squkf.examples.g13ej_example"], capture_output=True, text=True, check=True
    ).stdout
    lines = out.splitlines()
    assert lines[0] == "g13ej example results"
    assert lines[3].split() == list(ex.STATE_NAMES)  # the columns are named
    rows = [line.split() for line in lines if line.strip()[:1].isdigit() and len(line.split()) == 4]
    assert len(rows) == 15
    published = DATA["published_state_estimates"]["x"]
    for t, row in enumerate(rows):
        assert int(row[0]) == t + 1
        assert [float(v) for v in row[1:]] == published[t]
    start = lines.index("Covariance Matrix at the Last Time Point") + 1
    printed = [[float(v) for v in line.split()] for line in lines[start : start + 3]]
    assert printed == DATA["published_final_st"]["rows"]
    # the last line compares the unrounded estimates with the table: all agree, and the largest
    # difference it reports is the one computed here, below half a unit of the third decimal
    states, _ = ex.run()
    largest = np.abs(states - np.array(published)).max()
    assert lines[-1] == (
        "All 45 values agree with NAG's published results to the 3 decimal places printed "
        f"(max abs difference from the printed values {largest:.1e})"
    )
    assert largest < 5e-4


def test_example_comparison_reports_a_value_that_differs():
    states, _ = ex.run()
    states[8, 1] += 0.002
    line = ex.comparison_line(states, DATA)
    assert line.startswith("44 of 45 values agree")
    assert f"{ex.STATE_NAMES[1]} at time 9" in line


def test_example_program_names_the_columns_in_ascii_where_greek_cannot_be_printed():
    out = subprocess.run(
        [sys.executable, "-m", "squkf.examples.g13ej_example"],
        capture_output=True,
        check=True,
        env={**os.environ, "PYTHONIOENCODING": "ascii"},
    ).stdout.decode("ascii")
    assert out.splitlines()[3].split() == ["xi", "eta", "theta"]
    assert out.splitlines()[-1].startswith("All 45 values agree")


def test_first_time_point_exits():
    a = first_entry()
    irevcm, n = call(a)
    assert (irevcm, n) == (1, 7)
    g = np.sqrt(3.0) * 0.1  # gamma = sqrt(L + lambda) = sqrt(3) with NAG's defaults; ST = 0.1 I
    expected = np.hstack([np.zeros((3, 1)), g * np.eye(3), -g * np.eye(3)])
    np.testing.assert_allclose(a["xt"][:, :7], expected, rtol=0, atol=1e-16)
    fill(a, n)
    irevcm, n = call(a)
    assert (irevcm, n) == (2, 7)
    # independent prediction in covariance form: Wm = [0, 1/6...], Wc = [2, 1/6...], + LX LX^T
    F = a["fxt"][:3, :7]
    Wm = np.r_[0.0, np.full(6, 1 / 6)]
    Wc = np.r_[2.0, np.full(6, 1 / 6)]
    xbar = F @ Wm
    D = F - xbar[:, None]
    Pbar = (D * Wc) @ D.T + 0.01 * np.eye(3)
    np.testing.assert_allclose(a["x"], xbar, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(np.tril(a["st"]) @ np.tril(a["st"]).T, Pbar, rtol=1e-12, atol=1e-15)
    fill(a, n)
    assert call(a)[0] == 3
    np.testing.assert_array_equal(np.round(a["x"], 3), DATA["published_state_estimates"]["x"][0])


def test_augmented_second_set_has_13_points():
    a = first_entry(ropt=[2])
    irevcm, n = call(a)
    assert (irevcm, n) == (1, 7)
    fill(a, n)
    irevcm, n = call(a)
    assert (irevcm, n) == (2, 13)
    # the propagated first set, then F_1 +/- gamma' LX columns, gamma' = sqrt(3) (L'+kappa' = L+kappa)
    F = a["fxt"][:3, :7]
    np.testing.assert_allclose(a["xt"][:, :7], F, rtol=0, atol=0)
    g = np.sqrt(3.0) * 0.1
    np.testing.assert_allclose(a["xt"][:, 7:10], F[:, :1] + g * np.eye(3), atol=1e-15)
    np.testing.assert_allclose(a["xt"][:, 10:13], F[:, :1] - g * np.eye(3), atol=1e-15)
    states, st = ex.run(ropt=[2])
    assert np.all(np.isfinite(states)) and np.all(np.diag(st) > 0)


def test_section_9_unscented_transform():
    """lx=None and stopping at irevcm == 2 leaves the UT of F in x and st."""
    S0 = np.array([[0.3, 0, 0], [0.1, 0.2, 0], [-0.05, 0.02, 0.4]])
    a = first_entry(lx=None)
    a["st"] = S0.copy()
    irevcm, n = call(a)
    fill(a, n)
    irevcm, n = call(a)
    assert irevcm == 2
    m = DATA["model"]
    mean, S = unscented_transform(lambda v: ex.f(v[:, None], m["r"], m["d"], 0.4, 0.1)[:, 0], np.zeros(3), S0)
    np.testing.assert_allclose(a["x"], mean, rtol=1e-14, atol=1e-16)
    np.testing.assert_allclose(np.tril(a["st"]), S, rtol=1e-13, atol=1e-16)


# -- documented errors: a row per number, state left as it was ---------------------------------


def snapshot(a):
    return {k: copy.deepcopy(v) for k, v in a.items() if k in ("x", "st", "xt", "comm")}


def assert_unchanged(a, snap):
    for k in ("x", "st", "xt"):
        np.testing.assert_array_equal(a[k], snap[k])
    assert a["comm"].keys() == snap["comm"].keys()
    for k in a["comm"]:
        if k in ("icomm", "digest_i", "digest_r"):
            assert a["comm"][k] == snap["comm"][k]


def expect(a, errno):
    snap = snapshot(a)
    with pytest.raises(Exception) as info:
        call(a)
    assert getattr(info.value, "errno", None) == errno, info.value
    assert_unchanged(a, snap)
    return info.value


def _set(**values):
    """An edit of the arguments: ``values`` assigned."""
    return lambda a: a.update(values)


# (where the call is made: "entry" or intermediate exit 1 or 2, ROPT, the edit, errno, the class)
ERRNO_CASES = [
    pytest.param("entry", None, _set(irevcm=4), 11, ValueError, id="11-irevcm-at-entry"),
    pytest.param(1, None, _set(irevcm=2), 11, Exception, id="11-irevcm-at-exit"),
    pytest.param("entry", None, _set(x=np.zeros(0)), 21, Exception, id="21-mx"),
    pytest.param(1, None, _set(x=np.zeros(2)), 22, Exception, id="22-mx-changed"),
    pytest.param("entry", None, _set(y=[]), 31, Exception, id="31-my"),
    pytest.param(1, None, _set(y=[1.0, 2.0, 3.0]), 32, Exception, id="32-my-changed"),
    pytest.param("entry", None, _set(lx=np.eye(2)), 61, Exception, id="61-lx"),
    pytest.param("entry", None, _set(ly=np.eye(1)), 81, Exception, id="81-ly"),
    pytest.param("entry", None, _set(st=np.eye(2)), 111, Exception, id="111-st"),
    pytest.param("entry", [2], _set(xt=np.zeros((3, 12))), 121, Exception, id="121-augmented-capacity"),
    pytest.param("entry", None, _set(xt=np.zeros((3, 6))), 122, Exception, id="122-redrawn-capacity"),
    pytest.param(1, None, _set(xt=np.zeros((3, 9))), 123, Exception, id="123-n-changed"),
    pytest.param("entry", None, _set(xt=np.zeros((2, 13))), 141, Exception, id="141-xt-rows"),
    pytest.param(1, None, _set(fxt=np.zeros((2, 13))), 161, Exception, id="161-fxt-rows-for-f"),
    pytest.param(2, None, _set(fxt=np.zeros((1, 13))), 162, Exception, id="162-fxt-rows-for-h"),
    pytest.param("entry", [3], _set(), 171, Exception, id="171-scheme"),
    pytest.param("entry", [1, -3.0], _set(), 172, Exception, id="172-kappa-redrawn"),
    pytest.param("entry", [1, 0.0, 1, 2, -3.0], _set(), 172, Exception, id="172-kappa-second-set"),
    pytest.param("entry", [2, 0.0, 1, 2, -6.0], _set(), 172, Exception, id="172-kappa-augmented"),
    pytest.param("entry", [1, 0.0, 0.0], _set(), 173, Exception, id="173-alpha-zero"),
    pytest.param("entry", [1, 0.0, 1.0, 2.0, 0.0, -1.0], _set(), 173, Exception, id="173-alpha-second-set"),
    pytest.param("entry", [1, 0, 1, 2, 0, 1, 2, 9], _set(), 181, Exception, id="181-lropt"),
    pytest.param(
        1,
        None,
        lambda a: a["comm"].update(icomm=(3, 2, 13, 1, 8, 0)),
        191,
        Exception,
        id="191-icomm-corrupted",
    ),
    pytest.param(1, None, lambda a: a["comm"].clear(), 191, Exception, id="191-comm-emptied"),
    # x must remain unchanged between exits and re-entries
    pytest.param(
        1, None, lambda a: a["x"].__setitem__(0, a["x"][0] + 1.0), 211, Exception, id="211-x-changed"
    ),
]


@pytest.mark.parametrize("where, ropt, edit, errno, cls", ERRNO_CASES)
def test_documented_errno(where, ropt, edit, errno, cls):
    """Each documented IFAIL number, raised as ``cls`` with ``errno``, the arguments left as they were."""
    a = first_entry(ropt=ropt) if where == "entry" else at_exit(where, ropt=ropt)
    edit(a)
    assert isinstance(expect(a, errno), cls)


def test_errno_301_negative_weight_downdate():
    # alpha = 1, beta = 0, kappa = -1: the weights outside the centre sum to s = 1.5 > 1, so
    # when every non-central point is mapped to the same place the weighted "covariance" is
    # s (1 - s) e e^T < 0 along e: the negative-weight downdate must fail
    a = first_entry(ropt=[1, -1.0, 1.0, 0.0], lx=None)
    _, n = call(a)
    a["fxt"][:3, :n] = 0.0
    a["fxt"][:3, 0] = [50.0, 0, 0]
    expect(a, 301)


def test_tiny_alpha_needs_no_downdate():
    """The input g13ej's downdate fails on (alpha = 0.01, beta = 2) is a valid rank-1 covariance.

    With beta >= alpha**2 the covariance is written with non-negative weights only (deviations
    from the central point), so squkf factors it by QR and gets it right instead of failing.
    """
    a = first_entry(ropt=[1, 0.0, 0.01], lx=None)
    _, n = call(a)
    a["fxt"][:3, :n] = 0.0
    a["fxt"][:3, 0] = [50.0, 0, 0]
    irevcm, _ = call(a)
    assert irevcm == 2
    Wm, Wc = MerweScaledWeights(0.01, 2.0, 0.0).weights(3)
    F = a["fxt"][:3, :n].T
    mean = Wm @ F
    D = F - mean
    P = (D.T * Wc) @ D  # terms of 2.5e15 cancel to 5e11: the reference is good to ~1e-11
    np.testing.assert_allclose(a["x"], mean, rtol=1e-12)
    St = np.tril(a["st"])
    np.testing.assert_allclose(St @ St.T, P, rtol=1e-9, atol=1e-9 * P[0, 0])
    assert P[0, 0] > 0 and np.all(np.diag(St)[1:] == 0)


def test_errno_302_singular_innovation():
    a = at_exit(2)
    a["ly"] = np.zeros((2, 2))
    a["fxt"][:2, :] = 1.0  # H constant: no spread and no noise
    err = expect(a, 302)
    assert isinstance(err, np.linalg.LinAlgError)


def test_errno_303_posterior_downdate():
    # augmented set with alpha' != alpha: the downdate form is used; a wildly inconsistent H
    # (huge cross-covariance, tiny innovation variance) makes Pbar - K Pyy K^T indefinite
    a = first_entry(ropt=[2, 0.0, 1.0, 2.0, -2.0, 0.5])
    _, n = call(a)
    fill(a, n)
    _, n = call(a)
    a["ly"] = np.eye(2) * 1e-8
    Y = a["xt"][:, :n]
    a["fxt"][:2, :n] = 1e3 * (Y[:2] - Y[:2, :1]) ** 3
    err = expect(a, 303)
    assert isinstance(err, np.linalg.LinAlgError)


# == bad input: a corrupted comm, non-numeric arguments, bad ROPT ==================================
#
# Every failure is a squkf exception carrying g13ej's IFAIL number (``errno``),
# never a raw numpy or Python error, and leaves ``x``, ``st``, ``xt`` and
# ``comm`` as they were.

COMM_ERRNOS = {11, 191, 211}  # what a changed comm can give (11: a comm from another exit)


def state(a):
    return {k: np.array(a[k], copy=True) for k in ("x", "st", "xt")}


def assert_same_state(a, before):
    for k, v in before.items():
        np.testing.assert_array_equal(a[k], v)


def expect_errno(a, errno):
    before = state(a)
    comm = dict(a["comm"]) if isinstance(a["comm"], dict) else a["comm"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a ComplexWarning would mean a silent cast
        with pytest.raises(SqukfError) as info:
            call(a)
    assert info.value.errno == errno, info.value
    assert_same_state(a, before)
    if isinstance(comm, dict):
        assert a["comm"].keys() == comm.keys()
        assert all(a["comm"][k] is comm[k] for k in comm)
    return info.value


def reference(k, ropt):
    """The result of the call from exit k: (irevcm, n, x, st, xt)."""
    a = at_exit(k, ropt=ropt)
    irevcm, n = call(a)
    return irevcm, n, a["x"].copy(), a["st"].copy(), a["xt"].copy()


REFERENCES = {(k, s): reference(k, [s]) for k in (1, 2) for s in (1, 2)}


# -- comm corrupted between calls ----------------------------------------------------------------

JUNK = st.sampled_from(
    [None, 0, -1, 1.5, float("nan"), "x", b"\x00", [], {}, (), np.zeros(3), np.array(["a"]), object()]
)


def corrupt(data, comm):
    """Change comm in place in one of many ways (or return a replacement for it)."""
    op = data.draw(
        st.sampled_from(
            ["delete", "replace", "swap", "icomm", "icomm_shape", "digest", "machine", "family", "generator"]
        ),
        label="op",
    )
    keys = sorted(comm)
    if op == "delete":
        del comm[data.draw(st.sampled_from(keys))]
    elif op == "replace":
        comm[data.draw(st.sampled_from(keys))] = data.draw(JUNK)
    elif op == "swap":
        k1, k2 = data.draw(st.permutations(keys))[:2]
        comm[k1], comm[k2] = comm[k2], comm[k1]
    elif op == "icomm":
        ints = list(comm["icomm"])
        i = data.draw(st.integers(0, len(ints) - 1))
        new = data.draw(st.one_of(st.integers(-5, 50), st.floats(), st.text(max_size=2), st.none()))
        if type(new) is int and new == ints[i]:
            new += 1
        ints[i] = new
        comm["icomm"] = tuple(ints)
    elif op == "icomm_shape":
        ints = comm["icomm"]
        comm["icomm"] = data.draw(
            st.sampled_from(
                [ints[:-1], ints + (0,), list(ints), np.array(ints, dtype=float), str(ints), ints[::-1]]
            )
        )
    elif op == "digest":
        key = data.draw(st.sampled_from(["digest_i", "digest_r"]))
        d = comm[key]
        i = data.draw(st.integers(0, len(d) - 1))
        how = data.draw(st.sampled_from(["flip", "truncate", "bytes", "upper"]))
        if how == "flip":
            comm[key] = d[:i] + ("0" if d[i] != "0" else "1") + d[i + 1 :]
        elif how == "truncate":
            comm[key] = d[:i]
        elif how == "bytes":
            comm[key] = d.encode()
        else:
            comm[key] = d.upper() if d.upper() != d else d + "0"
    elif op == "machine":
        machine = comm["machine"]
        attrs = sorted(machine.__getstate__())
        attr = data.draw(st.sampled_from(attrs))
        value = getattr(machine, attr)
        how = data.draw(st.sampled_from(["junk", "delete", "flip_byte", "reshape", "complex", "phase"]))
        if how == "delete":
            object.__delattr__(machine, attr)  # corrupt the kept step state
        elif how == "phase":
            object.__setattr__(
                machine,
                "phase",
                data.draw(
                    st.sampled_from(["idle", "prior", "predicting", "updating", 3]).filter(
                        lambda p: p != machine.phase
                    )
                ),
            )
        elif isinstance(value, np.ndarray) and value.size and how in ("flip_byte", "reshape", "complex"):
            if how == "flip_byte":
                new = value.copy()
                raw = new.view(np.uint8).reshape(-1)
                j = data.draw(st.integers(0, raw.size - 1))
                raw[j] ^= 1 << data.draw(st.integers(0, 7))
            elif how == "reshape":
                new = value.reshape(-1)[:-1]
            else:
                new = value.astype(complex)
            object.__setattr__(machine, attr, new)
        else:
            object.__setattr__(machine, attr, data.draw(JUNK))
    elif op == "family":
        how = data.draw(st.sampled_from(["other", "junk", "attribute"]))
        if how == "other":
            comm["family"] = data.draw(
                st.sampled_from(
                    [
                        MerweScaledWeights(0.5),
                        JulierWeights(),
                        SimplexWeights(),
                        MerweScaledWeights(1.0, 2.0, 1.0),
                    ]
                )
            )
        elif how == "junk":
            comm["family"] = data.draw(JUNK)
        else:
            attr = data.draw(st.sampled_from(["alpha", "beta", "kappa"]))
            setattr(comm["family"], attr, data.draw(st.one_of(st.floats(), st.none(), st.text(max_size=1))))
    else:
        how = data.draw(st.sampled_from(["other", "junk", "weights"]))
        if how == "other":
            comm["generator"] = data.draw(
                st.sampled_from([Redrawn(), Augmented(), Redrawn(weights=MerweScaledWeights(0.5))])
            )
        elif how == "junk":
            comm["generator"] = data.draw(JUNK)
        else:
            comm["generator"].weights = data.draw(st.one_of(JUNK, st.just(MerweScaledWeights(0.7))))
    return comm


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data(), k=st.sampled_from([1, 2]), scheme=st.sampled_from([1, 2]))
def test_a_corrupted_comm_gives_a_numbered_error_and_changes_nothing(data, k, scheme):
    a = at_exit(k, ropt=[scheme])
    pristine = copy.deepcopy(a["comm"])
    a["comm"] = corrupt(data, copy.deepcopy(a["comm"]))
    corrupted = dict(a["comm"])
    before = state(a)
    ref = REFERENCES[(k, scheme)]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            irevcm, n = call(a)
    except SqukfError as exc:
        assert isinstance(exc, CallSequenceError)
        assert exc.errno in COMM_ERRNOS, exc
        assert_same_state(a, before)
        assert a["comm"].keys() == corrupted.keys()
        assert all(a["comm"][key] is corrupted[key] for key in corrupted)
    else:  # a change that changed nothing: the result is the uncorrupted one
        assert (irevcm, n) == ref[:2]
        np.testing.assert_array_equal(a["x"], ref[2])
        np.testing.assert_array_equal(a["st"], ref[3])
        return
    # the documented way out: pass back the comm as it was, and the call goes on as if nothing happened
    a["comm"] = pristine
    a["irevcm"] = k
    assert call(a) == ref[:2]
    np.testing.assert_array_equal(a["x"], ref[2])
    np.testing.assert_array_equal(a["st"], ref[3])
    np.testing.assert_array_equal(a["xt"][:, : ref[1]], ref[4][:, : ref[1]])


def test_a_deep_copy_of_comm_is_comm_unchanged():
    for (k, scheme), ref in REFERENCES.items():
        a = at_exit(k, ropt=[scheme])
        a["comm"] = copy.deepcopy(a["comm"])
        assert call(a) == ref[:2]
        np.testing.assert_array_equal(a["x"], ref[2])


@pytest.mark.parametrize("comm", [None, [], (), np.zeros(30), "comm", 0], ids=repr)
@pytest.mark.parametrize("k", [0, 1, 2])
def test_a_comm_that_is_not_a_dict_is_191(comm, k):
    a = first_entry() if k == 0 else at_exit(k)
    a["comm"] = comm
    expect_errno(a, 191)


def test_a_comm_from_the_other_exit_is_refused():
    a, b = at_exit(1), at_exit(2)
    a["comm"], b["comm"] = b["comm"], a["comm"]
    expect_errno(a, 11)  # this comm expects irevcm 2
    expect_errno(b, 11)


def test_state_changed_inside_the_kept_machine_is_191():
    a = at_exit(1)
    kept = copy.copy(a["comm"]["machine"])  # a corrupted copy of the kept step state
    kept.X = kept.X * 1.5  # the points handed out: the same shape, other values
    a["comm"]["machine"] = kept
    expect_errno(a, 191)
    b = at_exit(2, ropt=[2])
    b["comm"]["generator"].weights = MerweScaledWeights(0.5, 2.0, -3.0)
    expect_errno(b, 191)


# -- arguments that are not real numbers ---------------------------------------------------------


@pytest.mark.parametrize(
    "y",
    [
        np.array([0.5 + 0j, 0.1 + 0j]),
        np.array([0.5 + 1j, 0.1]),
        ["a", "b"],
        "0.5",
        None,
        [0.5, None],
        np.array([0.5, 0.1], dtype=object),
        [0.5, [0.1, 0.2]],
        [True, False],
    ],
    ids=repr,
)
@pytest.mark.parametrize("k", [0, 1, 2])
def test_y_not_real_is_31(y, k):
    a = first_entry() if k == 0 else at_exit(k)
    a["y"] = y
    expect_errno(a, 31)


BAD_MATRICES = [np.eye(3) + 0j, np.eye(3) + 1e-3j, [["a"] * 3] * 3, None, np.eye(3).astype(object), "eye", {}]


@pytest.mark.parametrize("bad", BAD_MATRICES, ids=lambda v: type(v).__name__)
@pytest.mark.parametrize("arg, errno", [("lx", 61), ("ly", 81)])
@pytest.mark.parametrize("k", [0, 1, 2])
def test_lx_ly_not_real_are_61_81(bad, arg, errno, k):
    a = first_entry() if k == 0 else at_exit(k)
    if arg == "lx" and bad is None:
        return  # lx=None is no process noise
    a[arg] = bad
    expect_errno(a, errno)


@pytest.mark.parametrize(
    "bad",
    [np.zeros((3, 13)) + 0j, np.zeros((3, 13), dtype=object), "fxt", None, [[None]]],
    ids=lambda v: type(v).__name__,
)
@pytest.mark.parametrize("k", [1, 2])
def test_fxt_not_real_is_161_162(bad, k):
    a = at_exit(k)
    a["fxt"] = bad
    expect_errno(a, 160 + k)


@pytest.mark.parametrize(
    "arg, bad, errno",
    [
        ("x", np.zeros(3, dtype=int), 21),
        ("x", [0.0, 0.0, 0.0], 21),
        ("x", np.zeros(3, dtype=complex), 21),
        ("st", np.eye(3, dtype=np.float32), 111),
        ("st", np.eye(3).tolist(), 111),
        ("xt", np.zeros((3, 13), dtype=complex), 141),
        ("xt", None, 141),
    ],
    ids=repr,
)
def test_in_place_arrays_of_another_type_are_numbered(arg, bad, errno):
    a = first_entry()
    a[arg] = bad
    with pytest.raises(SqukfError) as info:
        call(a)
    assert info.value.errno == errno


def test_a_read_only_state_is_refused_before_anything_is_written():
    a = first_entry()
    a["st"].setflags(write=False)
    with pytest.raises(SqukfError) as info:
        call(a)
    assert info.value.errno == 111 and a["comm"] == {}


# -- ROPT ----------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "ropt, errno, names",
    [
        ("abc", 171, "ROPT(1)"),
        ([1 + 0j], 171, "ROPT(1)"),
        ([float("nan")], 171, "ROPT(1)"),
        ([1, None], 172, "ROPT(2)"),
        ([1, float("nan")], 172, "ROPT(2)"),
        ([1, float("inf")], 172, "ROPT(2)"),
        ([1, 0.0, 1j], 173, "ROPT(3)"),
        ([1, 0.0, "1"], 173, "ROPT(3)"),
        ([1, 0.0, float("inf")], 173, "ROPT(3)"),
        ([1, 0.0, 1e-9], 173, "ROPT(3)"),  # L + lambda = alpha**2 (L + kappa) rounds to 0
        ([1, 0.0, 1e-200], 173, "ROPT(3)"),  # alpha**2 underflows
        ([1, 1e300, 1e10], 173, "ROPT(3)"),  # alpha**2 (L + kappa) overflows
        ([1, 0.0, 1.0, 2.0, float("nan")], 172, "ROPT(5)"),
        ([1, 0.0, 1.0, 2.0, 0.0, float("nan")], 173, "ROPT(6)"),
        ([2, 0.0, 1.0, 2.0, -2.0, 1e-9], 173, "ROPT(6)"),
        ([1, 0.0, 1.0, 2.0, 0.0, 1.0, object()], None, "ROPT(7)"),
        ([1, [2, 3]], 181, "ROPT"),
        (list(range(8)), 181, "LROPT"),
    ],
    ids=repr,
)
def test_bad_ropt_entries_are_numbered_by_position(ropt, errno, names):
    a = first_entry(ropt=ropt)
    err = expect_errno(a, errno)
    assert isinstance(err, ParameterError) and names in str(err)


@pytest.mark.parametrize("i", [4, 7])
@pytest.mark.parametrize("beta", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_beta_is_refused_naming_its_entry(i, beta):
    ropt = [1, 0.0, 1.0, 2.0, 0.0, 1.0, 2.0]
    ropt[i - 1] = beta
    a = first_entry(ropt=ropt)
    err = expect_errno(a, None)  # g13ej documents no constraint on beta
    assert isinstance(err, ParameterError) and f"ROPT({i})" in str(err) and "beta" in str(err)


def test_ropt_of_numpy_numbers_and_nested_length_one_is_accepted():
    for ropt in (
        np.array([1.0, 0.0]),
        [np.int64(1), np.float32(0.0)],
        [[1]],
        1,
        np.array([1, 0], dtype=object),
    ):
        a = first_entry(ropt=ropt)
        assert call(a) == (1, 7)


# -- any junk in any argument --------------------------------------------------------------------

SCALARS = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-3, 3),
    st.floats(),
    st.complex_numbers(max_magnitude=10),
    st.text(max_size=2),
)
JUNK_ARGS = st.one_of(
    SCALARS,
    st.lists(SCALARS, max_size=4),
    st.lists(st.lists(st.floats(-2, 2), max_size=3), max_size=3),
    st.builds(
        lambda v, dt: np.array(v, dtype=dt),
        st.lists(st.floats(-2, 2), min_size=1, max_size=9),
        st.sampled_from([complex, object, bool, str, np.float32, int]),
    ),
    st.dictionaries(st.text(max_size=1), st.integers(), max_size=2),
)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(arg=st.sampled_from(["y", "ly", "lx", "fxt", "ropt"]), junk=JUNK_ARGS, k=st.sampled_from([0, 1, 2]))
@example(arg="ropt", junk=[0, 0, 0, None], k=0)  # beta not a number: no IFAIL, and the message says beta
def test_junk_in_any_argument_is_a_numbered_squkf_error(arg, junk, k):
    a = first_entry() if k == 0 else at_exit(k)
    if arg == "ropt" and k != 0:
        return  # ROPT is read at initial entry only
    a[arg] = junk
    before = state(a)
    comm = dict(a["comm"])
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            call(a)
    except SqukfError as exc:
        if exc.errno is None:  # the failures g13ej has no number for
            assert isinstance(exc, NonFiniteError) or "beta" in str(exc), exc
        assert_same_state(a, before)
        assert a["comm"].keys() == comm.keys() and all(a["comm"][key] is comm[key] for key in comm)
