"""The plan: everything about one configuration that does not change between steps.

A :class:`Plan` is built once per sigma-point family, second-set generator and
state dimension: the first set's unit points, weights and covariance rows
(:mod:`squkf.rows`), the structure the points allow (axis points, ``+/-``
pairs: :class:`squkf.generators.UnitSet`), and the generator's prepared second
set. The step (:mod:`squkf.step`) reads it and never changes it, so one plan
serves any number of filters, and a configuration is data, not code.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from .errors import ParameterError
from .generators import FusedDraw, Redrawn, UnitSet, noise_family, prepare_second_set
from .kernels import plan_array

__all__ = ["Plan", "Hooks", "build_plan"]


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
    wm1, scale1, sign1 : ndarray, shape (N,)
        The first set's mean weights and its best row form (:mod:`squkf.rows`):
        the prediction's transform.
    fused_draw : FusedDraw or None
        The second set as the prediction's kernel can draw it with the prior
        (redrawn, augmented), or None (the propagated set, a user's generator).
    """

    n: int
    family: Any
    generator: Any
    first: UnitSet
    second: Any
    w_xi: np.ndarray | None = None
    v_xi: np.ndarray | None = None
    keeps_propagated: bool = field(init=False)
    xi1: np.ndarray = field(init=False)
    gamma1: float = field(init=False)
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
        derived(self, "wm1", plan_array(first.rows.Wm))
        derived(self, "scale1", plan_array(form.scale))
        derived(self, "sign1", plan_array(form.sign))
        fused = getattr(self.second, "fused", None)
        draw = None if fused is None else fused()
        if draw is not None:
            draw = draw._replace(xi=plan_array(draw.xi))
        derived(self, "fused_draw", draw)

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
        serve the family (the augmented set needs ``+/-`` pairs).
    """
    if (fx_noise or hx_noise) and not isinstance(generator, Redrawn):
        raise ParameterError(
            f"noise entering fx or hx (fx_noise={fx_noise or None}, hx_noise={hx_noise or None}) needs the"
            f" redrawn second set, scheme='redrawn', got scheme={generator!r}"
        )
    w_xi = v_xi = None
    try:
        if fx_noise:
            first, w_xi = UnitSet.augmented(noise_family(family, n, fx_noise), n, fx_noise)
        else:
            first = UnitSet(family, n)
        if hx_noise:
            second, v_xi = generator.prepare_augmented(family, n, hx_noise)
        else:
            second = prepare_second_set(generator, family, n)
    except ParameterError:
        raise
    except Exception as exc:  # a user's family or generator that cannot serve this dimension
        raise ParameterError(f"points cannot give sigma points for dim_x={n}: {exc}") from exc
    return Plan(n, family, generator, first, second, w_xi, v_xi)
