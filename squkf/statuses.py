"""A kernel's status as squkf's exception: the one wording of every route and face.

The kernels report a status per filter (:mod:`squkf.kernels.phases`): 0, or
g13ej's codes for an update (301, 302, 303; 304 for a posterior factor with a
zero on its diagonal), ``r + 1`` / ``-(r + 1)`` for a prediction's negative row
``r`` whose downdate failed or found the factor singular, and 305 for a result
that is not finite. The engine, a fleet's chunks and :mod:`squkf.measurement`
turn them into exceptions here.
"""

from __future__ import annotations

import math

import numpy as np

from .errors import DowndateError, GainError, NonFiniteError, PosteriorFactorError, SqukfError
from .rows import RowForm

__all__ = ["NOT_FINITE", "failure", "first_status", "prior_failure", "singular_allowed"]

#: The status of a result that is not finite.
NOT_FINITE = 305


def failure(code: int, form: RowForm | None = None, what: str = "update") -> SqukfError:
    """The exception of a kernel's status ``code`` (not 0): the one wording of every route and face.

    Parameters
    ----------
    code : int
        From the transform kernel (``r + 1`` / ``-(r + 1)``: negative row ``r``'s downdate failed, or
        found the factor singular; 305: the result is not finite) or an update kernel (g13ej's 301,
        302, 303; 304 only where the posterior is not allowed to be singular).
    form : RowForm, optional
        The rows of the weights, for the negative weights' values.
    what : {"prior", "update"}
        Which phase.

    Returns
    -------
    SqukfError
    """
    negative = "" if form is None else ", ".join(f"{w:.6g}" for w in form.weights[form.neg])
    if what == "prior":
        if code == NOT_FINITE:
            return NonFiniteError("the predicted mean or factor is not finite")
        k = abs(code) - 1
        why = "the factor to downdate is singular" if code < 0 else "its downdate failed"
        w = form.weights[k] if form is not None else math.nan
        return DowndateError(f"weight {w:.6g} of row {k} is negative and {why}", errno=301)
    if code == 304:
        return PosteriorFactorError(
            "the posterior factor lost rank to rounding (a zero on its diagonal from positive definite P"
            " and R): the covariances' scales are too far apart for double precision",
            errno=303,
        )
    if code == 301:
        return DowndateError(
            f"weight {negative} is negative and the innovation factor's downdate failed", 301
        )
    if code == 302:
        return GainError("innovation factor is singular: cannot form the Kalman gain", errno=302)
    if negative and code == 303:
        return PosteriorFactorError(
            f"the posterior factor could not be formed (downdate failed, or not finite; negative weight "
            f"{negative})",
            errno=303,
        )
    return PosteriorFactorError(
        "the posterior mean or factor is not finite, or its downdate failed", errno=303
    )


def prior_failure(code: int, form: RowForm | None) -> SqukfError:
    """:func:`failure` of a prediction's transform."""
    return failure(code, form, "prior")


def singular_allowed(status: np.ndarray, S: np.ndarray, R1_2: np.ndarray) -> np.ndarray:
    """The status with each 304 that is the right answer cleared.

    A posterior factor with a zero on its diagonal from a positive definite prior factor ``S`` and
    noise factor ``R1_2`` is rank lost to rounding (an error); from a singular one (an exactly measured
    component) it is right.
    """
    definite = (np.diagonal(S, 0, -2, -1) != 0).all(axis=-1) & (np.diagonal(R1_2, 0, -2, -1) != 0).all(
        axis=-1
    )
    return np.where((status == 304) & ~definite, 0, status)


def first_status(status: np.ndarray) -> int:
    """The first non-zero status of a block, in C order (0 if none)."""
    if status.size == 1:
        return int(status.flat[0])
    bad = np.flatnonzero(status)
    return int(status.flat[bad[0]]) if bad.size else 0
