"""Second sigma-point sets for the measurement update: redrawn and augmented.

A *generator* is any object with one method::

    second_set(x, S, *, family, propagated, Q1_2, state_add) -> SigmaSet

called after the time update with

- ``x`` ``(..., n)`` and ``S`` ``(..., n, n)``: the predicted mean and lower factor;
- ``family``: the first set's sigma-point family (for defaults);
- ``propagated`` ``(..., N1, n)``: the first set's images under ``fx``, or ``None``
  when no prediction precedes this update (a second update at the same time,
  or an update straight after the state was assigned);
- ``Q1_2`` ``(n, n)`` or ``None``: the process-noise factor of that prediction;
- ``state_add``: ``state_add(x, dx)`` adds a deviation to a state, or ``None``.

It returns a :class:`SigmaSet`: the points (rows), their weights, and whether
their weighted mean and covariance equal ``(x, S @ S.T)`` exactly. The filter
uses that flag to pick the downdate-free QR form of the measurement update,
which is identical to the downdate form only when it holds (and with no
``residual_x`` or ``state_add``, whose deviations need not reproduce ``S``:
with them the downdate form is always taken, :mod:`squkf.measurement`).

A generator may also offer ``prepare(family, n)``, returning an object with
``draw(x, S, propagated, Q1_2, state_add) -> SigmaSet`` that holds what does
not change between steps (unit points, their covariance rows); the filter's
plan (:mod:`squkf.plan`) calls it once per configuration. The built-in
generators do; a generator with ``second_set`` only is adapted, and its
weights' rows are computed at each draw. Every array may carry leading batch
axes ``(...)``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .angles import is_data, wrap
from .checks import call_hook
from .errors import ParameterError
from .kernels import wrappers
from .kernels.table import KernelTable
from .rows import WeightRows, weight_rows
from .transform import StackedHook
from .weights import FilterpyPoints, as_family

__all__ = [
    "FusedDraw",
    "SigmaSet",
    "Redrawn",
    "Augmented",
    "Propagated",
    "UnitSet",
    "as_generator",
    "prepare_second_set",
    "noise_family",
    "axis_gamma",
    "sigma_points_from_factor",
    "sigma_points_and_offsets",
]


class FusedDraw(NamedTuple):
    """A second set the prediction's kernel draws with the prior (the drawer's ``fused()``).

    Attributes
    ----------
    xi : ndarray, shape (N2, n), read-only
        The unit points drawn: the redrawn set's, or the augmented set's noise part.
    gamma : float
        Non-zero for axis points (:func:`axis_gamma`).
    augmented : bool
        The set is the propagated set followed by ``F_1 + xi @ Q1_2.T`` (else ``x + xi @ S.T``).
    rows : WeightRows
    exact : bool
    axis : bool
        The set is ``x + [0; gamma S^T; -gamma S^T]`` with its offsets (:class:`SigmaSet`).
    """

    xi: np.ndarray
    gamma: float
    augmented: bool
    rows: WeightRows
    exact: bool
    axis: bool


class SigmaSet(NamedTuple):
    """A set of sigma points and weights.

    Attributes
    ----------
    sigmas : ndarray, shape (..., N, n)
    Wm, Wc : ndarray, shape (N,)
    moments_exact : bool
        The points' weighted mean and covariance are exactly the ``x`` and
        ``S @ S.T`` they were drawn for.
    offsets : ndarray, shape (..., N, n), or None
        ``sigmas - x`` as the generator formed it (``xi @ S.T``), before the
        rounding of adding ``x``; None when it is not known. The update uses
        it for the points' deviations, which keeps their spread when ``x`` is
        large compared with it.
    rows : WeightRows or None
        The covariance rows of ``(Wm, Wc)``, when the generator prepared them
        (a plan's generators do); None makes the update compute them.
    axis : bool
        The points are ``x + [0; gamma S^T; -gamma S^T]`` with those ``offsets``
        (each ``+/-`` pair exactly opposite): the update may rotate the pairs
        of its joint rows (:mod:`squkf.measurement`).
    """

    sigmas: np.ndarray
    Wm: np.ndarray
    Wc: np.ndarray
    moments_exact: bool
    offsets: np.ndarray | None = None
    rows: WeightRows | None = None
    axis: bool = False

    def rewritten(self, sigmas: np.ndarray) -> SigmaSet:
        """This set's weights with points the caller wrote (a written ``sigmas_f``).

        They no longer reproduce the mean and factor the set was drawn for: the set is marked not
        exact, with no offsets and no axis structure, so that its update keeps the prior factor and
        takes the gain out of it by downdates (:mod:`squkf.measurement`'s downdate form), on every
        route (one filter, a fleet, a gate's update again).

        Parameters
        ----------
        sigmas : ndarray, shape (..., N, n)

        Returns
        -------
        SigmaSet
        """
        return self._replace(sigmas=sigmas, moments_exact=False, offsets=None, axis=False)


def axis_gamma(xi: np.ndarray) -> float | None:
    """``gamma`` if the unit points ``xi`` are ``[0; gamma I; -gamma I]``, else None.

    Parameters
    ----------
    xi : ndarray, shape (N, n)

    Returns
    -------
    float or None
    """
    N, n = xi.shape
    if N != 2 * n + 1 or n == 0:
        return None
    gamma = float(xi[1, 0])
    axes = np.vstack([np.zeros((1, n)), gamma * np.eye(n), -gamma * np.eye(n)])
    return gamma if gamma != 0.0 and np.array_equal(xi, axes) else None


def _plain_sum(state_add) -> bool:
    """Whether ``state_add`` is the plain sum ``x + dx`` (the kernel forms the points itself)."""
    return state_add is None or state_add is np.add


def sigma_points_and_offsets(
    x: np.ndarray,
    S: np.ndarray,
    xi: np.ndarray,
    state_add=None,
    gamma: float | None = None,
    *,
    kernels: KernelTable | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Sigma points ``x + xi[i] @ S.T`` (one per row) and their offsets ``xi @ S.T``.

    Parameters
    ----------
    x : ndarray, shape (..., n)
    S : ndarray, shape (..., n, n)
        Lower factor of the covariance.
    xi : ndarray, shape (N, n)
        Unit sigma points.
    state_add : callable ``state_add(x, dx)``, optional
        Called once per point (and filter) when given (angles, manifolds);
        what it returns is checked.
    gamma : float, optional
        ``xi`` is ``[0; gamma I; -gamma I]`` (see :func:`axis_gamma`) or
        ``[gamma I; -gamma I]``: the offsets are ``+/- gamma S^T``, formed in
        O(n^2) (the same numbers as the product).
    kernels : KernelTable, optional
        The kernel table to call (a filter's route's); default the installed one.

    Returns
    -------
    sigmas : ndarray, shape (..., N, n)
    offsets : ndarray, shape (..., N, n)
    """
    sigmas, dx = wrappers.sigma_points(x, S, xi, 0.0 if gamma is None else gamma, kernels=kernels)
    assert dx is not None
    if _plain_sum(state_add):
        return sigmas, dx
    if is_data(state_add):  # squkf's AngleAdd: x + dx wrapped, on every filter and point at once
        idx = list(state_add.angle_indices)
        sigmas[..., idx] = wrap(sigmas[..., idx])
        return sigmas, dx
    n = x.shape[-1]
    if isinstance(state_add, StackedHook):  # once: (k, 1, n) and (k, N, n)
        shape = sigmas.shape
        k, N = int(np.prod(shape[:-2], dtype=np.int64)), shape[-2]
        xs = np.broadcast_to(x[..., None, :], shape[:-2] + (1, n)).reshape(k, 1, n)
        return call_hook(state_add.fn, (xs, dx.reshape(k, N, n)), (k, N, n), "state_add").reshape(shape), dx
    out = np.empty(sigmas.shape)
    for idx in np.ndindex(out.shape[:-2]):
        xk = x[idx] if x.ndim > 1 else x
        dk = dx[idx] if dx.ndim > 2 else dx
        for i, d in enumerate(dk):
            out[idx + (i,)] = call_hook(state_add, (xk, d), (n,), "state_add")
    return out, dx


def sigma_points_from_factor(
    x: np.ndarray,
    S: np.ndarray,
    xi: np.ndarray,
    state_add=None,
    gamma: float | None = None,
    *,
    kernels: KernelTable | None = None,
) -> np.ndarray:
    """The sigma points of :func:`sigma_points_and_offsets` alone, shape ``(..., N, n)``."""
    g = 0.0 if gamma is None else gamma
    if _plain_sum(state_add):  # the offsets are not needed: not formed
        return wrappers.sigma_points(x, S, xi, g, offsets=False, kernels=kernels)[0]
    return sigma_points_and_offsets(x, S, xi, state_add, gamma, kernels=kernels)[0]


def _frozen(a: np.ndarray) -> np.ndarray:
    """``a`` made read-only: a plan's data, never changed (and handed to the kernels as it is)."""
    a.setflags(write=False)
    return a


def _identity_moments(family, n: int) -> bool:
    """True when the unit points have weighted mean 0 and weighted covariance I."""
    xi = family.unit_sigma_points(n)
    Wm, Wc = family.weights(n)
    # rounding in these sums scales with the weights' magnitudes (huge for a small alpha)
    big = float(np.max(np.abs(xi))) if xi.size else 1.0
    tol_m = 64 * np.finfo(float).eps * max(1.0, float(np.abs(Wm).sum()))
    tol_c = 64 * np.finfo(float).eps * max(1.0, float(np.abs(Wc).sum()) * big**2)
    mean_ok = np.allclose(Wm @ xi, 0.0, atol=tol_m * max(1.0, big)) and abs(Wm.sum() - 1.0) <= tol_m
    cov_ok = np.allclose((xi.T * Wc) @ xi, np.eye(n), atol=tol_c, rtol=0)
    return bool(mean_ok and cov_ok)


class UnitSet:
    """One family's points at one dimension, prepared once: ``x + xi @ S.T`` with its weights.

    Parameters
    ----------
    family : sigma-point family
    n : int
        Dimension of the points.

    Attributes
    ----------
    xi : ndarray, shape (N, n)
    rows : WeightRows
    exact : bool
        The points reproduce the mean and covariance they are drawn for.
    gamma : float or None
        Set for axis points (see :func:`axis_gamma`).
    """

    def __init__(self, family, n: int):
        self.xi = _frozen(np.array(family.unit_sigma_points(n), dtype=np.float64))
        self.rows = weight_rows(*family.weights(n))
        self.exact = _identity_moments(family, n)
        self.gamma = axis_gamma(self.xi)

    @classmethod
    def augmented(cls, family, n: int, d: int) -> tuple[UnitSet, np.ndarray]:
        """The state part of ``family``'s points over ``[x, noise]`` (dim ``n + d``), and the noise part.

        The augmented factor is block diagonal, ``diag(S, N1_2)``, so a point
        ``[x, 0] + xi_i diag(S, N1_2)^T`` is ``x + xi_i[:n] S^T`` beside
        ``xi_i[n:] N1_2^T``: neither block is ever formed together.

        Parameters
        ----------
        family : sigma-point family
            Serving dimension ``n + d`` (:func:`noise_family` gives it).
        n, d : int
            State and noise dimensions.

        Returns
        -------
        unit : UnitSet
            Its ``xi`` ``(N, n)`` is the state part; rows and exactness are the
            ``(n + d)``-dimensional family's (no axis structure in ``n``).
        noise_xi : ndarray, shape (N, d)
            The noise part of the unit points (read-only).
        """
        full = cls(family, n + d)
        unit = cls.__new__(cls)
        unit.xi = _frozen(full.xi[:, :n].copy())
        unit.rows, unit.exact, unit.gamma = full.rows, full.exact, None
        return unit, _frozen(full.xi[:, n:].copy())

    def draw(
        self, x: np.ndarray, S: np.ndarray, state_add=None, *, kernels: KernelTable | None = None
    ) -> SigmaSet:
        """The set for mean ``x`` ``(..., n)`` and lower factor ``S`` ``(..., n, n)`` (by ``kernels``, a
        route's table; None: the installed one)."""
        sigmas, offsets = sigma_points_and_offsets(x, S, self.xi, state_add, self.gamma, kernels=kernels)
        rows = self.rows
        axis = self.gamma is not None and _plain_sum(state_add)
        return SigmaSet(sigmas, rows.Wm, rows.Wc, self.exact, offsets, rows, axis)


class Redrawn:
    """Draw the second set afresh from the predicted mean and factor (g13ej's default).

    Parameters
    ----------
    weights : family, optional
        Sigma-point family for the second set (its own kappa/alpha/beta,
        g13ej's ROPT(5..7)). Defaults to the first set's family.
    """

    def __init__(self, weights=None):
        self.weights = None if weights is None else as_family(weights)

    def __repr__(self):
        return f"Redrawn(weights={self.weights!r})"

    def family_for(self, family):
        """The family used for the second set, given the first set's."""
        return self.weights if self.weights is not None else family

    def num_sigmas(self, n: int, family) -> int:
        """Number of points in the second set for an ``n``-state."""
        return self.family_for(family).num_sigmas(n)

    def prepare(self, family, n: int) -> _RedrawnSet:
        """What this generator needs for ``family`` at dimension ``n``, prepared once."""
        return _RedrawnSet(UnitSet(self.family_for(family), n))

    def prepare_augmented(self, family, n: int, d: int) -> tuple[_RedrawnSet, np.ndarray]:
        """The drawer of the set over ``[x, v]`` (``v`` of dimension ``d`` enters ``hx``), and its noise part.

        Returns
        -------
        drawer : object with ``draw(x, S, propagated, Q1_2, state_add) -> SigmaSet``
            Draws the state part, ``(N2, n)`` per filter, with the weights of
            the ``(n + d)``-dimensional family.
        v_xi : ndarray, shape (N2, d)
            The unit noise points (``v_i = v_xi[i] @ R1_2.T``).
        """
        unit, v_xi = UnitSet.augmented(noise_family(self.family_for(family), n, d), n, d)
        return _RedrawnSet(unit), v_xi

    def second_set(self, x, S, *, family, propagated=None, Q1_2=None, state_add=None) -> SigmaSet:
        """The redrawn set ``x + xi @ S.T`` (see the module docstring)."""
        return self.prepare(family, x.shape[-1]).draw(x, S, propagated, Q1_2, state_add)


class _RedrawnSet:
    uses_propagated = False  # the step need not keep the first set's images for it

    def __init__(self, unit: UnitSet):
        self.unit = unit

    def fused(self) -> FusedDraw:
        """The set as the prediction's kernel draws it (with the plain sum)."""
        u = self.unit
        axis = u.gamma is not None
        return FusedDraw(u.xi, u.gamma if axis else 0.0, False, u.rows, u.exact, axis)  # type: ignore[arg-type]

    @property
    def drawn_rows(self) -> tuple[WeightRows, ...]:
        """The weight rows every set it draws carries (the routes of their updates are fixed by them)."""
        return (self.unit.rows,)

    def draw(self, x, S, propagated, Q1_2, state_add, *, kernels: KernelTable | None = None) -> SigmaSet:
        return self.unit.draw(x, S, state_add, kernels=kernels)


class Augmented:
    """Augment the propagated first set with the process noise (g13ej's eq. 13).

    The second set is the propagated first set followed by
    ``F_1 +/- gamma' * Q1_2[:, j]``, where ``F_1`` is the propagated central
    point; its weights are those of a ``2n``-dimensional set. The predicted
    mean and factor are unchanged by the augmentation.

    Parameters
    ----------
    weights : family, optional
        Family of the ``2n``-dimensional set; must have a central point and
        ``+/- gamma`` pairs (Merwe or Julier type). Defaults to the first
        set's family with ``kappa' = kappa - n``, so that both sets have the
        same spread (``L' + kappa' = L + kappa``); this makes the augmented
        set's mean and covariance exactly the prior's.

    Notes
    -----
    Without process noise (``Q1_2`` is None) the second set is the propagated
    first set itself. With no propagated set available (an update that does
    not follow a prediction), the set is redrawn from ``(x, S)`` with the first
    set's family.
    """

    def __init__(self, weights=None):
        self.weights = None if weights is None else as_family(weights)
        if self.weights is not None:
            _require_symmetric(self.weights, "Augmented(weights=...)")

    def __repr__(self):
        return f"Augmented(weights={self.weights!r})"

    def family_for(self, family, n: int):
        """The ``2n``-dimensional family used for the second set."""
        fam2 = self._second_family(family, n)
        _require_symmetric(fam2, "the augmented family")
        return fam2

    def _second_family(self, family, n: int):
        if self.weights is not None:
            return self.weights
        native = family.as_native() if hasattr(family, "as_native") else family
        if native is None or not hasattr(native, "augmented"):
            raise ParameterError(
                "the augmented second set needs a family with a central point and "
                f"+/- gamma pairs (Merwe or Julier type); got {family!r}"
            )
        return native.augmented(n)

    def num_sigmas(self, n: int, family) -> int:
        """Number of points in the second set for an ``n``-state: ``4n + 1``."""
        return self.family_for(family, n).num_sigmas(2 * n)

    def prepare(self, family, n: int) -> _AugmentedSet:
        """What this generator needs for ``family`` at dimension ``n``, prepared once."""
        fam2 = self.family_for(family, n)
        Wm2, Wc2 = fam2.weights(2 * n)
        if Wm2.shape[0] != family.num_sigmas(n) + 2 * n:
            raise ParameterError(
                f"the augmented set has {family.num_sigmas(n) + 2 * n} points but its family gives "
                f"{Wm2.shape[0]} weights; the first set must be a centre and +/- pairs"
            )
        g = fam2.gamma(2 * n)
        return _AugmentedSet(
            UnitSet(family, n),
            weight_rows(Wm2, Wc2),
            _augmented_exact(family, fam2, n, g),
            _frozen(np.vstack([g * np.eye(n), -g * np.eye(n)])),
        )

    def second_set(self, x, S, *, family, propagated=None, Q1_2=None, state_add=None) -> SigmaSet:
        """The augmented set (see the class docstring)."""
        return self.prepare(family, x.shape[-1]).draw(x, S, propagated, Q1_2, state_add)


class _AugmentedSet:
    def __init__(self, first: UnitSet, rows: WeightRows, exact: bool, noise_xi: np.ndarray):
        self.first = first
        self.rows = rows
        self.exact = exact
        self.noise_xi = noise_xi
        n = noise_xi.shape[1]
        g = float(noise_xi[0, 0]) if n else 0.0
        axes = g != 0.0 and np.array_equal(noise_xi, np.vstack([g * np.eye(n), -g * np.eye(n)]))
        self.noise_gamma = g if axes else None  # [g I; -g I]: the extra points in O(n^2)

    def fused(self) -> FusedDraw:
        """The set with process noise as the prediction's kernel draws it (with the plain sum)."""
        g = 0.0 if self.noise_gamma is None else self.noise_gamma
        return FusedDraw(self.noise_xi, g, True, self.rows, self.exact, False)

    @property
    def drawn_rows(self) -> tuple[WeightRows, ...]:
        """The weight rows every set it draws carries: the augmented set's, the first set's."""
        return (self.rows, self.first.rows)

    def draw(self, x, S, propagated, Q1_2, state_add, *, kernels: KernelTable | None = None) -> SigmaSet:
        if propagated is None:
            return self.first.draw(x, S, state_add, kernels=kernels)
        if Q1_2 is None:
            r = self.first.rows
            return SigmaSet(propagated, r.Wm, r.Wc, True, None, r)
        centre = propagated[..., 0, :]
        extra = sigma_points_from_factor(
            centre, Q1_2, self.noise_xi, state_add, self.noise_gamma, kernels=kernels
        )
        batch = np.broadcast_shapes(propagated.shape[:-2], extra.shape[:-2])
        sigmas = np.concatenate(
            [
                np.broadcast_to(propagated, batch + propagated.shape[-2:]),
                np.broadcast_to(extra, batch + extra.shape[-2:]),
            ],
            axis=-2,
        )
        r = self.rows
        return SigmaSet(sigmas, r.Wm, r.Wc, self.exact, None, r)


class Propagated:
    """Reuse the propagated first set as the second set (no redraw, no augmentation).

    This is the classic UKF of Julier and Uhlmann without redrawing, and what
    filterpy's ``CubatureKalmanFilter`` does. The points' covariance lacks the
    process noise, so unless there is none the measurement update uses the
    downdate form. With no propagated set available (an update that does not
    follow a prediction) the set is redrawn with the first set's family.
    """

    def __repr__(self):
        return "Propagated()"

    def num_sigmas(self, n: int, family) -> int:
        """Number of points in the second set: the first set's."""
        return family.num_sigmas(n)

    def prepare(self, family, n: int) -> _PropagatedSet:
        """What this generator needs for ``family`` at dimension ``n``, prepared once."""
        return _PropagatedSet(UnitSet(family, n))

    def second_set(self, x, S, *, family, propagated=None, Q1_2=None, state_add=None) -> SigmaSet:
        """The propagated first set with the first set's weights."""
        return self.prepare(family, x.shape[-1]).draw(x, S, propagated, Q1_2, state_add)


class _PropagatedSet:
    def __init__(self, first: UnitSet):
        self.first = first

    @property
    def drawn_rows(self) -> tuple[WeightRows, ...]:
        """The weight rows every set it draws carries: the first set's."""
        return (self.first.rows,)

    def draw(self, x, S, propagated, Q1_2, state_add, *, kernels: KernelTable | None = None) -> SigmaSet:
        if propagated is None:
            return self.first.draw(x, S, state_add, kernels=kernels)
        r = self.first.rows
        return SigmaSet(propagated, r.Wm, r.Wc, Q1_2 is None, None, r)


class _UserSet:
    """A user's generator (only ``second_set``): its weights' rows are computed when they change."""

    def __init__(self, generator, family):
        self.generator = generator
        self.family = family

    def draw(self, x, S, propagated, Q1_2, state_add, *, kernels: KernelTable | None = None) -> SigmaSet:
        # (the protocol takes no kernel table: a user's generator draws by the installed one)
        sset = self.generator.second_set(
            x, S, family=self.family, propagated=propagated, Q1_2=Q1_2, state_add=state_add
        )
        if not isinstance(sset, SigmaSet):
            raise ParameterError(f"the generator's second_set returned {type(sset).__name__}, not a SigmaSet")
        if sset.rows is None:
            sset = sset._replace(rows=weight_rows(sset.Wm, sset.Wc))
        return sset


def noise_family(family, n: int, d: int):
    """The family that weighs a set drawn in dimension ``n + d``: over ``[x, noise]``, or ``x`` (``d = 0``).

    A family with a spread parameter (Merwe, Julier: its ``augmented``) keeps
    the spread it has at ``n``: ``kappa`` is lowered by ``d``, so that
    ``L + kappa`` and the state part of the points are unchanged, and a model
    whose noise is in fact additive, written with the noise as an argument,
    gives the additive filter's numbers. A filterpy points object serves a set
    of the dimension it was built for as it is, and a set of any other
    dimension as its squkf equivalent (:meth:`~squkf.weights.FilterpyPoints.as_native`,
    its parameters read for ``n``, as if it were built for ``n``) weighed as
    above; any other family is asked for ``n + d`` points.

    Parameters
    ----------
    family : sigma-point family
    n : int
        State dimension.
    d : int
        Noise dimension (0: the state alone).

    Returns
    -------
    sigma-point family
        ``family`` itself when it serves the set as it is.

    Raises
    ------
    ParameterError
        A points object built for another dimension, with no squkf equivalent.
    """
    dim = n + d
    if isinstance(family, FilterpyPoints):
        if family.n == dim:
            return family
        native = family.as_native()
        if native is None:
            raise ParameterError(
                f"points: the points object {type(family.points).__name__} was built for n={family.n}, and"
                " it has no squkf equivalent (Merwe or Julier type) to serve a set of another dimension, but"
                f" a set is drawn in dimension {dim} ({'dim_x' if not d else f'dim_x + {d} of noise'}): build"
                " it for the dimension of every set the filter draws, or give a squkf family"
            )
        family = native
    if not d:
        return family
    if hasattr(family, "augmented"):
        return family.augmented(d)
    family.num_sigmas(dim)  # fails now if it cannot
    return family


def prepare_second_set(generator, family, n: int):
    """The generator's second-set drawer for ``family`` at ``n`` (its ``prepare``, or an adapter).

    Returns
    -------
    object with ``draw(x, S, propagated, Q1_2, state_add) -> SigmaSet``
    """
    if hasattr(generator, "prepare"):
        return generator.prepare(family, n)
    return _UserSet(generator, family)


def _require_symmetric(fam, what: str):
    if not hasattr(fam, "gamma"):
        raise ParameterError(
            f"{what} must have a central point and +/- gamma pairs (Merwe or Julier type); got {fam!r}"
        )


def _augmented_exact(fam1, fam2, n: int, g2: float) -> bool:
    """Whether the augmented set reproduces the prior's mean and covariance exactly.

    True when the weights of the propagated points agree between the sets,
    the centre's weight absorbs the noise points' weights, and each noise
    pair carries exactly the noise covariance.
    """
    Wm1, Wc1 = fam1.weights(n)
    Wm2, Wc2 = fam2.weights(2 * n)
    N1 = Wm1.shape[0]
    if Wm2.shape[0] != N1 + 2 * n:
        return False
    ok = True
    for W1, W2 in ((Wm1, Wm2), (Wc1, Wc2)):
        tol = 64 * np.finfo(float).eps * max(1.0, float(np.abs(W2).sum()))
        ok &= np.allclose(W2[1:N1], W1[1:], rtol=1e-13, atol=0)
        ok &= abs(W2[0] + W2[N1:].sum() - W1[0]) <= tol
    ok &= np.allclose(2.0 * Wc2[N1:] * g2**2, 1.0, rtol=1e-12)
    return bool(ok)


def as_generator(scheme):
    """Return a generator for ``scheme``: ``"redrawn"``, ``"augmented"`` or a generator object.

    Raises
    ------
    ParameterError
        For an unknown name or an object without ``second_set``.
    """
    if isinstance(scheme, str):
        key = scheme.lower()
        if key == "redrawn":
            return Redrawn()
        if key == "augmented":
            return Augmented()
        if key == "propagated":
            return Propagated()
        raise ParameterError(
            f"scheme must be 'redrawn', 'augmented', 'propagated' or a generator, got scheme={scheme!r}"
        )
    if not hasattr(scheme, "second_set"):
        raise ParameterError(
            f"scheme must be 'redrawn', 'augmented' or an object with a second_set method, got {scheme!r}"
        )
    return scheme
