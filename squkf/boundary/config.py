"""A filter's configuration as one record: what the front ends read of each other.

``SquareRootUKF.configuration()`` and ``Fleet.configuration()`` give a
:class:`Config`; ``Fleet.from_filters`` compares the filters' records and
builds the fleet from one, ``fleet[k]`` builds a filter from the fleet's, and
the smoothers and :mod:`squkf.dask` read the time step, the model and the
noise from it. No module reads another's private members.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np

from ..angles import _AngleHook
from ..errors import ParameterError
from ..gating import Gate
from ..plan import Hooks, Plan
from ..weights import FilterpyPoints

__all__ = ["Config", "common_config", "filter_kwargs"]


class Config(NamedTuple):
    """One filter's (or a fleet's) configuration, and its noise factors.

    The arrays are the filter's own, handed over to be read, not written.

    Attributes
    ----------
    dim_x, dim_z : int
    dt : float
        The default time step.
    hx, fx : callable
    points : object
        The first set's family as given (``points_fn``); ``family`` as used.
    family : SigmaPointFamily
    scheme : generator
    x_mean, z_mean, residual_x, residual_z, state_add : callable or None
        The hooks as given; None where filterpy's default is meant.
    gate : Gate or None
    fx_noise, hx_noise : int or None
    vectorized : bool
    plan : Plan
    hooks : Hooks
        The hooks as the step takes them.
    Q1_2, R1_2 : ndarray or None
        Lower factors of ``Q`` and ``R``: ``(d, d)``, or ``(K, d, d)`` per filter
        of a fleet; ``Q1_2`` None when there is no process noise.
    step : str
        The phase of one filter's pending ask/tell step (``squkf.step.IDLE``,
        ...), which ``Fleet.from_filters`` checks; a fleet's is left idle
        (``fleet[k]`` checks the fleet's own).
    """

    dim_x: int
    dim_z: int
    dt: float
    hx: Callable
    fx: Callable
    points: Any
    family: Any
    scheme: Any
    x_mean: Callable | None
    z_mean: Callable | None
    residual_x: Callable | None
    residual_z: Callable | None
    state_add: Callable | None
    gate: Gate | None
    fx_noise: int | None
    hx_noise: int | None
    vectorized: bool
    plan: Plan
    hooks: Hooks
    Q1_2: np.ndarray | None
    R1_2: np.ndarray | None
    step: str = "idle"


def filter_kwargs(c: Config) -> dict:
    """The keyword arguments of ``SquareRootUKF`` and ``Fleet`` that make a filter of configuration ``c``.

    Parameters
    ----------
    c : Config

    Returns
    -------
    dict
        ``scheme``, the hooks (``x_mean_fn``, ...), ``gate``, ``fx_noise``, ``hx_noise``.
    """
    return {
        "scheme": c.scheme,
        "x_mean_fn": c.x_mean,
        "z_mean_fn": c.z_mean,
        "residual_x": c.residual_x,
        "residual_z": c.residual_z,
        "state_add": c.state_add,
        "gate": c.gate,
        "fx_noise": c.fx_noise,
        "hx_noise": c.hx_noise,
    }


def _same(h):  # squkf's angle hooks are equal when they wrap the same components
    return (type(h), tuple(h.angle_indices)) if isinstance(h, _AngleHook) else h


def _by_value(family):
    """A family as compared: a filterpy points object (equal only to itself) by the points it gives."""
    if not isinstance(family, FilterpyPoints):
        return family
    n = family.n
    Wm, Wc = family.weights(n)
    return (type(family.points), n, family.unit_sigma_points(n).tobytes(), Wm.tobytes(), Wc.tobytes())


def _key(c: Config) -> tuple:
    scheme = c.scheme
    fields = (
        c.dim_x,
        c.dim_z,
        c.dt,
        c.hx,
        c.fx,
        _by_value(c.family),
        type(scheme),
        # a generator's parameters (Augmented(weights=...)), not only its kind
        tuple(sorted(vars(scheme).items())) if hasattr(scheme, "__dict__") else scheme,
        c.x_mean,
        c.z_mean,
        c.residual_x,
        c.residual_z,
        c.state_add,
        c.gate,
        c.fx_noise,
        c.hx_noise,
    )
    return tuple(_same(v) for v in fields)


def common_config(configs: Sequence[Config]) -> Config:
    """The one configuration of filters to be stacked into a fleet (``Fleet.from_filters``).

    Parameters
    ----------
    configs : sequence of Config
        The filters' configurations, in order.

    Returns
    -------
    Config
        The first filter's.

    Raises
    ------
    ParameterError
        No filters; a filter that is not vectorised; a filter whose
        configuration differs from the first's.
    """
    if not configs:
        raise ParameterError("from_filters needs at least one filter")
    key0 = _key(configs[0])
    for k, c in enumerate(configs):
        if not c.vectorized:
            raise ParameterError(f"filters[{k}] is not vectorized: a fleet calls fx and hx with all points")
        if _key(c) != key0:
            raise ParameterError(f"filters[{k}] differs in configuration from filters[0]")
    return configs[0]
