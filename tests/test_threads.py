"""The thread count of the compiled core: what it takes, its cap, its environment variable, when a change
takes effect, and the compiled core's refusal to run uncompiled (``NUMBA_DISABLE_JIT``).

A change of the count while a fleet steps is made from inside the step (by its model function) or from
another thread at a point the step waits for, so each race is met the same way every run.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import threading
import warnings

import numpy as np
import pytest
from models import plain_fleet, plain_fx

import squkf
from squkf.errors import ParameterError
from squkf.kernels import threads

#: The process's own core count, kept before the fixture below replaces it for each test.
REAL_CORES = getattr(threads, "usable_cores", None)
CORES = 4  # what the tests below see, whatever the machine


@pytest.fixture(autouse=True)
def four_cores(monkeypatch):
    """Four usable cores, so that the counts asked for here are not capped; one thread after each test."""
    monkeypatch.setattr(threads, "usable_cores", lambda: CORES, raising=False)
    yield
    threads.set_num_threads(1)


def thread_names(calls: list[str]) -> set[str]:
    """``"pool"`` for a thread of squkf's pool, else the thread's name."""
    return {"pool" if name.startswith("squkf-kernel") else name for name in calls}


class FirstCall:
    """``first()`` is True at its first call only, whichever thread makes it."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._done = False

    def __call__(self) -> bool:
        with self._lock:
            first, self._done = not self._done, True
        return first


def serial_predicts(K: int, steps: int, chunk: int | None) -> list[tuple[np.ndarray, np.ndarray]]:
    fleet, _ = plain_fleet(K, chunk=chunk)
    out = []
    for _ in range(steps):
        fleet.predict()
        out.append((fleet.x.copy(), fleet.P.copy()))
    return out


def assert_same(fleet, expected: tuple[np.ndarray, np.ndarray]) -> None:
    np.testing.assert_array_equal(fleet.x, expected[0])
    np.testing.assert_array_equal(fleet.P, expected[1])


# ---------------------------------------------------------------- the count


@pytest.mark.parametrize("bad", [0, -1, "2", 2.0, 1.5, True, None, np.float64(2.0)])
def test_a_count_that_is_not_a_whole_number_of_at_least_one_is_refused(bad):
    squkf.set_num_threads(2)
    with pytest.raises(ParameterError, match=rf"thread count .* got n={re.escape(repr(bad))}$"):
        squkf.set_num_threads(bad)
    assert squkf.get_num_threads() == 2


def test_a_count_above_the_usable_cores_is_capped_there_with_a_warning():
    for n in (CORES + 1, 10**6, np.int64(7)):
        with pytest.warns(RuntimeWarning, match=rf"n={re.escape(repr(n))}\).* {CORES} cores.* uses {CORES}$"):
            squkf.set_num_threads(n)
        assert squkf.get_num_threads() == CORES
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        squkf.set_num_threads(np.int64(CORES))
        squkf.set_num_threads(3)
    assert squkf.get_num_threads() == 3


def test_a_fleet_on_a_capped_count_is_cut_for_the_cores_not_for_the_count_asked():
    sizes = []

    def fx(X, dt):
        sizes.append(X.shape[0])
        return plain_fx(X, dt)

    fleet, _ = plain_fleet(5000, fx=fx)
    with pytest.warns(RuntimeWarning):
        squkf.set_num_threads(10**6)
    fleet.predict()
    assert sorted(sizes) == [1250] * CORES  # 5000 / CORES each, not 5000 chunks of one filter


def test_the_usable_cores_are_the_process_affinity():
    assert REAL_CORES is not None
    expected = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    assert REAL_CORES() == expected


# ---------------------------------------------------------------- SQUKF_NUM_THREADS, read at import


def import_squkf(env: dict[str, str]) -> dict:
    """``import squkf`` in a new process with ``env`` added: its thread count and what it said about it."""
    code = (
        "import json, warnings\n"
        "with warnings.catch_warnings(record=True) as seen:\n"
        "    warnings.simplefilter('always')\n"
        "    import squkf\n"
        "said = [(w.category.__name__, str(w.message)) for w in seen\n"
        "        if 'SQUKF_NUM_THREADS' in str(w.message)]\n"
        "print(json.dumps({'threads': squkf.get_num_threads(), 'said': said}))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env={**os.environ, **env}, timeout=300
    )
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("value", ["abc", "0", "-3", "2.5", " "])
def test_a_thread_count_from_the_environment_that_is_not_one_warns_once_and_uses_one_thread(value):
    got = import_squkf({"SQUKF_NUM_THREADS": value})
    assert got["threads"] == 1
    [(category, message)] = got["said"]
    assert category == "RuntimeWarning"
    assert f"SQUKF_NUM_THREADS={value!r}" in message and "one thread" in message


def test_a_thread_count_from_the_environment_above_the_cores_is_capped_with_a_warning():
    assert REAL_CORES is not None
    cores = REAL_CORES()
    got = import_squkf({"SQUKF_NUM_THREADS": "1000000"})
    assert got["threads"] == cores
    [(category, message)] = got["said"]
    assert category == "RuntimeWarning"
    assert "SQUKF_NUM_THREADS='1000000'" in message and message.endswith(f"uses {cores}")
    assert import_squkf({"SQUKF_NUM_THREADS": str(cores)}) == {"threads": cores, "said": []}


# ---------------------------------------------------------------- a change while a fleet steps


@pytest.mark.parametrize("new", [1, 3])
def test_a_count_changed_by_a_model_function_inside_a_step_takes_effect_at_the_next_step(new):
    """fx, on a pool thread, changes the count: the step ends on its two threads, the next uses ``new``."""
    K, chunk = 16, 2
    expected = serial_predicts(K, 2, chunk)
    calls: list[str] = []
    first = FirstCall()

    def fx(X, dt):
        calls.append(threading.current_thread().name)  # list.append is atomic
        if first():
            squkf.set_num_threads(new)
        return plain_fx(X, dt)

    fleet, _ = plain_fleet(K, fx=fx, chunk=chunk)
    squkf.set_num_threads(2)
    fleet.predict()
    assert_same(fleet, expected[0])
    assert len(calls) == 8 and thread_names(calls) == {"pool"}  # 8 chunks, cut for two threads, on them
    assert squkf.get_num_threads() == new
    calls.clear()
    fleet.predict()
    assert_same(fleet, expected[1])
    if new == 1:
        assert len(calls) == 8 and thread_names(calls) == {threading.current_thread().name}
    else:  # cut for three threads: a multiple of three chunks
        assert len(calls) == 9 and thread_names(calls) == {"pool"}


def test_a_count_changed_from_another_thread_during_a_step_takes_effect_at_the_next_step():
    """The step waits inside fx until another thread has set the count: neither waits for the other."""
    K, chunk = 16, 2
    expected = serial_predicts(K, 2, chunk)
    calls: list[str] = []
    first, inside, changed, waited = FirstCall(), threading.Event(), threading.Event(), []

    def fx(X, dt):
        calls.append(threading.current_thread().name)
        if first():
            inside.set()
            waited.append(changed.wait(20))  # set_num_threads must not wait for this step
        return plain_fx(X, dt)

    fleet, _ = plain_fleet(K, fx=fx, chunk=chunk)
    squkf.set_num_threads(2)
    errors: list[BaseException] = []

    def step():
        try:
            fleet.predict()
        except BaseException as exc:  # noqa: BLE001 - reported by the main thread
            errors.append(exc)

    stepper = threading.Thread(target=step)
    stepper.start()
    assert inside.wait(20)
    squkf.set_num_threads(1)
    changed.set()
    stepper.join(60)
    assert not stepper.is_alive() and errors == [] and waited == [True]
    assert_same(fleet, expected[0])
    assert len(calls) == 8 and thread_names(calls) == {"pool"}
    calls.clear()
    fleet.predict()
    assert_same(fleet, expected[1])
    assert thread_names(calls) == {threading.current_thread().name}


# ---------------------------------------------------------------- NUMBA_DISABLE_JIT


def test_numba_disable_jit_is_refused_at_import_with_a_squkf_error():
    code = (
        "import json\n"
        "try:\n"
        "    import squkf\n"
        "    got = None\n"
        "except Exception as exc:\n"
        "    kind = type(exc)\n"
        "    got = [kind.__module__, kind.__name__, [c.__name__ for c in kind.__mro__], str(exc)]\n"
        "print(json.dumps(got))\n"
    )
    env = {**os.environ, "NUMBA_DISABLE_JIT": "1"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got is not None, "import squkf succeeded with NUMBA_DISABLE_JIT=1"
    module, name, mro, message = got
    assert (module, name) == ("squkf.errors", "UnsupportedEnvironmentError")
    assert {"SqukfError", "ImportError"} <= set(mro)
    assert "NUMBA_DISABLE_JIT" in message and "does not support" in message
