"""A filter's configuration as one record, and filters into a fleet and out of it.

``SquareRootUKF.configuration()`` and ``Fleet.configuration()`` give a
:class:`Config`; ``Fleet.from_filters`` compares the filters' records and
builds the fleet from one (:func:`stacked`), ``fleet[k]`` builds a filter from
the fleet's (:func:`filter_of`), and the smoothers and :mod:`squkf.dask` read
the time step, the model and the noise from it. No module reads another's
private members. A pending ask/tell step is kept where the single filter and
the fleet take it the same way, and refused otherwise (:func:`check_pending`).
The parts of a configuration are checked against each other here when it is
made: the sigma-point family at the state's dimension (:func:`sigma_family`),
the second set with it (:func:`second_set`), the noise entering the model
with the model functions (:func:`model_noise`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np

from ..angles import AngleHook
from ..errors import CallSequenceError, ParameterError
from ..gating import Gate
from ..generators import as_generator, noise_family
from ..kernels.table import KernelTable
from ..noise import check_accepts_noise, check_noise_dim
from ..plan import IDLE, PRIOR, Hooks, Plan, check_built_for
from ..weights import FilterpyPoints, WrittenWeights, as_family

__all__ = [
    "check_pending",
    "common_config",
    "Config",
    "filter_kwargs",
    "filter_of",
    "model_noise",
    "second_set",
    "sigma_family",
    "stacked",
]


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
        The phase of one filter's pending ask/tell step (``squkf.plan.IDLE``,
        ...), which ``Fleet.from_filters`` checks; a fleet's is left idle
        (``fleet[k]`` checks the fleet's own).
    kernels : KernelTable or None
        The kernel table of the filter's route, which the smoother calls (None: the installed one).
    """

    dim_x: int
    dim_z: int
    dt: float | None  # None: every predict passes its own
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
    kernels: KernelTable | None = None


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
    return (type(h), tuple(h.angle_indices)) if isinstance(h, AngleHook) else h


def _by_value(family):
    """A family as compared: a filterpy points object (equal only to itself) by the points it gives, weights
    a program wrote by the family and weights."""
    if isinstance(family, WrittenWeights):
        return (WrittenWeights, _by_value(family.base), family.n, family.Wm.tobytes(), family.Wc.tobytes())
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
        raise ParameterError("filters is empty: from_filters needs at least one filter")
    key0 = _key(configs[0])
    for k, c in enumerate(configs):
        if not c.vectorized:
            raise ParameterError(f"filters[{k}] is not vectorized: a fleet calls fx and hx with all points")
        if _key(c) != key0:
            raise ParameterError(f"filters[{k}] differs in configuration from filters[0]")
    return configs[0]


def check_pending(phase: str, plan: Plan, who: str) -> None:
    """Refuse to copy a filter out of (or into) a fleet when its pending step would be lost.

    After a prediction whose second set is redrawn from the prior alone, the
    copy draws the same set from the same prior at its update: the step is
    kept. Points handed out by ``ask_*`` and not yet told, or a second set
    that reads the propagated points (``"augmented"``, ``"propagated"``),
    cannot be carried over.

    Parameters
    ----------
    phase : str
        The step's phase (:data:`squkf.plan.IDLE`, ...).
    plan : squkf.plan.Plan
    who : str
        For the message, e.g. ``"fleet[3]"`` or ``"filters[1]"``.

    Raises
    ------
    CallSequenceError
    """
    if phase == IDLE or (phase == PRIOR and not plan.keeps_propagated):
        return
    what = (
        "a prediction whose second set reads the propagated points" if phase == PRIOR else f"an ask ({phase})"
    )
    raise CallSequenceError(
        f"{who}: the step is pending ({what}), which a copy cannot carry over: "
        "complete the step (update, or tell) first"
    )


def filter_of(make: Callable[..., Any], c: Config, k: int, x: np.ndarray, S: np.ndarray, phase: str):
    """Filter ``k`` of a fleet as a :class:`squkf.SquareRootUKF` (vectorised).

    Parameters
    ----------
    make : type
        :class:`squkf.SquareRootUKF` (given by the fleet: the boundary imports no front end).
    c : Config
        The fleet's configuration and noise factors (shared or per filter).
    k : int
        A valid index of the fleet's filters.
    x : ndarray, shape (K, n)
    S : ndarray, shape (K, n, n)
        The fleet's states and lower factors.
    phase : str
        The fleet's pending step (:func:`check_pending`).

    Returns
    -------
    SquareRootUKF
        With its own copies of filter ``k``'s state and noise.
    """
    check_pending(phase, c.plan, f"fleet[{k}]")
    f = make(c.dim_x, c.dim_z, c.dt, c.hx, c.fx, c.points, vectorized=True, **filter_kwargs(c))
    f.x = x[k]
    f.P1_2 = S[k]
    Q, R = c.Q1_2, c.R1_2
    f.Q1_2 = None if Q is None else (Q if Q.ndim == 2 else Q[k])
    f.R1_2 = R if R is None or R.ndim == 2 else R[k]
    return f


def stacked(filters: Sequence[Any]) -> tuple[Config, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What ``Fleet.from_filters`` builds its fleet of: the filters' one configuration and stacked arrays.

    Parameters
    ----------
    filters : sequence of SquareRootUKF
        Of one configuration (:func:`squkf.boundary.config.common_config`),
        none with a step pending that a fleet cannot carry (:func:`check_pending`).

    Returns
    -------
    c : Config
        The first filter's.
    x : ndarray, shape (K, n)
    P1_2 : ndarray, shape (K, n, n)
    Q1_2, R1_2 : ndarray, shape (d, d) or (K, d, d)
        Shared where every filter's is the same (zeros: no noise).
    """
    configs = [f.configuration() for f in filters]  # edits in place of Q and R taken (validated)
    c = common_config(configs)
    for k, ck in enumerate(configs):
        check_pending(ck.step, ck.plan, f"filters[{k}]")
    x = np.stack([f.x for f in filters])  # validated by the fleet's setter
    P1_2 = np.stack([f.P1_2 for f in filters])  # edits in place of P taken (validated)
    Qs = [f.Q1_2 for f in filters]
    Rs = [f.R1_2 for f in filters]
    Q = Qs[0] if all(np.array_equal(q, Qs[0]) for q in Qs) else np.stack(Qs)
    R = Rs[0] if all(np.array_equal(r, Rs[0]) for r in Rs) else np.stack(Rs)
    return c, x, P1_2, Q, R


def model_noise(fx: Callable | None, hx: Callable | None, fx_noise, hx_noise) -> tuple[int, int]:
    """The dimensions of the noise entering ``fx`` and ``hx``, checked with the functions that take it.

    Parameters
    ----------
    fx, hx : callable or None
        With noise, ``fx(x, w, dt)`` and ``hx(x, v)`` must take it (:mod:`squkf.noise`);
        None (a function given per call) is not checked.
    fx_noise, hx_noise : int or None
        None: additive noise.

    Returns
    -------
    (int, int)
        The dimensions, 0 for additive noise.
    """
    dw = check_noise_dim(fx_noise, "fx_noise")
    dv = check_noise_dim(hx_noise, "hx_noise")
    check_accepts_noise(fx, "fx", dw, 3)
    check_accepts_noise(hx, "hx", dv, 2)
    return dw, dv


def sigma_family(points, n: int, fx_noise: int) -> tuple[object, int]:
    """``points`` as a sigma-point family, checked to serve dimension ``n``, and its number of points.

    Parameters
    ----------
    points : sigma-point family or filterpy points object
    n : int
        State dimension.
    fx_noise : int
        Dimension of the noise entering ``fx`` (0: additive); the first set is then augmented.

    Returns
    -------
    family : squkf.weights.SigmaPointFamily
    num : int
        Number of points of the first set.

    Notes
    -----
    The dimension a filterpy points object was built for is checked against
    every set it serves with the plan (:func:`squkf.plan.check_built_for`),
    which the filter builds next; here only the first set is known.
    """
    family = as_family(points)
    if isinstance(family, FilterpyPoints) and family.as_native() is None:
        check_built_for(family, "points", n, fx_noise)  # it serves the first set as it is, or not at all
    try:
        num = noise_family(family, n, fx_noise).num_sigmas(n + fx_noise)
    except ParameterError:
        raise
    except Exception as exc:  # a user's family that cannot serve this dimension
        raise ParameterError(f"points cannot give sigma points for dim_x={n}: {exc}") from exc
    return family, num


def second_set(scheme, n: int, family, hx_noise: int):
    """The second-set generator of ``scheme``, checked against the family at dimension ``n`` now.

    Parameters
    ----------
    scheme : {"redrawn", "augmented", "propagated"} or generator
    n : int
    family : squkf.weights.SigmaPointFamily
    hx_noise : int
        Dimension of the noise entering ``hx`` (0: additive).

    Returns
    -------
    generator
    """
    gen = as_generator(scheme)
    if hasattr(gen, "num_sigmas") and not hx_noise:
        gen.num_sigmas(n, noise_family(family, n, 0))  # fails now, not at the first update
    return gen
