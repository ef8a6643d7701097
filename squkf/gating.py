"""Outlier gating: a measurement whose normalised innovation is too large is treated as missing.

The test statistic is the normalised innovation squared (NIS) that the update
already has, ``w.w`` with ``w = Sy^-1 y`` (``Sy`` the innovation factor, ``y``
the innovation): no covariance is formed and nothing is inverted. A
:class:`Gate` rejects

- the whole measurement when its NIS exceeds the threshold for its number of
  measured components ``m`` (``per_component=False``, the default), or
- each component ``j`` whose own normalised innovation ``y_j^2 / Py_jj``
  exceeds the threshold for one component (``per_component=True``), where
  ``Py_jj`` is the squared norm of row ``j`` of ``Sy``; the update then uses
  the components that passed, as a partial measurement.

A threshold is a chi-square probability (``Gate(0.999)``: reject when the
statistic is above the 0.999 quantile of the chi-square distribution with
``m`` degrees of freedom, or 1 per component) or a squared Mahalanobis
distance (``Gate(nis=16.0)``, the same for every ``m``). A statistic equal to
the threshold passes.
"""

from __future__ import annotations

import functools
import math
from numbers import Real

import numpy as np

from .errors import ParameterError

__all__ = ["Gate", "as_gate"]


@functools.lru_cache(maxsize=256)
def _chi2_quantile(probability: float, dof: int) -> float:
    from scipy.stats import chi2  # scipy.stats takes a while to import: only when a gate is used

    return float(chi2.ppf(probability, dof))


def _real(value, name: str) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (Real, np.floating, np.integer)):
        raise ParameterError(f"{name} must be a real number, got {name}={value!r}")
    return float(value)


class Gate:
    """A gate on the normalised innovation squared (NIS) of each update.

    Parameters
    ----------
    probability : float, optional
        Chi-square probability in the open interval (0, 1), e.g. 0.999: a
        measurement of ``m`` measured components is rejected when its NIS is
        above ``chi2.ppf(probability, m)`` (one degree of freedom per
        component with ``per_component=True``).
    nis : float, optional, keyword-only
        Instead of ``probability``: the threshold itself, a squared
        Mahalanobis distance (positive, finite), the same for any ``m``.
    per_component : bool, keyword-only
        Test each measured component by its own normalised innovation
        ``y_j^2 / Py_jj`` and reject only those above the threshold (the rest
        update the state as a partial measurement), instead of the whole
        measurement at once.

    Examples
    --------
    >>> from squkf import Gate
    >>> gate = Gate(0.99)
    >>> round(gate.threshold(2), 4)  # chi-square, 2 degrees of freedom
    9.2103
    >>> Gate(nis=16.0).threshold(3)
    16.0
    """

    __slots__ = ("_probability", "_nis", "_per_component")

    def __init__(
        self, probability: float | None = None, *, nis: float | None = None, per_component: bool = False
    ):
        if (probability is None) == (nis is None):
            raise ParameterError(
                "Gate needs exactly one threshold: a chi-square probability (Gate(0.999))"
                " or a squared Mahalanobis distance (Gate(nis=16.0)),"
                f" got probability={probability!r}, nis={nis!r}"
            )
        if probability is not None:
            p = _real(probability, "probability")
            if not 0.0 < p < 1.0:
                raise ParameterError(
                    f"probability must be in the open interval (0, 1), got probability={probability!r}"
                )
            probability = p
        if nis is not None:
            d = _real(nis, "nis")
            if not (d > 0.0 and math.isfinite(d)):
                raise ParameterError(f"nis must be a positive finite number, got nis={nis!r}")
            nis = d
        if not isinstance(per_component, (bool, np.bool_)):
            raise ParameterError(f"per_component must be True or False, got per_component={per_component!r}")
        # read-only afterwards (properties below): a gate is checked once, when made
        self._probability = probability
        self._nis = nis
        self._per_component = bool(per_component)

    @property
    def probability(self) -> float | None:
        """The chi-square probability, or None when the threshold is given as ``nis``."""
        return self._probability

    @property
    def nis(self) -> float | None:
        """The threshold as a squared Mahalanobis distance, or None when given as a probability."""
        return self._nis

    @property
    def per_component(self) -> bool:
        """Whether each measured component is tested on its own."""
        return self._per_component

    def threshold(self, m: int) -> float:
        """The threshold for a statistic of ``m`` degrees of freedom (1 per component)."""
        if self.nis is not None:
            return self.nis
        return _chi2_quantile(self.probability, 1 if self.per_component else int(m))  # type: ignore[arg-type]

    def reject(self, y: np.ndarray, Sy: np.ndarray, nis: np.ndarray) -> np.ndarray:
        """Which measured components are rejected.

        Parameters
        ----------
        y : ndarray, shape (..., m)
            Innovations of the measured components.
        Sy : ndarray, shape (..., m, m)
            Lower factors of their innovation covariance.
        nis : ndarray, shape (...)
            ``w.w``, ``w = Sy^-1 y``, as the update computed it.

        Returns
        -------
        ndarray of bool, shape (..., m)
            True where a component is rejected (with ``per_component=False``,
            all of a measurement's components or none). A non-finite
            statistic is rejected.
        """
        m = y.shape[-1]
        limit = self.threshold(m)
        if self.per_component:
            # an outlier beyond float64's range squared is an inf statistic, rejected as it should be
            with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
                py = np.einsum("...jk,...jk->...j", Sy, Sy)
                stat = y * y / py
                if np.isinf(py).any():  # a spread beyond that range squared: (y / s)^2 / |Sy_j / s|^2
                    s = np.max(np.abs(Sy), axis=-1)
                    scaled = (y / s) ** 2 / np.einsum(
                        "...jk,...jk->...j", Sy / s[..., None], Sy / s[..., None]
                    )
                    stat = np.where(np.isinf(py), scaled, stat)
            return ~(stat <= limit)
        whole = ~(np.asarray(nis) <= limit)
        return np.broadcast_to(whole[..., None], y.shape).copy()

    def __eq__(self, other) -> bool:
        return isinstance(other, Gate) and (self.probability, self.nis, self.per_component) == (
            other.probability,
            other.nis,
            other.per_component,
        )

    def __hash__(self) -> int:
        return hash((Gate, self.probability, self.nis, self.per_component))

    def __repr__(self) -> str:
        what = f"{self.probability!r}" if self.nis is None else f"nis={self.nis!r}"
        return f"Gate({what}{', per_component=True' if self.per_component else ''})"

    def __reduce__(self):
        return (_make_gate, (self.probability, self.nis, self.per_component))


def _make_gate(probability, nis, per_component) -> Gate:
    return Gate(probability, nis=nis, per_component=per_component)


def as_gate(value) -> Gate | None:
    """``gate=`` as given to a filter: None (no gating), a :class:`Gate`, or a probability.

    Parameters
    ----------
    value : None, Gate or float
        A bare number is a chi-square probability in (0, 1).

    Returns
    -------
    Gate or None

    Raises
    ------
    ParameterError
        Anything else, a number outside (0, 1) included (a squared
        Mahalanobis distance is spelled ``Gate(nis=...)``).
    """
    if value is None:
        return None
    if isinstance(value, Gate):
        return value
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (Real, np.floating, np.integer)):
        raise ParameterError(
            f"gate must be None, a squkf.Gate or a chi-square probability in (0, 1), got gate={value!r}"
        )
    try:
        p = float(value)
    except OverflowError:  # a Python integer beyond float64's range: far outside (0, 1)
        p = float("inf")
    if not 0.0 < p < 1.0:
        raise ParameterError(
            f"gate={value!r} is not a chi-square probability in the open interval (0, 1);"
            f" for a threshold on the squared Mahalanobis distance write gate=squkf.Gate(nis={value!r})"
        )
    return Gate(p)
