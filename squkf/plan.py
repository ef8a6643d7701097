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

from .errors import ParameterError
from .generators import UnitSet, prepare_second_set

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
    keeps_propagated : bool
        Whether the second set reads the first set's images (augmented,
        propagated), which the step then keeps (derived from ``second``).
    """

    n: int
    family: Any
    generator: Any
    first: UnitSet
    second: Any
    keeps_propagated: bool = field(init=False)

    def __post_init__(self):
        # read twice a step: an attribute, not a property
        object.__setattr__(self, "keeps_propagated", bool(getattr(self.second, "uses_propagated", True)))

    @property
    def num_sigmas(self) -> int:
        """Points in the first set."""
        return self.first.xi.shape[0]


def build_plan(family, generator, n: int) -> Plan:
    """The plan for ``family`` and ``generator`` at dimension ``n``.

    Parameters
    ----------
    family : sigma-point family
    generator : second-set generator
    n : int

    Returns
    -------
    Plan

    Raises
    ------
    ParameterError
        If the family cannot give points for ``n`` or the generator cannot
        serve the family (the augmented set needs ``+/-`` pairs).
    """
    try:
        first = UnitSet(family, n)
        second = prepare_second_set(generator, family, n)
    except ParameterError:
        raise
    except Exception as exc:  # a user's family or generator that cannot serve this dimension
        raise ParameterError(f"points cannot give sigma points for dim_x={n}: {exc}") from exc
    return Plan(n, family, generator, first, second)
