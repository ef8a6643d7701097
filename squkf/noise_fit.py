"""``Q`` and ``R`` fitted by maximum likelihood, every candidate an optimiser asks for in one fleet pass.

:func:`fit_noise` moves the parameters ``theta`` of two parametrisations
(:mod:`squkf.parametrise`) to maximise the exact innovation log-likelihood of
the recordings (:mod:`squkf.candidates`: each candidate a filter of one fleet).
Whatever an optimiser asks for at once is one fleet pass: a point with the
forward differences of its residuals (``"least_squares"``, the default: the
log-likelihood written as residuals, below, for scipy's ``least_squares``), a
point with the central differences of its gradient (``"quasi_newton"``: scipy's
L-BFGS-B given the value and gradient of each pass), a population of
differential evolution, or a grid (in as few passes as ``max_filters``
allows). The least-squares forms end with Newton's method on the
finite-difference Hessian of ``-log L`` (plus the prior's terms), whose last pass
is at the optimum: that Hessian, the observed information, costs no pass more
(the objective keeps every candidate's exact log-likelihood), and its inverse is
``theta``'s covariance.

As residuals (as LowLevelParticleFilters.jl writes it): each update's whitened
innovation ``S1_2^-1 y`` (its measured components) and one residual per update,
``sqrt(2 log det S1_2 + c)``, so that half their sum of squares is
``-log L`` up to a constant; ``c`` keeps every root real (it is fixed from the
start's values with a margin, and a candidate below it restarts the solver from
the best point so far with a larger ``c``). The Gauss-Newton matrix of these
residuals is not the information of a variance, so the fit's covariance comes
from the Hessian of the exact ``-log L`` all the same.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from .boundary.loop import progress_callback
from .candidates import Candidates, all_failed, candidate_factors, check_template, evaluate, recordings
from .errors import ParameterError, ShapeError, SqukfError
from .parametrise import Scaled

__all__ = ["NoiseFit", "fit_noise", "METHODS"]

METHODS = ("least_squares", "quasi_newton", "differential_evolution", "grid")

#: the step of the central differences in theta (log-variances: a relative change of 1e-4)
GRADIENT_STEP = 1e-4
#: the step of the residuals' forward differences (their rounding, about 1e-15, over it stays near 1e-9)
RESIDUAL_STEP = 1e-6
#: what ``c`` leaves above ``-2 log det S1_2`` at the start (a candidate may have a smaller det: e**-8 of it)
C_MARGIN = 16.0
#: the margin a restart adds above the lowest ``-2 log det S1_2`` seen, more at each restart
RESTART_MARGIN = 16.0
#: restarts of the least-squares solver before it stops where it is
MAX_RESTARTS = 8
#: iterations of the batched Gauss-Newton method before its problems go to Newton's method all the same
LM_ITERATIONS = 50
#: where the least-squares phase hands over to Newton's method: a step that gains less than this in
#: ``log L`` (the Gauss-Newton model converges only linearly near an optimum, where its matrix misses
#: the log-determinant's curvature; Newton's method on the exact Hessian ends it in a step or two)
HANDOVER = 1e-2
#: Newton's method stops where its step would gain less than this in ``log L`` (the issue's optima agree
#: to 1e-3)
NEWTON_TOL = 1e-5
#: the step of the Hessian's differences (its rounding error in f, about 1e-9, over h**2 stays small)
HESSIAN_STEP = 1e-3
#: an eigenvalue of the information below this times the largest is a direction the data do not fix
WEAK = 1e-8
#: scipy's smallest tolerance (below it a condition is off, with a warning)
EPS = float(np.finfo(float).eps)


@dataclass
class NoiseFit:
    """What :func:`fit_noise` found.

    Attributes
    ----------
    Q, R : ndarray
        The fitted covariances (the template's where not fitted).
    x, P : ndarray or None
        The fitted initial state and covariance, where a ``Custom`` sets them.
    theta : ndarray, shape (p,)
        The parameters at the optimum (``Q``'s first, then ``R``'s).
    names : list of str
    theta_cov : ndarray, shape (p, p)
        The inverse of the observed information (inf on a direction the data do not fix).
    log_likelihood : float
        The exact log-likelihood at the optimum (summed over the recordings).
    log_likelihood_template : float
        At the template's own values.
    success : bool
    message : str
    method : str
    passes : int
        Fleet passes run.
    filter_steps : int
        Filter-steps run, over all passes.
    failures : dict
        Candidate ``theta`` (a tuple) -> why it failed, the first 20.
    identifiable : bool
        Whether every eigenvalue of the information is above ``1e-8`` times the largest.
    weak_directions : list of dict
        For each eigenvalue that is not: the eigenvector's components by parameter name.
    surface : tuple (thetas (G, p), values (G,)) or None
        The grid and its log-likelihoods (``method="grid"``; with a ``prior``,
        less its ``|r|^2 / 2``: the log-posterior up to a constant).
    """

    Q: np.ndarray
    R: np.ndarray
    x: np.ndarray | None
    P: np.ndarray | None
    theta: np.ndarray
    names: list[str]
    theta_cov: np.ndarray
    log_likelihood: float
    log_likelihood_template: float
    success: bool
    message: str
    method: str
    passes: int
    filter_steps: int
    failures: dict = field(default_factory=dict)
    identifiable: bool = True
    weak_directions: list = field(default_factory=list)
    surface: tuple | None = None
    _parts: tuple = field(default=(), repr=False)

    def intervals(self, level: float = 0.95) -> dict:
        """Confidence intervals of the fitted quantities on their natural scale.

        Computed on ``theta`` (normal, with ``theta_cov``) and mapped through
        the parametrisation: as endpoints for ``Scaled`` (the scale) and
        ``Diagonal`` (the variances), by the delta method for ``Full`` (the
        matrix entries), on ``theta`` itself for ``Custom``.

        Parameters
        ----------
        level : float
            In (0, 1).

        Returns
        -------
        dict
            ``{"Q": {...}, "R": {...}}``, each ``{quantity: (estimate, low, high)}``.
        """
        if isinstance(level, bool) or not isinstance(level, (int, float)) or not 0.0 < float(level) < 1.0:
            raise ParameterError(f"level must be a probability in (0, 1), got level={level!r}")
        from scipy.stats import norm  # (imported when used: importing squkf stays light)

        z = float(norm.ppf(0.5 + float(level) / 2))
        out = {}
        for label, (param, M0, sl) in zip(("Q", "R"), self._parts):
            out[label] = param.natural(self.theta[sl], self.theta_cov[sl, sl], M0, z)
        return out

    def apply(self, ukf) -> None:
        """Set the fitted ``Q`` and ``R`` (and ``x``, ``P`` where fitted) on the filter ``ukf``."""
        ukf.Q, ukf.R = self.Q, self.R
        if self.x is not None:
            ukf.x = self.x
        if self.P is not None:
            ukf.P = self.P

    def __repr__(self) -> str:
        sd = np.sqrt(np.maximum(np.diagonal(self.theta_cov), 0.0)) if self.theta.size else np.zeros(0)
        lines = [
            f"NoiseFit ({self.method}): {'converged' if self.success else 'not converged'}: {self.message}",
            f"  log-likelihood {self.log_likelihood:.6g} (template's {self.log_likelihood_template:.6g}),"
            f" {self.passes} fleet passes, {self.filter_steps} filter-steps",
        ]
        for name, value, s in zip(self.names, self.theta, sd):
            lines.append(f"  {name} = {value:.6g} ± {s:.3g}")
        if not self.identifiable:
            lines.append(f"  not identifiable: {len(self.weak_directions)} weak direction(s)")
        if self.failures:
            lines.append(f"  {len(self.failures)} candidate(s) failed")
        lines.append(f"  Q = {np.array2string(self.Q, precision=4)}".replace("\n", "\n      "))
        lines.append(f"  R = {np.array2string(self.R, precision=4)}".replace("\n", "\n      "))
        return "\n".join(lines)


class _Objective:
    """``-log L(theta) + |prior(theta)|^2 / 2`` of many candidates at once, one fleet pass per call."""

    def __init__(self, ukf, Z, burn_in, parts, prior, kwargs, max_filters):
        self.ukf, self.Z, self.burn_in, self.parts = ukf, Z, burn_in, parts
        self.prior, self.kwargs, self.max_filters = prior, kwargs, max_filters
        self.passes = 0
        self.filter_steps = 0
        self.failures: dict[tuple, str] = {}
        # the exact log-likelihood of every candidate run, by (theta's bytes, its recording or -1): asked
        # again (the start, a stencil's centre, the optimum's Hessian after Newton's last step) it costs
        # no pass
        self._known: dict[tuple[bytes, int], float] = {}
        self.after_pass: Callable[[int], object] | None = None  # progress: called with the pass's index
        # the template's values, read once: what a candidate that does not set one keeps
        self.template = {k: _as_floats(getattr(ukf, k)) for k in ("Q", "R", "x", "P")}

    def loglik(self, thetas: np.ndarray, rec: np.ndarray | None = None) -> np.ndarray:
        """The exact log-likelihood of each candidate, ``(K,)`` (-inf: failed): summed over every
        recording, or (``rec``, ``(K,)``) on its own recording ``Z[rec[k]]``."""
        return self._passes(thetas, rec, False)[0]

    def whitened(self, thetas: np.ndarray, rec: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Each candidate's whitened innovations ``(K, S, T', m)`` and ``log det S1_2`` ``(K, S, T')`` on
        every recording after the burn-in (NaN for a failed candidate), or (``rec``, ``(K,)``) on its own
        recording ``Z[rec[k]]``, ``(K, T', m)`` and ``(K, T')``."""
        _, W, L = self._passes(thetas, rec, True)
        return W, L

    def _passes(self, thetas: np.ndarray, rec: np.ndarray | None, whitened: bool) -> tuple:
        """The candidates ``thetas`` run in as few fleet passes as ``max_filters`` allows (usually one):
        each one's log-likelihood ``(K,)`` summed over the recordings (or on its own, ``rec``), and, with
        ``whitened``, its whitened records (else None). Invalid or failed candidates: ``-inf``, NaN."""
        thetas = np.atleast_2d(np.asarray(thetas, dtype=float))
        K = thetas.shape[0]
        S, T, m = self.Z.shape
        each = (S,) if rec is None else ()
        loglik = np.full(K, -np.inf)
        W = np.full((K, *each, T - self.burn_in, m), np.nan) if whitened else None
        L = np.full((K, *each, T - self.burn_in), np.nan) if whitened else None
        recs = np.full(K, -1) if rec is None else np.asarray(rec)
        keys = [(t.tobytes(), int(r)) for t, r in zip(thetas, recs)]
        todo = np.arange(K)
        if not whitened:
            known = np.array([key in self._known for key in keys], dtype=bool)
            loglik[known] = [self._known[keys[k]] for k in np.flatnonzero(known)]
            todo = np.flatnonzero(~known)
        per_pass = max(1, self.max_filters // S) if rec is None else self.max_filters
        for start in range(0, todo.size, per_pass):
            part = todo[start : start + per_pass]
            cand, failures = self._candidates(thetas[part])
            good = [j for j in range(part.size) if j not in failures]
            if good:
                sub = Candidates(*(None if a is None else a[good] for a in cand))
                Z = self.Z if rec is None else self.Z[rec[part[good]]]
                done = evaluate(
                    self.ukf, Z, sub, len(good), self.burn_in, self.kwargs, paired=rec is not None,
                    whitened=whitened,
                )  # fmt: skip
                self._counted(len(good) * (S if rec is None else 1) * T)
                totals = done.loglik.sum(axis=1) if rec is None else done.loglik
                loglik[part[good]] = totals
                if W is not None and L is not None:
                    W[part[good]], L[part[good]] = done.y_whitened, done.log_det_S1_2
                for j, why in done.failures.items():
                    failures[good[j]] = why
            for j in failures:
                loglik[part[j]] = -np.inf
            self._note(thetas[part], failures)
            for k in part:
                self._known[keys[k]] = float(loglik[k])
        return loglik, W, L

    def prior_residuals(self, theta: np.ndarray) -> np.ndarray:
        """The prior's residuals at ``theta`` (none without a prior), checked finite."""
        if self.prior is None:
            return np.zeros(0)
        r = np.asarray(self.prior(theta.copy()), dtype=float).reshape(-1)
        if not np.all(np.isfinite(r)):
            raise ParameterError(f"prior returned values not finite at theta={theta.tolist()}")
        return r

    def _counted(self, filter_steps: int) -> None:
        self.filter_steps += filter_steps
        self.passes += 1
        if self.after_pass is not None:
            self.after_pass(self.passes - 1)

    def _note(self, thetas: np.ndarray, failures: dict[int, str]) -> None:
        for k, why in failures.items():
            if len(self.failures) < 20:
                self.failures.setdefault(tuple(np.round(thetas[k], 12).tolist()), why)

    def __call__(self, thetas: np.ndarray, rec: np.ndarray | None = None) -> np.ndarray:
        """The objective of each candidate (``+inf`` for a failed one), as :meth:`loglik` reads ``rec``."""
        thetas = np.atleast_2d(np.asarray(thetas, dtype=float))
        f = -self.loglik(thetas, rec)
        if self.prior is not None:
            for k, theta in enumerate(thetas):
                r = self.prior_residuals(theta)
                f[k] += 0.5 * float(r @ r)
        return f

    def _candidates(self, thetas: np.ndarray) -> tuple[Candidates, dict[int, str]]:
        """The candidates' factors (and initial states) from their ``theta``, and those that are invalid."""
        K = thetas.shape[0]
        failures: dict[int, str] = {}
        mats: dict[str, list] = {"Q": [None] * K, "R": [None] * K, "x": [None] * K, "P": [None] * K}
        for label, (param, M0, sl) in zip(("Q", "R"), self.parts):
            try:
                out = param.matrices(thetas[:, sl], M0)
            except SqukfError as exc:
                raise ParameterError(f"the parametrisation of {label} ({param!r}) failed: {exc}") from None
            for k in range(K):
                value = out[k]
                if isinstance(value, dict):
                    for key, v in value.items():
                        if key not in mats:
                            raise ParameterError(
                                f"a Custom parametrisation set {key!r}: it may set Q, R, x and P"
                            )
                        mats[key][k] = v
                else:
                    mats[label][k] = value
        result: list[np.ndarray | None] = []
        for key in ("Q", "R", "x", "P"):
            column = mats[key]
            if all(v is None for v in column):
                result.append(None)
                continue
            result.append(self._column(key, column, failures))
        return Candidates(*result), failures

    def _column(self, key: str, column: list, failures: dict[int, str]) -> np.ndarray:
        default = self.template[key]
        shape = np.shape(default)
        values = np.empty((len(column),) + shape)
        for k, v in enumerate(column):
            a = np.asarray(default if v is None else v, dtype=float)
            if a.shape != shape:
                raise ShapeError(f"the parametrisation gave {key} of shape {a.shape}, expected {shape}")
            if not np.all(np.isfinite(a)):
                failures[k] = f"{key} is not finite"
                a = np.asarray(default, dtype=float)
            values[k] = a
        if key == "x":
            return values
        factors, bad = candidate_factors(values, key, shape[0])
        for k, why in bad.items():
            failures.setdefault(k, why)
        return factors


def fit_noise(
    ukf,
    zs,
    *,
    Q=None,
    R=None,
    method: str = "least_squares",
    grid=None,
    bounds=None,
    burn_in: int = 0,
    prior: Callable | None = None,
    shared: bool = True,
    seed=None,
    maxiter: int | None = None,
    max_filters: int = 20000,
    progress=False,
    dts=None,
    fx_args=None,
    hx_args=None,
) -> NoiseFit | list[NoiseFit]:
    """Fit ``Q`` and ``R`` of the template ``ukf`` to recordings by maximum (a posteriori) likelihood.

    Parameters
    ----------
    ukf : SquareRootUKF
        The template: model, configuration, ``x``, ``P``, and the ``Q``, ``R``
        the parametrisations start from. Never changed, whatever the outcome
        (an interrupt included).
    zs : array_like, shape (T, dim_z) or (S, T, dim_z), or a list of S recordings
        As :func:`squkf.tune.log_likelihood` takes them; S recordings fit one
        ``Q`` and ``R`` (``shared=True``).
    Q, R : parametrisation, optional
        :class:`~squkf.parametrise.Fixed`, ``Scaled`` (the default for both),
        ``Diagonal``, ``Full`` or ``Custom`` (:mod:`squkf.parametrise`).
        With ``fx_noise``/``hx_noise`` they are the noise's covariances.
    method : {"least_squares", "quasi_newton", "differential_evolution", "grid"}
        ``"least_squares"``: scipy's ``least_squares`` on the log-likelihood
        written as residuals (the whitened innovations and one
        ``sqrt(2 log det S1_2 + c)`` per update, the module's docstring says
        more), from the template's values, each evaluation one fleet pass of
        the point and its forward differences (the Jacobian).
        ``"quasi_newton"``: L-BFGS-B from the template's values, each step one
        fleet pass of the point and its central differences.
        ``"differential_evolution"``: scipy's, its population one fleet pass a
        generation, polished by the quasi-Newton method.
        ``"grid"``: the ``grid`` given, in as few passes as ``max_filters``
        allows; the surface is kept.
    grid : array_like, shape (G, p), optional
        The ``theta`` values of ``method="grid"``.
    bounds : sequence of p (low, high), optional
        On ``theta``, for every method; default the start ± ln 1000 (a
        variance within a factor of 1000 of the template's), which keeps a
        fit from collapsing a variance to zero where the likelihood grows
        without bound (a recording too short to tell ``Q`` from ``R``).
    burn_in : int
        Early steps left out of the likelihood.
    prior : callable, optional
        ``prior(theta) -> residuals``: ``|r|^2 / 2`` is added to ``-log L`` (a
        maximum a posteriori fit).
    shared : bool
        ``True``: the S recordings fit one ``Q`` and ``R``. ``False``: each
        recording gets its own fit (one sensor or asset per recording), all
        advancing together in the same fleet passes by a batched Gauss-Newton
        method on the residuals, then Newton's method on the
        finite-difference gradient and Hessian of the exact ``-log L`` (a
        trust region per problem); a list of S fits is returned. ``method``
        is then the default (or ``"quasi_newton"``, the same).
    seed : optional
        Of differential evolution.
    maxiter : int, optional
        Of the optimiser.
    max_filters : int
        The most filters in one fleet pass (memory).
    progress : bool or callable
        ``True`` shows a tqdm bar over the fleet passes (the ``progress``
        extra); a callable is called with each pass's index after it.
    dts, fx_args, hx_args : optional
        As :meth:`squkf.Fleet.batch_filter` takes them.

    Returns
    -------
    NoiseFit, or a list of S with ``shared=False``

    Raises
    ------
    ParameterError
        A gated template, an unknown method (or one other than the default
        with ``shared=False``), nothing to fit, a bad grid, bounds or start.
    ShapeError, NonFiniteError
        Recordings of the wrong shape, or with no measurement.
    FleetStepError
        Every candidate of a pass failed, at the start or on the whole grid.
    CallSequenceError
        The template has an ask pending.
    """
    if method not in METHODS:
        raise ParameterError(f"method must be one of {', '.join(map(repr, METHODS))}, got method={method!r}")
    if not isinstance(shared, (bool, np.bool_)):
        raise ParameterError(f"shared must be True or False, got shared={shared!r}")
    if not shared and method not in ("least_squares", "quasi_newton"):
        raise ParameterError(
            "shared=False fits every recording together by a batched least-squares and Newton method:"
            f" method={method!r} is for shared fits (leave method at its default)"
        )
    c = ukf.configuration()
    Z, _ = recordings(zs, c.dim_z)
    check_template(ukf, burn_in, Z.shape[1])
    Q = Scaled() if Q is None else Q
    R = Scaled() if R is None else R
    Q0, R0 = np.atleast_2d(np.array(ukf.Q, dtype=float)), np.atleast_2d(np.array(ukf.R, dtype=float))
    pq, pr = Q.size(Q0), R.size(R0)
    parts = ((Q, Q0, slice(0, pq)), (R, R0, slice(pq, pq + pr)))
    theta0 = np.concatenate([Q.start(Q0, ukf.Q1_2), R.start(R0, ukf.R1_2)])
    p = theta0.size
    if p == 0:
        raise ParameterError("nothing to fit: Q and R are both Fixed()")
    names = Q.names("Q", Q0) + R.names("R", R0)
    kwargs = {"dts": dts, "fx_args": fx_args, "hx_args": hx_args}
    if isinstance(max_filters, bool) or not isinstance(max_filters, int) or max_filters < 1:
        raise ParameterError(f"max_filters must be a positive integer, got {max_filters!r}")
    objective = _Objective(ukf, Z, burn_in, parts, prior, kwargs, max_filters)
    lo_hi = _bounds(bounds, theta0, p)
    bar, objective.after_pass = progress_callback(progress, None)
    try:
        return _fit(objective, method, theta0, names, lo_hi, grid, shared, seed, maxiter)
    finally:
        if bar is not None:
            bar.close()


def _fit(objective: _Objective, method: str, theta0, names, lo_hi, grid, shared, seed, maxiter):
    """:func:`fit_noise` once its inputs are checked: the optimiser, then the fit at its optimum."""
    p = theta0.size
    if not shared:
        return _fit_each(objective, theta0, names, lo_hi, 50 if maxiter is None else maxiter)
    surface = None
    f0: float
    if method == "grid":
        G = _grid(grid, p)
        values = objective(np.vstack([theta0, G]))
        f0, fg = float(values[0]), values[1:]
        if not np.any(np.isfinite(fg)):
            raise all_failed({k: "failed" for k in range(G.shape[0])}, "grid point")
        best = int(np.argmin(fg))
        theta, success, message = G[best].copy(), True, f"the best of {G.shape[0]} grid points"
        surface = (G.copy(), -fg)
    elif method == "differential_evolution":
        f0 = float(objective(theta0[None])[0])
        from scipy.optimize import differential_evolution

        res = differential_evolution(
            lambda X: objective(np.asarray(X).T),
            list(zip(*lo_hi)),
            vectorized=True,
            updating="deferred",
            seed=seed,
            polish=False,  # polished below, each step one pass (scipy's polish evaluates one point at a time)
            tol=1e-6,
            maxiter=1000 if maxiter is None else maxiter,
            x0=np.clip(theta0, *lo_hi),
        )
        theta, success, message = _quasi_newton(objective, np.asarray(res.x, dtype=float), lo_hi, None)
        success = success and bool(res.success)
        message = f"{res.message}; polished: {message}"
    elif method == "least_squares":
        theta, success, message = _least_squares(objective, theta0, lo_hi, maxiter)
        f0 = float(objective(theta0[None])[0])  # (known from the first pass)
        polished, ok = _batched_newton(
            objective, theta[None], None, lo_hi, 50 if maxiter is None else maxiter
        )
        theta, success = polished[0], success and bool(ok[0])
        message = (
            f"{message.rstrip('.')}; then Newton's method on the exact Hessian:"
            f" {'converged' if ok[0] else 'stopped'}"
        )
    else:
        f0 = float(objective(theta0[None])[0])
        if not math.isfinite(f0):
            raise all_failed({0: next(iter(objective.failures.values()), "failed")}, "start")
        theta, success, message = _quasi_newton(objective, theta0, lo_hi, maxiter)
    H, f_hat = _hessian(objective, theta)
    cov, identifiable, weak = _covariance(H, names)
    loglik_hat = float(objective.loglik(theta[None])[0])
    Qf, Rf, xf, Pf = _fitted(objective, theta)
    return NoiseFit(
        Q=Qf, R=Rf, x=xf, P=Pf, theta=theta, names=names, theta_cov=cov, log_likelihood=loglik_hat,
        log_likelihood_template=-f0 if objective.prior is None else float(objective.loglik(theta0[None])[0]),
        success=success and math.isfinite(f_hat), message=message, method=method, passes=objective.passes,
        filter_steps=objective.filter_steps, failures=dict(objective.failures), identifiable=identifiable,
        weak_directions=weak, surface=surface, _parts=objective.parts,
    )  # fmt: skip


def _fit_each(
    objective: _Objective, theta0: np.ndarray, names: list[str], lo_hi, maxiter: int
) -> list[NoiseFit]:
    """``shared=False``: one fit per recording, all advancing together (:func:`_batched_least_squares`)."""
    B = objective.Z.shape[0]
    own = np.arange(B)
    thetas, _ = _batched_least_squares(objective, theta0, B, lo_hi, min(maxiter, LM_ITERATIONS))
    f0 = objective(np.tile(theta0, (B, 1)), own)  # (known from the first pass)
    if not np.any(np.isfinite(f0)):
        raise all_failed({b: "failed at the start" for b in range(B)}, "recording")
    thetas, success = _batched_newton(objective, thetas, own, lo_hi, maxiter)
    left = np.flatnonzero(~success)
    if left.size:  # where no optimum was reached from there: Newton's method from the start, the better kept
        again, done = _batched_newton(objective, np.tile(theta0, (left.size, 1)), left, lo_hi, maxiter)
        f = objective(np.vstack([thetas[left], again]), np.concatenate([left, left]))
        better = f[left.size :] < f[: left.size]
        thetas[left[better]], success[left[better]] = again[better], done[better]
    Hs = _hessians(objective, thetas)
    loglik = objective.loglik(thetas, own)
    t0 = objective.loglik(np.tile(theta0, (B, 1)), own) if objective.prior is not None else -f0
    fits = []
    for b in range(B):
        cov, identifiable, weak = _covariance(Hs[b], names)
        Qf, Rf, xf, Pf = _fitted(objective, thetas[b])
        fits.append(
            NoiseFit(
                Q=Qf,
                R=Rf,
                x=xf,
                P=Pf,
                theta=thetas[b],
                names=names,
                theta_cov=cov,
                log_likelihood=float(loglik[b]),
                log_likelihood_template=float(t0[b]),
                success=bool(success[b]) and math.isfinite(loglik[b]),
                message="converged"
                if success[b]
                else "stopped short of an optimum (no step lowered -log L, or the iterations ran out)",
                method="batched_least_squares",
                passes=objective.passes,
                filter_steps=objective.filter_steps,
                failures=dict(objective.failures),
                identifiable=identifiable,
                weak_directions=weak,
                _parts=objective.parts,
            )  # fmt: skip
        )
    return fits


class _RestartError(Exception):
    """A candidate's ``log det S1_2`` fell below ``-c / 2``: the solver restarts with a larger ``c``."""

    def __init__(self, c: float):
        self.c = c


class _Residuals:
    """The log-likelihood as residuals at a point, with their forward-difference Jacobian from the same
    fleet pass (kept for the solver's ``jac`` call at that point)."""

    def __init__(self, objective: _Objective):
        self.objective = objective
        Z = objective.Z[:, objective.burn_in :]
        self.measured = ~np.isnan(Z)  # (S, T', m): the whitened innovation's entries that are residuals
        self.updated = self.measured.any(axis=-1)  # (S, T'): the updates, each a log det residual
        self.c = math.nan
        self.restarts = 0
        self.best: tuple[float, np.ndarray] | None = None  # (-log L + prior, theta): where a restart starts
        self._kept: tuple[bytes, np.ndarray, np.ndarray] | None = None

    def rows(self, thetas: np.ndarray) -> np.ndarray:
        """The residuals of each candidate ``(K, r)`` (inf for a failed one), from one fleet pass."""
        W, L = self.objective.whitened(thetas)
        logdets = L[:, self.updated]
        if math.isnan(self.c) and np.isfinite(logdets[0]).any():  # the first point: c from its own values
            self.c = -2.0 * float(np.nanmin(logdets[0])) + C_MARGIN
        lowest = np.nanmin(logdets, initial=np.inf)
        if 2.0 * lowest + self.c < 0.0 and self.restarts < MAX_RESTARTS:
            self.restarts += 1
            raise _RestartError(-2.0 * lowest + RESTART_MARGIN * self.restarts)
        prior = [self.objective.prior_residuals(theta) for theta in thetas]
        with np.errstate(invalid="ignore"):
            roots = np.sqrt(2.0 * logdets + self.c)
        rows = np.concatenate([W[:, self.measured], roots, np.array(prior)], axis=1)
        rows[~np.all(np.isfinite(rows), axis=1)] = np.inf  # (an imaginary root too, past the restarts)
        for theta, logdet, w, r in zip(thetas, logdets, W[:, self.measured], prior):
            if np.all(np.isfinite(logdet)):
                f = 0.5 * float(w @ w) + float(logdet.sum()) + 0.5 * float(r @ r)
                if self.best is None or f < self.best[0]:
                    self.best = (f, theta.copy())
        return rows

    def __call__(self, theta: np.ndarray) -> np.ndarray:
        """The residuals at ``theta``, and (kept) their Jacobian: ``theta`` and its steps in one pass."""
        if self._kept is not None and self._kept[0] == theta.tobytes():
            return self._kept[1]
        p, h = theta.size, RESIDUAL_STEP
        rows = self.rows(np.vstack([theta, theta + h * np.eye(p)]))
        r = rows[0]
        if np.all(np.isfinite(r)):
            J = (rows[1:] - r) / h
            back = np.flatnonzero(~np.all(np.isfinite(J), axis=1))
            if back.size:  # a step that failed: backward differences on those axes (one pass more)
                J[back] = (r - self.rows(theta - h * np.eye(p)[back])) / h
            self._kept = (theta.tobytes(), r, J.T)
        return r

    def jacobian(self, theta: np.ndarray, r: np.ndarray | None = None) -> np.ndarray:
        """The Jacobian at ``theta`` ``(r, p)``: the one kept by the call at ``theta``."""
        if self._kept is None or self._kept[0] != theta.tobytes():
            self(theta)
        assert self._kept is not None
        return self._kept[2]


def _least_squares(objective: _Objective, theta0: np.ndarray, lo_hi, maxiter: int | None):
    """scipy's ``least_squares`` (trust region, within the bounds) on the log-likelihood's residuals, each
    evaluation one fleet pass of the point and its forward steps."""
    from scipy.optimize import least_squares

    residuals = _Residuals(objective)
    theta = theta0
    budget = 200 if maxiter is None else maxiter
    while True:
        try:
            r = residuals(theta)
            if not np.all(np.isfinite(r)):
                raise all_failed({0: next(iter(objective.failures.values()), "failed")}, "start")
            res = least_squares(
                residuals,
                theta,
                jac=residuals.jacobian,
                bounds=lo_hi,
                method="trf",
                x_scale="jac",
                ftol=max(
                    HANDOVER / max(0.5 * float(r @ r), 1.0), EPS
                ),  # (scipy's ftol is relative to the cost)
                xtol=1e-9,
                gtol=1e-9,
                max_nfev=budget,
            )
        except _RestartError as restart:
            residuals.c, residuals._kept = restart.c, None  # (what was kept had the old c)
            assert residuals.best is not None
            theta = np.clip(residuals.best[1], *lo_hi)
            continue
        return np.asarray(res.x, dtype=float), bool(res.status > 0), str(res.message)


def _quasi_newton(objective: _Objective, theta0: np.ndarray, lo_hi, maxiter: int | None):
    """L-BFGS-B from ``theta0``, each step the value and gradient of one fleet pass."""
    from scipy.optimize import minimize

    res = minimize(
        lambda t: _value_and_gradient(objective, t),
        theta0,
        jac=True,
        method="L-BFGS-B",
        bounds=None if lo_hi is None else list(zip(*lo_hi)),
        options={"maxiter": 200 if maxiter is None else maxiter},
    )
    return np.asarray(res.x, dtype=float), bool(res.success), str(res.message)


def _value_and_gradient(objective: _Objective, theta: np.ndarray) -> tuple[float, np.ndarray]:
    """The objective at ``theta`` and its central-difference gradient, in one fleet pass."""
    p = theta.size
    h = GRADIENT_STEP
    E = h * np.eye(p)
    values = objective(np.vstack([theta, theta + E, theta - E]))
    if not np.all(np.isfinite(values)):
        return 1e300, np.zeros(p)  # a wall: the line search steps back from a failed candidate
    return float(values[0]), (values[1 : p + 1] - values[p + 1 :]) / (2 * h)


def _stencil(theta: np.ndarray, h: float) -> np.ndarray:
    """The points of the central differences at ``theta``: itself, ``+/- h`` on each axis, and the four
    corners of each pair of axes, ``(2 p^2 + 1, p)``."""
    p = theta.size
    points = [theta]
    for i in range(p):
        for s in (1.0, -1.0):
            e = np.zeros(p)
            e[i] = s * h
            points.append(theta + e)
    for i in range(p):
        for j in range(i + 1, p):
            for si, sj in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
                e = np.zeros(p)
                e[i], e[j] = si * h, sj * h
                points.append(theta + e)
    return np.array(points)


def _derivatives(f: np.ndarray, p: int, h: float) -> tuple[float, np.ndarray, np.ndarray]:
    """The value, the gradient and the Hessian from the objective at :func:`_stencil`'s points."""
    f0 = float(f[0])
    g = np.empty(p)
    H = np.empty((p, p))
    for i in range(p):
        fp, fm = f[1 + 2 * i], f[2 + 2 * i]
        g[i] = (fp - fm) / (2 * h)
        H[i, i] = (fp - 2 * f0 + fm) / (h * h)
    n = 1 + 2 * p
    for i in range(p):
        for j in range(i + 1, p):
            fpp, fpm, fmp, fmm = f[n : n + 4]
            H[i, j] = H[j, i] = (fpp - fpm - fmp + fmm) / (4 * h * h)
            n += 4
    return f0, g, H


def _hessian(objective: _Objective, theta: np.ndarray) -> tuple[np.ndarray, float]:
    """The finite-difference Hessian of the objective at ``theta``, every point in one fleet pass."""
    f0, _, H = _derivatives(objective(_stencil(theta, HESSIAN_STEP)), theta.size, HESSIAN_STEP)
    return H, f0


def _hessians(objective: _Objective, thetas: np.ndarray) -> np.ndarray:
    """The finite-difference Hessian of each problem's objective at its ``theta`` (problem ``b`` on
    recording ``b``), ``(B, p, p)``, every point in one fleet pass."""
    B, p = thetas.shape
    h = HESSIAN_STEP
    n_points = 2 * p * p + 1
    f = objective(np.concatenate([_stencil(t, h) for t in thetas]), np.repeat(np.arange(B), n_points))
    return np.array([_derivatives(row, p, h)[2] for row in f.reshape(B, n_points)])


def _batched_least_squares(objective: _Objective, theta0: np.ndarray, B: int, lo_hi, maxiter: int):
    """``B`` fits from ``theta0``, problem ``b`` on recording ``b``, advancing together: a Gauss-Newton
    method in a trust region (one radius per problem, as :func:`_batched_newton`'s) on each problem's
    residuals (the log-likelihood as the least-squares form writes it, the module's docstring), the model
    the Gauss-Newton matrix plus a secant estimate of the residuals' own curvature.

    Each iteration is one fleet pass: every active problem's trial point and its forward steps (the
    Jacobian there, kept if the trial is taken). A trial is taken when it lowers the exact objective
    (``-log L``, plus the prior's ``|r|^2 / 2``), whatever the constant ``c`` of its roots, which is set
    per problem from its first point and raised (a margin below the lowest ``-2 log det S1_2`` seen)
    whenever a root would be imaginary: ``c`` shapes the model, never the acceptance. A problem is handed
    on (to :func:`_batched_newton`) where its model is convex and its whole step would gain less than
    :data:`HANDOVER` in ``log L``, or where it cannot go on.

    Returns
    -------
    thetas : ndarray, shape (B, p)
    handed : ndarray of bool, shape (B,)
        Whether the problem reached the hand-over (else it stopped: a failed step, or the iterations ran out).
    """
    p = theta0.size
    h = RESIDUAL_STEP
    lo, hi = lo_hi
    Z = objective.Z[:, objective.burn_in :]
    measured = ~np.isnan(Z)  # (B, T', m)
    updated = measured.any(axis=-1)  # (B, T')
    thetas = np.tile(theta0, (B, 1))
    trials = thetas.copy()
    f_now = np.full(B, np.inf)
    c = np.full(B, np.nan)
    radius = np.ones(B)
    predicted = np.zeros(B)
    done = np.zeros(B, dtype=bool)
    handed = np.zeros(B, dtype=bool)
    steps = np.eye(p) * h
    # the model at each problem's current point: the gradient, the Hessian made positive (_positive)
    models: list[tuple[np.ndarray, np.ndarray] | None] = [None] * B
    convex = np.zeros(B, dtype=bool)
    last: list[tuple[np.ndarray, np.ndarray, np.ndarray] | None] = [None] * B  # theta, J, r at the last point
    second = np.zeros((B, p, p))  # the structured secant part: the residuals' own curvature
    for _ in range(maxiter + 1):
        active = np.flatnonzero(~done)
        if active.size == 0:
            break
        points = np.concatenate([np.vstack([trials[b], trials[b] + steps]) for b in active])
        W, L = objective.whitened(points, np.repeat(active, p + 1))
        for j, b in enumerate(active):
            rows = slice(j * (p + 1), (j + 1) * (p + 1))
            w, ld = W[rows][:, measured[b]], L[rows][:, updated[b]]
            prior = np.array([objective.prior_residuals(t) for t in points[rows]])
            f_trial = 0.5 * float(w[0] @ w[0]) + float(ld[0].sum()) + 0.5 * float(prior[0] @ prior[0])
            moved = float(np.linalg.norm(trials[b] - thetas[b]))
            if not math.isfinite(f_trial) or f_trial > f_now[b]:
                radius[b] = moved / 4.0  # a worse trial: a shorter step from where it is
            else:
                if models[b] is not None:
                    radius[b] = _new_radius(radius[b], moved, _ratio(f_now[b] - f_trial, predicted[b]))
                thetas[b], f_now[b] = trials[b], f_trial
                finite = np.all(np.isfinite(ld), axis=1)
                lowest = float(np.min(ld[finite]))
                if math.isnan(c[b]) or 2.0 * lowest + c[b] < 0.0:
                    c[b] = -2.0 * lowest + C_MARGIN
                with np.errstate(invalid="ignore"):
                    R = np.concatenate([w, np.sqrt(2.0 * ld + c[b]), prior], axis=1)
                J = (R[1:] - R[0]) / h  # (p, r)
                if not np.all(np.isfinite(J)):  # a step failed: the filters break next to it (Newton's turn)
                    done[b] = True
                    continue
                g = J @ R[0]
                before = last[b]
                if before is not None:
                    theta_old, J_old, r_old = before
                    s_b, y_b = thetas[b] - theta_old, g - J_old @ r_old
                    second[b] = _secant_update(second[b], s_b, y_b, (J - J_old) @ R[0])
                last[b] = (thetas[b].copy(), J, R[0])
                A = J @ J.T + second[b]
                convex[b], models[b] = _positive(0.5 * (A + A.T), g)
            model = models[b]
            if model is None or radius[b] < 1e-10:
                done[b] = True  # failed at its start, or no step lowers it: it stays where it is
                continue
            if convex[b] and _decrement(thetas[b], *model, lo, hi) <= HANDOVER:
                done[b] = handed[b] = True
                continue
            trials[b], predicted[b] = _trust_step(thetas[b], *model, radius[b], lo, hi)
    return thetas, handed


def _batched_newton(
    objective: _Objective, thetas: np.ndarray, problems: np.ndarray | None, lo_hi, maxiter: int
) -> tuple[np.ndarray, np.ndarray]:
    """Problems from ``thetas`` ``(B, p)`` advancing together by Newton's method in a trust region (one
    radius per problem) on the finite-difference gradient and Hessian of the exact objective: problem ``b``
    on recording ``problems[b]``, or (``problems`` None, ``B = 1``) on every recording.

    Each iteration is one fleet pass: the central-difference stencil (:func:`_stencil`) at every active
    problem's trial point, whose centre says whether the trial is taken and whose differences give the next
    step. Curvatures are taken in absolute value, with a floor, so that a step goes downhill where the
    Hessian is not positive; the radius, in ``theta``'s units, bounds the step where the model is not to be
    trusted (along a variance the data barely fix, the curvature is tiny and the Newton step long), and
    does not shorten it elsewhere as a damping scaled by the largest curvature would. A problem converges
    where its Newton step would gain less than :data:`NEWTON_TOL` in ``log L``: its last stencil is then
    the one at its optimum, and the observed information there costs no further pass (the objective knows
    those values).

    Returns
    -------
    thetas : ndarray, shape (B, p)
    success : ndarray of bool, shape (B,)
    """
    B, p = thetas.shape
    h = HESSIAN_STEP
    lo, hi = lo_hi
    current, trials = thetas.copy(), thetas.copy()
    f_now = np.full(B, np.inf)
    predicted = np.zeros(B)  # what the model predicted the trial would gain
    # the model at each problem's current point: the gradient, the Hessian made positive (_positive)
    models: list[tuple[np.ndarray, np.ndarray] | None] = [None] * B
    radius = np.ones(B)
    done = np.zeros(B, dtype=bool)
    success = np.zeros(B, dtype=bool)
    n_points = 2 * p * p + 1
    for _ in range(maxiter + 1):
        active = np.flatnonzero(~done)
        if active.size == 0:
            break
        points = np.concatenate([_stencil(trials[b], h) for b in active])
        rec = None if problems is None else np.repeat(problems[active], n_points)
        f = objective(points, rec).reshape(active.size, n_points)
        for row, b in enumerate(active):
            moved = float(np.linalg.norm(trials[b] - current[b]))
            if np.all(np.isfinite(f[row])) and f[row, 0] <= f_now[b]:
                if models[b] is not None:
                    radius[b] = _new_radius(radius[b], moved, _ratio(f_now[b] - f[row, 0], predicted[b]))
                f0, g, H = _derivatives(f[row], p, h)
                current[b], f_now[b] = trials[b], f0
                models[b] = _positive(0.5 * (H + H.T), g)[1]
            else:  # a worse trial, or a failed candidate next to it: a shorter step from where it is
                radius[b] = moved / 4.0
            model = models[b]
            if model is None or radius[b] < 1e-10:
                done[b] = True  # failed at its start, or no step lowers it: it stays where it is
                continue
            if _decrement(current[b], *model, lo, hi) <= NEWTON_TOL:  # the whole step gains too little
                done[b] = success[b] = True
                trials[b] = current[b]
                continue
            trials[b], predicted[b] = _trust_step(current[b], *model, radius[b], lo, hi)
    return current, success


def _new_radius(radius: float, moved: float, ratio: float) -> float:
    """The trust region's radius after a step of length ``moved`` was taken, ``ratio`` the gain it made
    over the gain its model predicted: longer where the model was right, shorter where it was not."""
    if ratio > 0.75:
        return max(radius, 2.0 * moved)
    if ratio < 0.25:
        return moved / 4.0
    return radius


def _ratio(gained: float, predicted: float) -> float:
    """The gain a step made over the gain its model predicted (0 where the model predicted none)."""
    return gained / predicted if predicted > 0.0 else 0.0


def _positive(H: np.ndarray, g: np.ndarray) -> tuple[bool, tuple[np.ndarray, np.ndarray]]:
    """Whether the symmetric ``H`` is positive definite, and the model ``(g, M)``: ``M`` is ``H`` with its
    eigenvalues taken in absolute value and floored at 1e-8 of the largest, so that a step goes downhill
    where ``H`` is not positive and stays finite along a direction of no curvature."""
    lam, V = np.linalg.eigh(H)
    curvature = np.maximum(np.abs(lam), 1e-8 * max(float(np.max(np.abs(lam))), 1e-12))
    return bool(np.all(lam > 0)), (g, (V * curvature) @ V.T)


def _free(theta, g, lo, hi) -> np.ndarray:
    """The parameters free to move: not held at a bound by a gradient that points out of the box."""
    return ~(((theta <= lo) & (g > 0)) | ((theta >= hi) & (g < 0)))


def _decrement(theta, g, M, lo, hi) -> float:
    """What the whole Newton step of the free parameters (:func:`_free`) would gain by the model
    ``(g, M)``: ``g_f^T M_ff^-1 g_f / 2``, never negative (those held at a bound are where they belong)."""
    f = _free(theta, g, lo, hi)
    if not f.any():
        return 0.0
    return 0.5 * float(g[f] @ np.linalg.solve(M[np.ix_(f, f)], g[f]))


def _trust_step(theta, g, M, radius: float, lo, hi) -> tuple[np.ndarray, float]:
    """The Newton step from ``theta`` of the free parameters (:func:`_free`; the model's gradient ``g`` and
    positive Hessian ``M``), of length at most ``radius``, within the bounds, and the decrease of the
    objective the model predicts. Longer than the radius, the step is the model's minimum on the sphere:
    ``-(M_ff + mu I)^-1 g_f`` with ``mu`` found by bisection. Where the bounds cut it and the cut step
    would predict no decrease, it is the longest fraction of the step within them instead."""
    f = _free(theta, g, lo, hi)
    step = np.zeros_like(theta)
    if f.any():
        lam, V = np.linalg.eigh(M[np.ix_(f, f)])
        gv = V.T @ g[f]
        s = -gv / lam
        if float(np.linalg.norm(s)) > radius:
            low, high = 0.0, float(np.linalg.norm(gv)) / radius  # (at mu = high the step is within it)
            for _ in range(60):
                mu = 0.5 * (low + high)
                if float(np.linalg.norm(gv / (lam + mu))) > radius:
                    low = mu
                else:
                    high = mu
            s = -gv / (lam + high)
        step[f] = V @ s

    def predicted(taken):
        return -float(g @ taken + 0.5 * taken @ M @ taken)

    trial = np.clip(theta + step, lo, hi)
    gain = predicted(trial - theta)
    if gain <= 0.0 and np.any(step):  # the bounds' cut spoiled it: the part of the step within them
        with np.errstate(divide="ignore", invalid="ignore"):
            room = np.where(step > 0, (hi - theta) / step, np.where(step < 0, (lo - theta) / step, np.inf))
        t = float(np.clip(np.min(room), 0.0, 1.0))
        trial = np.clip(theta + t * step, lo, hi)
        gain = predicted(trial - theta)
    return trial, gain


def _secant_update(S: np.ndarray, s: np.ndarray, y: np.ndarray, y_sharp: np.ndarray) -> np.ndarray:
    """Dennis, Gay and Welsch's update of the second-order part ``S`` of a least-squares Hessian (NL2SOL):
    ``J^T J + S`` then models the curvature the Gauss-Newton matrix leaves out (here the log-determinant's),
    from the step ``s``, the gradient's change ``y`` and ``y# = (J_new - J_old)^T r_new``."""
    ys = float(y @ s)
    if ys <= 1e-12 * float(np.linalg.norm(y) * np.linalg.norm(s)):
        return S  # no curvature along the step: keep the model
    v = y_sharp - S @ s
    return S + (np.outer(v, y) + np.outer(y, v)) / ys - float(v @ s) * np.outer(y, y) / ys**2


def _covariance(H: np.ndarray, names: list[str]) -> tuple[np.ndarray, bool, list]:
    """``theta``'s covariance from the observed information ``H`` (its inverse, by its eigenvectors), whether
    every direction is fixed by the data, and the weak directions named."""
    if not np.all(np.isfinite(H)):
        p = H.shape[0]
        return np.full((p, p), np.inf), False, [{"reason": "the information is not finite"}]
    lam, V = np.linalg.eigh(0.5 * (H + H.T))
    top = float(np.max(np.abs(lam))) if lam.size else 0.0
    strong = lam > WEAK * top
    cov = (V[:, strong] / lam[strong]) @ V[:, strong].T
    weak_idx = np.flatnonzero(~strong).tolist()
    for i in range(H.shape[0]):  # a parameter on a weak direction is not fixed: its variance is infinite
        if any(abs(V[i, w]) > 1e-3 for w in weak_idx):
            cov[i, :] = cov[:, i] = np.inf
    weak = [
        {
            "eigenvalue": float(lam[w]),
            "direction": {n: float(v) for n, v in zip(names, V[:, w]) if abs(v) > 1e-3},
        }
        for w in weak_idx
    ]
    return cov, not weak_idx, weak


def _as_floats(value) -> np.ndarray | None:
    """A template's attribute as a float array (None: a placeholder, refused when the fleet is built)."""
    return None if value is None else np.array(value, dtype=float)


def _fitted(objective: _Objective, theta: np.ndarray):
    """The covariances (and initial state) the parameters give, as matrices."""
    out = {}
    for label, (param, M0, sl) in zip(("Q", "R"), objective.parts):
        value = param.matrices(theta[None, sl], M0)[0]
        if isinstance(value, dict):
            out.update({k: np.asarray(v, dtype=float) for k, v in value.items()})
        else:
            out[label] = np.asarray(value, dtype=float)
    Q = out.get("Q", objective.template["Q"].copy())
    R = out.get("R", objective.template["R"].copy())
    return Q, R, out.get("x"), out.get("P")


def _bounds(bounds, theta0: np.ndarray, p: int) -> tuple[np.ndarray, np.ndarray]:
    """``(low, high)`` arrays of ``p`` bounds: as given, else the start ± ln 1000."""
    if bounds is None:
        spread = math.log(1000.0)
        return theta0 - spread, theta0 + spread
    try:
        b = np.asarray(bounds, dtype=float)
    except (TypeError, ValueError):
        raise ParameterError(f"bounds must be {p} (low, high) pairs, got bounds={bounds!r}") from None
    if b.shape != (p, 2) or not np.all(np.isfinite(b)) or np.any(b[:, 0] >= b[:, 1]):
        raise ParameterError(f"bounds must be {p} finite (low, high) pairs with low < high, got {bounds!r}")
    if np.any(theta0 < b[:, 0]) or np.any(theta0 > b[:, 1]):
        raise ParameterError(f"the start theta0={theta0.tolist()} is outside bounds={b.tolist()}")
    return b[:, 0].copy(), b[:, 1].copy()


def _grid(grid, p: int) -> np.ndarray:
    if grid is None:
        raise ParameterError("method='grid' needs grid=, an array (G, p) of theta values")
    try:
        G = np.asarray(grid, dtype=float)
    except (TypeError, ValueError):
        raise ParameterError(f"grid must be an array (G, {p}) of numbers, got {grid!r:.100}") from None
    if G.ndim == 1 and p == 1:
        G = G[:, None]
    if G.ndim != 2 or G.shape[1] != p or G.shape[0] == 0 or not np.all(np.isfinite(G)):
        raise ParameterError(f"grid must be a finite array (G, {p}), got shape {G.shape}")
    return G
