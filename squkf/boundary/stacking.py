"""One filter out of a fleet and filters into one: ``fleet[k]`` and ``Fleet.from_filters``.

Both read the public faces only: a filter's or fleet's :class:`Config`, and
the attributes a caller reads (``f.x``, ``f.P1_2``, ``f.Q1_2``, ``f.R1_2``,
whose in-place edits are validated as they are read or assigned). A pending
ask/tell step is kept where the single filter and the fleet take it the same
way, and refused otherwise (:func:`check_pending`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from ..errors import CallSequenceError
from ..plan import IDLE, PRIOR, Plan
from .config import Config, common_config, filter_kwargs

__all__ = ["check_pending", "filter_of", "stacked"]


def check_pending(phase: str, plan: Plan, who: str) -> None:
    """Refuse to copy a filter out of (or into) a fleet when its pending step would be lost.

    After a prediction whose second set is redrawn from the prior alone, the
    copy draws the same set from the same prior at its update: the step is
    kept. Points handed out by ``ask_*`` and not yet told, or a second set
    that reads the propagated points (``"augmented"``, ``"propagated"``),
    cannot be carried over.

    Parameters
    ----------
    phase : str
        The step's phase (:data:`squkf.plan.IDLE`, ...).
    plan : squkf.plan.Plan
    who : str
        For the message, e.g. ``"fleet[3]"`` or ``"filters[1]"``.

    Raises
    ------
    CallSequenceError
    """
    if phase == IDLE or (phase == PRIOR and not plan.keeps_propagated):
        return
    what = (
        "a prediction whose second set reads the propagated points" if phase == PRIOR else f"an ask ({phase})"
    )
    raise CallSequenceError(
        f"{who}: the step is pending ({what}), which a copy cannot carry over: "
        "complete the step (update, or tell) first"
    )


def filter_of(make: Callable[..., Any], c: Config, k: int, x: np.ndarray, S: np.ndarray, phase: str):
    """Filter ``k`` of a fleet as a :class:`squkf.SquareRootUKF` (vectorised).

    Parameters
    ----------
    make : type
        :class:`squkf.SquareRootUKF` (given by the fleet: the boundary imports no front end).
    c : Config
        The fleet's configuration and noise factors (shared or per filter).
    k : int
        A valid index of the fleet's filters.
    x : ndarray, shape (K, n)
    S : ndarray, shape (K, n, n)
        The fleet's states and lower factors.
    phase : str
        The fleet's pending step (:func:`check_pending`).

    Returns
    -------
    SquareRootUKF
        With its own copies of filter ``k``'s state and noise.
    """
    check_pending(phase, c.plan, f"fleet[{k}]")
    f = make(c.dim_x, c.dim_z, c.dt, c.hx, c.fx, c.points, vectorized=True, **filter_kwargs(c))
    f.x = x[k]
    f.P1_2 = S[k]
    Q, R = c.Q1_2, c.R1_2
    f.Q1_2 = None if Q is None else (Q if Q.ndim == 2 else Q[k])
    f.R1_2 = R if R is None or R.ndim == 2 else R[k]
    return f


def stacked(filters: Sequence[Any]) -> tuple[Config, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What ``Fleet.from_filters`` builds its fleet of: the filters' one configuration and stacked arrays.

    Parameters
    ----------
    filters : sequence of SquareRootUKF
        Of one configuration (:func:`squkf.boundary.config.common_config`),
        none with a step pending that a fleet cannot carry (:func:`check_pending`).

    Returns
    -------
    c : Config
        The first filter's.
    x : ndarray, shape (K, n)
    P1_2 : ndarray, shape (K, n, n)
    Q1_2, R1_2 : ndarray, shape (d, d) or (K, d, d)
        Shared where every filter's is the same (zeros: no noise).
    """
    configs = [f.configuration() for f in filters]  # edits in place of Q and R taken (validated)
    c = common_config(configs)
    for k, ck in enumerate(configs):
        check_pending(ck.step, ck.plan, f"filters[{k}]")
    x = np.stack([f.x for f in filters])  # validated by the fleet's setter
    P1_2 = np.stack([f.P1_2 for f in filters])  # edits in place of P taken (validated)
    Qs = [f.Q1_2 for f in filters]
    Rs = [f.R1_2 for f in filters]
    Q = Qs[0] if all(np.array_equal(q, Qs[0]) for q in Qs) else np.stack(Qs)
    R = Rs[0] if all(np.array_equal(r, Rs[0]) for r in Rs) else np.stack(Rs)
    return c, x, P1_2, Q, R
