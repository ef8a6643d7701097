"""The plan: everything about one configuration that does not change between steps.

A :class:`Plan` is built once per sigma-point family, second-set generator and
state dimension: the first set's unit points, weights and covariance rows
(:mod:`squkf.rows`), the structure the points allow (axis points, ``+/-``
pairs: :class:`squkf.generators.UnitSet`), and the generator's prepared second
set. The engine (:mod:`squkf.engine`) reads it and never changes it, so one plan
serves any number of filters, and a configuration is data, not code.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from .errors import ParameterError
from .generators import Augmented, FusedDraw, Propagated, Redrawn, UnitSet, noise_family, prepare_second_set
from .kernels.table import CENTRAL, GIVEN, MEAN, plan_array
from .rows import RowForm, WeightRows
from .weights import CubatureWeights, FilterpyPoints, JulierWeights, MerweScaledWeights, SimplexWeights

__all__ = [
    "IDLE",
    "PREDICTING",
    "PRIOR",
    "UPDATING",
    "SET_KINDS",
    "Plan",
    "Hooks",
    "SetRoutes",
    "UpdateRoute",
    "build_plan",
    "check_built_for",
]

#: The phases of a step done in halves (ask/tell): none pending, a prediction asked, its prior told
#: (the update pending), an update asked.
IDLE, PREDICTING, PRIOR, UPDATING = "idle", "predicting", "prior", "updating"


class Hooks(NamedTuple):
    """filterpy's hooks for non-additive quantities; None means the plain operation.

    Attributes
    ----------
    x_mean_fn, z_mean_fn : callable ``(sigmas, Wm) -> mean`` or None
    residual_x, residual_z : callable ``(a, b) -> a - b`` or None
    state_add : callable ``(x, dx) -> x + dx`` or None
    """

    x_mean_fn: Any = None
    z_mean_fn: Any = None
    residual_x: Any = None
    residual_z: Any = None
    state_add: Any = None


class UpdateRoute(NamedTuple):
    """The route of an update by one kernel: which rows of the set it takes and how.

    The joint QR kernel's (``downdate`` False), with no hook, or with squkf's angle hooks on the
    measurement (``angles``: the angle kernel forms the given rows, mode 2, of the images about the
    point ``ref``; the state rows are the set's deviations from the prior mean, its offsets where it
    has them); or the downdate kernel's (``downdate``: the set need not reproduce the prior; its state
    rows ``X - xref``, wrapped where ``xkind`` says, and its covariance weights ``wc``).
    """

    form: RowForm
    mode: int
    offsets: bool  # the set's offsets are the state rows (else its points, with xref = x for MEAN)
    xref: bool
    pair: float
    wm: np.ndarray
    scale: np.ndarray
    sign: np.ndarray
    angles: bool = False
    ref: int = 0
    downdate: bool = False
    wc: np.ndarray | None = None
    xkind: np.ndarray | None = None


#: The kinds of set an update's route depends on besides its rows: (moments exact, offsets known, axis).
SET_KINDS = tuple((e, o, a) for e in (False, True) for o in (False, True) for a in (False, True))


class SetRoutes(NamedTuple):
    """The update routes of the sets with one pair of weight rows, whatever the hooks: made once per
    configuration (:attr:`Plan.set_routes`), from which a :class:`squkf.engine.Route` takes its own.

    Attributes
    ----------
    rows : WeightRows
    joint : dict
        ``(offsets known, axis points) -> UpdateRoute``: the joint QR kernel's (the offsets where known;
        the pairs of axis points rotated).
    angle : dict
        ``offsets known -> UpdateRoute``: the joint kernel's with squkf's angle hooks on the measurement
        (the mean form's given rows, as the hooks' Python route weighs them; the circular means about
        the point of the largest ``|Wm|``).
    wc : ndarray, shape (N,)
        The covariance weights (the downdate kernel's).
    """

    rows: WeightRows
    joint: dict
    angle: dict
    wc: np.ndarray

    @classmethod
    def of(cls, rows: WeightRows) -> SetRoutes:
        """The routes of sets with ``rows``."""
        wm = plan_array(rows.Wm)
        form = rows.best
        scale, sign = plan_array(form.scale), plan_array(form.sign)
        if form.central:
            joint = {
                (have, axis): UpdateRoute(
                    form, CENTRAL, have, False, rows.pair_scale if axis else 0.0, wm, scale, sign
                )
                for have, axis in ((False, False), (True, False), (True, True))
            }
        else:
            joint = {
                (have, False): UpdateRoute(form, MEAN, have, not have, 0.0, wm, scale, sign)
                for have in (False, True)
            }
            joint[True, True] = joint[True, False]
        mean = rows.mean_form
        ref = int(np.argmax(np.abs(wm)))
        mscale, msign = plan_array(mean.scale), plan_array(mean.sign)
        angle = {
            have: UpdateRoute(mean, GIVEN, have, False, 0.0, wm, mscale, msign, True, ref)
            for have in (False, True)
        }
        return cls(rows, joint, angle, plan_array(rows.Wc))


@dataclass(frozen=True)
class Plan:
    """One configuration at one state dimension, prepared once.

    Attributes
    ----------
    n : int
        State dimension.
    family : sigma-point family
        The first set's family.
    generator : second-set generator
    first : UnitSet
        The first set's unit points, weights, rows and structure.
    second : object with ``draw(x, S, propagated, Q1_2, state_add) -> SigmaSet``
        The generator's prepared second set.
    w_xi : ndarray, shape (N, dim_w), or None
        With noise entering ``fx`` (``fx_noise``): the first set is drawn over
        ``[x, w]``; ``first.xi`` is its state part and ``w_xi`` its noise part.
    v_xi : ndarray, shape (N2, dim_v), or None
        The same for the second set over ``[x, v]`` (``hx_noise``).
    keeps_propagated : bool
        Whether the second set reads the first set's images (augmented,
        propagated), which the step then keeps (derived from ``second``).

    The route's data for the kernels, read-only (derived once):

    xi1 : ndarray, shape (N, n)
        The first set's unit points (state part).
    gamma1 : float
        Non-zero for axis points (the offsets in O(n^2)).
    mode1 : int
        The prediction's row form (``CENTRAL`` or ``MEAN``, :mod:`squkf.kernels`).
    wm1, scale1, sign1 : ndarray, shape (N,)
        The first set's mean weights and its best row form (:mod:`squkf.rows`):
        the prediction's transform.
    fused_draw : FusedDraw or None
        The second set as the prediction's kernel can draw it with the prior
        (redrawn, augmented), or None (the propagated set, a user's generator).
    set_routes : tuple of SetRoutes
        The update routes of every set the second-set generator draws, one per
        pair of weight rows they carry (squkf's generators: ``drawn_rows``),
        from which a route fixes its own when it is built
        (:class:`squkf.engine.Route`); empty for a user's generator, whose
        sets are classified as they come. Made once per configuration (with
        its prepared sets).
    route_cache : dict
        What a :class:`squkf.engine.Route` without state angle hooks fixes from
        this configuration (its prediction's draws and its sets' update routes),
        per its hooks' flags: made by the first route and shared, with the
        prepared sets, by every plan of the configuration.
    """

    n: int
    family: Any
    generator: Any
    first: UnitSet
    second: Any
    w_xi: np.ndarray | None = None
    v_xi: np.ndarray | None = None
    set_routes: tuple = ()
    # the routes a filter without state angle hooks takes from this configuration, per its hooks' flags:
    # made by the first such Route and shared, with the prepared sets, by every plan of the configuration
    route_cache: dict = field(default_factory=dict, repr=False, compare=False)
    keeps_propagated: bool = field(init=False)
    xi1: np.ndarray = field(init=False)
    gamma1: float = field(init=False)
    mode1: int = field(init=False)
    wm1: np.ndarray = field(init=False)
    scale1: np.ndarray = field(init=False)
    sign1: np.ndarray = field(init=False)
    fused_draw: FusedDraw | None = field(init=False)

    def __post_init__(self):
        # read at every step: attributes, not properties
        derived = object.__setattr__
        derived(self, "keeps_propagated", bool(getattr(self.second, "uses_propagated", True)))
        first = self.first
        form = first.rows.best
        derived(self, "xi1", plan_array(first.xi))
        derived(self, "gamma1", 0.0 if first.gamma is None else float(first.gamma))
        derived(self, "mode1", CENTRAL if form.central else MEAN)
        derived(self, "wm1", plan_array(first.rows.Wm))
        derived(self, "scale1", plan_array(form.scale))
        derived(self, "sign1", plan_array(form.sign))
        fused = getattr(self.second, "fused", None)
        draw = None if fused is None else fused()
        if draw is not None:
            draw = draw._replace(xi=plan_array(draw.xi))
        derived(self, "fused_draw", draw)

    def __reduce__(self):
        # built again when unpickled: its arrays frozen (read-only, as the kernels take them) and derived
        fx_noise = 0 if self.w_xi is None else self.w_xi.shape[1]
        hx_noise = 0 if self.v_xi is None else self.v_xi.shape[1]
        return (build_plan, (self.family, self.generator, self.n, fx_noise, hx_noise))

    @property
    def num_sigmas(self) -> int:
        """Points in the first set."""
        return self.first.xi.shape[0]


def build_plan(family, generator, n: int, fx_noise: int = 0, hx_noise: int = 0) -> Plan:
    """The plan for ``family`` and ``generator`` at dimension ``n``.

    Parameters
    ----------
    family : sigma-point family
    generator : second-set generator
    n : int
    fx_noise, hx_noise : int
        Dimensions of the noise that ``fx`` and ``hx`` take as an argument
        (0: additive noise). The sets are then drawn over ``[x, w]`` and
        ``[x, v]`` (:meth:`squkf.generators.UnitSet.augmented`); the second
        set must be redrawn.

    Returns
    -------
    Plan

    Raises
    ------
    ParameterError
        If the family cannot give points for ``n`` or the generator cannot
        serve the family (the augmented set needs ``+/-`` pairs); if a
        filterpy points object is built for a dimension no set it serves is
        drawn in (:func:`check_built_for`); if a set over ``[x, noise]`` is
        too large to allocate (naming ``fx_noise`` or ``hx_noise``).
    """
    if (fx_noise or hx_noise) and not isinstance(generator, Redrawn):
        raise ParameterError(
            f"noise entering fx or hx (fx_noise={fx_noise or None}, hx_noise={hx_noise or None}) needs the"
            f" redrawn second set, scheme='redrawn', got scheme={generator!r}"
        )
    own = generator.weights if isinstance(generator, Redrawn) else None  # the second set's own family
    serves_second = isinstance(generator, Redrawn) and own is None
    check_built_for(family, "points", n, fx_noise, hx_noise if serves_second else None)
    if own is not None:
        check_built_for(own, "Redrawn(weights=...)", n, None, hx_noise)
    key = _prepared_key(family, generator, n, fx_noise, hx_noise)
    prepared = _PREPARED.get(key) if key is not None else None
    if prepared is None:
        prepared = _prepare(family, generator, n, fx_noise, hx_noise)
        if key is not None:
            if len(_PREPARED) >= _PREPARED_MAX:
                _PREPARED.clear()
            _PREPARED[key] = prepared
    return Plan(n, family, generator, *prepared)


#: The sets prepared for a configuration, by its value (:func:`_prepared_key`): a program that builds a
#: filter per track or per request prepares them once (the unit points, weights and their rows).
_PREPARED: dict[tuple, tuple] = {}
_PREPARED_MAX = 64


def _prepared_key(family, generator, n: int, fx_noise: int, hx_noise: int) -> tuple | None:
    """A key equal for two configurations that prepare the same sets, or None where that is not known
    (a user's family or generator: prepared each time)."""
    fam = _value_key(family)
    if fam is None:
        return None
    if type(generator) in (Redrawn, Augmented):
        own = generator.weights
        gen: tuple | None = (type(generator), None if own is None else _value_key(own))
        if own is not None and gen[1] is None:  # type: ignore[index]
            return None
    elif type(generator) is Propagated:
        gen = (Propagated,)
    else:
        return None
    return (fam, gen, n, fx_noise, hx_noise)


_NATIVE = (MerweScaledWeights, JulierWeights, SimplexWeights, CubatureWeights)


def _value_key(family) -> tuple | None:
    """A squkf family by its parameters, a filterpy points object by its class, parameters and weights."""
    if isinstance(family, FilterpyPoints):
        p = family.points
        if not type(p).__module__.startswith("filterpy."):  # (a look-alike's points may depend on more)
            return None
        numbers_ = tuple(
            (k, v) for k, v in sorted(vars(p).items()) if isinstance(v, (int, float, str, np.generic))
        )
        Wm, Wc = np.asarray(p.Wm), np.asarray(p.Wc)
        if Wm.dtype.kind != "f" or Wc.dtype.kind != "f":
            return None
        return (FilterpyPoints, type(p), family.n, numbers_, Wm.tobytes(), Wc.tobytes())
    if type(family) in _NATIVE:
        try:
            hash(family)
        except TypeError:
            return None
        return (type(family), family)
    return None


def _prepare(family, generator, n: int, fx_noise: int, hx_noise: int) -> tuple:
    """The first set and the second set's drawer (and the noise parts of their unit points), and the update
    routes of the sets it draws."""
    w_xi = v_xi = None
    with _serving(n, "fx_noise", fx_noise):
        if fx_noise:
            first, w_xi = UnitSet.augmented(noise_family(family, n, fx_noise), n, fx_noise)
        else:
            first = UnitSet(noise_family(family, n, 0), n)
    with _serving(n, "hx_noise", hx_noise):
        if hx_noise:
            second, v_xi = generator.prepare_augmented(family, n, hx_noise)
        else:
            second = prepare_second_set(generator, noise_family(family, n, 0), n)
    drawn = getattr(second, "drawn_rows", ())
    distinct = [r for i, r in enumerate(drawn) if all(r is not o for o in drawn[:i])]
    return first, second, w_xi, v_xi, tuple(SetRoutes.of(r) for r in distinct), {}


def check_built_for(
    family, name: str, n: int, fx_noise: int | None = None, hx_noise: int | None = None
) -> None:
    """Refuse a filterpy points object built for a dimension that none of the sets it serves is drawn in.

    A points object serves the sets it is given for as it is where a set is
    drawn in the dimension it was built for, and as its squkf equivalent
    elsewhere (:func:`squkf.generators.noise_family`); so it must be built for
    ``dim_x`` or for the dimension of one of those sets, and one with no squkf
    equivalent for the dimension of each.

    Parameters
    ----------
    family : sigma-point family
        Anything but a :class:`~squkf.weights.FilterpyPoints` passes.
    name : str
        The argument it was given as (``"points"``), for the message.
    n : int
        State dimension.
    fx_noise, hx_noise : int or None
        The noise dimensions of the first and the second set (0: the set is
        drawn in ``n``); None: ``family`` does not serve that set.

    Raises
    ------
    ParameterError
        Naming ``name``, the dimension the object was built for and the
        dimensions of the sets.
    """
    if not isinstance(family, FilterpyPoints):
        return
    sets = {
        f"the {which} set, drawn in dimension {_dimension(n, noise, d)}": n + d
        for which, noise, d in (("first", "fx_noise", fx_noise), ("second", "hx_noise", hx_noise))
        if d is not None
    }
    dims = sorted(set(sets.values()))
    built, native = family.n, family.as_native() is not None
    if (native and built in (n, *dims)) or dims == [built]:
        return
    what = (
        f"{name}: the points object {type(family.points).__name__} was built for n={built}, but it serves"
        f" {' and '.join(sets)}"
    )
    if native:
        raise ParameterError(f"{what}: build it with n={' or n='.join(str(d) for d in sorted({n, *dims}))}")
    raise ParameterError(
        f"{what}, and it has no squkf equivalent (Merwe or Julier type) to serve a set of another dimension: "
        + (f"build it with n={dims[0]}" if len(dims) == 1 else "give a squkf family")
    )


def _dimension(n: int, noise: str, d: int) -> str:
    """A set's dimension as said in a message: ``dim_x = 2``, ``dim_x + fx_noise = 2 + 1 = 3``."""
    return f"dim_x + {noise} = {n} + {d} = {n + d}" if d else f"dim_x = {n}"


@contextmanager
def _serving(n: int, name: str, d: int) -> Iterator[None]:
    """A family's or generator's failure to serve a set as a ParameterError (naming the noise: too large)."""
    try:
        yield
    except ParameterError:
        raise
    except Exception as exc:  # a user's family or generator that cannot serve this dimension
        if d and isinstance(exc, MemoryError):
            raise ParameterError(
                f"{name}={d} is too large: its set of sigma points over [x, noise], of dimension"
                f" {n} + {d} = {n + d}, cannot be allocated ({exc})"
            ) from exc
        raise ParameterError(f"points cannot give sigma points for dim_x={n}: {exc}") from exc
