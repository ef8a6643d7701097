"""A covariance carried as its lower factor but readable and writable as a matrix.

filterpy code reads and writes covariances as matrices, in place as often as
not (``ukf.Q[2:4, 2:4] = ...``, ``ukf.P *= 10``). A :class:`FactorSlot` keeps
the factor as the truth and hands out the matrix on demand; the matrix it
handed out is remembered (:class:`squkf.boundary.edits.Handed`), and if the
caller has changed it in place by the next time the factor is needed, the
changed matrix is validated and factored (once). Nothing is formed or compared while nobody reads the
matrix.
"""

from __future__ import annotations

import copy

import numpy as np

from .boundary.edits import Handed
from .errors import NonFiniteError, NotPositiveDefiniteError, ShapeError, SqukfValueError
from .linalg import all_finite, factor_covariance
from .validate import as_float_array

__all__ = ["FactorSlot", "as_matrix", "as_lower_factor"]


def as_matrix(value, name: str, dim: int | None) -> np.ndarray:
    """Validate a covariance given as a matrix (or a scalar meaning ``value * I``).

    Parameters
    ----------
    value : array_like or float
        A square matrix; a scalar (``value * I``); for ``dim == 1`` also a
        1-element array.
    name : str
        Argument name for messages.
    dim : int or None
        Required size; ``None`` accepts any square matrix (a scalar then
        needs ``dim``).

    Returns
    -------
    A : ndarray, shape (dim, dim), float64, symmetrised copy

    Raises
    ------
    ShapeError, NonFiniteError, SqukfValueError (not symmetric)
    """
    A = as_float_array(value, name)
    if A.ndim == 1 and A.shape[0] == 1 and dim in (None, 1):
        A = A.reshape(1, 1)
    if A.ndim == 0 and dim is not None:
        if not np.isfinite(A):
            raise NonFiniteError(f"{name} is not finite: {float(A)!r}")
        A = A * np.eye(dim)
    if A.ndim == 1 and A.shape[0] > 1:
        raise ShapeError(
            f"{name} is a 1-D array of length {A.shape[0]}; a covariance is a matrix: "
            f"for a diagonal one use np.diag({name})"
        )
    if A.ndim != 2 or A.shape[0] != A.shape[1] or (dim is not None and A.shape[0] != dim):
        want = f"({dim}, {dim})" if dim is not None else "square"
        raise ShapeError(f"{name} has shape {A.shape}, expected {want}")
    if not np.all(np.isfinite(A)):
        raise NonFiniteError(f"{name} contains NaN or inf: {A!r}")
    scale = float(np.max(np.abs(A))) if A.size else 0.0
    asym = float(np.max(np.abs(A - A.T))) if A.size else 0.0
    if asym > 1e-9 * scale:
        raise SqukfValueError(
            f"{name} is not symmetric: max |{name} - {name}.T| = {asym:.3g} (max |{name}| = {scale:.3g})"
        )
    return 0.5 * A + 0.5 * A.T  # halves first: A + A.T overflows for entries near the largest float


def as_lower_factor(value, name: str, dim: int | None, singular_ok: bool) -> np.ndarray:
    """Validate a lower-triangular factor given directly.

    A negative diagonal entry is made positive by flipping its column (the
    covariance ``S @ S.T`` is unchanged).

    Parameters
    ----------
    value : array_like
        A lower-triangular matrix; a scalar (``value * I``); for ``dim == 1``
        also a 1-element array.
    name : str
    dim : int or None
    singular_ok : bool
        Accept zeros on the diagonal (a covariance of lower rank).

    Returns
    -------
    S : ndarray, shape (dim, dim), float64 copy

    Raises
    ------
    ShapeError, NonFiniteError (also when the covariance ``S @ S.T`` is beyond
    float64's range: read as a matrix it would hold inf), SqukfValueError (not
    lower triangular), NotPositiveDefiniteError (zero on the diagonal)
    """
    S = as_float_array(value, name)
    if S.ndim == 1 and S.shape[0] == 1 and dim in (None, 1):
        S = S.reshape(1, 1)
    if S.ndim == 0 and dim is not None:
        if not np.isfinite(S):
            raise NonFiniteError(f"{name} is not finite: {float(S)!r}")
        S = S * np.eye(dim)
    if S.ndim != 2 or S.shape[0] != S.shape[1] or (dim is not None and S.shape[0] != dim):
        want = f"({dim}, {dim})" if dim is not None else "square"
        raise ShapeError(f"{name} has shape {S.shape}, expected {want}")
    if not np.all(np.isfinite(S)):
        raise NonFiniteError(f"{name} contains NaN or inf: {S!r}")
    upper = np.triu(S, 1)
    if np.any(upper != 0):
        i, j = np.argwhere(upper != 0)[0]
        raise SqukfValueError(
            f"{name} must be lower triangular, but {name}[{i}, {j}] = {S[i, j]!r} is above the diagonal"
        )
    with np.errstate(over="ignore"):  # overflow is what is checked here
        # the diagonal of S @ S.T, its largest entries (Cauchy-Schwarz): finite iff the matrix is
        norms = np.einsum("ij,ij->i", S, S)
    if not all_finite(norms):
        i = int(np.flatnonzero(~np.isfinite(norms))[0])
        raise NonFiniteError(
            f"{name} stands for a covariance {name} @ {name}.T beyond float64's range: its entry [{i}, {i}]"
            f" overflows (the largest entry of {name} is {float(np.max(np.abs(S))):.3g})"
        )
    d = S.diagonal()
    if not singular_ok and np.any(d == 0):
        raise NotPositiveDefiniteError(
            f"{name} has a zero on its diagonal (at {int(np.flatnonzero(d == 0)[0])}): "
            "the covariance it stands for is singular"
        )
    neg = d < 0
    if neg.any():
        S[:, neg] *= -1.0
    return S


class FactorSlot:
    """One covariance (``P``, ``Q`` or ``R``) held as its lower factor.

    The factor is the truth. The matrix is formed when first read and then
    handed out as the same array until the factor changes, so that edits in
    place (also several statements of them) reach it; they are validated and
    factored when the factor is next needed (:meth:`factor`). An assignment is
    validated at once, and one that fails changes nothing, pending in-place
    edits included.

    Parameters
    ----------
    name : str
        ``"P"``, ``"Q"`` or ``"R"``, used in messages.
    dim : int or None
        Fixed size, or None for any size.
    semidefinite : bool
        Whether a singular covariance is acceptable (noise) or not (``P``).
        A factor given directly is accepted exactly when its covariance is.
    factor : ndarray or None
        Initial lower factor; None means a zero covariance (no noise).
    """

    def __init__(self, name: str, dim: int | None, semidefinite: bool, factor: np.ndarray | None):
        self.name = name
        self.dim = dim
        self.semidefinite = semidefinite
        self._factor = factor
        self._view: Handed | None = None  # the matrix handed out, and its record when it matched the factor
        self._assigned: np.ndarray | None = None  # the matrix assigned, handed out when first read

    def detached(self) -> FactorSlot:
        """A copy for an independent filter: the factor shared (never changed in place), the matrix copied.

        A pending step recognises the shared factor as the prior its second
        set was drawn from; the matrix handed out (and its pending edits) is
        the copy's own.
        """
        new = copy.copy(self)
        if new._view is not None:
            new._view = new._view.copy()  # pending edits stay pending in the copy
        if new._assigned is not None:
            new._assigned = new._assigned.copy()
        return new

    def _size(self) -> int:
        if self._factor is not None:
            return self._factor.shape[0]
        return self.dim if self.dim is not None else 0

    def pending(self) -> bool:
        """Whether the matrix handed out was edited in place since it matched the factor."""
        return self._view is not None and self._view.edited()

    def factor(self) -> np.ndarray | None:
        """The current lower factor (None: zero covariance), after validating in-place edits.

        The array returned is the slot's own: callers inside the library only
        read it, and hand out copies.

        Raises
        ------
        SqukfValueError, NotPositiveDefiniteError
            The edited matrix is not a valid covariance; the edit stays pending.
        """
        if self._view is not None:
            self._view = self._view.take(self._take_matrix)
        return self._factor

    def _take_matrix(self, A: np.ndarray) -> None:
        self._factor = self._factor_of(as_matrix(A, self.name, self.dim))

    def _factor_of(self, A: np.ndarray) -> np.ndarray | None:
        if self.semidefinite and not np.any(A):
            return None
        return factor_covariance(A, self.name, semidefinite=self.semidefinite)

    def matrix(self) -> np.ndarray:
        """The covariance ``S @ S.T``; edits to the returned array take effect at the next step.

        ``(dim, dim)``, or ``(1,)`` when a 1-element vector was assigned (:meth:`set_matrix`).
        """
        if self._view is None:
            A = self._assigned
            if A is None:
                S = self._factor
                A = S @ S.T if S is not None else np.zeros((self._size(),) * 2)
            # handed out from now on: edits in place are looked for at each use of the factor
            self._view, self._assigned = Handed(A), None
        return self._view.array

    def set_matrix(self, value) -> None:
        """Assign from a covariance matrix (validated, factored once; a copy is kept).

        The copy handed out by :meth:`matrix` has the shape assigned: a
        ``(dim, dim)`` matrix, or for dimension 1 also a 1-element vector
        ``(1,)`` (filterpy keeps what it is given, so ``R[0]`` is a number). A
        scalar ``s`` is the matrix ``s * I``. When the filter installs a new
        factor (:meth:`set_trusted_factor`) the matrix is formed ``(dim, dim)``.
        """
        if value is None:
            if not self.semidefinite:
                raise SqukfValueError(f"{self.name} cannot be None")
            self._factor, self._view, self._assigned = None, None, None
            return
        A = as_matrix(value, self.name, self.dim)
        S = self._factor_of(A)
        if np.ndim(value) == 1:  # a 1-element vector (dimension 1): handed out as assigned, as filterpy
            A = A.reshape(1)  # does, so that ``R[0]`` is a number; edits in place still reach it
        self._factor, self._view, self._assigned = S, None, A

    def set_factor(self, value) -> None:
        """Assign from a lower-triangular factor (validated; a copy is kept)."""
        if value is None and self.semidefinite:
            self._factor, self._view, self._assigned = None, None, None
            return
        S: np.ndarray | None = as_lower_factor(
            value, f"{self.name}1_2", self.dim, singular_ok=self.semidefinite
        )
        if self.semidefinite and not np.any(S):
            S = None
        self._factor, self._view, self._assigned = S, None, None

    def set_trusted_factor(self, S: np.ndarray) -> None:
        """Install a factor computed by the filter itself (no validation; not copied)."""
        self._factor, self._view, self._assigned = S, None, None

    def factor_or_zeros(self) -> np.ndarray:
        """The factor, with an absent (zero) covariance shown as zeros."""
        S = self.factor()
        if S is None:
            n = self._size()
            return np.zeros((n, n))
        return S
