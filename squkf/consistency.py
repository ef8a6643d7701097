"""Is a filter consistent? NEES and NIS, their chi-square bands, and the whiteness of innovations.

A consistent filter's errors are as large as its covariances say. Three tests
of that, by the textbook (Bar-Shalom, Li and Kirubarajan, *Estimation with
Applications to Tracking and Navigation*, 5.4):

- :func:`nees`: the normalised estimation error squared ``e^T P^-1 e`` of each
  step, ``e = truth - mean`` (needs the truth: simulations);
- :func:`nis`: the normalised innovation squared ``y^T S^-1 y`` that
  ``batch_filter`` records at each step (needs nothing but the measurements);
- :func:`check`: their mean over runs against a two-sided chi-square band,
  step by step and over the whole run, with a verdict
  (:class:`Consistency`);
- :func:`whiteness`: whether the whitened innovations are white, by their
  autocorrelation, the Ljung-Box statistic of each component and Hosking's
  multivariate portmanteau statistic (:class:`Whiteness`).

Every covariance is read as its lower factor (``P = S S^T``) and every
quadratic form is a triangular solve; nothing is inverted.

The module needs numpy and scipy only (``scipy.stats``, imported when a band
or a p-value is computed); :meth:`Consistency.plot` needs matplotlib (the
``plot`` extra).
"""

from __future__ import annotations

import html
import math
from collections.abc import Sequence
from dataclasses import dataclass
from numbers import Integral, Real
from typing import Any, NamedTuple

import numpy as np

from .batch import BatchResult
from .boundary.records import FleetResult
from .checks import as_float_array, as_measurements, check_flag, describe_nonfinite, short_repr
from .errors import FleetStepError, NonFiniteError, NotPositiveDefiniteError, ParameterError, ShapeError
from .fleet import Fleet
from .linalg import solve_lower, tria

__all__ = [
    "nees", "nis", "check", "Consistency", "whiteness", "Whiteness", "monte_carlo", "MonteCarlo",
    "MonteCarloRun", "wilson_interval",
]  # fmt: skip

#: the verdicts of :func:`check`
CONSISTENT = "consistent"
TOO_LARGE = "too large: overconfident (P or S too small)"
TOO_SMALL = "too small: pessimistic (P or S too large)"


# -- checks of the arguments ---------------------------------------------------------------------


def _pyplot(who: str) -> Any:
    """matplotlib's pyplot, or the ModuleNotFoundError that names the ``plot`` extra."""
    try:
        import matplotlib.pyplot as plt
    except ImportError as exc:
        raise ModuleNotFoundError(
            f'{who} needs matplotlib, the plot extra: pip install "squkf[plot]" ({exc})', name=exc.name
        ) from exc
    return plt


def _probability(level: Any) -> float:
    """``level`` as a float in the open interval (0, 1)."""
    if isinstance(level, (bool, np.bool_)) or not isinstance(level, (Real, np.floating, np.integer)):
        raise ParameterError(f"level must be a probability in (0, 1), got level={short_repr(level)}")
    value = float(level)
    if not 0.0 < value < 1.0:  # NaN fails too
        raise ParameterError(f"level must be a probability in the open interval (0, 1), got level={value!r}")
    return value


def _require_finite(a: np.ndarray, name: str) -> None:
    if not np.isfinite(a).all():
        where = tuple(int(i) for i in np.argwhere(~np.isfinite(a))[0])
        raise NonFiniteError(f"{name} is not finite: entry {where} holds {a[where]}")


def _components(idx: Any, n: int) -> np.ndarray:
    """``idx`` as distinct non-negative component indices below ``n``."""
    try:
        sel = np.asarray(idx)
    except (TypeError, ValueError):
        sel = np.asarray(None)
    if sel.ndim != 1 or sel.size == 0 or sel.dtype.kind not in "iu":
        raise ParameterError(
            f"idx must be a non-empty sequence of component indices (integers), got idx={short_repr(idx)}"
        )
    if (sel < -n).any() or (sel >= n).any():
        raise ParameterError(f"idx holds an index out of range for {n} components: idx={short_repr(idx)}")
    sel = sel % n
    if np.unique(sel).size != sel.size:
        raise ParameterError(f"idx names a component twice: idx={short_repr(idx)}")
    return sel


def _nonsingular(S: np.ndarray, what: str) -> None:
    """Refuse a stack of lower factors with a zero on a diagonal."""
    d = np.diagonal(S, axis1=-2, axis2=-1)
    if (d == 0).any():
        where = tuple(int(i) for i in np.argwhere(d == 0)[0])
        raise NotPositiveDefiniteError(
            f"{what} is singular: diagonal entry {where[-1]} is zero"
            + (f" at index {where[:-1]}" if len(where) > 1 else "")
        )


# -- NEES and NIS --------------------------------------------------------------------------------


def nees(
    truth: Any,
    means: Any,
    P1_2s: Any,
    *,
    idx: Sequence[int] | np.ndarray | None = None,
) -> np.ndarray:
    """The normalised estimation error squared of each step, ``e^T P^-1 e`` with ``e = truth - means``.

    Computed as ``w . w`` with ``w = S^-1 e`` by a triangular solve with the
    lower factor ``S`` of ``P = S S^T`` (``P`` is never formed or inverted).
    For a consistent filter each value is chi-square with ``n`` degrees of
    freedom (``len(idx)`` with ``idx``); judge them with :func:`check`.

    Parameters
    ----------
    truth : array_like, shape (..., n)
        The true states, e.g. ``(runs, steps, n)`` from a simulation.
    means : array_like, shape (..., n)
        The filter's estimates (posterior means of ``batch_filter``, or
        ``FleetResult.means``).
    P1_2s : array_like, shape (..., n, n)
        Lower factors of the covariances (``return_factors=True`` of
        ``batch_filter``, or ``FleetResult.P1_2s``); only the lower triangle is
        read, and the sign of each column does not matter.
        The leading shapes of the three arguments must be equal or broadcast
        (one ``truth`` of shape ``(steps, n)`` for many runs' ``means``).
    idx : sequence of int, optional, keyword-only
        The NEES of these components only (e.g. ``[0, 2]``, the positions),
        from the marginal covariance ``P[idx][:, idx] = S[idx, :] S[idx, :]^T``,
        whose factor comes from one QR factorisation of the rows ``S[idx, :]``
        (:func:`squkf.linalg.tria`). Distinct, negative counting from the end.

    Returns
    -------
    ndarray, shape (...)
        The broadcast leading shape (0-d for one step).

    Raises
    ------
    ShapeError
        ``truth``, ``means`` or ``P1_2s`` not of the shapes above (the message
        names the argument), or not a real numeric array.
    NonFiniteError
        A NaN or infinity in ``truth``, ``means`` or ``P1_2s``, named.
    ParameterError
        ``idx`` not distinct integer indices below ``n``.
    NotPositiveDefiniteError
        A factor with a zero on its diagonal (a singular covariance).

    Examples
    --------
    >>> import numpy as np
    >>> from squkf import consistency
    >>> S = np.array([[2.0, 0.0], [1.0, 1.0]])      # P = S S^T = [[4, 2], [2, 2]]
    >>> float(consistency.nees([2.0, 1.0], [0.0, 0.0], S))  # [2, 1] P^-1 [2, 1]^T
    1.0
    >>> float(consistency.nees([2.0, 1.0], [0.0, 0.0], S, idx=[0]))  # 2^2 / 4
    1.0

    Runs and steps at once (the same factor for each):

    >>> rng = np.random.default_rng(0)
    >>> errors = rng.standard_normal((400, 50, 2)) @ S.T     # e ~ N(0, P)
    >>> consistency.nees(errors, np.zeros(2), S).shape
    (400, 50)
    """
    x = as_float_array(truth, "truth")
    xm = as_float_array(means, "means")
    S = as_float_array(P1_2s, "P1_2s")
    if x.ndim < 1 or x.shape[-1] == 0:
        raise ShapeError(f"truth must have shape (..., n) with n >= 1 components, got shape {x.shape}")
    n = x.shape[-1]
    if xm.ndim < 1 or xm.shape[-1] != n:
        raise ShapeError(f"means must have shape (..., {n}) as truth {x.shape} has, got shape {xm.shape}")
    if S.ndim < 2 or S.shape[-2:] != (n, n):
        raise ShapeError(f"P1_2s must have shape (..., {n}, {n}) for {n} components, got shape {S.shape}")
    try:
        np.broadcast_shapes(x.shape[:-1], xm.shape[:-1])
    except ValueError:
        raise ShapeError(
            f"means of shape {xm.shape} does not match truth of shape {x.shape}: their leading shapes"
            " must be equal or broadcast"
        ) from None
    try:
        np.broadcast_shapes(x.shape[:-1], xm.shape[:-1], S.shape[:-2])
    except ValueError:
        raise ShapeError(
            f"P1_2s of shape {S.shape} does not match truth {x.shape} and means {xm.shape}: the leading"
            " shapes must be equal or broadcast"
        ) from None
    _require_finite(x, "truth")
    _require_finite(xm, "means")
    _require_finite(S, "P1_2s")
    e = x - xm
    what = "P1_2s"
    if idx is not None:
        sel = _components(idx, n)
        e = e[..., sel]
        # the rows S[idx, :] as columns: tria(A) factors A^T A = S[idx, :] S[idx, :]^T
        S = tria(np.ascontiguousarray(np.swapaxes(np.tril(S)[..., sel, :], -1, -2)))
        what = f"the marginal factor of components {sel.tolist()} of P1_2s"
    _nonsingular(S, what)
    k = e.shape[-1]
    if S.ndim == 2:  # one factor for every step: its solve with all of them as columns
        w = solve_lower(S, e.reshape(-1, k).T).T
    else:
        batch = np.broadcast_shapes(e.shape[:-1], S.shape[:-2])
        w = solve_lower(np.broadcast_to(S, batch + (k, k)), np.broadcast_to(e, batch + (k,)))
    return np.einsum("...i,...i->...", w, w).reshape(np.broadcast_shapes(e.shape[:-1], S.shape[:-2]))


def nis(result: Any) -> np.ndarray:
    """The normalised innovation squared ``y^T S^-1 y`` of each step of a batch run.

    The values ``batch_filter`` recorded (computed there from the innovation
    factor ``S1_2``, never by inverting ``S``), as a new array. For a consistent
    filter each is chi-square with ``m`` degrees of freedom, ``m`` the number of
    components measured; judge them with :func:`check`.

    A step with nothing measured (every component NaN, or rejected by the gate)
    holds 0, as does every step of a fleet's filter after it failed
    (``FleetResult.failed``): leave such steps or filters out before
    :func:`check` (``values[~result.failed]``), and note that a step with a
    partial measurement has fewer degrees of freedom.

    Parameters
    ----------
    result : BatchResult or FleetResult
        What :meth:`SquareRootUKF.batch_filter <squkf.SquareRootUKF.batch_filter>`
        returns (:class:`squkf.batch.BatchResult`, ``nis`` of shape ``(T,)``) or
        what :meth:`Fleet.batch_filter <squkf.Fleet.batch_filter>` returns
        (:class:`squkf.FleetResult`, ``nis`` of shape ``(K, T)``), run with a
        ``keep=`` that keeps per-step records (not ``"final"``); a
        :mod:`squkf.dask` result's lazy ``nis`` is computed.

    Returns
    -------
    ndarray, shape (T,) or (K, T)

    Raises
    ------
    ParameterError
        ``result`` has no per-step NIS: a fleet run with ``keep="final"``, or
        anything else than a batch run's result.
    """
    if isinstance(result, FleetResult) and result.nis is None:
        raise ParameterError(
            "result holds no per-step NIS: the fleet ran with keep='final'; run Fleet.batch_filter with"
            " keep='all', 'diagonals' or 'means', which keep each step's records"
        )
    values = np.asarray(result.nis) if isinstance(result, (BatchResult, FleetResult)) else None
    if values is None or values.ndim not in (1, 2) or values.dtype.kind not in "fiu":
        raise ParameterError(
            "result must be what batch_filter returns (a BatchResult of SquareRootUKF.batch_filter or a"
            f" FleetResult of Fleet.batch_filter), with per-step NIS; got {type(result).__name__}"
        )
    return np.array(values, dtype=float)


# -- bands ---------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Consistency:
    """What :func:`check` found: mean values against their chi-square bands, and a verdict.

    Every value and band is on the scale :func:`check` was asked for: the
    degrees-of-freedom scale (target ``dof``) or, with ``normalised``, divided
    by ``dof`` (target 1).

    Attributes
    ----------
    mean : ndarray, shape (steps,)
        The mean over runs at each step.
    band : tuple of float
        ``(low, high)``: the two-sided band that holds the mean of one step
        with probability ``level`` for a consistent filter
        (``runs * mean ~ chi2(runs * dof)``).
    inside : ndarray of bool, shape (steps,)
        Whether each step's mean is inside ``band`` (ends included).
    fraction_inside : float
        The fraction of steps inside; about ``level`` for a consistent filter.
    time_average : float
        The mean over all runs and steps.
    time_band : tuple of float
        Its band (``runs * steps * time_average ~ chi2(runs * steps * dof)``).
        Exact for NIS, whose innovations are white; too narrow for NEES,
        whose errors are correlated in time.
    verdict : str
        ``"consistent"`` when ``time_average`` is inside ``time_band``, else
        ``"too large: overconfident (P or S too small)"`` or
        ``"too small: pessimistic (P or S too large)"``.
    dof : float
        Degrees of freedom of one value.
    runs, steps : int
    level : float
    normalised : bool
    """

    mean: np.ndarray
    band: tuple[float, float]
    inside: np.ndarray
    fraction_inside: float
    time_average: float
    time_band: tuple[float, float]
    verdict: str
    dof: float
    runs: int
    steps: int
    level: float
    normalised: bool

    @property
    def target(self) -> float:
        """The expected value of one value: ``dof``, or 1 when ``normalised``."""
        return 1.0 if self.normalised else self.dof

    def _lines(self) -> list[tuple[str, str]]:
        lo, hi = self.band
        tlo, thi = self.time_band
        return [
            ("runs x steps", f"{self.runs} x {self.steps}"),
            ("degrees of freedom", f"{self.dof:g}"),
            ("scale", f"{'normalised (/ dof)' if self.normalised else 'dof'}, target {self.target:g}"),
            ("level", f"{self.level:g}"),
            ("per-step band", f"[{lo:.4g}, {hi:.4g}]"),
            (
                "steps inside",
                f"{int(self.inside.sum())} of {self.steps} ({self.fraction_inside:.1%})",
            ),
            ("time average", f"{self.time_average:.4g}"),
            ("time-average band", f"[{tlo:.4g}, {thi:.4g}]"),
            ("verdict", self.verdict),
        ]

    def __repr__(self) -> str:
        lines = self._lines()
        width = max(len(k) for k, _ in lines)
        return "Consistency(\n" + "\n".join(f"  {k:<{width}}  {v}" for k, v in lines) + "\n)"

    def _repr_html_(self) -> str:
        rows = "".join(
            f"<tr><th style='text-align:left'>{html.escape(k)}</th><td style='text-align:left'>"
            f"{html.escape(v)}</td></tr>"
            for k, v in self._lines()
        )
        return f"<table><caption>Consistency</caption>{rows}</table>"

    def plot(self, ax: Any = None) -> Any:
        """Draw the mean over runs at each step, its band shaded, and the target.

        Parameters
        ----------
        ax : matplotlib.axes.Axes, optional
            Where to draw; a new figure's axes if None.

        Returns
        -------
        matplotlib.axes.Axes

        Raises
        ------
        ModuleNotFoundError
            matplotlib is not installed (``pip install "squkf[plot]"``).
        """
        plt = _pyplot("Consistency.plot")
        if ax is None:
            _, ax = plt.subplots()
        k = np.arange(self.steps)
        lo, hi = self.band
        ax.fill_between(k, lo, hi, alpha=0.25, color="C0", lw=0, label=f"{self.level:g} band")
        ax.plot(k, self.mean, color="C1", label=f"mean over {self.runs} run{'s' if self.runs > 1 else ''}")
        ax.axhline(self.target, color="k", lw=0.8, ls="--", label=f"target {self.target:g}")
        ax.set_xlabel("step")
        ax.set_ylabel("mean / dof" if self.normalised else "mean")
        ax.set_title(f"{self.fraction_inside:.0%} of steps inside; {self.verdict}")
        ax.legend()
        return ax


def check(
    values: Any, dof: float, *, level: float = 0.95, normalised: bool = False, white: bool = True
) -> Consistency:
    """Test NEES or NIS values against their chi-square bands.

    For a consistent filter, ``M`` independent runs' values at one step are
    chi-square with ``dof`` degrees of freedom each, so ``M`` times their mean
    is chi-square with ``M * dof``: the mean lies in
    ``chi2.ppf([(1 - level) / 2, (1 + level) / 2], M * dof) / M`` with
    probability ``level``. The mean over all ``N`` steps as well has its band,
    ``chi2.ppf(..., N * M * dof) / (N * M)``, which treats the steps as
    independent: exact for NIS (a consistent filter's innovations are white),
    too narrow for NEES (its errors are correlated from step to step, so the
    time average of NEES strays out of this band more often than
    ``1 - level``; judge NEES by the per-step band and ``fraction_inside``).

    Values are on the degrees-of-freedom scale (a consistent filter's mean is
    ``dof``), as filterpy's ``NEES``, nrl-tracker and kalman-py report them.
    ``normalised=True`` divides every value and band by ``dof`` (target 1), as
    Stone Soup and ukfm report them.

    Parameters
    ----------
    values : array_like, shape (M, N) or (N,)
        ``M`` runs of ``N`` steps of NEES (:func:`nees`) or NIS (:func:`nis`);
        one run as a 1-D array. Finite and non-negative.
    dof : float
        Degrees of freedom of one value: the state's dimension (or
        ``len(idx)``) for NEES, the measurement's for NIS.
    level : float, keyword-only
        The probability each band holds, in (0, 1). Default 0.95.
    normalised : bool, keyword-only
        Report values divided by ``dof``. Default False.
    white : bool, keyword-only
        Whether the values are independent from step to step (NIS; the
        default): the verdict is then the time average's against its band.
        ``False`` (NEES, whose errors are correlated in time) reads the
        verdict from the per-step bands instead: consistent while
        ``fraction_inside`` is at least ``level`` less three binomial
        standard deviations, ``sqrt(level (1 - level) / N)``; else too large
        or too small by the side most steps left their band on.

    Returns
    -------
    Consistency

    Raises
    ------
    ShapeError
        ``values`` not of shape ``(M, N)`` or ``(N,)`` with ``M, N >= 1``.
    NonFiniteError
        A NaN or infinity in ``values``.
    ParameterError
        A negative value, ``dof`` not a positive number, ``level`` outside
        (0, 1), ``normalised`` not a bool.

    Examples
    --------
    400 runs of 50 steps of a consistent filter's NEES in 2 dimensions:

    >>> import numpy as np
    >>> from squkf import consistency
    >>> rng = np.random.default_rng(1)
    >>> values = rng.chisquare(2, size=(400, 50))
    >>> c = consistency.check(values, 2)
    >>> c.verdict, bool(0.85 < c.fraction_inside <= 1.0)
    ('consistent', True)
    >>> lo, hi = c.band
    >>> print(f"{lo:.3f} {hi:.3f}")
    1.809 2.201
    >>> consistency.check(3.0 * values, 2).verdict
    'too large: overconfident (P or S too small)'
    >>> consistency.check(values, 2, normalised=True).target
    1.0
    """
    v = as_float_array(values, "values")
    if v.ndim == 1:
        v = v[None]
    if v.ndim != 2 or v.size == 0:
        raise ShapeError(f"values must have shape (runs, steps) or (steps,), not empty, got shape {v.shape}")
    _require_finite(v, "values")
    if (v < 0).any():
        where = tuple(int(i) for i in np.argwhere(v < 0)[0])
        raise ParameterError(f"values must be NEES or NIS, never negative: entry {where} holds {v[where]}")
    if (
        isinstance(dof, (bool, np.bool_))
        or not isinstance(dof, (Real, np.floating, np.integer))
        or not (math.isfinite(float(dof)) and float(dof) > 0)
    ):
        raise ParameterError(
            f"dof must be a positive number of degrees of freedom, got dof={short_repr(dof)}"
        )
    k = float(dof)
    p = _probability(level)
    norm = check_flag(normalised, "normalised")
    from scipy.stats import chi2  # scipy.stats takes a while to import: only when used

    M, N = v.shape
    tails = np.array([(1.0 - p) / 2.0, (1.0 + p) / 2.0])
    band = chi2.ppf(tails, M * k) / M
    time_band = chi2.ppf(tails, N * M * k) / (N * M)
    mean = v.mean(axis=0)
    average = float(v.mean())
    inside = (mean >= band[0]) & (mean <= band[1])
    if check_flag(white, "white"):
        above, below = average > time_band[1], average < time_band[0]
    else:
        tolerance = 3.0 * math.sqrt(p * (1.0 - p) / N)
        poor = float(inside.mean()) < p - tolerance
        high, low = int(np.count_nonzero(mean > band[1])), int(np.count_nonzero(mean < band[0]))
        above, below = poor and high >= low, poor and low > high
    verdict = TOO_LARGE if above else TOO_SMALL if below else CONSISTENT
    scale = k if norm else 1.0
    return Consistency(
        mean=mean / scale,
        band=(float(band[0] / scale), float(band[1] / scale)),
        inside=inside,
        fraction_inside=float(inside.mean()),
        time_average=average / scale,
        time_band=(float(time_band[0] / scale), float(time_band[1] / scale)),
        verdict=verdict,
        dof=k,
        runs=M,
        steps=N,
        level=p,
        normalised=norm,
    )


# -- whiteness -----------------------------------------------------------------------------------


class Whiteness(NamedTuple):
    """What :func:`whiteness` found. For a batch of series, each field has the batch's leading shape.

    Attributes
    ----------
    autocorrelation : ndarray, shape (..., lags, m)
        ``autocorrelation[..., k - 1, j]``: the sample autocorrelation at lag
        ``k`` of whitened component ``j``.
    bound : float or ndarray, shape (...)
        ``z / sqrt(T)``, ``z`` the standard normal's ``(1 + level) / 2``
        quantile: a white series' autocorrelation at each lag is within
        ``+-bound`` with probability about ``level``.
    ljung_box : ndarray, shape (..., m)
        The Ljung-Box statistic of each whitened component, chi-square with
        ``lags`` degrees of freedom for a white series.
    ljung_box_pvalue : ndarray, shape (..., m)
    hosking : float or ndarray, shape (...)
        Hosking's multivariate portmanteau statistic, chi-square with
        ``m**2 * lags`` degrees of freedom for a white series.
    hosking_pvalue : float or ndarray, shape (...)
    lags : int
        The largest lag ``L``.
    steps : int or ndarray, shape (...)
        ``T``: the steps used (steps with a NaN left out).
    level : float
    """

    autocorrelation: np.ndarray
    bound: Any
    ljung_box: np.ndarray
    ljung_box_pvalue: np.ndarray
    hosking: Any
    hosking_pvalue: Any
    lags: int
    steps: Any
    level: float


def _portmanteau(w: np.ndarray, L: int) -> tuple[np.ndarray, np.ndarray, float]:
    """One series ``w`` (T, m): autocorrelations (L, m), Ljung-Box (m,), Hosking's statistic."""
    T, m = w.shape
    c = w - w.mean(axis=0)
    C = np.stack([c[k:].T @ c[: T - k] for k in range(L + 1)]) / T  # C[k] = sum_t c_t c_{t-k}^T / T
    var = np.diagonal(C[0]).copy()
    if (var == 0).any():
        raise NotPositiveDefiniteError(
            f"whitened innovation component {int(np.argmax(var == 0))} is constant over the {T} steps used:"
            " its autocorrelation is undefined"
        )
    r = np.diagonal(C[1:], axis1=-2, axis2=-1) / var  # (L, m)
    span = (T - np.arange(1, L + 1))[:, None]
    ljung_box = T * (T + 2) * (r**2 / span).sum(axis=0)
    L0 = tria(c / math.sqrt(T))  # L0 L0^T = C[0], from the series itself: nothing formed and factored again
    if (np.diagonal(L0) == 0).any():
        raise NotPositiveDefiniteError(
            f"the whitened innovations' lag-0 covariance is singular over the {T} steps used"
            f" (fewer than m + 1 = {m + 1} steps, or components that are linearly dependent)"
        )
    # tr(C_k^T C0^-1 C_k C0^-1) = ||L0^-1 C_k L0^-T||_F^2
    A = solve_lower(L0, np.swapaxes(solve_lower(L0, C[1:]), -1, -2))
    hosking = T * T * float(((A**2).sum(axis=(-2, -1)) / span[:, 0]).sum())
    return r, ljung_box, hosking


def whiteness(innovations: Any, S1_2s: Any, lags: int | None = None, *, level: float = 0.95) -> Whiteness:
    """Whether the whitened innovations of a filter are white: autocorrelation and portmanteau tests.

    Each innovation is whitened by its factor, ``w_t = S1_2_t^-1 y_t`` (a
    triangular solve): for a consistent filter the ``w_t`` are independent
    standard normal vectors. Of the whitened series, mean removed, with ``T``
    steps and ``C_k = sum_t c_t c_{t-k}^T / T`` its lag-``k`` autocovariance:

    - the autocorrelation ``r_k = C_k[j, j] / C_0[j, j]`` of each component
      ``j`` at lags ``k = 1..L``, and the bound ``z / sqrt(T)`` a white
      series' ``r_k`` stays within with probability about ``level``;
    - the Ljung-Box statistic of each component,
      ``Q = T (T + 2) sum_k r_k^2 / (T - k)``, chi-square with ``L`` degrees of
      freedom for a white series, and its p-value;
    - Hosking's multivariate statistic
      ``Q_m = T^2 sum_k tr(C_k^T C_0^-1 C_k C_0^-1) / (T - k)``, chi-square
      with ``m^2 L`` degrees of freedom, and its p-value (computed with the
      factor of ``C_0``, which is never inverted).

    **Missing measurements.** A step whose innovation holds a NaN (a component
    not measured) is left out whole, and the steps around it are treated as
    consecutive: for a white series that changes nothing, as its steps are
    independent. Its ``S1_2`` is not read.

    Parameters
    ----------
    innovations : array_like, shape (..., T, m)
        The innovations ``y`` of each step (``ukf.y`` after each update);
        leading axes are separate series (runs), each tested on its own.
    S1_2s : array_like, shape (..., T, m, m) or (m, m)
        The lower factors of the innovation covariances (``ukf.S1_2`` after
        each update), broadcast against ``innovations``' leading shape.
    lags : int, optional
        The largest lag ``L``, from 1 to ``T - 1``. Default
        ``max(1, min(10, T // 5))``, ``T`` the steps used (of the shortest
        series).
    level : float, keyword-only
        The probability of the autocorrelation's bound, in (0, 1). Default 0.95.

    Returns
    -------
    Whiteness

    Raises
    ------
    ShapeError
        ``innovations`` or ``S1_2s`` not of the shapes above (named), or
        fewer than 2 steps without a NaN.
    NonFiniteError
        An infinity in ``innovations``, or a NaN or infinity in a factor of a
        step used.
    ParameterError
        ``lags`` not an integer from 1 to ``T - 1``; ``level`` outside (0, 1).
    NotPositiveDefiniteError
        A factor of a step used with a zero on its diagonal, or a whitened
        series whose lag-0 covariance is singular (a constant component, or
        fewer than ``m + 1`` steps).

    Examples
    --------
    >>> import numpy as np
    >>> from squkf import consistency
    >>> rng = np.random.default_rng(2)
    >>> S1_2 = np.array([[1.0, 0.0], [0.5, 2.0]])
    >>> y = rng.standard_normal((200, 2)) @ S1_2.T        # white, covariance S1_2 S1_2^T
    >>> white = consistency.whiteness(y, S1_2)
    >>> white.lags, white.autocorrelation.shape, bool(white.hosking_pvalue > 0.05)
    (10, (10, 2), True)
    >>> drifting = np.cumsum(y, axis=0)                   # far from white
    >>> bool(consistency.whiteness(drifting, S1_2).ljung_box_pvalue.max() < 1e-6)
    True
    """
    y = as_float_array(innovations, "innovations")
    if y.ndim < 2 or 0 in y.shape[-2:]:
        raise ShapeError(f"innovations must have shape (..., T, m), T and m >= 1, got shape {y.shape}")
    T, m = y.shape[-2:]
    S = as_float_array(S1_2s, "S1_2s")
    if S.ndim < 2 or S.shape[-2:] != (m, m):
        raise ShapeError(f"S1_2s must have shape (..., {T}, {m}, {m}) or ({m}, {m}), got shape {S.shape}")
    try:
        S = np.broadcast_to(S, y.shape[:-1] + (m, m))
    except ValueError:
        raise ShapeError(
            f"S1_2s of shape {S.shape} does not match innovations of shape {y.shape}: one factor per"
            " innovation (or one for all)"
        ) from None
    if np.isinf(y).any():
        where = tuple(int(i) for i in np.argwhere(np.isinf(y))[0])
        raise NonFiniteError(f"innovations is not finite: entry {where} holds {y[where]} (NaN is missing)")
    used = ~np.isnan(y).any(axis=-1)  # (..., T)
    bad = used & ~np.isfinite(S).all(axis=(-2, -1))
    if bad.any():
        where = tuple(int(i) for i in np.argwhere(bad)[0])
        raise NonFiniteError(f"S1_2s is not finite at step {where}, whose innovation is measured")
    eye = np.eye(m)
    S = np.where(used[..., None, None], np.tril(S), eye)
    _nonsingular(S, "S1_2s")
    w = solve_lower(S, np.where(used[..., None], y, 0.0))
    steps = used.sum(axis=-1)
    shortest = int(steps.min())
    if shortest < 2:
        raise ShapeError(
            f"innovations has {shortest} step(s) without a NaN in a series: at least 2 are needed"
            " (a step with a NaN is left out)"
        )
    if lags is None:
        L = max(1, min(10, shortest // 5))
    elif isinstance(lags, (bool, np.bool_)) or not isinstance(lags, (Integral, np.integer)):
        raise ParameterError(f"lags must be an integer from 1 to T - 1, got lags={short_repr(lags)}")
    else:
        L = int(lags)
    if not 1 <= L <= shortest - 1:
        raise ParameterError(
            f"lags must be from 1 to T - 1 = {shortest - 1} (T = {shortest} steps used), got lags={L}"
        )
    p = _probability(level)
    from scipy.stats import chi2, norm  # scipy.stats takes a while to import: only when used

    flat_w: np.ndarray = w.reshape((-1, T, m))
    flat_used: np.ndarray = used.reshape((-1, T))
    count = int(flat_w.shape[0])
    r = np.empty((count, L, m))
    lb = np.empty((count, m))
    hk = np.empty(count)
    for b in range(count):
        r[b], lb[b], hk[b] = _portmanteau(flat_w[b][flat_used[b]], L)
    bound = norm.ppf((1.0 + p) / 2.0) / np.sqrt(steps)
    batch = y.shape[:-2]
    ljung_box = lb.reshape(batch + (m,))
    hosking = hk.reshape(batch)
    return Whiteness(
        autocorrelation=r.reshape(batch + (L, m)),
        bound=bound[()],
        ljung_box=ljung_box,
        ljung_box_pvalue=chi2.sf(ljung_box, L),
        hosking=hosking[()],
        hosking_pvalue=chi2.sf(hosking, m * m * L)[()],
        lags=L,
        steps=steps[()],
        level=p,
    )


# == Monte Carlo: configurations compared on the same runs ==========================================


class MonteCarloRun(NamedTuple):
    """One configuration's Monte Carlo runs (:func:`monte_carlo`).

    Attributes
    ----------
    rmse : ndarray, shape (T, n)
        Root mean squared error of the posterior mean, per step and component, over the runs that did
        not diverge.
    nees, nis : Consistency
        :func:`check` of the NEES (``n`` degrees of freedom) and the NIS (``m``) of those runs.
    diverged : float
        The share of runs that diverged: flagged by the fleet (a numerical failure), or with a NEES
        that is not finite.
    diverged_interval : tuple of float
        Wilson's score interval of that share, at the ``level`` asked.
    runs : int
    failures : dict
        Run -> why it diverged.
    """

    rmse: np.ndarray
    nees: Consistency
    nis: Consistency
    diverged: float
    diverged_interval: tuple[float, float]
    runs: int
    failures: dict


class MonteCarlo:
    """Configurations compared over the same runs (:func:`monte_carlo`): ``mc[name]`` is a
    :class:`MonteCarloRun`; :meth:`table` and :meth:`plot` put them side by side."""

    def __init__(self, results: dict[str, MonteCarloRun], level: float):
        self.results = results
        self.level = level

    def __getitem__(self, name: str) -> MonteCarloRun:
        return self.results[name]

    def __iter__(self):
        return iter(self.results)

    def __len__(self) -> int:
        return len(self.results)

    def table(self):
        """One row per configuration: RMSE (over steps and components), average NEES and NIS with their
        bands' verdicts, the share of steps in band, the diverged share and its interval.

        A pandas ``DataFrame`` if pandas is installed, else a dict of arrays (one entry per column).
        """
        columns: dict[str, list] = {k: [] for k in _TABLE_COLUMNS}
        for name, r in self.results.items():
            values = (
                name, float(np.sqrt(np.nanmean(r.rmse**2))), r.nees.time_average, r.nees.verdict,
                r.nees.fraction_inside, r.nis.time_average, r.nis.verdict, r.nis.fraction_inside,
                r.diverged, r.diverged_interval[0], r.diverged_interval[1],
            )  # fmt: skip
            for key, value in zip(_TABLE_COLUMNS, values):
                columns[key].append(value)
        try:
            import pandas
        except ImportError:
            return {k: np.array(v) for k, v in columns.items()}
        return pandas.DataFrame(columns).set_index("configuration")

    def __repr__(self) -> str:
        lines = [f"MonteCarlo of {len(self)} configuration(s), level {self.level:g}:"]
        for name, r in self.results.items():
            rmse = float(np.sqrt(np.nanmean(r.rmse**2)))
            lines.append(
                f"  {name}: RMSE {rmse:.4g}, NEES {r.nees.time_average:.3g} ({r.nees.verdict}),"
                f" NIS {r.nis.time_average:.3g} ({r.nis.verdict}), diverged {r.diverged:.1%} of {r.runs}"
            )
        return "\n".join(lines)

    def plot(self, axes=None):
        """RMSE, NEES and NIS per step, one line per configuration (the ``plot`` extra).

        Parameters
        ----------
        axes : sequence of 3 matplotlib Axes, optional
            Made in a new figure when not given.

        Returns
        -------
        axes : the three Axes
        """
        plt = _pyplot("MonteCarlo.plot")
        if axes is None:
            _, axes = plt.subplots(1, 3, figsize=(12, 3.5))
        for name, r in self.results.items():
            steps = np.arange(1, r.rmse.shape[0] + 1)
            axes[0].plot(steps, np.sqrt(np.mean(r.rmse**2, axis=1)), label=name)
            axes[1].plot(steps, r.nees.mean, label=name)
            axes[2].plot(steps, r.nis.mean, label=name)
        for ax, title in zip(axes, ("RMSE", "NEES", "NIS")):
            ax.set_title(title)
            ax.set_xlabel("step")
        axes[0].legend()
        return axes


_TABLE_COLUMNS = (
    "configuration", "rmse", "nees", "nees verdict", "nees in band", "nis", "nis verdict", "nis in band",
    "diverged", "diverged low", "diverged high",
)  # fmt: skip


def wilson_interval(successes: int, trials: int, level: float = 0.95) -> tuple[float, float]:
    """Wilson's score interval for a binomial proportion ``successes / trials`` at confidence ``level``.

    Parameters
    ----------
    successes, trials : int
        ``0 <= successes <= trials``, ``trials >= 1``.
    level : float
        In (0, 1).

    Returns
    -------
    (low, high) : tuple of float
    """
    level = _probability(level)
    if trials < 1 or not 0 <= successes <= trials:
        raise ParameterError(f"a proportion needs 0 <= successes <= trials >= 1, got {successes}/{trials}")
    from scipy.stats import norm  # (imported when used: importing squkf stays light)

    z = float(norm.ppf(0.5 + level / 2))
    p = successes / trials
    denom = 1 + z * z / trials
    centre = (p + z * z / (2 * trials)) / denom
    half = z * np.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / denom
    return max(0.0, centre - half), min(1.0, centre + half)


def monte_carlo(
    filters, truth, zs, *, level: float = 0.95, dts=None, fx_args=None, hx_args=None
) -> MonteCarlo:
    """Filter every run with each configuration, all runs of one in one fleet, and judge them.

    Parameters
    ----------
    filters : SquareRootUKF or dict of str to SquareRootUKF
        The template(s): each configuration runs from its template's ``x``,
        ``P``, ``Q`` and ``R`` on every run. The templates are read, never
        changed. ``fx`` and ``hx`` of a vectorised template must take
        stacked points ``(..., N, dim_x)`` (a fleet's), as for
        :meth:`Fleet.from_filters`; a per-point template's are called per
        point.
    truth : array_like, shape (runs, T, dim_x)
        The true states at the measurements (:func:`squkf.simulate`'s, or
        another model's, for a mismatch study).
    zs : array_like, shape (runs, T, dim_z)
        The measurements; NaN entries are missing, as in ``batch_filter``.
    level : float
        Of the NEES and NIS bands and of the diverged share's interval, in (0, 1).
    dts, fx_args, hx_args : optional
        As :meth:`Fleet.batch_filter` takes them.

    Returns
    -------
    MonteCarlo
        Per configuration a :class:`MonteCarloRun`.

    Raises
    ------
    ShapeError
        ``truth`` and ``zs`` disagree in runs or steps, or with a template's dimensions.
    NonFiniteError
        ``truth`` holds NaN or inf.
    ParameterError
        ``filters`` is empty or not filters; ``level`` outside (0, 1).
    """
    level = _probability(level)
    templates = _templates(filters)
    X = as_float_array(truth, "truth")
    Z = as_measurements(zs, "zs")
    if X.ndim != 3 or Z.ndim != 3 or X.shape[:2] != Z.shape[:2]:
        raise ShapeError(
            f"truth has shape {X.shape} and zs {Z.shape}: expected (runs, T, dim_x) and (runs, T, dim_z)"
        )
    if not np.all(np.isfinite(X)):
        raise NonFiniteError(describe_nonfinite(X, "truth"))
    runs = X.shape[0]
    results = {}
    for name, template in templates.items():
        c = template.configuration()
        if (c.dim_x, c.dim_z) != (X.shape[2], Z.shape[2]):
            raise ShapeError(
                f"filters[{name!r}] has dim_x={c.dim_x}, dim_z={c.dim_z} but truth and zs have {X.shape[2]}"
                f" and {Z.shape[2]} components"
            )
        fleet = Fleet.from_template(template, runs)
        result = fleet.batch_filter(Z, dts=dts, keep="all", fx_args=fx_args, hx_args=hx_args)
        failed = np.asarray(result.failed)
        failures = {int(k): str(fleet.failure[k]) for k in np.flatnonzero(failed).tolist()}
        ok = ~failed
        if not ok.any():
            order = sorted(failures)
            raise FleetStepError(f"every run of {name!r} diverged", order, [failures[k] for k in order])
        means = np.asarray(result.means)[ok]
        e = nees(X[ok], means, np.asarray(result.P1_2s)[ok])
        rmse = np.sqrt(np.mean((means - X[ok]) ** 2, axis=0))
        results[name] = MonteCarloRun(
            rmse, check(e, c.dim_x, level=level, white=False),
            check(np.asarray(result.nis)[ok], c.dim_z, level=level),
            len(failures) / runs, wilson_interval(len(failures), runs, level), runs, failures,
        )  # fmt: skip
    return MonteCarlo(results, level)


def _templates(filters) -> dict[str, Any]:
    """``filters`` as named templates: one filter is ``{"filter": it}``."""
    from .ukf import SquareRootUKF

    if isinstance(filters, SquareRootUKF):
        return {"filter": filters}
    if not isinstance(filters, dict) or not filters:
        raise ParameterError(
            f"filters must be a SquareRootUKF or a dict of named ones, got {short_repr(filters)}"
        )
    for name, f in filters.items():
        if not isinstance(f, SquareRootUKF):
            raise ParameterError(f"filters[{name!r}] is not a squkf.SquareRootUKF: got {short_repr(f)}")
    return {str(k): v for k, v in filters.items()}
