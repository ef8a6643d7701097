"""squkf.nag: g13ej's calling sequence, its example, and its documented errors."""

import copy
import os
import subprocess
import sys

import numpy as np
import pytest

from squkf import MerweScaledWeights, unscented_transform
from squkf.examples import g13ej_example as ex
from squkf.nag import kalman_unscented_state_revcom as g13ej

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


def first_entry(ropt=None, lx="default"):
    lx = np.array(DATA["lx"]) if lx == "default" else lx
    x = np.array(DATA["x0"], dtype=float)
    st = np.array(DATA["st0"], dtype=float)
    xt = np.zeros((3, 13))
    fxt = np.zeros((3, 13))
    comm = {}
    return dict(
        irevcm=0,
        y=DATA["y"][0],
        ly=np.array(DATA["ly"]),
        x=x,
        st=st,
        xt=xt,
        fxt=fxt,
        comm=comm,
        lx=lx,
        ropt=ropt,
    )


def call(a):
    a["irevcm"], n = g13ej(
        a["irevcm"],
        a["y"],
        a["ly"],
        a["x"],
        a["st"],
        a["xt"],
        a["fxt"],
        a["comm"],
        lx=a["lx"],
        ropt=a["ropt"],
    )
    return a["irevcm"], n


def fill(a, n):
    m = DATA["model"]
    if a["irevcm"] == 1:
        a["fxt"][:3, :n] = ex.f(a["xt"][:, :n], m["r"], m["d"], 0.4, 0.1)
    else:
        a["fxt"][:2, :n] = ex.h(a["xt"][:, :n], m["Delta"], m["A"])


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


# -- documented errors: one test per number, state left as it was ------------------------------


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


def at_exit(k, ropt=None):
    """Arguments positioned at intermediate exit k (1 or 2)."""
    a = first_entry(ropt=ropt)
    _, n = call(a)
    if k == 2:
        fill(a, n)
        _, n = call(a)
    fill(a, n)
    return a


def test_errno_11_irevcm():
    a = first_entry()
    a["irevcm"] = 4
    assert isinstance(expect(a, 11), ValueError)
    b = at_exit(1)
    b["irevcm"] = 2
    expect(b, 11)


def test_errno_21_mx():
    a = first_entry()
    a["x"] = np.zeros(0)
    expect(a, 21)


def test_errno_22_mx_changed():
    a = at_exit(1)
    a["x"] = np.zeros(2)
    expect(a, 22)


def test_errno_31_my():
    a = first_entry()
    a["y"] = []
    expect(a, 31)


def test_errno_32_my_changed():
    a = at_exit(1)
    a["y"] = [1.0, 2.0, 3.0]
    expect(a, 32)


def test_errno_61_lx():
    a = first_entry()
    a["lx"] = np.eye(2)
    expect(a, 61)


def test_errno_81_ly():
    a = first_entry()
    a["ly"] = np.eye(1)
    expect(a, 81)


def test_errno_111_st():
    a = first_entry()
    a["st"] = np.eye(2)
    expect(a, 111)


def test_errno_121_augmented_capacity():
    a = first_entry(ropt=[2])
    a["xt"] = np.zeros((3, 12))
    expect(a, 121)


def test_errno_122_redrawn_capacity():
    a = first_entry()
    a["xt"] = np.zeros((3, 6))
    expect(a, 122)


def test_errno_123_n_changed():
    a = at_exit(1)
    a["xt"] = np.zeros((3, 9))
    expect(a, 123)


def test_errno_141_xt_rows():
    a = first_entry()
    a["xt"] = np.zeros((2, 13))
    expect(a, 141)


def test_errno_161_fxt_rows_for_f():
    a = at_exit(1)
    a["fxt"] = np.zeros((2, 13))
    expect(a, 161)


def test_errno_162_fxt_rows_for_h():
    a = at_exit(2)
    a["fxt"] = np.zeros((1, 13))
    expect(a, 162)


def test_errno_171_scheme():
    a = first_entry(ropt=[3])
    expect(a, 171)


@pytest.mark.parametrize("ropt", [[1, -3.0], [1, 0.0, 1, 2, -3.0], [2, 0.0, 1, 2, -6.0]])
def test_errno_172_kappa(ropt):
    a = first_entry(ropt=ropt)
    expect(a, 172)


@pytest.mark.parametrize("ropt", [[1, 0.0, 0.0], [1, 0.0, 1.0, 2.0, 0.0, -1.0]])
def test_errno_173_alpha(ropt):
    a = first_entry(ropt=ropt)
    expect(a, 173)


def test_errno_181_lropt():
    a = first_entry(ropt=[1, 0, 1, 2, 0, 1, 2, 9])
    expect(a, 181)


def test_errno_191_icomm_corrupted():
    a = at_exit(1)
    a["comm"]["icomm"] = (3, 2, 13, 1, 8, 0)
    expect(a, 191)
    b = at_exit(1)
    b["comm"].clear()
    expect(b, 191)


def test_errno_211_rcomm_corrupted():
    a = at_exit(1)
    a["x"][0] += 1.0  # x must remain unchanged between exits and re-entries
    expect(a, 211)


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
