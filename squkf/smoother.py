"""The unscented Rauch-Tung-Striebel smoother (Särkkä 2008) in square-root form.

Each backward step draws the first-set sigma points from the filtered
``(x[k], S[k])``, propagates them through ``fx`` with the time step and
process noise of the prediction *into* step ``k + 1`` (``dts[k+1]``,
``Qs[k+1]``: the same lists given to ``batch_filter``), and forms

- the predicted mean and factor ``x_pred``, ``S_pred`` (QR + rank-1 steps),
- the cross-covariance ``C = sum Wc_i dX_i dF_i^T`` and the gain
  ``G = C (S_pred S_pred^T)^-1`` by two triangular solves,
- ``x_s[k] = x[k] + G (x_s[k+1] - x_pred)``, and the smoothed factor as one
  QR of ``[sqrt(Wc_i) (dX_i - G dF_i), G Q1_2, G S_s[k+1]]`` (plus a
  downdate per negative weight): since the points reproduce ``P[k]``,
  ``P[k] - G P_pred G^T = sum Wc_i (dX_i - G dF_i)(...)^T + G Q G^T``.

No covariance is formed and re-factored. Note the difference from filterpy's
``UnscentedKalmanFilter.rts_smoother``, which ignores ``Qs`` (it always uses
``self.Q``) and propagates step ``k`` with ``dts[k]`` rather than the time
step of the prediction into ``k + 1``; filterpy's ``KalmanFilter.rts_smoother``
reads ``Qs`` the way this smoother does.

Inputs are checked before the backward pass: the filtered means and factors
must be finite, the factors lower triangular with a non-zero diagonal, and
the per-step arguments (see :mod:`squkf.batch`) must have one entry per step;
``dts`` entries follow the filter's one rule for a time step
(:func:`squkf.checks.check_time_step`): any finite real number, ``0`` (a
prediction of zero length) and negative steps included, as ``predict`` takes them.

One algorithm, written once
---------------------------
The backward recursion is one pure function, ``_backward``, on stacked
arrays: means ``(..., T, n)`` and factors ``(..., T, n, n)`` with any leading
batch shape. One filter (:func:`rts_smoother_factors`) runs it with no batch
axis, on plain matrices (LAPACK directly, as the filter step does); a
:class:`squkf.Fleet` (:func:`fleet_rts_smoother`, behind
:meth:`squkf.Fleet.rts_smoother`) runs it with the filter axis ``(K,)``,
calling ``fx`` once per backward step with the points of all filters
``(K, N, n)``. filterpy's hooks are called per filter and per point.

For a fleet, a numerical failure of one filter while smoothing (non-finite
``fx`` values, a singular predicted factor, a failed downdate, a non-finite
result) is that filter's alone, as in the fleet's filtering: its whole output
is its filtered input, unsmoothed, and it is flagged in the result's
``failed`` mask with the reason in ``failure``; every other filter is smoothed
as if the failing one were absent. Filters already flagged in the
:class:`squkf.FleetResult` are returned unsmoothed and flagged likewise. With
the fleet's ``on_error="raise"`` a smoothing failure raises
:class:`squkf.FleetStepError` instead.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from typing import Any, NamedTuple

import numpy as np

from .batch import model_kwargs, per_step
from .boundary.attributes import FactorSlot
from .boundary.records import FleetResult, failures_error
from .checks import (
    as_float_array,
    as_lower_factor,
    call_hook,
    check_values,
    evaluate,
    finite_images,
    model_function,
    noise_factor,
    with_filter_axis,
)
from .errors import (
    NonFiniteError,
    NotPositiveDefiniteError,
    ParameterError,
    ShapeError,
    SqukfError,
)
from .generators import UnitSet, sigma_points_from_factor
from .kernels import wrappers
from .kernels.table import KernelTable
from .linalg import chol_downdate_columns, kalman_gain, tria
from .plan import Hooks
from .stacks import rows_of, run_isolated
from .transform import deviations, factor_rows, swap_last, transform_factor

__all__ = ["rts_smoother", "rts_smoother_factors", "fleet_rts_smoother", "FleetSmoothed"]


def _as_stack(value, name: str, tail: tuple[int, ...], T: int | None = None) -> np.ndarray:
    """``value`` as a finite float array of shape ``(T, *tail)``, or a ShapeError/NonFiniteError naming it."""
    expected = f"(T, {', '.join(map(str, tail))})"
    if isinstance(value, (str, bytes, Mapping)) or value is None:
        raise ShapeError(f"{name} must be an array of shape {expected}, got {type(value).__name__}")
    if not hasattr(value, "__len__") and isinstance(value, Iterable):
        value = list(value)  # a generator: the backward pass needs all of it
    try:
        A = np.array(value, dtype=float)
    except OverflowError:  # a Python integer beyond float64's range
        A = as_float_array(value, name)  # raises, naming the number
    except (TypeError, ValueError) as exc:
        raise ShapeError(f"{name} must be an array of shape {expected}: {exc}") from None
    if A.ndim == 1 and A.size == 0:
        A = A.reshape((0, *tail))
    if len(tail) == 1 and A.ndim == 3 and A.shape[2] == 1:  # filterpy's column vectors
        A = A[:, :, 0]
    if A.ndim != 1 + len(tail) or A.shape[1:] != tail:
        raise ShapeError(f"{name} has shape {A.shape}, expected {expected}")
    if T is not None and A.shape[0] != T:
        raise ShapeError(f"{name} has {A.shape[0]} entries but Xs has {T}: they must be the same length")
    finite = np.isfinite(A).all(axis=tuple(range(1, A.ndim)))
    if not finite.all():
        k = int(np.flatnonzero(~finite)[0])
        raise NonFiniteError(f"{name}[{k}] (step {k}) contains NaN or inf: {A[k]!r}")
    return A


def _check_UT(UT) -> None:
    if UT is not None and not callable(UT):
        raise ParameterError(f"UT must be a callable (or None), got {UT!r}")


def rts_smoother(
    ukf,
    Xs,
    Ps,
    Qs=None,
    dts=None,
    UT: Callable | None = None,
    *,
    fx_args: Mapping[str, Any] | Iterable[Mapping[str, Any] | None] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Square-root unscented RTS smoother with filterpy's signature.

    Parameters
    ----------
    ukf : SquareRootUKF
        Supplies ``fx``, the sigma-point family, the hooks and the defaults.
    Xs : array_like, shape (T, dim_x) or (T, dim_x, 1)
        Filtered means (``batch_filter``'s first output).
    Ps : array_like, shape (T, dim_x, dim_x)
        Filtered covariances; each is checked (symmetric, positive definite)
        and factored once.
    Qs : None, scalar, ndarray of shape (dim_x, dim_x), or T entries, optional
        ``Qs[k]``: process noise of the prediction into step ``k`` (a scalar
        ``q`` means ``q * I`` at every step; default ``ukf.Q``).
    dts : None, float, or T floats, optional
        ``dts[k]``: time step of the prediction into step ``k`` (default: the
        filter's ``dt``). Any finite real number, as for ``predict``.
    UT : callable, optional
        Square-root transform (see :func:`squkf.sqrt_unscented_transform`).
    fx_args : None, dict, or T dicts, optional
        Keyword arguments of ``fx`` for the prediction into step ``k``.

    Returns
    -------
    xs : ndarray, shape (T, dim_x)
        Smoothed means.
    Ps : ndarray, shape (T, dim_x, dim_x)
        Smoothed covariances.
    Ks : ndarray, shape (T, dim_x, dim_x)
        Smoother gains (the last is zero).

    Raises
    ------
    ShapeError
        ``Xs``, ``Ps`` or a per-step argument of the wrong shape or length.
    NonFiniteError
        NaN or inf in ``Xs[k]`` or ``Ps[k]`` (the message names ``k``).
    SqukfValueError, NotPositiveDefiniteError
        ``Ps[k]`` not symmetric or not positive definite.
    ParameterError
        A ``dts`` entry that is not a finite number, ``fx_args`` not dicts.

    Examples
    --------
    On a linear model the smoother is the Rauch-Tung-Striebel smoother of
    filterpy's ``KalmanFilter``:

    >>> import numpy as np
    >>> from filterpy.kalman import KalmanFilter
    >>> from squkf import MerweScaledWeights, SquareRootUKF
    >>> F, H = np.array([[1.0, 1.0], [0.0, 1.0]]), np.array([[1.0, 0.0]])
    >>> ukf = SquareRootUKF(
    ...     2, 1, 1.0, hx=lambda x: H @ x, fx=lambda x, dt: F @ x, points=MerweScaledWeights()
    ... )
    >>> ukf.Q, ukf.R = np.diag([0.01, 0.01]), [[0.25]]
    >>> zs = [[1.1], [1.9], [3.2], [3.9], [5.1]]
    >>> means, covs = ukf.batch_filter(zs)
    >>> xs, Ps, Ks = ukf.rts_smoother(means, covs)
    >>> print(np.round(xs[0], 4))
    [1.0726 0.9727]
    >>> kf = KalmanFilter(dim_x=2, dim_z=1)
    >>> kf.F, kf.H, kf.Q, kf.R = F, H, ukf.Q, ukf.R
    >>> mk, ck, _, _ = kf.batch_filter(np.array(zs))
    >>> xk, Pk, _, _ = kf.rts_smoother(mk, ck)
    >>> bool(np.allclose(xk.reshape(xs.shape), xs)), bool(np.allclose(Pk, Ps))
    (True, True)
    """
    n = ukf.dim_x
    Xs = _as_stack(Xs, "Xs", (n,))
    Ps = _as_stack(Ps, "Ps", (n, n), len(Xs))
    slot = FactorSlot("Ps[k]", n, semidefinite=False, factor=None)
    factors = np.empty_like(Ps)
    for k, P in enumerate(Ps):
        slot.name = f"Ps[{k}]"
        slot.set_matrix(P)
        factors[k] = slot.factor()
    xs, S, Ks = rts_smoother_factors(ukf, Xs, factors, Qs=Qs, dts=dts, UT=UT, fx_args=fx_args)
    return xs, S @ np.swapaxes(S, 1, 2), Ks


def rts_smoother_factors(
    ukf,
    Xs,
    P1_2s,
    Qs=None,
    dts=None,
    UT: Callable | None = None,
    *,
    fx_args: Mapping[str, Any] | Iterable[Mapping[str, Any] | None] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The smoother on lower factors: ``(xs, P1_2s, Ks)`` from filtered means and factors.

    Parameters
    ----------
    ukf : SquareRootUKF
    Xs : array_like, shape (T, dim_x) or (T, dim_x, 1)
        Filtered means.
    P1_2s : array_like, shape (T, dim_x, dim_x)
        Lower factors of the filtered covariances (``batch_filter(...,
        return_factors=True)``): each must be lower triangular with no zero on
        its diagonal (a negative diagonal entry is accepted and its column
        negated, which leaves ``S @ S.T`` unchanged, as the ``P1_2`` setter
        does).
    Qs, dts, UT, fx_args
        As for :func:`rts_smoother`.

    Returns
    -------
    xs : ndarray, shape (T, dim_x)
    P1_2s : ndarray, shape (T, dim_x, dim_x)
        Lower factors of the smoothed covariances.
    Ks : ndarray, shape (T, dim_x, dim_x)

    Raises
    ------
    ShapeError, NonFiniteError, ParameterError
        As for :func:`rts_smoother`, naming the argument and the step.
    SqukfValueError
        ``P1_2s[k]`` is not lower triangular.
    NotPositiveDefiniteError
        ``P1_2s[k]`` has a zero on its diagonal.
    SqukfError
        Raised during the backward pass at step ``k`` (e.g. by ``fx`` values,
        or ``Qs[k + 1]`` of the wrong size): its message starts with
        ``"at smoothing step k"``.

    Examples
    --------
    The smoother on factors gives the same result without forming a covariance:

    >>> import numpy as np
    >>> from squkf import MerweScaledWeights, SquareRootUKF
    >>> F = np.array([[1.0, 1.0], [0.0, 1.0]])
    >>> ukf = SquareRootUKF(
    ...     2, 1, 1.0, hx=lambda x: x[:1], fx=lambda x, dt: F @ x, points=MerweScaledWeights()
    ... )
    >>> ukf.Q, ukf.R = np.diag([0.01, 0.01]), [[0.25]]
    >>> zs = [[1.1], [1.9], [3.2], [3.9], [5.1]]
    >>> means, P1_2s = ukf.batch_filter(zs, return_factors=True)
    >>> xs, S_s, Ks = ukf.rts_smoother_factors(means, P1_2s)
    >>> xs2, Ps, _ = ukf.rts_smoother(means, P1_2s @ np.swapaxes(P1_2s, 1, 2))
    >>> bool(np.allclose(xs, xs2)), bool(np.allclose(S_s @ np.swapaxes(S_s, 1, 2), Ps))
    (True, True)
    >>> bool(np.all(np.triu(S_s, 1) == 0))
    True
    """
    c = ukf.configuration()
    fx = model_function(None, c.fx, "fx", "rts_smoother", per_call=False)
    n = c.dim_x
    Xs = _as_stack(Xs, "Xs", (n,))
    T = len(Xs)
    S_in = _as_stack(P1_2s, "P1_2s", (n, n), T)
    for k in range(T):
        S_in[k] = as_lower_factor(S_in[k], f"P1_2s[{k}]", n, singular_ok=False)
    _check_UT(UT)
    dt_list = per_step(dts, T, "dts", "dt", default=c.dt)
    kw_list = per_step(fx_args, T, "fx_args", "kwargs")
    Q_list = per_step(Qs, T, "Qs", "noise")
    cache: dict = {}

    def fx_eval(k: int, X: np.ndarray):
        return evaluate(fx, X, (dt_list[k + 1],), kw_list[k + 1], c.vectorized)

    def noise(k: int) -> np.ndarray | None:
        return noise_factor(Q_list[k + 1], "Q", n, lambda: c.Q1_2, cache)

    out = _backward(
        Xs,
        S_in,
        fx_eval,
        noise,
        c.plan.first,  # the first set as the filter draws it
        c.hooks,
        ut=UT,
        label=lambda k: f"Qs[{k + 1}], dts[{k + 1}], fx_args[{k + 1}]",
        kernels=c.kernels,
    )
    return out.xs, out.Ss, out.Gs


# -- the backward recursion on stacked arrays -----------------------------------------


class Smoothed(NamedTuple):
    """What ``_backward`` returns.

    Attributes
    ----------
    xs : ndarray, shape (..., T, n)
        Smoothed means.
    Ss : ndarray, shape (..., T, n, n)
        Lower factors of the smoothed covariances.
    Gs : ndarray, shape (..., T, n, n)
        Smoother gains (zero at the last step, and for a failed filter).
    failed : ndarray of bool, shape (...)
        Filters returned unsmoothed (only set with ``isolate``).
    failure : ndarray of str, shape (...)
        Why each of them failed ("" for the others).
    """

    xs: np.ndarray
    Ss: np.ndarray
    Gs: np.ndarray
    failed: np.ndarray
    failure: np.ndarray


def _combine(fn: Callable | None, a: np.ndarray, b: np.ndarray, default: Callable, hook: str) -> np.ndarray:
    """``fn(a, b)`` per filter (``a``, ``b`` of shape ``(..., n)``), or ``default(a, b)`` without a hook."""
    if fn is None or fn is default:
        return default(a, b)
    n = a.shape[-1]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    for idx in np.ndindex(out.shape[:-1]):
        out[idx] = call_hook(fn, (a[idx], b[idx]), (n,), hook)
    return out


def _matvec(A: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``A @ v`` for stacks of matrices ``(..., n, m)`` and vectors ``(..., m)``."""
    return A @ v if A.ndim == 2 else np.matmul(A, v[..., None])[..., 0]


def _smooth_step(
    x: np.ndarray,
    S: np.ndarray,
    X: np.ndarray,
    F: np.ndarray,
    x_next: np.ndarray,
    S_next: np.ndarray,
    Q1_2: np.ndarray | None,
    unit: UnitSet,
    hooks: Hooks,
    ut: Callable | None,
    kernels: KernelTable | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One backward step, for every filter of the batch at once (pure).

    Parameters
    ----------
    x, S : ndarray, shapes (..., n) and (..., n, n)
        Filtered mean and lower factor at step ``k``.
    X, F : ndarray, shape (..., N, n)
        Their sigma points and the points' images under ``fx`` (finite).
    x_next, S_next : ndarray, shapes (..., n) and (..., n, n)
        Smoothed mean and factor at step ``k + 1``.
    Q1_2 : ndarray, shape (n, n) or (..., n, n), or None
        Lower factor of the process noise of the prediction into ``k + 1``.
    unit : UnitSet
        The first set's unit points, weights and rows.
    hooks : Hooks
    ut : callable or None
        A user's square-root transform (default: :func:`squkf.transform.transform_factor`).
    kernels : KernelTable or None
        The filter's kernel table (its route's; None: the installed one).

    Returns
    -------
    x_s : ndarray, shape (..., n)
    S_s : ndarray, shape (..., n, n)
    G : ndarray, shape (..., n, n)
    """
    rows = unit.rows
    residual_x = hooks.residual_x
    if ut is None:
        x_pred, S_pred = transform_factor(F, rows, Q1_2, hooks.x_mean_fn, residual_x, kernels=kernels)
    else:
        x_pred, S_pred = ut(F, rows.Wm, rows.Wc, Q1_2, hooks.x_mean_fn, residual_x)
    dF = deviations(F, x_pred, residual_x, "residual_x")
    dX = deviations(X, x, residual_x, "residual_x")
    C = np.matmul(swap_last(dX) * rows.Wc, dF)
    G = kalman_gain(C, S_pred, kernels=kernels)
    diff = _combine(residual_x, x_next, x_pred, np.subtract, "residual_x")
    x_s = _combine(hooks.state_add, x, _matvec(G, diff), np.add, "state_add")
    GS = np.matmul(G, S_next)
    if unit.exact:
        # the points reproduce P[k]: P[k] - G P_pred G^T = sum Wc (dX - G dF)(...)^T + G Q G^T
        extra = GS if Q1_2 is None else np.concatenate([np.matmul(G, Q1_2), GS], axis=-1)
        S_s = factor_rows(dX - np.matmul(dF, swap_last(G)), rows.mean_form, extra, kernels=kernels)
    else:
        base = chol_downdate_columns(S, np.matmul(G, S_pred), kernels=kernels)
        S_s = tria(np.concatenate([swap_last(base), swap_last(GS)], axis=-2), kernels=kernels)
    return x_s, S_s, G


def _backward(
    xs: np.ndarray,
    Ss: np.ndarray,
    fx_eval: Callable[[int, np.ndarray], Any],
    Q1_2_at: Callable[[int], np.ndarray | None],
    unit: UnitSet,
    hooks: Hooks,
    *,
    ut: Callable | None = None,
    isolate: np.ndarray | None = None,
    label: Callable[[int], str] | None = None,
    kernels: KernelTable | None = None,
) -> Smoothed:
    """The square-root unscented RTS backward recursion on stacked arrays.

    Parameters
    ----------
    xs : ndarray, shape (..., T, n)
        Filtered means (finite).
    Ss : ndarray, shape (..., T, n, n)
        Their lower factors (lower triangular, non-negative non-zero diagonal).
    fx_eval : callable ``fx_eval(k, X) -> array_like (..., N, n)``
        ``fx`` at the points ``X`` (shape ``(..., N, n)``, all filters at once)
        for the prediction into step ``k + 1``.
    Q1_2_at : callable ``Q1_2_at(k) -> None or ndarray (n, n) or (..., n, n)``
        Lower factor of the process noise of the prediction into step ``k + 1``.
    unit : UnitSet
        The first sigma-point set's unit points, weights and rows.
    hooks : Hooks
        filterpy's hooks (``x_mean_fn``, ``residual_x``, ``state_add``), called per filter.
    ut : callable, optional
        A square-root transform with the signature of
        :func:`squkf.sqrt_unscented_transform`.
    isolate : ndarray of bool, shape (K,), optional
        With a batch of one axis ``(K,)``: isolate numerical failures per filter,
        the filters marked True being already failed. A failed filter's output
        is its input (unsmoothed, zero gains). Without it, every error raises.
    label : callable ``label(k) -> str``, optional
        The per-step arguments of backward step ``k``, for error messages.
    kernels : KernelTable, optional
        The filter's kernel table (its route's, from its configuration); default the installed one.

    Returns
    -------
    Smoothed

    Raises
    ------
    SqukfError
        Any error of backward step ``k`` not isolated; its message is prefixed
        with ``"at smoothing step k"``.
    """
    batch = xs.shape[:-2]
    T, n = xs.shape[-2:]
    xs_s, Ss_s = xs.copy(), Ss.copy()
    Gs = np.zeros(batch + (T, n, n))
    if isolate is not None and (len(batch) != 1 or isolate.shape != batch):
        raise ParameterError(f"isolate needs a batch of one axis and one flag per filter, got {batch}")
    failed = np.zeros(batch, dtype=bool) if isolate is None else isolate.astype(bool)
    failure = np.full(batch, "", dtype=object)
    failure[failed] = "flagged in the filtered result: returned unsmoothed"
    K = batch[0] if batch else 1
    state_add = hooks.state_add
    k = T - 2
    try:
        for k in range(T - 2, -1, -1):
            Q1_2 = Q1_2_at(k)
            x, S = xs[..., k, :], Ss[..., k, :, :]
            X = sigma_points_from_factor(x, S, unit.xi, state_add, kernels=kernels)
            if isolate is None:
                F = check_values(fx_eval(k, X), X.shape, "fx values")
                xs_s[..., k, :], Ss_s[..., k, :, :], Gs[..., k, :, :] = _smooth_step(
                    x, S, X, F, xs_s[..., k + 1, :], Ss_s[..., k + 1, :, :], Q1_2, unit, hooks, ut, kernels
                )
                continue
            F = as_float_array(fx_eval(k, X), "fx values")
            if F.shape != X.shape:
                raise ShapeError(f"fx values have shape {F.shape}, expected {X.shape} (a row per point)")
            fails: dict[int, str] = {}
            finite = finite_images(F, "fx values", ~failed, fails, kernels=kernels)
            idx = np.flatnonzero(~failed & finite)
            x_next, S_next = xs_s[:, k + 1], Ss_s[:, k + 1]

            def step(ix, X=X, F=F, x=x, S=S, x_next=x_next, S_next=S_next, Q1_2=Q1_2):
                out = _smooth_step(
                    x[ix], S[ix], X[ix], F[ix], x_next[ix], S_next[ix], rows_of(Q1_2, ix, 2), unit, hooks, ut,
                    kernels,
                )  # fmt: skip
                if not _finite_per_filter(out, kernels).all():
                    raise NonFiniteError("the smoothed estimate is not finite")
                return out

            good, res = run_isolated(step, idx, K, fails)
            if res is not None:
                xs_s[good, k], Ss_s[good, k], Gs[good, k] = res
            for j, why in fails.items():
                failed[j], failure[j] = True, f"{_where(k, label)}: {why}"
    except SqukfError as exc:
        msg = exc.args[0] if exc.args else ""
        exc.args = (f"{_where(k, label)}: {msg}",)
        raise
    if failed.any():
        xs_s[failed], Ss_s[failed], Gs[failed] = xs[failed], Ss[failed], 0.0
    return Smoothed(xs_s, Ss_s, Gs, failed, failure)


def _where(k: int, label: Callable[[int], str] | None) -> str:
    return f"at smoothing step {k}" + (f" ({label(k)})" if label is not None else "")


def _finite_per_filter(arrays: tuple[np.ndarray, ...], kernels: KernelTable | None) -> np.ndarray:
    """Whether each filter's slice (leading axis) of every array is finite."""
    ok = np.ones(arrays[0].shape[0], dtype=bool)
    for a in arrays:
        ok &= wrappers.finite_rows(a, kernels=kernels)
    return ok


# -- a fleet -------------------------------------------------------------------------------


class FleetSmoothed(tuple):
    """What :meth:`squkf.Fleet.rts_smoother` returns: ``(means, P1_2s, Gs)``, with the failures attached.

    It unpacks as a 3-tuple; the arrays are also attributes.

    Attributes
    ----------
    means : ndarray, shape (K, T, n)
        Smoothed means.
    P1_2s : ndarray, shape (K, T, n, n)
        Lower factors of the smoothed covariances.
    Gs : ndarray, shape (K, T, n, n)
        Smoother gains (zero at the last step and for a failed filter).
    failed : ndarray of bool, shape (K,)
        Filters returned unsmoothed (their filtered values): flagged in the
        :class:`squkf.FleetResult`, or failed numerically while smoothing.
    failure : ndarray of str, shape (K,)
        Why each of them failed ("" for the others).
    """

    failed: np.ndarray
    failure: np.ndarray

    def __new__(cls, means, P1_2s, Gs, failed, failure):
        self = super().__new__(cls, (means, P1_2s, Gs))
        self.failed, self.failure = failed, failure
        return self

    def __reduce__(self):
        return (type(self), (*self, self.failed, self.failure))

    @property
    def means(self) -> np.ndarray:
        """Smoothed means, shape ``(K, T, n)``."""
        return self[0]

    @property
    def P1_2s(self) -> np.ndarray:
        """Lower factors of the smoothed covariances, shape ``(K, T, n, n)``."""
        return self[1]

    @property
    def Gs(self) -> np.ndarray:
        """Smoother gains, shape ``(K, T, n, n)``."""
        return self[2]

    @property
    def Ps(self) -> np.ndarray:
        """Smoothed covariances ``P1_2s @ P1_2s^T``, shape ``(K, T, n, n)`` (formed fresh)."""
        return self[1] @ np.swapaxes(self[1], -1, -2)


def fleet_rts_smoother(fleet, result, dts=None, fx_args: Mapping[str, Any] | None = None) -> FleetSmoothed:
    """The square-root unscented RTS smoother for every filter of a fleet.

    See :meth:`squkf.Fleet.rts_smoother`.

    Parameters
    ----------
    fleet : Fleet
        Supplies ``fx``, the sigma-point family, the hooks, ``Q`` (shared or
        per filter) and ``dt``.
    result : FleetResult
        From ``fleet.batch_filter(zs, keep="all")``.
    dts : None, float or array_like of shape (T,)
        ``dts[k]``: time step of the prediction into step ``k`` (as given to
        ``batch_filter``; default the fleet's ``dt``).
    fx_args : dict, optional
        Keyword arguments of ``fx`` at every step (arrays with a leading axis
        of length K are per filter, as for :meth:`squkf.Fleet.predict`).

    Returns
    -------
    FleetSmoothed
        ``(means (K, T, n), P1_2s (K, T, n, n), Gs (K, T, n, n))`` with
        ``failed`` and ``failure`` attached.
    """
    c = fleet.configuration()  # the fleet's in-place edits taken first
    if not isinstance(result, FleetResult):
        raise ParameterError(
            "result must be the FleetResult of Fleet.batch_filter(..., keep='all'),"
            f" got {type(result).__name__}"
        )
    if result.means is None or result.P1_2s is None:
        raise ParameterError(
            "result holds no factors: the smoother needs every step's mean and factor, "
            "from Fleet.batch_filter(..., keep='all')"
        )
    K, n = fleet.n_filters, c.dim_x
    xs = as_float_array(result.means, "result.means")
    if xs.ndim != 3 or xs.shape[0] != K or xs.shape[2] != n:
        raise ShapeError(f"result.means has shape {xs.shape}, expected ({K}, T, {n})")
    T = xs.shape[1]
    Ss = as_float_array(result.P1_2s, "result.P1_2s")
    if Ss.shape != (K, T, n, n):
        raise ShapeError(f"result.P1_2s has shape {Ss.shape}, expected {(K, T, n, n)}")
    failed = np.asarray(result.failed)
    if failed.shape != (K,) or failed.dtype != bool:
        raise ShapeError(f"result.failed must be bools of shape ({K},), got {failed.dtype} {failed.shape}")
    for name, a in (("result.means", xs), ("result.P1_2s", Ss)):
        finite = np.isfinite(a).all(axis=tuple(range(2, a.ndim)))  # (K, T), also for T = 0
        if not finite.all():
            j, k = (int(i) for i in np.argwhere(~finite)[0])
            raise NonFiniteError(f"{name}[{j}, {k}] (filter {j}, step {k}) contains NaN or inf")
    if np.any(np.triu(Ss, 1)):
        j, k = (int(i) for i in np.argwhere(np.triu(Ss, 1).any(axis=(2, 3)))[0])
        raise ParameterError(f"result.P1_2s[{j}, {k}] is not lower triangular")
    diag = np.diagonal(Ss, axis1=-2, axis2=-1)
    if not np.all(diag[~failed] != 0):
        j, k = (int(i) for i in np.argwhere((diag == 0).any(axis=2) & ~failed[:, None])[0])
        raise NotPositiveDefiniteError(f"result.P1_2s[{j}, {k}] has a zero on its diagonal")
    Ss = Ss * np.copysign(1.0, diag)[..., None, :]  # a column's sign leaves S S^T unchanged
    dt_list = per_step(dts, T, "dts", "dt", default=c.dt, ref="result")
    kwargs = with_filter_axis(model_kwargs(fx_args, "fx_args"), K)
    Q1_2, fx = c.Q1_2, c.fx

    def fx_eval(k: int, X: np.ndarray):
        return fx(X.copy(), dt_list[k + 1], **kwargs)

    out = _backward(
        xs,
        Ss,
        fx_eval,
        lambda k: Q1_2,
        c.plan.first,
        c.hooks,
        isolate=failed.copy(),
        label=lambda k: f"dts[{k + 1}]",
        kernels=c.kernels,
    )
    new = np.flatnonzero(out.failed & ~failed)
    if fleet.on_error == "raise" and new.size:
        raise failures_error({j: out.failure[j] for j in new.tolist()}, " while smoothing")
    return FleetSmoothed(out.xs, out.Ss, out.Gs, out.failed, out.failure)
