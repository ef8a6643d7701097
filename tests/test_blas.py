"""squkf.blas: the filter's own numerics run on one BLAS thread for larger states, nothing else touched.

The counts are read through threadpoolctl's own controllers, independently of
``squkf.blas``; the numerics are observed from inside a ``UT=`` transform,
which runs inside the hold (``fx`` and ``hx`` run outside it).
"""

import subprocess
import sys
import threading
from contextlib import ExitStack
from pathlib import Path

import numpy as np
import pytest
import threadpoolctl
from models import decay_filter

from squkf import blas, sqrt_unscented_transform
from squkf.errors import NonFiniteError


def _libs():
    libs = threadpoolctl.ThreadpoolController().select(user_api="blas").lib_controllers
    if not libs:
        pytest.skip("threadpoolctl finds no BLAS library")
    return libs


def _set_all(libs, n):
    """Set every library to ``n`` threads (a list: one each) as a user would, then give up that right.

    threadpoolctl >= 3.8 lets one Python thread at a time set a process-wide
    OpenBLAS; releasing it lets the test's other threads (and the hold) set it.
    """
    for lib, k in zip(libs, n if isinstance(n, list) else [n] * len(libs)):
        lib.set_num_threads(k)
    release = getattr(threadpoolctl.OpenBLASController, "clear_controlling_thread", None)
    if release is not None:
        release(force=True)


def _counts(libs):
    return [lib.get_num_threads() for lib in libs]


@pytest.fixture
def libs(monkeypatch):
    """The BLAS libraries at two threads for the test (a multi-core default), put back afterwards."""
    libs = _libs()
    before = _counts(libs)
    monkeypatch.setattr(blas, "MIN_DIM", 8)
    _set_all(libs, 2)
    if _counts(libs) != [2] * len(libs):
        pytest.skip("the BLAS libraries cannot be set to two threads here")
    yield libs
    _set_all(libs, before)


def _recording_ut(seen, libs, inside=None):
    """A ``UT=`` transform: the default one, recording the counts (and running ``inside``) first."""

    def UT(*args):
        seen.append(_counts(libs))
        if inside is not None:
            inside()
        return sqrt_unscented_transform(*args)

    return UT


# ---------------------------------------------------------------- with threadpoolctl


@pytest.mark.parametrize("n, inside", [(8, 1), (7, 2)])
def test_numerics_on_one_thread_user_functions_untouched(libs, n, inside):
    seen = {"fx": [], "hx": [], "UT": []}
    f = decay_filter(
        n,
        fx=lambda x, dt: seen["fx"].append(_counts(libs)) or 0.9 * x,
        hx=lambda x: seen["hx"].append(_counts(libs)) or x[:2],
    )
    UT = _recording_ut(seen["UT"], libs)
    f.predict(UT=UT)
    f.update(np.array([0.1, -0.1]), UT=UT)
    assert len(seen["UT"]) == 2
    assert all(c == [inside] * len(libs) for c in seen["UT"])
    assert seen["fx"] and seen["hx"]
    assert all(c == [2] * len(libs) for c in seen["fx"] + seen["hx"])
    assert _counts(libs) == [2] * len(libs)


def test_min_dim_none_leaves_the_blas_alone(libs, monkeypatch):
    monkeypatch.setattr(blas, "MIN_DIM", None)
    seen = []
    f = decay_filter(8)
    f.predict(UT=_recording_ut(seen, libs))
    f.update(np.zeros(2), UT=_recording_ut(seen, libs))
    assert seen == [[2] * len(libs)] * 2


def test_hold_restores_on_return_and_on_error(libs):
    with blas.one_blas_thread():
        assert _counts(libs) == [1] * len(libs)
    assert _counts(libs) == [2] * len(libs)
    with pytest.raises(KeyError):
        with blas.one_blas_thread():
            assert _counts(libs) == [1] * len(libs)
            raise KeyError("inside")
    assert _counts(libs) == [2] * len(libs)


def test_failed_step_restores_the_count(libs):
    f = decay_filter(8, fx=lambda x, dt: x * np.nan)
    with pytest.raises(NonFiniteError):
        f.predict()
    assert _counts(libs) == [2] * len(libs)

    def failing(*args):
        assert _counts(libs) == [1] * len(libs)
        raise ZeroDivisionError("user transform")

    with pytest.raises(ZeroDivisionError):
        decay_filter(8).predict(UT=failing)
    assert _counts(libs) == [2] * len(libs)


def test_hold_nests(libs):
    with blas.one_blas_thread():
        with blas.one_blas_thread():
            assert _counts(libs) == [1] * len(libs)
        assert _counts(libs) == [1] * len(libs)
    assert _counts(libs) == [2] * len(libs)


def test_a_count_changed_during_the_step_is_not_overwritten(libs):
    seen = []
    f = decay_filter(8)
    f.predict(UT=_recording_ut(seen, libs, inside=lambda: _set_all(libs, 3)))
    assert seen == [[1] * len(libs)]
    assert _counts(libs) == [3] * len(libs)


def test_a_threadpool_limits_block_ending_during_the_step_stands(libs):
    # The block starts before the step (2 -> 3) and ends inside it, putting back 2;
    # the hold, which saw 3 on entry, must not write 3 back over that.
    seen = []
    with ExitStack() as stack:
        stack.enter_context(threadpoolctl.threadpool_limits(limits=3, user_api="blas"))
        assert _counts(libs) == [3] * len(libs)
        decay_filter(8).predict(UT=_recording_ut(seen, libs, inside=stack.close))
    assert seen == [[1] * len(libs)]
    assert _counts(libs) == [2] * len(libs)


def test_a_library_already_at_one_thread_stays_there(libs):
    _set_all(libs, [1] + [2] * (len(libs) - 1))
    with blas.one_blas_thread():
        assert _counts(libs) == [1] * len(libs)
    assert _counts(libs) == [1] + [2] * (len(libs) - 1)


def test_filters_stepped_in_several_threads_at_once(libs):
    k = 3
    barrier = threading.Barrier(k, timeout=30)
    seen, errors = [], []

    def run(i):
        try:
            f = decay_filter(8 + i)
            # every thread inside its hold at once, then each leaves at its own time
            UT = _recording_ut(seen, libs, inside=barrier.wait)
            for j in range(4):
                f.predict(UT=UT)
                f.update(np.array([0.1, -0.1]) * j)
        except BaseException as exc:  # noqa: BLE001 - reported by the main thread
            errors.append(exc)
            barrier.abort()

    threads = [threading.Thread(target=run, args=(i,)) for i in range(k)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert not errors
    assert len(seen) == 4 * k and all(c == [1] * len(libs) for c in seen)
    assert _counts(libs) == [2] * len(libs)


def test_unsynchronised_threads_leave_the_count_as_found(libs):
    errors = []

    def run(seed):
        try:
            rng = np.random.default_rng(seed)
            f = decay_filter(8)
            for _ in range(30):
                f.predict()
                f.update(rng.standard_normal(2) * 0.1)
        except BaseException as exc:  # noqa: BLE001 - reported by the main thread
            errors.append(exc)

    threads = [threading.Thread(target=run, args=(s,)) for s in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert not errors
    assert _counts(libs) == [2] * len(libs)


# ---------------------------------------------------------------- the hold's rules, on model libraries


class _ModelLib:
    """A BLAS library as threadpoolctl presents it: one count for the process, or one per thread."""

    def __init__(self, per_thread: bool, start: int = 2):
        self.internal_api = "model"
        self.start = start
        self.per_thread = per_thread
        self._local = threading.local()
        self._shared = start

    def get_num_threads(self):
        return getattr(self._local, "n", self.start) if self.per_thread else self._shared

    def set_num_threads(self, n):
        if self.per_thread:
            self._local.n = n
        else:
            self._shared = n


@pytest.mark.parametrize("per_thread", [False, True])
def test_concurrent_holds_on_model_libraries(monkeypatch, per_thread):
    lib = _ModelLib(per_thread)
    monkeypatch.setattr(blas, "_found", ((), (lib,), None) if per_thread else ((lib,), (), None))
    k = 4
    barrier = threading.Barrier(k, timeout=30)
    inside, after, errors = [], [], []

    def run():
        try:
            for _ in range(3):
                with blas.one_blas_thread():
                    barrier.wait()  # every thread inside its hold at once
                    inside.append(lib.get_num_threads())
                    barrier.wait()
                after.append(lib.get_num_threads())  # per thread: this thread's own count, put back
        except BaseException as exc:  # noqa: BLE001 - reported by the main thread
            errors.append(exc)
            barrier.abort()

    threads = [threading.Thread(target=run) for _ in range(k)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert not errors
    assert inside == [1] * (3 * k)
    if per_thread:
        assert after == [2] * (3 * k)
    assert lib.get_num_threads() == 2


def test_late_holder_stays_held_until_it_leaves(monkeypatch):
    lib = _ModelLib(per_thread=False)
    monkeypatch.setattr(blas, "_found", ((lib,), (), None))
    entered, first_left, seen = threading.Event(), threading.Event(), []

    def late():
        with blas.one_blas_thread():
            entered.set()
            first_left.wait(30)
            seen.append(lib.get_num_threads())

    with blas.one_blas_thread():
        t = threading.Thread(target=late)
        t.start()
        entered.wait(30)
    first_left.set()
    t.join(30)
    assert seen == [1]
    assert lib.get_num_threads() == 2


# ---------------------------------------------------------------- the lookup


def test_a_failed_inspection_warns_and_leaves_the_blas_alone(libs, monkeypatch):
    def broken():
        raise OSError("no /proc here")

    monkeypatch.setattr(threadpoolctl, "ThreadpoolController", broken)
    monkeypatch.setattr(blas, "_found", None)
    with pytest.warns(RuntimeWarning):
        with blas.one_blas_thread():
            assert _counts(libs) == [2] * len(libs)


def test_importing_squkf_does_not_import_threadpoolctl():
    code = "import sys, squkf; sys.exit('threadpoolctl' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], cwd=Path(__file__).parents[1]).returncode == 0
