"""A weight vector's covariance rows: how ``sum_i Wc[i] d_i d_i^T`` becomes a QR.

A weighted covariance is written as *signed rows*: rows ``r_k`` and signs
``s_k`` with ``P = sum_k s_k r_k r_k^T``. The positive rows go into one QR
factorisation; each negative row is removed by an O(n^2) rank-1 downdate.
Two ways of writing the rows are used:

*mean form*
    ``r_i = sqrt(|Wc[i]|) (X_i - mean)``, one row per point, the sign of
    ``Wc[i]``. A negative central weight (Merwe's alpha < 1) costs a downdate.
*central form*
    With ``e_i = X_i - X_0`` and ``mu = sum_i Wm[i] e_i`` (so that
    ``mean = X_0 + mu``), and when ``Wc[i] == Wm[i]`` for every ``i >= 1``
    (true of Merwe's, Julier's and filterpy's symmetric points)::

        sum_i Wc[i] (X_i - mean)(X_i - mean)^T
            = sum_{i>=1} Wc[i] e_i e_i^T + (sum(Wc) - 2) mu mu^T.

    For Merwe's points ``sum(Wc) - 2 = beta - alpha**2``, so with the usual
    ``beta >= alpha**2`` every weight is non-negative and the factor is one QR
    with no downdate, however small alpha is. The offsets ``e_i`` from the
    central point are also what keeps the mean free of cancellation when the
    weights are large and of both signs.

:func:`weight_rows` picks, once per weight vector, the form with fewer
negative rows (the central form on a tie). It is computed when a plan is
built (:mod:`squkf.plan`), never per step. A form is data for the kernels
(:mod:`squkf.kernels`): each row's scale and sign.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["RowForm", "WeightRows", "weight_rows"]


@dataclass(frozen=True)
class RowForm:
    """How the ``N`` deviations of a weighted set become signed rows.

    Attributes
    ----------
    central : bool
        Rows are ``(e_1, ..., e_{N-1}, mu)`` (central form) rather than
        ``(X_0 - mean, ..., X_{N-1} - mean)`` (mean form).
    scale : ndarray, shape (N,)
        ``sqrt(|w_k|)`` of each row's weight.
    sign : ndarray, shape (N,)
        ``+1``, ``-1`` or ``0``: the sign of each row's weight (float64, as the kernels read it).
    pos : ndarray of int or None
        Rows with a positive weight, in order; None when that is every row.
    neg : ndarray of int, shape (k,)
        Rows with a negative weight (removed by downdates); usually empty.
    weights : ndarray, shape (N,)
        The signed weight of each row.
    """

    central: bool
    scale: np.ndarray
    sign: np.ndarray
    pos: np.ndarray | None
    neg: np.ndarray
    weights: np.ndarray


@dataclass(frozen=True)
class WeightRows:
    """The row forms of one pair of weight vectors.

    Attributes
    ----------
    Wm, Wc : ndarray, shape (N,)
    mean_form : RowForm
    central_form : RowForm or None
        None unless ``Wc[1:] == Wm[1:]``.
    best : RowForm
        The form used when no hook forces the mean form.
    fast : bool
        ``best`` is the central form with no negative weight: one QR and no
        downdate.
    pair_scale : float
        For a set ``[c, c + D, c - D]`` whose ``+/-`` rows all have one weight
        (with ``fast``): that row scale over ``sqrt(2)``, what the 45-degree
        rotation of each pair of joint rows needs (:mod:`squkf.measurement`);
        0 otherwise.
    """

    Wm: np.ndarray
    Wc: np.ndarray
    mean_form: RowForm
    central_form: RowForm | None
    best: RowForm
    fast: bool
    pair_scale: float


def _frozen(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


def _row_form(w: np.ndarray, central: bool) -> RowForm:
    pos = np.flatnonzero(w > 0)
    neg = np.flatnonzero(w < 0)
    return RowForm(
        central=central,
        scale=_frozen(np.sqrt(np.abs(w))),
        sign=_frozen(np.sign(w).astype(np.float64)),
        pos=None if pos.size == w.size else _frozen(pos),
        neg=_frozen(neg),
        weights=_frozen(w.copy()),
    )


def weight_rows(Wm: np.ndarray, Wc: np.ndarray) -> WeightRows:
    """The row forms for weights ``(Wm, Wc)``.

    Parameters
    ----------
    Wm, Wc : ndarray, shape (N,)
        Mean and covariance weights (``Wm`` sums to 1).

    Returns
    -------
    WeightRows
    """
    Wm_ = np.array(Wm, dtype=float)
    Wc_ = np.array(Wc, dtype=float)
    mean_rows = _row_form(Wc_, central=False)
    central_form = None
    if Wm_.shape[0] >= 2 and np.array_equal(Wc_[1:], Wm_[1:]):
        c = float(Wc_.sum()) - 2.0
        if abs(c) <= 8 * Wc_.shape[0] * np.finfo(float).eps * float(np.abs(Wc_).sum()):
            c = 0.0  # within the rounding of its own sum (beta == alpha**2): no row, not a downdate
        central_form = _row_form(np.append(Wc_[1:], c), central=True)
    best = mean_rows
    if central_form is not None and central_form.neg.size <= mean_rows.neg.size:
        best = central_form
    fast = best.central and best.neg.size == 0  # zero-weight rows are left out of the QR
    tail = best.scale[:-1]
    N = Wm_.shape[0]
    uniform = fast and N >= 3 and N % 2 == 1 and bool(np.all(tail == tail[0])) and tail[0] > 0
    return WeightRows(
        Wm=_frozen(Wm_),
        Wc=_frozen(Wc_),
        mean_form=mean_rows,
        central_form=central_form,
        best=best,
        fast=fast,
        pair_scale=float(tail[0]) / float(np.sqrt(2.0)) if uniform else 0.0,
    )
