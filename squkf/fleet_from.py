"""A fleet from single filters: what ``Fleet.from_filters`` and ``Fleet.from_template`` read.

The filters checked (:func:`as_filters`), stacked (:func:`stacked_filters`) or read as a template
(:func:`template`), and a per-point model function called on a fleet's stacked points
(:class:`PerPoint`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping

import numpy as np

from .boundary.config import Config, check_pending, stacked
from .checks import short_repr
from .errors import ParameterError, UnsetError
from .ukf import SquareRootUKF

__all__ = ["PerPoint", "as_filters", "stacked_filters", "template"]


def as_filters(filters) -> list[SquareRootUKF]:
    """``Fleet.from_filters``'s ``filters`` as a list of :class:`squkf.SquareRootUKF`, or a ParameterError."""
    if filters is None or isinstance(filters, (str, bytes, Mapping)) or not isinstance(filters, Iterable):
        raise ParameterError(
            f"filters must be a sequence of squkf.SquareRootUKF, got filters={short_repr(filters)}"
            f" ({type(filters).__name__})"
        )
    filters = list(filters)
    for k, f in enumerate(filters):
        if isinstance(f, SquareRootUKF):
            continue
        kind = type(f).__name__
        if type(f).__module__.split(".")[0] == "filterpy":
            how = (
                " build each as squkf.SquareRootUKF with the same arguments (dim_x, dim_z, dt, hx, fx,"
                " points, the hooks) and vectorized=True, and give it the filterpy filter's x, P, Q and R"
                " (g.x, g.P, g.Q, g.R = f.x, f.P, f.Q, f.R)"
                if kind == "UnscentedKalmanFilter"
                else " a fleet stacks square-root UKFs only"
            )
            raise ParameterError(f"filters[{k}] is filterpy's {kind}, not a squkf.SquareRootUKF:{how}")
        raise ParameterError(f"filters[{k}] is not a squkf.SquareRootUKF: got {short_repr(f)} ({kind})")
    return filters


class PerPoint:
    """A per-point model function called on a fleet's stacked points, point by point.

    ``fx(x, dt, **kw)``, ``hx(x, **kw)``, or with a noise argument ``fx(x, w, dt)``, ``hx(x, v)``
    (``noise``), as a filter with ``vectorized=False`` calls them; the fleet gives ``(..., N, d)``
    points (and noise points) and gets ``(..., N, d_out)`` values. A class, so a fleet of it pickles
    where the function does.

    Parameters
    ----------
    fn : callable
    noise : bool
        The first argument after the points is their noise points.
    """

    def __init__(self, fn: Callable, noise: bool):
        self.fn, self.noise = fn, noise

    def __call__(self, X: np.ndarray, *args, **kwargs) -> np.ndarray:
        lead = X.shape[:-1]
        points = X.reshape(-1, X.shape[-1])
        if self.noise:
            W, rest = args[0], args[1:]
            noise = W.reshape(-1, W.shape[-1])
            values = [self.fn(x, w, *rest, **kwargs) for x, w in zip(points, noise)]
        else:
            values = [self.fn(x, *args, **kwargs) for x in points]
        try:
            return np.asarray(values, dtype=float).reshape(lead + (-1,))
        except (TypeError, ValueError):  # values of different shapes, or not numbers: said by the step
            return np.asarray(values, dtype=object)


def stacked_filters(filters) -> tuple:
    """``Fleet.from_filters``'s ``filters``, checked, as their configuration and stacked ``x``, ``P1_2``,
    ``Q1_2``, ``R1_2`` (:func:`squkf.boundary.config.stacked`)."""
    return stacked(as_filters(filters))


def template(ukf) -> tuple[Config, tuple]:
    """``Fleet.from_template``'s filter as a fleet's configuration (a per-point ``fx`` and ``hx`` as
    :class:`PerPoint`) and its ``x``, ``P1_2``, ``Q1_2``, ``R1_2``; raises as ``Fleet.from_template``
    says."""
    f = as_filters([ukf])[0]
    c = f.configuration()
    check_pending(c.step, c.plan, "the template")
    for name in ("x", "P"):
        value = getattr(f, name)
        if value is None or np.isnan(value).all():
            raise UnsetError(f"a fleet of the template needs its {name}, but {name} was never set")
    fx, hx = c.fx, c.hx
    if fx is None or hx is None:
        missing = "fx" if fx is None else "hx"
        raise ParameterError(f"a fleet needs fx and hx, but the template has {missing}=None")
    if not c.vectorized:
        c = c._replace(fx=PerPoint(fx, bool(c.fx_noise)), hx=PerPoint(hx, bool(c.hx_noise)))
    return c, (f.x, f.P1_2, f.Q1_2, f.R1_2)
