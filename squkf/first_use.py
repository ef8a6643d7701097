"""Compile every kernel ahead of first use: :func:`precompile` and ``python -m squkf precompile``.

The kernels compile on first call (:ref:`first use <first-use>`). For a container image
or a CI cache, :func:`precompile` runs tiny workloads through every public
route (one filter and a fleet in each configuration, the smoothers, the
linear algebra, the transforms, NAG's example), so that every kernel any of
them can call is compiled into numba's cache (or loaded from it), and then
checks that every kernel of :mod:`squkf.kernels.phases` got its code. The
workloads name no kernel and no signature: a kernel is reached through the
public faces or reported as unreached.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

from .angles import AngleAdd, AngleMean, AngleResidual
from .fleet import Fleet
from .gating import Gate
from .generators import Propagated
from .kernels import cache, phases
from .linalg import chol_downdate_columns, chol_update, factor_covariance, kalman_gain, solve_lower, tria
from .transform import sqrt_unscented_transform
from .ukf import SquareRootUKF
from .ut import unscented_transform
from .weights import JulierWeights, MerweScaledWeights, SimplexWeights

__all__ = ["precompile", "Precompiled", "unreached"]

_DT = 0.5
_X0 = np.array([1.0, 0.5, 0.3])
_P0 = np.diag([0.5, 0.2, 0.1])
_Q = np.diag([1e-3, 1e-2, 1e-3])
_R = np.diag([0.04, 0.01])
#: Measurements of position and heading: a usual one, one far off (a gate rejects it), a partial one.
_Z = np.array([1.3, 0.35])
_WILD = np.array([40.0, 0.35])
_PARTIAL = np.array([np.nan, 0.4])


class Precompiled(NamedTuple):
    """What :func:`precompile` did.

    Attributes
    ----------
    kernels : int
        The entry kernels of :mod:`squkf.kernels.phases`, each now with its code.
    compiled : int
        Kernels and helpers compiled during the run (0 when the cache held them all).
    seconds : float
        Wall time of the run.
    cache_dir : str or None
        numba's cache directory for the kernels; None when they are compiled in memory.
    """

    kernels: int
    compiled: int
    seconds: float
    cache_dir: str | None

    def __str__(self) -> str:
        where = "in memory (nothing kept for later processes)" if self.cache_dir is None else self.cache_dir
        return (
            f"squkf.precompile: {self.kernels} kernels ready, {self.compiled} functions compiled, "
            f"{self.seconds:.1f} s; cache: {where}"
        )


# -- the model: position, velocity and heading; position and heading measured ---------------------------


def _fx(x: np.ndarray, dt: float) -> np.ndarray:
    """Constant velocity and a slow turn, for one point ``(3,)`` or stacked points ``(..., 3)``."""
    return np.stack([x[..., 0] + dt * x[..., 1], x[..., 1], x[..., 2] + 0.1 * dt], axis=-1)


def _hx(x: np.ndarray) -> np.ndarray:
    return np.stack([x[..., 0], x[..., 2]], axis=-1)


def _fx_noise(x: np.ndarray, w: np.ndarray, dt: float) -> np.ndarray:
    """:func:`_fx` with a gust ``w`` ``(..., 1)`` on the velocity and the heading."""
    return _fx(x, dt) + dt * np.concatenate([0.0 * w, w, w], axis=-1)


def _hx_noise(x: np.ndarray, v: np.ndarray) -> np.ndarray:
    """:func:`_hx` with errors ``v`` ``(..., 2)``."""
    return _hx(x) + v


def _hooks() -> dict[str, Any]:
    """The heading as an angle (squkf.angles) in the state and in the measurement."""
    return dict(
        x_mean_fn=AngleMean([2]),
        z_mean_fn=AngleMean([1]),
        residual_x=AngleResidual([2]),
        residual_z=AngleResidual([1]),
        state_add=AngleAdd([2]),
    )


def _noise_forms() -> dict[str, Any]:
    return dict(fx=_fx_noise, hx=_hx_noise, fx_noise=1, hx_noise=2)


def _configurations() -> list[dict[str, Any]]:
    """Every kind of configuration: families, schemes, hooks, a gate, noise entering the model."""
    from filterpy.kalman import MerweScaledSigmaPoints

    return [
        dict(points=MerweScaledWeights()),
        dict(points=MerweScaledWeights(0.3, 0.0, 0.0)),  # a negative central weight: a downdate
        dict(points=SimplexWeights()),
        dict(points=MerweScaledSigmaPoints(3, 0.5, 2.0, 0.0)),  # filterpy's points object
        dict(points=JulierWeights(1.0), scheme="augmented"),
        dict(points=MerweScaledWeights(), scheme=Propagated()),
        dict(points=MerweScaledWeights(0.5), **_hooks()),
        # squkf's angle hooks on the measurement alone: the kernels do them (angle_rows_kernel)
        dict(points=MerweScaledWeights(), z_mean_fn=AngleMean([1]), residual_z=AngleResidual([1])),
        dict(points=MerweScaledWeights(), gate=0.99),
        dict(points=MerweScaledWeights(), gate=Gate(0.99, per_component=True)),
        dict(points=MerweScaledWeights(), **_noise_forms()),
    ]


# -- the workloads ----------------------------------------------------------------------------------------


def _filter(vectorized: bool, config: dict[str, Any]) -> SquareRootUKF:
    config = dict(config)
    fx, hx = config.pop("fx", _fx), config.pop("hx", _hx)
    f = SquareRootUKF(3, 2, _DT, hx, fx, vectorized=vectorized, **config)
    f.x, f.P = _X0, _P0
    if "fx_noise" not in config:
        f.Q, f.R = _Q, _R
    return f


def _step_one_filter(f: SquareRootUKF, additive: bool) -> None:
    """Whole steps with a usual, a far-off and a partial measurement; with additive noise, the step in
    halves and the smoothers too."""
    for z in (_Z, _WILD, _PARTIAL, None):
        f.predict()
        f.update(z)
    if not additive:
        return
    X = f.ask_predict()
    f.tell_predict(_fx(X, _DT) if f.vectorized else [_fx(x, _DT) for x in X])
    Y = f.ask_update()
    f.tell_update(_hx(Y) if f.vectorized else [_hx(y) for y in Y], _Z)
    means, factors = f.batch_filter([_Z, _PARTIAL, _Z], return_factors=True)[:2]
    f.rts_smoother_factors(means, factors)
    f.rts_smoother(*f.batch_filter([_Z, _Z])[:2])


def _one_filter() -> None:
    for config in _configurations():
        for vectorized in (True, False):
            _step_one_filter(_filter(vectorized, config), "fx_noise" not in config)


def _users_transform() -> None:
    """A user's ``UT`` (squkf's square-root transform behind a function of the user's)."""

    def UT(*args):
        return sqrt_unscented_transform(*args)

    f = _filter(True, dict(points=MerweScaledWeights()))
    f.predict(UT=UT)
    f.update(_Z, UT=UT)


def _fleet() -> None:
    """Fleets of three in every configuration: steps with a far-off, a missing and a partial row; with
    additive noise, the step in halves and the fleet's smoother too."""
    measured = np.stack([_Z, _PARTIAL, np.full(2, np.nan)])
    for config in _configurations():
        config = dict(config)
        fx, hx = config.pop("fx", _fx), config.pop("hx", _hx)
        if isinstance(config.get("scheme"), Propagated):
            config["scheme"] = "propagated"
        fleet = Fleet(3, 3, 2, _DT, hx, fx, **config)
        fleet.x, fleet.P = _X0, _P0
        if "fx_noise" not in config:
            fleet.Q, fleet.R = _Q, _R
        for zs in (np.stack([_Z, _WILD, _Z]), measured):
            fleet.predict()
            fleet.update(zs)
        if "fx_noise" in config:
            continue
        fleet.tell_predict(_fx(fleet.ask_predict(), _DT))
        fleet.tell_update(_hx(fleet.ask_update()), measured)
        fleet.rts_smoother(fleet.batch_filter(np.stack([measured, measured], axis=1)))


def _linear_algebra() -> None:
    """squkf.linalg's functions, one matrix and a stack of two."""
    S = np.linalg.cholesky(_P0)
    for S_, v in ((S, S[:, 0]), (np.stack([S, 2.0 * S]), np.stack([S[:, 0], S[:, 1]]))):
        tria(np.concatenate([S_, S_], axis=-1).swapaxes(-1, -2))
        solve_lower(S_, v)
        solve_lower(S_, v, trans=True)
        chol_update(S_, 0.1 * v, 1.0)
        chol_update(S_, 0.1 * v, -1.0)
        chol_downdate_columns(S_, 0.1 * S_[..., :1])
    kalman_gain(0.1 * S[:, :2], np.linalg.cholesky(_R))
    factor_covariance(_P0, "P")
    factor_covariance(np.zeros((2, 2)), "Q", semidefinite=True)


def _transforms() -> None:
    """squkf.sqrt_unscented_transform and squkf.unscented_transform, with and without hooks."""
    points = MerweScaledWeights()
    S = np.linalg.cholesky(_P0)
    unscented_transform(_hx, _X0, S, points, np.linalg.cholesky(_R), vectorized=True)
    unscented_transform(_hx, _X0, S, points, mean_fn=AngleMean([1]), residual_fn=AngleResidual([1]))
    sigmas = SquareRootUKF(3, 2, _DT, _hx, _fx, points).ask_predict()
    Wm, Wc = points.weights(3)
    sqrt_unscented_transform(sigmas, Wm, Wc, np.linalg.cholesky(_Q))
    sqrt_unscented_transform(_hx(sigmas), Wm, Wc, None, AngleMean([1]), AngleResidual([1]))


def _nag() -> None:
    """NAG's g13ej example through squkf.nag."""
    from .examples import g13ej_example

    g13ej_example.run()


#: Every public route, by what it covers.
WORKLOADS: dict[str, Callable[[], None]] = {
    "one filter": _one_filter,
    "a user's UT": _users_transform,
    "fleet": _fleet,
    "squkf.linalg": _linear_algebra,
    "transforms": _transforms,
    "squkf.nag": _nag,
}


# -- the check ------------------------------------------------------------------------------------------


def _dispatchers() -> dict[str, Any]:
    """squkf's compiled functions by name, inlined ones aside (they never compile on their own)."""
    return {
        name: obj
        for name, obj in vars(phases).items()
        if cache.is_kernel(obj) and obj.targetoptions.get("inline") != "always"
    }


def unreached() -> list[str]:
    """The kernels without compiled code in this process, by name.

    An entry kernel (a name ending in ``_kernel``) is unreached when it has no
    signature. A helper is checked only when every entry kernel was compiled
    in this process (an empty cache): loaded from the cache, the entry
    kernels bring their helpers' code along and the helpers compile nothing.

    Returns
    -------
    list of str
        Empty when every kernel has its code.
    """
    dispatchers = _dispatchers()
    entries = {name for name in dispatchers if name.endswith("_kernel")}
    compiled = cache.compiled()
    cold = all(name in compiled for name in entries)
    return sorted(name for name, d in dispatchers.items() if not d.signatures and (name in entries or cold))


def precompile() -> Precompiled:
    """Compile every kernel that any public route can call into numba's cache.

    For a container image or CI: run it once where the cache will live
    (``python -m squkf precompile``); later processes load the kernels instead
    of compiling them. numba's cache is specific to the processor it was built
    on (:ref:`first use <first-use>`). Kernels already in the cache are loaded, not compiled.

    Returns
    -------
    Precompiled
        How many kernels, how many functions were compiled, the seconds taken
        and the cache directory (None: in memory, nothing kept).

    Raises
    ------
    RuntimeError
        If a kernel of :mod:`squkf.kernels.phases` got no code: no route here
        reaches it (a kernel added without a workload in this module).
    """
    start = time.perf_counter()
    before = sum(cache.compiled().values())
    cache.compiling_all(True)
    try:
        for run in WORKLOADS.values():
            run()
    finally:
        cache.compiling_all(False)
        cache.end_of_compile()
    missing = unreached()
    if missing:
        raise RuntimeError(
            f"squkf.precompile compiled no code for {', '.join(missing)}: no workload of squkf/first_use.py "
            "reaches them; add one that does (through the public API)"
        )
    entries = sum(name.endswith("_kernel") for name in _dispatchers())
    return Precompiled(
        kernels=entries,
        compiled=sum(cache.compiled().values()) - before,
        seconds=time.perf_counter() - start,
        cache_dir=cache.cache_directory(next(iter(_dispatchers().values())).py_func),
    )
