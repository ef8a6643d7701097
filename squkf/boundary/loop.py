"""The batch loop's boundary: its options, its progress bar, and its transaction.

A call that runs many steps (``batch_filter``) changes the filter step by
step; if anything fails (or is interrupted) the filter is put back as it was
before the call. Each facade says what its state is (``_snapshot`` and
``_restore``) and hands out a :class:`Transaction` over them from its public
``transaction()``; the loops (:func:`squkf.batch.batch_filter`,
``Fleet.batch_filter``) run inside one.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from ..errors import ParameterError

__all__ = ["KEEP", "Transaction", "check_fleet_progress", "check_keep", "fleet_progress"]

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


def check_keep(keep) -> str:
    """``keep`` of a fleet's run: one of ``"all"``, ``"diagonals"``, ``"means"``, ``"final"``.

    Parameters
    ----------
    keep : str

    Returns
    -------
    str
    """
    if keep not in KEEP:
        raise ParameterError(f"keep must be 'all', 'diagonals', 'means' or 'final', got keep={keep!r}")
    return keep


def check_fleet_progress(progress) -> None:
    """A fleet's ``progress``: True, False or a callable (checked before the run, with the other options)."""
    if not (isinstance(progress, bool) or callable(progress)):
        raise ParameterError(f"progress must be True, False or a callable, got {progress!r}")


def fleet_progress(progress, total: int):
    """``(bar, callback)`` for a fleet's ``progress`` option: a tqdm bar of ``total`` steps, or the callable.

    Parameters
    ----------
    progress : bool or callable
        Checked by :func:`check_fleet_progress`.
    total : int

    Returns
    -------
    (bar, callback)
        ``bar`` a tqdm bar (None unless ``progress`` is True), to close;
        ``callback(t)`` called after step ``t`` (None for no progress).
    """
    if progress is True:
        try:
            from tqdm.auto import tqdm
        except ImportError:
            raise ParameterError("progress=True needs tqdm: pip install 'squkf[progress]'") from None
        bar = tqdm(total=total, unit="step")
        return bar, lambda t: bar.update(1)
    if progress is False:
        return None, None
    return None, progress
