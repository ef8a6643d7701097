"""The square-root measurement update, as a pure function on stacked arrays.

Two compiled forms (and no update), each one kernel call (:mod:`squkf.kernels`):

- **the joint QR** (a set whose mean and covariance are the prior's,
  ``SigmaSet.moments_exact``, and no ``residual_x`` or ``state_add``): the
  joint rows of the measurement and the state (the "array form" of the
  square-root Kalman filter) are triangularised at once::

      tria([[Dz, Dx], [R1_2^T, 0]]) = [[Sy, 0], [L21, L22]]

  where ``Dz``, ``Dx`` are the signed rows (see :mod:`squkf.rows`) of the
  second set's images and of the second set itself. ``Sy`` is the
  innovation factor, ``L21 = Pxy Sy^-T`` (so the gain is ``K = L21 Sy^-1``
  and ``K y = L21 (Sy^-1 y)``), and ``L22 L22^T = Pxx - K Pyy K^T`` is the
  posterior covariance. A negative weight's row is removed from the joint
  factor by a downdate. One QR and two triangular solves; which form the
  rows take (central or mean) is data in the plan. ``L22`` is the posterior
  only because the state rows ``Dx`` reproduce the prior factor.
- **g13ej's downdate form** (:func:`squkf.kernels.phases.downdate_update_kernel`): ``Sy``
  formed by the same kernel from the images' rows (or a user's ``UT``'s), ``L21 = Pxy Sy^-T``,
  and the prior factor ``S`` kept and downdated by each column of ``L21``, so that the posterior
  is exactly filterpy's ``P_prior - K S K^T`` whatever the set's rows. It is taken whenever the
  state rows need not reproduce the prior factor, or ``Sy`` is not theirs:

  - a set whose covariance is not the prior's (the propagated set with
    process noise, a user's generator);
  - a ``residual_x`` or a ``state_add`` (:func:`keeps_prior_factor`): the
    deviations ``residual_x(sigma, x)`` of wrapped quantities (angles whose
    spread passes pi) do not reproduce it;
  - a set the caller rewrote (a written ``sigmas_f``), which no longer
    reproduces the prior: :meth:`squkf.generators.SigmaSet.rewritten` marks
    it so (``moments_exact`` False), and every route takes this form for it;
  - a user's ``UT``: its ``Sy`` is given, and the posterior is filterpy's formula with that ``S``
    (the joint QR would form its own ``Sy``).

  A downdate that fails (where the covariance form would return an
  indefinite ``P``) raises :class:`~squkf.errors.PosteriorFactorError`
  (IFAIL 303).
- **no measurement** (:meth:`squkf.engine.Engine.skip_update`).

Python does only what is the user's: the hooks (``z_mean_fn``, ``residual_z``, and a ``residual_x``
or ``state_add`` that is not squkf's) and the ``UT`` are called per filter and point as filterpy
calls them, what they return is checked, and their rows are handed to the one kernel call as given
rows (mode ``GIVEN``). squkf's own ``AngleResidual`` as ``residual_x`` and ``AngleAdd`` as
``state_add`` are data: the downdate kernel wraps the state deviations and ``x + dx`` itself.

Every array may carry leading batch axes ``(...)``: one filter has none.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .angles import is_data, state_angles
from .checks import call_hook, check_hook_result
from .errors import GainError, PosteriorFactorError
from .generators import SigmaSet
from .kernels import table, wrappers
from .kernels.phases import JointUpdate
from .kernels.table import CENTRAL, GIVEN, MEAN, KernelTable, no_angles, no_points, no_set, plan_array
from .linalg import all_finite, solve_lower, tria
from .rows import RowForm, weight_rows
from .statuses import failure, first_status, singular_allowed
from .transform import StackedHook, deviations, weighted_mean

__all__ = [
    "measurement_update",
    "keeps_prior_factor",
    "gain_from_factors",
    "check_gain",
    "observed_noise_factor",
]

_TINY = np.finfo(float).tiny
_INF = float("inf")


def gain_from_factors(Sy: np.ndarray, L21: np.ndarray, *, kernels: KernelTable | None = None) -> np.ndarray:
    """Kalman gain ``K = L21 Sy^-1`` from the blocks of the joint factor.

    Parameters
    ----------
    Sy : ndarray, shape (..., m, m)
        Lower factor of the innovation covariance.
    L21 : ndarray, shape (..., n, m)
        ``Pxy Sy^-T``.
    kernels : KernelTable, optional
        The kernel table to call (a filter's route's); default the installed one.

    Returns
    -------
    K : ndarray, shape (..., n, m)
    """
    Kt = solve_lower(Sy, np.ascontiguousarray(np.swapaxes(L21, -1, -2)), trans=True, kernels=kernels)
    return np.swapaxes(Kt, -1, -2)


def keeps_prior_factor(residual_x: Callable | None, state_add: Callable | None) -> bool:
    """Whether the update with these hooks takes the downdate form whatever the set (see the module).

    A ``residual_x`` or a ``state_add`` (None: the plain operation) makes the update keep the prior
    factor and downdate it by the columns of ``L21``: the deviations they give (wrapped angles) need
    not reproduce the prior factor, which the joint QR and the gain form need.

    Parameters
    ----------
    residual_x, state_add : callable or None

    Returns
    -------
    bool
    """
    return residual_x is not None or state_add is not None


def observed_noise_factor(
    R1_2: np.ndarray, observed: np.ndarray, *, kernels: KernelTable | None = None
) -> np.ndarray:
    """Lower factor of the observed block of ``R = R1_2 R1_2^T``, by one QR.

    The block ``R[obs][:, obs]`` is ``R1_2[obs] R1_2[obs]^T``: the rows of the
    factor for the observed components, triangularised (no covariance formed).

    Parameters
    ----------
    R1_2 : ndarray, shape (..., m, m)
    observed : ndarray of bool, shape (m,)
    kernels : KernelTable, optional
        The kernel table to call (a filter's route's); default the installed one.

    Returns
    -------
    ndarray, shape (..., m_obs, m_obs)
    """
    rows = np.swapaxes(R1_2[..., observed, :], -1, -2)
    return tria(rows.copy(order="F") if rows.ndim == 2 else rows.copy(), kernels=kernels)


def measurement_update(
    x: np.ndarray,
    S: np.ndarray,
    sset: SigmaSet,
    sigmas_h: np.ndarray,
    z: np.ndarray,
    R1_2: np.ndarray,
    *,
    observed: np.ndarray | None = None,
    z_mean_fn: Callable | None = None,
    residual_x: Callable | None = None,
    residual_z: Callable | None = None,
    state_add: Callable | None = None,
    UT: Callable | None = None,
    kernels: KernelTable | None = None,
) -> JointUpdate:
    """Square-root measurement update from the second set and its images.

    One kernel call, of the form the set and hooks take (see the module): the hooks and a ``UT``
    are called here and what they give is handed to it as given rows; squkf's own angle hooks on
    the state (exact :class:`~squkf.angles.AngleResidual`, :class:`~squkf.angles.AngleAdd`) are
    done by the kernel.

    Parameters
    ----------
    x : ndarray, shape (..., n)
        Prior mean.
    S : ndarray, shape (..., n, n)
        Lower factor of the prior covariance.
    sset : SigmaSet
        The second sigma-point set (``N`` points) and its weights.
    sigmas_h : ndarray, shape (..., N, m)
        The measurement function's values at ``sset.sigmas``.
    z : ndarray, shape (..., m)
        The measurement (components not measured may hold anything, NaN too).
    R1_2 : ndarray, shape (..., m, m)
        Lower factor of the measurement noise covariance.
    observed : ndarray of bool, shape (m,), optional
        The components the update uses (default: all). The update is that of
        the measurement of these alone, with the factor of R's observed block.
        ``z_mean_fn``, ``residual_z`` and ``UT`` see whole vectors (every
        component, the others too; ``residual_z`` sees the predicted value at
        a component of ``z`` not measured); the update takes the observed
        components of what they return, so a hook that indexes a fixed
        component stays right.
    z_mean_fn, residual_x, residual_z, state_add : callable, optional
        filterpy's hooks for non-additive quantities (angles), called per
        filter; what they return is checked.
    UT : callable, optional
        Replaces the transform of ``sigmas_h`` into ``(z_pred, Sy)``; same
        signature as :func:`squkf.sqrt_unscented_transform`.
    kernels : KernelTable, optional
        The kernels to call (a route's: :class:`squkf.engine.Route`); default the table installed
        as :data:`squkf.kernels.table.KERNELS`.

    Returns
    -------
    JointUpdate
        The kernel's outputs (:class:`squkf.kernels.phases.JointUpdate`), ``x`` the posterior mean
        (``state_add``'s, where a user's hook adds), of the observed components (``y``, ``z_pred``,
        ``Sy``, ``L21``, ``w`` have ``m_obs`` of them). ``K = L21 Sy^-1``: :func:`gain_from_factors`.

    Raises
    ------
    DowndateError
        A negative weight's downdate of the innovation factor failed (IFAIL 301).
    GainError
        The innovation factor is singular (IFAIL 302).
    PosteriorFactorError
        The posterior factor could not be formed (IFAIL 303): on the downdate
        form, a downdate of the prior factor failed (``P_prior - K S K^T`` is
        not positive definite).
    """
    kernels = table.chosen(kernels)
    rows = sset.rows if sset.rows is not None else weight_rows(sset.Wm, sset.Wc)
    z_hooks = z_mean_fn is not None or residual_z is not None
    cols: np.ndarray | slice = slice(None)  # the observed components of what is formed over all of them
    Ro = R1_2
    if observed is not None and not observed.all():
        Ro = observed_noise_factor(R1_2, observed, kernels=kernels)
        if z_hooks or UT is not None:  # they see every component: their results are cut below
            cols = observed
        else:  # the kernels form everything from the measured components alone
            sigmas_h, z = sigmas_h[..., observed], z[..., observed]
    # the measurement's given rows (mode GIVEN): what the hooks or the UT make of the images
    Sy: np.ndarray | None = None
    given = z_hooks or UT is not None
    if given:
        if UT is None:
            z_pred = weighted_mean(sigmas_h, rows.Wm, z_mean_fn, "z_mean_fn")
        else:
            m = z.shape[-1]
            z_pred, Sy = UT(sigmas_h, sset.Wm, sset.Wc, R1_2, z_mean_fn, residual_z)
            z_pred = check_hook_result(z_pred, sigmas_h.shape[:-2] + (m,), "UT")
            Sy = check_hook_result(Sy, sigmas_h.shape[:-2] + (m, m), "UT")
            if not isinstance(cols, slice):  # the factor of the observed block: its rows, by one QR
                Sy = observed_noise_factor(Sy, cols, kernels=kernels)
        D, y = _rows_and_innovation(sigmas_h, _present(z, z_pred, cols), z_pred, residual_z)
        H, z, z_pred = D[..., cols], y[..., cols], z_pred[..., cols]
        form, mode = rows.mean_form, GIVEN
    else:
        H, z_pred = sigmas_h, None
        form = rows.best
        mode = CENTRAL if form.central else MEAN
    n = x.shape[-1]
    if UT is None and sset.moments_exact and not keeps_prior_factor(residual_x, state_add):
        # the joint QR: the set's state rows reproduce the prior factor
        pair = 0.0
        if given:  # the deviations from the prior mean (the set's exact offsets where known)
            X, xref = _state_deviations(sset, x), None
        elif form.central:  # deviations from the central point: the offsets' own differences
            X, xref = (sset.sigmas if sset.offsets is None else sset.offsets), None
            if sset.axis and sset.offsets is not None:
                pair = rows.pair_scale  # 0 unless every +/- row has one weight, none negative
        elif sset.offsets is not None:
            X, xref = sset.offsets, None
        else:
            X, xref = sset.sigmas, x
        st = wrappers.update_stacks(H, X, z, Ro, x, xref=xref, zref=z_pred)
        kernels.joint_update(
            st.H, st.zref, st.X, st.xref, st.z, st.R1_2, st.x, mode, plan_array(rows.Wm),
            plan_array(form.scale), plan_array(form.sign), float(pair), *st.out, no_points(n), 0.0, no_set(n),
        )  # fmt: skip
    else:  # the downdate form: the prior factor kept, downdated by the gain's columns
        xkind = state_angles(None, _data(residual_x), _data(state_add), n)
        if residual_x is not None and not is_data(residual_x):
            X, xref = deviations(sset.sigmas, x, residual_x, "residual_x"), np.zeros(n)
        elif residual_x is not None or sset.offsets is None:  # (squkf's residual_x: wrapped in the kernel)
            X, xref = sset.sigmas, x
        else:  # (a state_add's points: their offsets are filterpy's sigmas - x)
            X, xref = sset.offsets, np.zeros(n)
        st = wrappers.update_stacks(H, X, z, Ro, x, xref=xref, zref=z_pred, S=S, Sy=Sy)
        kernels.downdate_update(
            st.H, st.zref, st.X, st.xref, st.z, st.R1_2, st.Sy, st.S, st.x, mode, plan_array(rows.Wm),
            plan_array(rows.Wc), plan_array(form.scale), plan_array(form.sign),
            no_angles(n) if xkind is None else xkind, *st.out,
        )  # fmt: skip
    u = st.result()
    _raise_update_status(u.status, form, S, Ro)
    x_post = u.x
    if state_add is not None and not is_data(state_add):
        x_post = _per_filter(state_add, x, u.dx, "state_add")
        if not all_finite(x_post):
            raise PosteriorFactorError("the posterior mean or factor is not finite", errno=303)
    return u if x_post is u.x else u._replace(x=x_post)


def _data(hook: Callable | None) -> Callable | None:
    """``hook`` if it is squkf's angle hook (done by the kernels), else None."""
    return hook if is_data(hook) else None


def _present(z: np.ndarray, z_pred: np.ndarray, cols: np.ndarray | slice) -> np.ndarray:
    """``z`` as ``residual_z`` sees it: every component, the predicted value where one is missing (NaN).

    The hook is called with whole vectors, so that one indexing a fixed component (an angle) stays
    right; a missing component holds ``z_pred``'s value there (finite; its innovation is discarded),
    a component a gate rejected its measured value.
    """
    if isinstance(cols, slice):
        return z
    return np.where(np.isnan(z), z_pred, z)


def _innovation(z: np.ndarray, z_pred: np.ndarray, residual_z: Callable | None) -> np.ndarray:
    """``residual_z(z, z_pred)`` (plain difference by default), per filter."""
    return z - z_pred if residual_z is None else _per_filter(residual_z, z, z_pred, "residual_z")


def _rows_and_innovation(
    H: np.ndarray, z: np.ndarray, z_pred: np.ndarray, residual_z: Callable | None
) -> tuple[np.ndarray, np.ndarray]:
    """The rows ``residual_z(H_i, z_pred)`` ``(..., N, m)`` and the innovation ``residual_z(z, z_pred)``
    ``(..., m)``: a :class:`~squkf.transform.StackedHook` called once for both (the innovation last)."""
    if not isinstance(residual_z, StackedHook):
        return deviations(H, z_pred, residual_z, "residual_z"), _innovation(z, z_pred, residual_z)
    both = deviations(np.concatenate([H, z[..., None, :]], axis=-2), z_pred, residual_z, "residual_z")
    return both[..., :-1, :], both[..., -1, :]


def _raise_update_status(status: np.ndarray, form: RowForm, S: np.ndarray, R1_2: np.ndarray) -> None:
    """The exception for the first failed filter of an update kernel's ``status`` (nothing if none).

    A kernel reports 304 for a posterior factor with a zero on its diagonal: from a positive
    definite prior factor ``S`` and measurement noise ``R1_2`` it is rank lost to rounding (an
    error), otherwise (a singular prior, an exactly measured component) the right answer
    (:func:`squkf.statuses.singular_allowed`).
    """
    if not status.any():
        return
    code = first_status(singular_allowed(status, S, R1_2))
    if code:
        raise failure(code, form)


def _per_filter(fn: Callable, a: np.ndarray, b: np.ndarray, hook: str) -> np.ndarray:
    """The user's hook for ``a + b`` or ``a - b``, called and checked per filter."""
    shape = np.broadcast_shapes(a.shape, b.shape)
    d = shape[-1]
    if isinstance(fn, StackedHook):  # once: (k, 1, d) and (k, 1, d)
        k = int(np.prod(shape[:-1], dtype=np.int64))
        a1, b1 = (np.broadcast_to(v, shape).reshape(k, 1, d) for v in (a, b))
        return call_hook(fn.fn, (a1, b1), (k, 1, d), hook).reshape(shape)
    out: np.ndarray = np.empty(shape)
    for idx in np.ndindex(out.shape[:-1]):
        out[idx] = call_hook(fn, (a[idx] if a.ndim > 1 else a, b[idx] if b.ndim > 1 else b), (d,), hook)
    return out


def _state_deviations(sset: SigmaSet, x: np.ndarray) -> np.ndarray:
    """Deviations of the second set from the prior mean (its exact offsets where known)."""
    return sset.offsets if sset.offsets is not None else deviations(sset.sigmas, x)


def check_gain(Sy: np.ndarray) -> None:
    """Raise GainError (IFAIL 302) unless each diagonal entry of ``Sy`` is finite and above ``tiny``."""
    diag = Sy.diagonal() if Sy.ndim == 2 else np.diagonal(Sy, axis1=-2, axis2=-1)
    if Sy.ndim == 2:  # one small matrix: a Python loop beats numpy's reductions
        ok = True
        for v in diag.tolist():
            if not _TINY < abs(v) < _INF:  # a NaN fails too
                ok = False
                break
    else:
        d = np.abs(diag)
        ok = bool(np.all(d > _TINY) and np.all(d < _INF))
    if not ok:
        raise GainError(
            f"innovation factor is singular (diagonal {np.array2string(diag, precision=3)}): "
            "cannot form the Kalman gain",
            errno=302,
        )
