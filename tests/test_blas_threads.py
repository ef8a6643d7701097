"""The filter's own numerics run on one BLAS thread for larger states, and nothing else does."""

import numpy as np
import pytest

import squkf.transform
from squkf import MerweScaledWeights, SquareRootUKF, blas

CONTROLS = blas.blas_controls()
pytestmark = pytest.mark.skipif(not CONTROLS, reason="no bundled OpenBLAS found (another BLAS build)")


@pytest.fixture
def two_threads():
    """Every bundled OpenBLAS at two threads for the test, as a multi-core default would be."""
    before = [get() for get, _ in CONTROLS]
    for _, set_ in CONTROLS:
        set_(2)
    yield
    for (_, set_), n in zip(CONTROLS, before):
        set_(n)


def _counts():
    return [get() for get, _ in CONTROLS]


def test_context_holds_one_thread_and_restores_on_error(two_threads):
    with pytest.raises(RuntimeError):
        with blas.one_blas_thread():
            assert _counts() == [1] * len(CONTROLS)
            raise RuntimeError("inside")
    assert _counts() == [2] * len(CONTROLS)


@pytest.mark.parametrize("n, inside", [(blas.MIN_DIM, 1), (blas.MIN_DIM - 1, 2)])
def test_step_numerics_on_one_thread_user_functions_untouched(two_threads, monkeypatch, n, inside):
    seen = {"fx": [], "hx": [], "qr": []}
    real_tria = squkf.transform.tria

    def tria(rows):
        seen["qr"].append(_counts())
        return real_tria(rows)

    def fx(x, dt):
        seen["fx"].append(_counts())
        return 0.9 * x

    def hx(x):
        seen["hx"].append(_counts())
        return x[:2]

    monkeypatch.setattr(squkf.transform, "tria", tria)
    f = SquareRootUKF(n, 2, 1.0, hx, fx, MerweScaledWeights(0.5, 2.0, 0.0))
    f.predict()
    f.update(np.array([0.1, -0.1]))
    assert seen["qr"] and all(c == [inside] * len(CONTROLS) for c in seen["qr"])
    assert all(c == [2] * len(CONTROLS) for c in seen["fx"] + seen["hx"])
    assert _counts() == [2] * len(CONTROLS)


def test_min_dim_none_leaves_the_blas_alone(two_threads, monkeypatch):
    monkeypatch.setattr(blas, "MIN_DIM", None)
    counts = []
    real_tria = squkf.transform.tria
    monkeypatch.setattr(squkf.transform, "tria", lambda rows: counts.append(_counts()) or real_tria(rows))
    n = 20
    f = SquareRootUKF(n, 1, 1.0, lambda x: x[:1], lambda x, dt: x, MerweScaledWeights(0.5, 2.0, 0.0))
    f.predict()
    f.update([0.0])
    assert counts and all(c == [2] * len(CONTROLS) for c in counts)


def test_failed_step_restores_the_thread_count(two_threads):
    n = 20
    f = SquareRootUKF(n, 1, 1.0, lambda x: x[:1], lambda x, dt: x * np.nan, MerweScaledWeights(0.5, 2.0, 0.0))
    with pytest.raises(squkf.errors.NonFiniteError):
        f.predict()
    assert _counts() == [2] * len(CONTROLS)
