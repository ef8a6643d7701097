"""The square-root unscented transform of a set of weighted points.

Pure functions: points in, mean and lower factor out. Points are rows,
``(n_sigma, dim)``, as filterpy stores ``sigmas_f``.

A weighted covariance ``sum_i Wc[i] d_i d_i^T`` is written as *signed
rows*: rows ``r_k`` and signs ``s_k`` with ``P = sum_k s_k r_k r_k^T``. The
positive rows go into one QR factorisation; each negative row is removed by
an O(n^2) rank-1 downdate. Two ways of writing the rows are used:

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

:func:`weight_plan` picks, once per weight vector, the form with fewer
negative rows (the central form on a tie).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .errors import DowndateError, NonFiniteError, ShapeError
from .linalg import all_finite, chol_update, tria

__all__ = [
    "RowForm",
    "WeightPlan",
    "weight_plan",
    "signed_rows",
    "central_rows",
    "transform_factor",
    "factor_rows",
    "weighted_mean",
    "deviations",
    "mean_and_deviations",
    "factor_from_deviations",
    "sqrt_unscented_transform",
]


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
    pos : ndarray of int or None
        Rows with a positive weight, in order; None when that is every row.
    neg : ndarray of int, shape (k,)
        Rows with a negative weight (removed by downdates); usually empty.
    weights : ndarray, shape (N,)
        The signed weight of each row.
    """

    central: bool
    scale: np.ndarray
    pos: np.ndarray | None
    neg: np.ndarray
    weights: np.ndarray


@dataclass(frozen=True)
class WeightPlan:
    """The row forms available for one pair of weight vectors.

    Attributes
    ----------
    Wm, Wc : ndarray, shape (N,)
    wm_tail : ndarray, shape (N - 1,)
        ``Wm[1:]``, contiguous (the central form's mean offset is ``wm_tail @ e``).
    mean_form : RowForm
    central_form : RowForm or None
        None unless ``Wc[1:] == Wm[1:]``.
    best : RowForm
        The form used when no hook forces the mean form.
    fast : bool
        ``best`` is the central form with no negative weight: its rows can be
        written straight into the QR buffer (:func:`central_rows`).
    tail_scale : ndarray, shape (N - 1, 1)
        ``best.scale[:-1]`` as a column (the scales of the rows ``e_i``).
    mu_scale : float
        ``best.scale[-1]`` (the scale of the row ``mu``).
    """

    Wm: np.ndarray
    Wc: np.ndarray
    wm_tail: np.ndarray
    mean_form: RowForm
    central_form: RowForm | None
    best: RowForm
    fast: bool
    tail_scale: np.ndarray
    mu_scale: float


def _row_form(w: np.ndarray, central: bool) -> RowForm:
    w = np.asarray(w, dtype=float)
    pos = np.flatnonzero(w > 0)
    neg = np.flatnonzero(w < 0)
    return RowForm(
        central=central,
        scale=_frozen(np.sqrt(np.abs(w))),
        pos=None if pos.size == w.size else _frozen(pos),
        neg=_frozen(neg),
        weights=_frozen(w.copy()),
    )


def _frozen(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


_PLANS: dict[tuple[int, int], tuple] = {}
_MEAN_FORMS: dict[int, tuple] = {}


def _cacheable(*arrays) -> bool:
    # families hand out the same read-only arrays every step; anything else is not cached
    return all(getattr(a, "flags", None) is not None and not a.flags.writeable for a in arrays)


def mean_form(Wc: np.ndarray) -> RowForm:
    """The mean form's rows for covariance weights ``Wc`` (cached for read-only arrays).

    Parameters
    ----------
    Wc : ndarray, shape (N,)

    Returns
    -------
    RowForm
    """
    entry = _MEAN_FORMS.get(id(Wc))
    if entry is not None and entry[0] is Wc:
        return entry[1]
    form = _row_form(Wc, central=False)
    if _cacheable(Wc):
        if len(_MEAN_FORMS) > 256:
            _MEAN_FORMS.clear()
        _MEAN_FORMS[id(Wc)] = (Wc, form)
    return form


def weight_plan(Wm: np.ndarray, Wc: np.ndarray) -> WeightPlan:
    """The row forms for weights ``(Wm, Wc)``; cached for read-only weight arrays.

    Parameters
    ----------
    Wm, Wc : ndarray, shape (N,)
        Mean and covariance weights (``Wm`` sums to 1).

    Returns
    -------
    WeightPlan
    """
    key = (id(Wm), id(Wc))
    entry = _PLANS.get(key)
    if entry is not None and entry[0] is Wm and entry[1] is Wc:
        return entry[2]
    Wm_ = np.asarray(Wm, dtype=float)
    Wc_ = np.asarray(Wc, dtype=float)
    mean_rows = mean_form(Wc)
    central_form = None
    if Wm_.shape[0] >= 2 and np.array_equal(Wc_[1:], Wm_[1:]):
        c = float(Wc_.sum()) - 2.0
        if abs(c) <= 8 * Wc_.shape[0] * np.finfo(float).eps * float(np.abs(Wc_).sum()):
            c = 0.0  # within the rounding of its own sum (beta == alpha**2): no row, not a downdate
        central_form = _row_form(np.append(Wc_[1:], c), central=True)
    best = mean_rows
    if central_form is not None and central_form.neg.size <= mean_rows.neg.size:
        best = central_form
    fast = best.central and best.neg.size == 0  # zero-weight rows are zero rows in the QR
    tail_scale = _frozen(best.scale[:-1, None].copy())
    mu_scale = float(best.scale[-1]) if best.scale.size else 0.0
    plan = WeightPlan(
        Wm_, Wc_, _frozen(Wm_[1:].copy()), mean_rows, central_form, best, fast, tail_scale, mu_scale
    )
    if _cacheable(Wm, Wc):
        if len(_PLANS) > 256:
            _PLANS.clear()
        _PLANS[key] = (Wm, Wc, plan)
    return plan


def weighted_mean(sigmas: np.ndarray, Wm: np.ndarray, mean_fn: Callable | None = None) -> np.ndarray:
    """Weighted mean of the rows of ``sigmas``.

    The plain mean is formed as ``sigmas[0] + Wm @ (sigmas - sigmas[0])``:
    with a small alpha the weights are large and of both signs, and summing
    offsets from a reference point avoids the cancellation of summing the
    points themselves.

    Parameters
    ----------
    sigmas : ndarray, shape (N, d)
    Wm : ndarray, shape (N,)
        Mean weights, summing to 1.
    mean_fn : callable ``mean_fn(sigmas, Wm) -> (d,)``, optional
        Replaces the weighted sum (e.g. a circular mean for angles).

    Returns
    -------
    mean : ndarray, shape (d,)
    """
    if mean_fn is None:
        ref = sigmas[0]
        return ref + Wm @ (sigmas - ref)
    mean = np.asarray(mean_fn(sigmas, Wm), dtype=float).reshape(-1)
    if mean.shape != (sigmas.shape[1],):
        raise ShapeError(f"mean function returned shape {mean.shape}, expected ({sigmas.shape[1]},)")
    return mean


def deviations(sigmas: np.ndarray, mean: np.ndarray, residual_fn: Callable | None = None) -> np.ndarray:
    """Rows ``residual_fn(sigmas[i], mean)`` (plain differences by default).

    Parameters
    ----------
    sigmas : ndarray, shape (N, d)
    mean : ndarray, shape (d,)
    residual_fn : callable ``residual_fn(a, b) -> (d,)``, optional
        Called once per row, with 1-D arrays, as filterpy calls it.

    Returns
    -------
    dev : ndarray, shape (N, d)
    """
    if residual_fn is None or residual_fn is np.subtract:
        return sigmas - mean
    dev = np.empty_like(sigmas)
    for i, s in enumerate(sigmas):
        dev[i] = residual_fn(s, mean)
    return dev


def mean_and_deviations(
    sigmas: np.ndarray,
    Wm: np.ndarray,
    mean_fn: Callable | None = None,
    residual_fn: Callable | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean of the rows of ``sigmas`` and each row's deviation from it.

    Parameters
    ----------
    sigmas : ndarray, shape (N, d)
    Wm : ndarray, shape (N,)
    mean_fn : callable ``mean_fn(sigmas, Wm)``, optional
    residual_fn : callable ``residual_fn(a, b)``, optional

    Returns
    -------
    mean : ndarray, shape (d,)
    dev : ndarray, shape (N, d)
    """
    mean = weighted_mean(sigmas, Wm, mean_fn)
    return mean, deviations(sigmas, mean, residual_fn)


def factor_from_deviations(
    dev: np.ndarray,
    Wc: np.ndarray,
    noise_sqrt: np.ndarray | None = None,
    errno: int = 301,
    error: type[DowndateError] | type = DowndateError,
) -> np.ndarray:
    """Lower factor of ``sum_i Wc[i] dev[i] dev[i]^T + noise_sqrt @ noise_sqrt.T`` (mean form).

    Parameters
    ----------
    dev : ndarray, shape (N, d)
        Deviations (from any common point).
    Wc : ndarray, shape (N,)
        Weights, of either sign.
    noise_sqrt : ndarray, shape (d, k), optional
    errno : int
    error : exception class

    Returns
    -------
    S : ndarray, shape (d, d)
    """
    return factor_rows(dev, mean_form(Wc), noise_sqrt, errno, error)


def signed_rows(
    sigmas: np.ndarray,
    plan: WeightPlan,
    mean_fn: Callable | None = None,
    residual_fn: Callable | None = None,
    mean: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, RowForm]:
    """Mean of a weighted set and its unscaled rows.

    Parameters
    ----------
    sigmas : ndarray, shape (N, d)
    plan : WeightPlan
    mean_fn, residual_fn : callable, optional
        filterpy's hooks; either forces the mean form.
    mean : ndarray, shape (d,), optional
        Take deviations from this point instead of the set's weighted mean
        (forces the mean form).

    Returns
    -------
    mean : ndarray, shape (d,)
    D : ndarray, shape (N, d)
        Row ``k`` times ``form.scale[k]`` is signed row ``k``.
    form : RowForm
    """
    form = plan.best
    plain = mean_fn is None and (residual_fn is None or residual_fn is np.subtract) and mean is None
    if plain and form.central:
        ref = sigmas[0]
        D = np.empty_like(sigmas)
        np.subtract(sigmas[1:], ref, out=D[:-1])
        mu = plan.wm_tail @ D[:-1]
        D[-1] = mu
        return ref + mu, D, form
    form = plan.mean_form
    if mean is None:
        mean = weighted_mean(sigmas, plan.Wm, mean_fn)
    return mean, deviations(sigmas, mean, residual_fn), form


def central_rows(sigmas: np.ndarray, plan: WeightPlan, out: np.ndarray) -> np.ndarray:
    """Write the central form's scaled rows into ``out[:N]``; return the weighted mean.

    For a plan with ``plan.fast`` (no negative weight), ``out[:N].T @ out[:N]``
    is then the weighted covariance of the points.

    Parameters
    ----------
    sigmas : ndarray, shape (N, d)
    plan : WeightPlan
        With ``plan.fast``.
    out : ndarray, shape (>= N, d)
        Rows ``0..N-1`` are overwritten (any memory layout).

    Returns
    -------
    mean : ndarray, shape (d,)
    """
    N = sigmas.shape[0]
    ref = sigmas[0]
    E = out[: N - 1]
    np.subtract(sigmas[1:], ref, out=E)
    mu = plan.wm_tail @ E
    E *= plan.tail_scale
    np.multiply(mu, plan.mu_scale, out=out[N - 1])
    return ref + mu


def transform_factor(
    sigmas: np.ndarray,
    plan: WeightPlan,
    noise_sqrt: np.ndarray | None = None,
    mean_fn: Callable | None = None,
    residual_fn: Callable | None = None,
    errno: int = 301,
    error: type[DowndateError] | type = DowndateError,
    rows: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean and lower factor of the points' covariance plus additive noise.

    Parameters
    ----------
    sigmas : ndarray, shape (N, d)
    plan : WeightPlan
    noise_sqrt : ndarray, shape (d, k), optional
    mean_fn, residual_fn : callable, optional
        filterpy's hooks (they force the mean form).
    errno : int
    error : exception class
        For a failed downdate.
    rows : ndarray, shape (N + k, d), Fortran order, optional
        A buffer for the QR of a ``plan.fast`` transform (overwritten; kept
        between calls by :class:`squkf.lane.Lane`); allocated when not given.

    Returns
    -------
    mean : ndarray, shape (d,)
    S : ndarray, shape (d, d)
    """
    plain = mean_fn is None and (residual_fn is None or residual_fn is np.subtract)
    if plain and plan.fast:
        N, d = sigmas.shape
        extra = 0 if noise_sqrt is None else noise_sqrt.shape[1]
        if rows is None:
            rows = np.empty((N + extra, d), order="F")  # LAPACK's layout: no copy in tria
        mean = central_rows(sigmas, plan, rows)
        if extra:
            rows[N:] = noise_sqrt.T
        return mean, tria(rows)
    mean, D, form = signed_rows(sigmas, plan, mean_fn, residual_fn)
    return mean, factor_rows(D, form, noise_sqrt, errno, error)


def factor_rows(
    D: np.ndarray,
    form: RowForm,
    noise_sqrt: np.ndarray | None = None,
    errno: int = 301,
    error: type[DowndateError] | type = DowndateError,
) -> np.ndarray:
    """Lower factor of ``sum_k w_k D_k D_k^T + noise_sqrt @ noise_sqrt.T``.

    The positive rows enter one QR factorisation together with the noise
    factor's columns; each negative row is then removed by a rank-1 downdate.

    Parameters
    ----------
    D : ndarray, shape (N, d)
        Unscaled rows (from :func:`signed_rows`).
    form : RowForm
        Their weights.
    noise_sqrt : ndarray, shape (d, k), optional
        A square root (any ``k`` columns) of additive noise.
    errno : int
        g13ej error number for a failed downdate.
    error : exception class
        Raised for a failed downdate (a :class:`DowndateError` subclass).

    Returns
    -------
    S : ndarray, shape (d, d)

    Raises
    ------
    DowndateError
        If a negative weight's downdate would lose positive-definiteness.
    """
    src = D if form.pos is None else D[form.pos]
    scale = form.scale if form.pos is None else form.scale[form.pos]
    npos, d = src.shape
    extra = 0 if noise_sqrt is None else noise_sqrt.shape[1]
    rows = np.empty((npos + extra, d), order="F")  # LAPACK's layout: no copy in tria
    np.multiply(src, scale[:, None], out=rows[:npos])
    if extra:
        rows[npos:] = noise_sqrt.T
    S = tria(rows)
    return downdate_rows(S, D, form, errno, error)


def downdate_rows(S: np.ndarray, D: np.ndarray, form: RowForm, errno: int, error: type) -> np.ndarray:
    """Remove the negative rows of ``form`` from the factor ``S`` (one downdate each).

    Parameters
    ----------
    S : ndarray, shape (d, d)
    D : ndarray, shape (N, d)
    form : RowForm
    errno : int
    error : exception class

    Returns
    -------
    S : ndarray, shape (d, d)
    """
    for k in form.neg:
        if not (S.diagonal() > 0).all():
            raise error(
                f"weight {form.weights[k]:.6g} of row {k} is negative and the factor to downdate is singular",
                errno=errno,
            )
        try:
            S = chol_update(S, form.scale[k] * D[k], -1.0)
        except DowndateError as exc:
            raise error(
                f"weight {form.weights[k]:.6g} of row {k} is negative and its downdate failed: {exc}",
                errno=errno,
            ) from None
    return S


def sqrt_unscented_transform(
    sigmas: np.ndarray,
    Wm: np.ndarray,
    Wc: np.ndarray,
    noise_sqrt: np.ndarray | None = None,
    mean_fn: Callable | None = None,
    residual_fn: Callable | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Square-root unscented transform of propagated sigma points.

    The square-root counterpart of filterpy's ``unscented_transform``: same
    arguments, but the noise is given by its lower factor and the result is
    a lower factor instead of a covariance. A function with this signature
    can be passed as ``UT`` to :meth:`SquareRootUKF.predict` and ``update``.

    Parameters
    ----------
    sigmas : ndarray, shape (N, d)
        Propagated sigma points, one per row.
    Wm, Wc : ndarray, shape (N,)
        Mean and covariance weights.
    noise_sqrt : ndarray, shape (d, d), optional
        Lower factor of the additive noise covariance.
    mean_fn : callable ``mean_fn(sigmas, Wm)``, optional
    residual_fn : callable ``residual_fn(a, b)``, optional

    Returns
    -------
    mean : ndarray, shape (d,)
    S : ndarray, shape (d, d)
        Lower factor of the transformed covariance.
    """
    sigmas = np.asarray(sigmas, dtype=float)
    if not all_finite(sigmas):
        raise NonFiniteError("sigma points contain NaN or inf")
    return transform_factor(sigmas, weight_plan(Wm, Wc), noise_sqrt, mean_fn, residual_fn)
