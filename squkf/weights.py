"""Sigma-point families: unit sigma points and their weights.

A *family* is any object with three methods, each taking the dimension ``n``
of the random vector the points are drawn for::

    num_sigmas(n) -> int
    unit_sigma_points(n) -> ndarray, shape (num_sigmas(n), n)
    weights(n) -> (Wm, Wc), each ndarray of shape (num_sigmas(n),)

The sigma points for a mean ``x`` and a lower factor ``S`` (``P = S @ S.T``)
are ``x + xi @ S.T``, one point per row, where ``xi`` are the unit points:
they are built from the factor's columns, never from a re-factored ``P``.

Families whose points are a centre and ``+/- gamma`` along each axis (Merwe's
scaled points and Julier's) also offer ``gamma(n)`` and
``augmented(n_more)``; those two are what the *augmented* second sigma-point
set of g13ej needs (``augmented`` also serves noise entering the model). An
adapter of another library's points offers ``as_native()``, its squkf
equivalent or None. :class:`SigmaPointFamily` states the three optional
methods and their shapes.

filterpy's own points objects (``MerweScaledSigmaPoints``,
``JulierSigmaPoints``, ``SimplexSigmaPoints`` or anything with the same
interface) are accepted wherever a family is, through :func:`as_family`.
"""

from __future__ import annotations

import copy
import numbers
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

from .checks import short_repr
from .errors import ParameterError

__all__ = [
    "SigmaPointFamily",
    "MerweScaledWeights",
    "JulierWeights",
    "SimplexWeights",
    "CubatureWeights",
    "FilterpyPoints",
    "as_family",
]


@runtime_checkable
class SigmaPointFamily(Protocol):
    """The protocol every sigma-point family follows (see the module docstring).

    The three methods below are required; ``isinstance(obj, SigmaPointFamily)``
    checks for them (and for nothing else).

    Notes
    -----
    A family may also offer three optional methods. squkf looks for each with
    ``hasattr`` where it needs it and does without it otherwise, so they are
    not members of the protocol (an object without them is still a family):

    ``gamma(n) -> float``
        For a family whose unit points at dimension ``n`` are a centre and
        ``+/- gamma`` along each axis, ``[0; gamma I; -gamma I]`` of shape
        ``(2 n + 1, n)`` (Merwe's and Julier's): that distance, ``gamma``.
        g13ej's augmented second set needs it of the family it draws with
        (``augmented(n)``, at dimension ``2 n``): its ``2 n`` noise points are
        ``+/- gamma(2 n)`` along the noise axes.
    ``augmented(n_more) -> SigmaPointFamily``
        The same family for a vector ``n_more`` dimensions longer, with the
        same spread (Merwe's ``kappa`` lowered by ``n_more``). At dimension
        ``n + n_more`` its unit points have shape
        ``(num_sigmas(n + n_more), n + n_more)`` and its weights shape
        ``(num_sigmas(n + n_more),)``. It serves the augmented second set
        (``n_more = n``: ``4 n + 1`` points of dimension ``2 n``) and the first
        set when noise enters the model (``n_more`` the noise's dimension, as
        ``fx_noise`` or ``hx_noise``). Without it the augmented second set is
        refused, and a family serves a noise-augmented dimension as it is.
    ``as_native() -> SigmaPointFamily or None``
        For an adapter of another library's points object
        (:class:`FilterpyPoints`): the equivalent squkf family
        (:class:`MerweScaledWeights`, :class:`JulierWeights`), or None when
        there is none. With an equivalent the points object serves sets of any
        dimension (its equivalent draws those it was not built for), and the
        augmented second set takes the equivalent's ``augmented``; without one
        it serves the dimension it was built for alone.

    Examples
    --------
    Any object with the three methods is a family; here the cubature rule
    written from scratch:

    >>> import numpy as np
    >>> from squkf import SigmaPointFamily, unscented_transform
    >>> class TwoPoint:
    ...     def num_sigmas(self, n):
    ...         return 2 * n
    ...     def unit_sigma_points(self, n):
    ...         return np.sqrt(n) * np.vstack([np.eye(n), -np.eye(n)])
    ...     def weights(self, n):
    ...         w = np.full(2 * n, 1 / (2 * n))
    ...         return w, w
    >>> isinstance(TwoPoint(), SigmaPointFamily)
    True
    >>> mean, S = unscented_transform(np.square, [1.0], [[0.5]], points=TwoPoint())
    >>> print(np.round(mean, 6), np.round(S, 6))
    [1.25] [[1.]]
    """

    def num_sigmas(self, n: int) -> int:
        """The number of points ``N`` for a random vector of dimension ``n``."""
        ...

    def unit_sigma_points(self, n: int) -> np.ndarray:
        """The unit points ``xi``, shape ``(N, n)``: a point is ``x + xi[i] @ S.T``."""
        ...

    def weights(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """The mean and covariance weights ``(Wm, Wc)``, each of shape ``(N,)``."""
        ...


def _frozen(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


def real_number(value, name: str, errno: int | None = None) -> float:
    """``value`` as a float if it is one real number (not a bool, string, complex or array).

    ``float()`` alone would parse strings and, for numpy complex scalars, drop
    the imaginary part with only a warning.
    """
    if isinstance(value, np.ndarray) and value.ndim == 0:
        value = value[()]
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise ParameterError(
            f"{name} must be a real number, got {name}={value!r} (a {type(value).__name__})", errno=errno
        )
    try:
        return float(value)
    except OverflowError:  # a Python integer beyond float64's range
        raise ParameterError(
            f"{name} must be a finite real number, got {name}={short_repr(value)}: beyond float64's range",
            errno=errno,
        ) from None


class _Described:
    """``"<prefix> <family!r> for n=<n>"``, a message's subject, formed only when a message is."""

    __slots__ = ("family", "n", "prefix")

    def __init__(self, family, n: int, prefix: str = ""):
        self.family, self.n, self.prefix = family, n, prefix

    def of(self, prefix: str) -> _Described:
        return _Described(self.family, self.n, prefix + " ")

    def __str__(self) -> str:
        return f"{self.prefix}{self.family!r} for n={self.n}"


def real_array(value, name: str | _Described, errno: int | None = None, error=ParameterError) -> np.ndarray:
    """``value`` as a new float64 array if it holds real numbers (int or float dtype) only.

    Complex, bool, string and object arrays are refused rather than cast
    (casting complex to float drops the imaginary part with only a warning).
    """
    try:
        arr = np.asarray(value)
    except Exception as exc:  # ragged nesting, objects whose __array__ fails
        raise error(f"{name} must be an array of real numbers: {exc}", errno=errno) from None
    if arr.dtype.kind not in "iuf":
        kind = "complex" if arr.dtype.kind == "c" else f"dtype {arr.dtype}"
        raise error(
            f"{name} must be an array of real numbers, got {kind} ({type(value).__name__})", errno=errno
        )
    return np.array(arr, dtype=float)


def _dimension(n) -> int:
    if isinstance(n, (bool, np.bool_)) or not isinstance(n, numbers.Integral) or n < 1:
        raise ParameterError(f"n (the dimension) must be a positive integer, got n={n!r}")
    return int(n)


def _alpha(value, errno: int | None = 173) -> float:
    alpha = real_number(value, "alpha", errno)
    if not (np.isfinite(alpha) and alpha > 0):
        raise ParameterError(f"alpha must be a positive finite number, got alpha={alpha!r}", errno=errno)
    a2 = alpha * alpha
    if not (np.isfinite(a2) and a2 >= np.finfo(float).tiny):
        raise ParameterError(
            f"alpha**2 must be a positive finite normal number (about 1.5e-154 < alpha < 1.3e154), "
            f"got alpha={alpha!r}",
            errno=errno,
        )
    return alpha


def _beta(value) -> float:
    beta = real_number(value, "beta")
    if not np.isfinite(beta):
        raise ParameterError(f"beta must be a finite number, got beta={beta!r}")
    return beta


def _kappa(value, errno: int | None = 172) -> float:
    kappa = real_number(value, "kappa", errno)
    if not np.isfinite(kappa):
        raise ParameterError(f"kappa must be a finite number, got kappa={kappa!r}", errno=errno)
    return kappa


class _CachedFamily:
    """Caches unit points and weights per dimension (they never change)."""

    if TYPE_CHECKING:
        # Supplied by each subclass; declared for the type checker only, so nothing changes at run time.
        def num_sigmas(self, n: int) -> int: ...

        def _unit_points(self, n: int) -> np.ndarray: ...

        def _weights(self, n: int) -> tuple[np.ndarray, np.ndarray]: ...

    def _cache(self) -> dict:
        c = self.__dict__.get("_by_n")
        if c is None:
            c = self.__dict__["_by_n"] = {}
        return c

    def unit_sigma_points(self, n: int) -> np.ndarray:
        """Unit sigma points for dimension ``n``, shape ``(num_sigmas(n), n)``, read-only."""
        try:
            return self.__dict__["_by_n"][n][0]
        except KeyError:
            return self._fill(n)[0]

    def weights(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Mean and covariance weights ``(Wm, Wc)`` for dimension ``n``, read-only."""
        try:
            return self.__dict__["_by_n"][n][1]
        except KeyError:
            return self._fill(n)[1]

    def _fill(self, n: int) -> tuple:
        n = _dimension(n)
        what = _Described(self, n)  # (formed only for a message: a filterpy object's repr is slow)
        xi = real_array(self._unit_points(n), what.of("the unit sigma points of"))
        Wm, Wc = self._weights(n)
        Wm = real_array(Wm, what.of("the mean weights Wm of"))
        Wc = real_array(Wc, what.of("the covariance weights Wc of"))
        N = self.num_sigmas(n)
        if xi.shape != (N, n) or Wm.shape != (N,) or Wc.shape != (N,):
            raise ParameterError(
                f"{what} gives unit points of shape {xi.shape} and weights of shapes {Wm.shape}, "
                f"{Wc.shape}; expected ({N}, {n}) and ({N},)"
            )
        if not (np.isfinite(xi).all() and np.isfinite(Wm).all() and np.isfinite(Wc).all()):
            raise ParameterError(
                f"{what} gives non-finite weights or unit points: its parameters are outside the "
                "range that can be used at this dimension",
                errno=getattr(self, "_nonfinite_errno", None),
            )
        entry = (_frozen(xi), (_frozen(Wm), _frozen(Wc)))
        self._cache()[n] = entry
        return entry

    def __getstate__(self):
        state = self.__dict__.copy()
        state.pop("_by_n", None)
        return state

    def __eq__(self, other):
        return type(self) is type(other) and self.__getstate__() == other.__getstate__()

    def __hash__(self):
        return hash((type(self), tuple(sorted(self.__getstate__().items()))))

    def __repr__(self):
        args = ", ".join(f"{k}={v!r}" for k, v in self.__getstate__().items())
        return f"{type(self).__name__}({args})"


class MerweScaledWeights(_CachedFamily):
    """Van der Merwe's scaled sigma points, with g13ej's parametrisation.

    For dimension ``L``: ``lambda = alpha**2 * (L + kappa) - L``,
    ``gamma = sqrt(L + lambda)``, points ``[0, +gamma e_j, -gamma e_j]``,
    ``Wm = [lambda/(L+lambda), 1/(2(L+lambda)), ...]`` and ``Wc`` equal to
    ``Wm`` except ``Wc[0] = Wm[0] + 1 - alpha**2 + beta``.

    Parameters
    ----------
    alpha : float
        Spread, ``alpha > 0`` (g13ej's ROPT(3)/ROPT(6); default 1), finite and
        with ``alpha**2`` a normal float.
    beta : float
        Prior-distribution parameter, finite (2 is optimal for a Gaussian; default 2).
    kappa : float or None
        Secondary scaling, finite. ``None`` means ``3 - L`` at whatever
        dimension the family is used (g13ej's default). Must satisfy
        ``kappa > -L``, checked when the family is used at dimension ``L``.

    Raises
    ------
    ParameterError
        At construction, for a parameter that is not a real number or is out
        of its domain (``errno`` 173 for alpha, 172 for kappa); when used at a
        dimension ``L``, for ``kappa <= -L`` (172) or when
        ``L + lambda = alpha**2 (L + kappa)`` is not a positive finite number
        in floating point (173; e.g. alpha below about 1e-8 with ``L + kappa = 3``).

    Examples
    --------
    >>> import numpy as np
    >>> from squkf import MerweScaledWeights
    >>> w = MerweScaledWeights(alpha=0.5, beta=2.0, kappa=0.0)
    >>> w.num_sigmas(2)
    5
    >>> Wm, Wc = w.weights(2)
    >>> print(Wm, Wc)
    [-3.  1.  1.  1.  1.] [-0.25  1.    1.    1.    1.  ]
    >>> round(w.gamma(2), 6)
    0.707107

    The unit points have mean zero and identity covariance under these weights:

    >>> xi = w.unit_sigma_points(2)
    >>> bool(np.allclose(Wm @ xi, 0.0)), bool(np.allclose((xi.T * Wc) @ xi, np.eye(2)))
    (True, True)

    The family of g13ej's augmented second set keeps the spread ``L + kappa``:

    >>> w.augmented(2)
    MerweScaledWeights(alpha=0.5, beta=2.0, kappa=-2.0)
    """

    _nonfinite_errno = 173

    def __init__(self, alpha: float = 1.0, beta: float = 2.0, kappa: float | None = None):
        alpha = _alpha(alpha)
        beta = _beta(beta)
        if kappa is not None:
            kappa = _kappa(kappa)
        self.alpha = alpha
        self.beta = beta
        self.kappa = kappa

    def kappa_for(self, n: int) -> float:
        """The kappa used at dimension ``n`` (``3 - n`` when ``kappa`` is None)."""
        kappa = 3.0 - n if self.kappa is None else self.kappa
        if not n + kappa > 0:
            raise ParameterError(
                f"kappa must be > -{n} for a {n}-dimensional sigma-point set, got kappa={kappa!r}",
                errno=172,
            )
        return kappa

    def _lambda(self, n: int) -> float:
        kappa = self.kappa_for(n)
        lam = self.alpha**2 * (n + kappa) - n
        spread = n + lam
        # lambda is formed as filterpy and g13ej form it, so L + lambda loses the
        # low bits of alpha**2 (L + kappa): a tiny alpha makes it exactly 0
        if not (np.isfinite(spread) and spread > 0):
            raise ParameterError(
                f"alpha={self.alpha!r} and kappa={kappa!r} give L + lambda = alpha**2 * (L + kappa) "
                f"= {spread!r} in floating point at L={n}; it must be a positive finite number "
                "(alpha is too small or too large for this kappa)",
                errno=self._nonfinite_errno,
            )
        return lam

    def num_sigmas(self, n: int) -> int:
        """``2 n + 1``."""
        return 2 * n + 1

    def gamma(self, n: int) -> float:
        """Distance of the non-central unit points from the centre: ``sqrt(n + lambda)``."""
        return float(np.sqrt(n + self._lambda(n)))

    def _unit_points(self, n):
        g = self.gamma(n)
        eye = np.eye(n)
        return np.vstack([np.zeros((1, n)), g * eye, -g * eye])

    def _weights(self, n):
        lam = self._lambda(n)
        Wm = np.full(2 * n + 1, 0.5 / (n + lam))
        Wm[0] = lam / (n + lam)
        Wc = Wm.copy()
        Wc[0] += 1.0 - self.alpha**2 + self.beta
        return Wm, Wc

    def augmented(self, n_state: int) -> MerweScaledWeights:
        """The family g13ej uses for the augmented second set of an ``n_state`` state.

        Same alpha and beta; kappa lowered by ``n_state`` so that
        ``L' + kappa' = L + kappa`` (both sets have the same spread). With
        ``kappa=None`` this gives g13ej's default ``3 - 2 n_state``.
        """
        kappa = None if self.kappa is None else self.kappa - n_state
        return type(self)._from_params(self.alpha, self.beta, kappa)

    @classmethod
    def _from_params(cls, alpha, beta, kappa):
        return MerweScaledWeights(alpha, beta, kappa)


class JulierWeights(MerweScaledWeights):
    """Julier and Uhlmann's (1997) sigma points: Merwe's with ``alpha = 1``, ``beta = 0``.

    Parameters
    ----------
    kappa : float or None
        ``None`` means ``3 - n`` (Julier and Uhlmann's choice for a Gaussian).

    Examples
    --------
    >>> import numpy as np
    >>> from squkf import JulierWeights
    >>> Wm, Wc = JulierWeights().weights(1)  # kappa = 3 - 1 = 2
    >>> print(np.round(Wm, 4))
    [0.6667 0.1667 0.1667]
    """

    _nonfinite_errno = 172

    def __init__(self, kappa: float | None = None):
        super().__init__(alpha=1.0, beta=0.0, kappa=kappa)

    def __getstate__(self):
        return {"kappa": self.kappa}

    def __setstate__(self, state):
        self.__init__(**state)

    @classmethod
    def _from_params(cls, alpha, beta, kappa):
        return JulierWeights(kappa)


class SimplexWeights(_CachedFamily):
    """Julier's spherical simplex sigma points: ``n + 1`` points of equal weight.

    The unit points are the columns of filterpy's ``SimplexSigmaPoints``
    construction (Moireau and Chapelle 2011), so the two agree point for point.

    Examples
    --------
    >>> import numpy as np
    >>> from squkf import SimplexWeights
    >>> s = SimplexWeights()
    >>> s.num_sigmas(2)
    3
    >>> print(np.round(s.unit_sigma_points(2), 4))
    [[-1.2247  0.7071]
     [ 1.2247  0.7071]
     [ 0.     -1.4142]]
    """

    def num_sigmas(self, n: int) -> int:
        """``n + 1``."""
        return n + 1

    def _unit_points(self, n):
        lam = n / (n + 1)
        pts = np.zeros((n, n + 1))
        pts[0, 0] = -1.0 / np.sqrt(2 * lam)
        pts[0, 1] = 1.0 / np.sqrt(2 * lam)
        for d in range(2, n + 1):
            r = 1.0 / np.sqrt(lam * d * (d + 1))
            pts[d - 1, :d] = r
            pts[d - 1, d] = -d * r
        return (np.sqrt(n) * pts).T

    def _weights(self, n):
        w = np.full(n + 1, 1.0 / (n + 1))
        return w, w.copy()


class CubatureWeights(_CachedFamily):
    """Spherical-radial cubature points (Arasaratnam and Haykin 2009).

    ``2 n`` points ``+/- sqrt(n) e_j`` with equal weights ``1/(2n)``, in the
    order of filterpy's ``CubatureKalmanFilter``: all ``+`` points, then all
    ``-`` points.

    Examples
    --------
    >>> import numpy as np
    >>> from squkf import CubatureWeights
    >>> Wm, Wc = CubatureWeights().weights(3)
    >>> print(Wm)
    [0.16666667 0.16666667 0.16666667 0.16666667 0.16666667 0.16666667]
    """

    def num_sigmas(self, n: int) -> int:
        """``2 n``."""
        return 2 * n

    def _unit_points(self, n):
        g = np.sqrt(n)
        eye = np.eye(n)
        return np.vstack([g * eye, -g * eye])

    def _weights(self, n):
        w = np.full(2 * n, 0.5 / n)
        return w, w.copy()


class FilterpyPoints(_CachedFamily):
    """Adapter that lets a filterpy points object act as a family.

    The object's weights (``Wm``, ``Wc``) and geometry are used; its unit
    points are read once by asking it for the sigma points of a zero mean and
    an identity covariance, with a Cholesky square root and plain subtraction
    (so an angle-wrapping ``subtract`` cannot fold them). The sigma points
    themselves are then built from the filter's own factor.

    Parameters
    ----------
    points : object
        Has ``n``, ``num_sigmas()``, ``sigma_points(x, P)``, ``Wm`` and ``Wc``.

    Raises
    ------
    ParameterError
        If ``points`` lacks one of those, if its ``n`` is not a positive
        integer, or if one of the parameters it has (``alpha``, ``beta``,
        ``kappa``) is not a real number in its domain: ``alpha`` positive and
        finite, ``beta`` finite, ``kappa`` finite with ``n + kappa > 0``. Using
        the adapter at a dimension other than ``n``, or a points object whose
        weights or points are not finite, raises it too.

    Examples
    --------
    Passing a filterpy object as ``points`` wraps it automatically; wrapped by
    hand it gives the same points and weights as the native family:

    >>> import numpy as np
    >>> from filterpy.kalman import MerweScaledSigmaPoints
    >>> from squkf import FilterpyPoints, MerweScaledWeights
    >>> fp = FilterpyPoints(MerweScaledSigmaPoints(2, alpha=0.5, beta=2.0, kappa=0.0))
    >>> native = MerweScaledWeights(alpha=0.5, beta=2.0, kappa=0.0)
    >>> bool(np.allclose(fp.unit_sigma_points(2), native.unit_sigma_points(2)))
    True
    >>> fp.as_native() == native
    True
    """

    def __init__(self, points):
        for attr in ("num_sigmas", "sigma_points", "Wm", "Wc"):
            if not hasattr(points, attr):
                raise ParameterError(
                    f"points must be a sigma-point family or a filterpy points object; "
                    f"{type(points).__name__} has no attribute {attr!r}"
                )
        name = type(points).__name__
        if hasattr(points, "n"):
            n = points.n
            if isinstance(n, (bool, np.bool_)) or not isinstance(n, numbers.Integral) or n < 1:
                raise ParameterError(f"{name}.n must be a positive integer, got n={n!r}")
            n = int(n)
        else:
            n = len(real_array(points.Wm, f"{name}.Wm").reshape(-1)) // 2
        if hasattr(points, "alpha"):
            self._param(points, "alpha", _alpha)
        if hasattr(points, "beta"):
            self._param(points, "beta", _beta)
        if hasattr(points, "kappa"):
            kappa = self._param(points, "kappa", _kappa)
            if not n + kappa > 0:
                raise ParameterError(f"{name}(n={n}, kappa={kappa!r}): kappa must be > -n = {-n}", errno=172)
        self.points = points
        self.n = n

    @staticmethod
    def _param(points, attr, check):
        try:
            return check(getattr(points, attr))
        except ParameterError as exc:
            raise ParameterError(f"{type(points).__name__}: {exc}", errno=exc.errno) from None

    def __getstate__(self):
        return {"points": self.points, "n": self.n}

    def __setstate__(self, state):
        self.__dict__.update(state)

    def _check(self, n):
        if n != self.n:
            raise ParameterError(
                f"the points object {type(self.points).__name__} was built for n={self.n}, but is used "
                f"for n={n} (the filter's dim_x, or 2 dim_x for an augmented set): build it with n={n}"
            )

    def num_sigmas(self, n: int) -> int:
        """The wrapped object's ``num_sigmas()``."""
        self._check(n)
        return int(self.points.num_sigmas())

    def _unit_points(self, n):
        from scipy.linalg import cholesky

        self._check(n)
        probe = copy.copy(self.points)
        if hasattr(probe, "sqrt"):
            probe.sqrt = cholesky
        if hasattr(probe, "subtract"):
            probe.subtract = np.subtract
        xi = real_array(probe.sigma_points(np.zeros(n), np.eye(n)), f"{type(self.points).__name__}'s points")
        if xi.size != self.num_sigmas(n) * n:
            raise ParameterError(
                f"{type(self.points).__name__}.sigma_points gave {xi.size} numbers for "
                f"num_sigmas() = {self.num_sigmas(n)} points of dimension {n}"
            )
        return xi.reshape(self.num_sigmas(n), n)

    def _weights(self, n):
        self._check(n)
        name = type(self.points).__name__
        return real_array(self.points.Wm, f"{name}.Wm"), real_array(self.points.Wc, f"{name}.Wc")

    def as_native(self) -> MerweScaledWeights | None:
        """The equivalent squkf family for Merwe- or Julier-type objects, else None."""
        p = self.points
        name = type(p).__name__
        if "Merwe" in name and all(hasattr(p, a) for a in ("alpha", "beta", "kappa")):
            key: tuple = (MerweScaledWeights, p.alpha, p.beta, p.kappa)
        elif "Julier" in name and hasattr(p, "kappa"):
            key = (JulierWeights, p.kappa)
        else:
            return None
        # made once per parameters read (a filter's plan asks more than once; the object may be changed)
        kept = self.__dict__.get("_native")
        if kept is None or kept[0] != key:
            kept = self.__dict__["_native"] = (key, key[0](*key[1:]))
        return kept[1]


class WrittenWeights(_CachedFamily):
    """A family's unit points with the weights a program wrote (``ukf.Wm = ...``, a filterpy habit).

    It serves the one dimension it was written for; a set of another (an
    augmented one) refuses, naming ``points``.

    Parameters
    ----------
    base : sigma-point family
        The family whose unit points are kept.
    n : int
    Wm, Wc : ndarray, shape (N,)
        The weights written, ``N = base.num_sigmas(n)``.
    """

    def __init__(self, base, n: int, Wm: np.ndarray, Wc: np.ndarray):
        self.base, self.n, self.Wm, self.Wc = base, n, Wm, Wc

    def _check(self, n: int) -> None:
        if n != self.n:
            raise ParameterError(
                f"the weights written as Wm and Wc serve the first set's dimension {self.n}, but the filter"
                f" also draws a set of dimension {n}: give points= a family with those weights instead"
            )

    def num_sigmas(self, n: int) -> int:
        """The number of weights written."""
        self._check(n)
        return int(self.Wm.shape[0])

    def _unit_points(self, n: int) -> np.ndarray:
        self._check(n)
        return self.base.unit_sigma_points(n)

    def _weights(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        self._check(n)
        return self.Wm, self.Wc

    # compared by identity: two programs' written weights are never taken for one another
    __eq__ = object.__eq__
    __hash__ = object.__hash__

    def __repr__(self) -> str:
        return f"WrittenWeights({self.base!r}, n={self.n}, Wm={self.Wm.tolist()}, Wc={self.Wc.tolist()})"


def as_family(points) -> SigmaPointFamily:
    """Return ``points`` as a family: squkf families pass through, filterpy objects are wrapped.

    Raises
    ------
    ParameterError
        If ``points`` is neither.
    """
    if isinstance(points, (_CachedFamily,)) or (
        not hasattr(points, "sigma_points") and isinstance(points, SigmaPointFamily)
    ):  # (the protocol's check is slow: a filterpy object, with sigma_points, skips it)
        return points
    return FilterpyPoints(points)
