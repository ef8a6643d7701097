"""A posterior that lost rank to rounding is an error (303), not a singular covariance committed.

Found by the junk-input property test: ``Q`` of 8e256 everywhere makes the
prior's small directions vanish below rounding, and the update then gave a
factor with a zero diagonal, which the filter committed as its ``P``. Whether
that example rounds to an exact zero depends on the processor (numpy's SIMD
``tanh`` and the kernels' code differ between AVX2 and AVX-512), so the
detection is tested with the update kernel's result made to lose rank
(``lose_rank``), and the example itself with what holds on every processor:
an error that changes nothing, or a factor with a positive diagonal.
"""

import numpy as np
import pytest
from models import tanh_filter

from squkf import Fleet, MerweScaledWeights, PosteriorFactorError, SquareRootUKF
from squkf.kernels import table


def lose_rank(monkeypatch, where):
    """The joint update kernel's posterior factor gets a zero last diagonal entry where ``where(x)``.

    ``where`` maps the prior means ``(B, n)`` to a bool per filter; those filters get the
    kernel's status for a zero on the posterior diagonal (304), as a kernel that found rank
    lost to rounding reports it. The kernel is replaced in the installed table, which a route
    built afterwards takes as its own (the one place the engine takes its kernels from).
    """
    real = table.KERNELS.joint_update

    def joint_update(*args):
        real(*args)
        x, S, status = args[6], args[19], args[23]  # the prior mean, the posterior factor, the status
        lost = np.broadcast_to(where(x), status.shape)
        S[lost, -1, -1] = 0.0
        status[lost] = 304

    monkeypatch.setattr(table, "KERNELS", table.KERNELS._replace(joint_update=joint_update))


def test_rank_lost_to_rounding_raises_and_changes_nothing(monkeypatch):
    lose_rank(monkeypatch, lambda x: np.ones(x.shape[:-1], dtype=bool))  # (a route takes it when built)
    f = SquareRootUKF(3, 2, 1.0, lambda x: np.tanh(x[:2]), lambda x, dt: x + dt, MerweScaledWeights())
    f.x, f.R = np.ones(3), np.eye(2)
    f.predict()
    x, S = f.x.copy(), f.P1_2.copy()
    with pytest.raises(PosteriorFactorError) as info:
        f.update(np.ones(2))
    assert info.value.errno == 303
    np.testing.assert_array_equal(f.x, x)
    np.testing.assert_array_equal(f.P1_2, S)


def test_the_junk_input_example_raises_or_keeps_a_positive_diagonal():
    f = tanh_filter()
    f.predict()
    x, S = f.x.copy(), f.P1_2.copy()
    try:
        f.update(np.ones(2))
    except PosteriorFactorError as exc:
        assert exc.errno == 303
        np.testing.assert_array_equal(f.x, x)
        np.testing.assert_array_equal(f.P1_2, S)
    else:
        assert np.all(np.diag(f.P1_2) > 0)


def test_in_a_fleet_only_that_filter_is_flagged(monkeypatch):
    def make():
        fleet = Fleet(3, 3, 2, 1.0, lambda X: np.tanh(X[..., :2]), lambda X, dt: X + dt, MerweScaledWeights())
        fleet.x, fleet.R = np.array([[1.0, 1, 1], [1000.0, 1, 1], [1.0, 1, 1]]), np.eye(2)
        fleet.predict()
        return fleet

    clean = make()
    clean.update(np.ones((3, 2)))
    lose_rank(monkeypatch, lambda x: x[..., 0] > 100.0)  # filter 1's (the fleet's route takes it when built)
    fleet = make()
    fleet.update(np.ones((3, 2)))
    np.testing.assert_array_equal(fleet.failed, [False, True, False])
    assert "303" in fleet.failure[1] or "rank" in fleet.failure[1]
    np.testing.assert_array_equal(fleet.x[[0, 2]], clean.x[[0, 2]])
    np.testing.assert_array_equal(fleet.P1_2[[0, 2]], clean.P1_2[[0, 2]])
    np.testing.assert_array_equal(fleet.x[1], make().x[1])  # kept its prior


def test_an_exactly_measured_component_may_have_zero_variance():
    """With a singular R the posterior is singular by right: no error."""
    f = SquareRootUKF(2, 2, 1.0, lambda x: x, lambda x, dt: x, MerweScaledWeights())
    f.R = np.diag([0.5, 0.0])
    f.Q = np.zeros((2, 2))
    f.predict()
    f.update(np.array([0.3, 0.7]))
    assert f.P[1, 1] == pytest.approx(0.0, abs=1e-15)
    assert f.x[1] == pytest.approx(0.7)
