"""The batch loop's boundary: its options, its progress bar, and its transaction.

A call that runs many steps (``batch_filter``) changes the filter step by
step; if anything fails (or is interrupted) the filter is put back as it was
before the call. Each facade says what its state is (``_snapshot`` and
``_restore``) and hands out a :class:`Transaction` over them from its public
``transaction()``. Both faces' loops (:func:`squkf.batch.batch_filter`,
``Fleet.batch_filter``) are :func:`run_steps`: the steps inside one
transaction, the progress option, and an error annotated with its step and the
results so far; each face says only what a step is and what it keeps.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

import numpy as np

from ..errors import ParameterError, SqukfError
from . import records

__all__ = [
    "KEEP",
    "Transaction",
    "annotate_step",
    "check_keep",
    "check_progress",
    "progress_callback",
    "run_steps",
]

KEEP = ("all", "diagonals", "means", "final")


class Transaction:
    """A context manager: on any exception inside it, ``restore(snapshot())`` as taken on entry.

    Parameters
    ----------
    snapshot : callable
        ``snapshot() -> state``: everything the calls inside may change.
    restore : callable
        ``restore(state)``: puts that state back.
    """

    __slots__ = ("_snapshot", "_restore", "_state")

    def __init__(self, snapshot: Callable[[], Any], restore: Callable[[Any], None]):
        self._snapshot, self._restore = snapshot, restore
        self._state: Any = None

    def __enter__(self) -> Transaction:
        self._state = self._snapshot()
        return self

    def __exit__(self, kind, exc, tb) -> None:
        if kind is not None:  # any exception, KeyboardInterrupt too: put back, then let it propagate
            self._restore(self._state)
        self._state = None


def check_keep(keep) -> tuple[str, tuple[str, ...]]:
    """``keep`` of a fleet's run, as what to keep of the state and which per-step records too.

    Parameters
    ----------
    keep : str or tuple of str
        One of :data:`KEEP` (``"all"``, ``"diagonals"``, ``"means"``, ``"final"``), or a tuple of one of
        them and ``keep`` words of the registry's records (:data:`squkf.boundary.records.STEP_RECORDS`;
        ``"whitened"``: each step's whitened innovations and ``log det S1_2``), each once, whose records
        are kept as well (not with ``"final"``, which keeps no step's records).

    Returns
    -------
    state : str
        One of :data:`KEEP`.
    words : tuple of str
        The records' ``keep`` words given (empty: none).
    """
    known = tuple(dict.fromkeys(r.keep for r in records.STEP_RECORDS))  # (in the registry's order, once)
    words = keep if isinstance(keep, tuple) else (keep,)
    states = [w for w in words if isinstance(w, str) and w in KEEP]
    rest = [w for w in words if not (isinstance(w, str) and w in KEEP)]
    if (
        len(states) != 1
        or not all(isinstance(w, str) and w in known for w in rest)
        or len(set(rest)) < len(rest)
    ):
        extra = repr(known[0]) if len(known) == 1 else "any of " + ", ".join(map(repr, known))
        raise ParameterError(
            f"keep must be 'all', 'diagonals', 'means' or 'final', or a tuple of one of them and {extra},"
            f" got keep={keep!r}"
        )
    if rest and states[0] == "final":
        names = ", ".join(r.name for r in records.STEP_RECORDS if r.keep in rest)
        raise ParameterError(
            f"keep={keep!r}: 'final' keeps no step's records, so not {names} of every step;"
            f" keep {('means', *rest)!r} for them"
        )
    return states[0], tuple(rest)


def check_progress(progress) -> None:
    """The ``progress`` option of a batch run: True, False (or None), or a callable taking the step index.

    Raises
    ------
    ParameterError
        Anything else.
    """
    if progress is None or isinstance(progress, (bool, np.bool_)) or callable(progress):
        return
    raise ParameterError(
        f"progress must be True, False or a callable taking the step index, got {progress!r}"
    )


def progress_callback(progress, total: int | None) -> tuple[Any, Callable[[int], object] | None]:
    """``(bar, callback)`` for a batch run's ``progress`` option (checked by :func:`check_progress`).

    Parameters
    ----------
    progress : bool, None or callable
    total : int or None
        The number of steps, when known.

    Returns
    -------
    (bar, callback)
        ``bar`` a tqdm bar on stderr when ``progress`` is True (to close),
        else None; ``callback(k)``, called after step ``k`` (None: no progress).

    Raises
    ------
    ParameterError
        ``progress`` is not an option, or is True and tqdm is not installed.
    """
    check_progress(progress)
    if progress is None or not progress:
        return None, None
    if progress is True or isinstance(progress, np.bool_):
        try:
            from tqdm.auto import tqdm
        except ImportError as exc:
            raise ParameterError(
                "progress=True needs tqdm, which is not installed: pip install 'squkf[progress]'"
                " (or pass progress=callable, called with each step's index)"
            ) from exc
        bar = tqdm(total=total, desc="batch_filter", unit="step")
        return bar, lambda k: bar.update(1)
    return None, progress


def annotate_step(exc: BaseException, k: int, partial: Any, at_step: bool) -> None:
    """Say where ``exc`` happened in a batch run and attach the results so far.

    A squkf error's message gets the prefix ``"at step k: "``; another
    exception a note (Python 3.11+). ``exc.partial`` is set to ``partial``
    and ``exc.step`` to ``k`` (None when the run failed after its steps).

    Parameters
    ----------
    exc : BaseException
    k : int
        The step (0-based) that raised.
    partial : object
        The results of the steps before ``k``.
    at_step : bool
        False when the error came after the last step (a check of the whole run).
    """
    if at_step:
        if isinstance(exc, SqukfError):
            msg = exc.args[0] if exc.args else ""
            exc.args = (f"at step {k}: {msg}", *exc.args[1:])
        elif hasattr(exc, "add_note"):  # Python 3.11+; other exceptions keep their message
            exc.add_note(f"raised at step {k} of batch_filter")
    try:
        exc.partial = partial  # type: ignore[attr-defined]
        exc.step = k if at_step else None  # type: ignore[attr-defined]
    except AttributeError:  # an exception type that takes no attributes
        pass


def run_steps(
    transaction: Transaction,
    steps: Iterable[Any],
    step: Callable[[int, Any], object],
    partial: Callable[[int], Any],
    progress,
    total: int | None,
    after: Callable[[int], object] | None = None,
) -> int:
    """A batch run: ``step(k, item)`` for each item of ``steps``, inside ``transaction``.

    The one loop of both faces' ``batch_filter``. After step ``k`` the ``progress`` option is told
    (a bar advanced, or the callable called with ``k``); after the last step ``after(T)`` may check
    the whole run (a per-step argument longer than the steps). On any exception (``KeyboardInterrupt``
    too) the transaction puts the face back as it was, and the exception is annotated
    (:func:`annotate_step`) with the step and ``partial(k)``, the results of the ``k`` steps before it.

    Parameters
    ----------
    transaction : Transaction
        The face's, as its ``transaction()`` hands it out.
    steps : iterable
        One item per step (a measurement, or a step index), read as the run goes.
    step : callable
        ``step(k, item)``: step ``k``, its records kept.
    partial : callable
        ``partial(k)``: what the run would return after its first ``k`` steps.
    progress : bool, None or callable
        As :func:`progress_callback` takes it.
    total : int or None
        The number of steps, when known (for the bar).
    after : callable, optional
        ``after(T)``, called after the last step, inside the transaction.

    Returns
    -------
    int
        The number of steps run, ``T``.
    """
    bar, callback = progress_callback(progress, total)
    k = 0
    at_step = True
    try:
        with transaction:
            for item in steps:
                step(k, item)
                if callback is not None:
                    callback(k)
                k += 1
            at_step = False
            if after is not None:
                after(k)
    except BaseException as exc:
        annotate_step(exc, k, partial(k), at_step)
        raise
    finally:
        if bar is not None:
            bar.close()
    return k
