"""The engine: the step of a block of B filters, its routes fixed by the plan, the kernels called directly.

One filter is a block of one (:class:`squkf.SquareRootUKF`, its phases run by
:data:`BLOCK`); a fleet is a block of K (:class:`squkf.Fleet`, its phases run a
chunk at a time on threads by :data:`squkf.stacks.CHUNKS`). The step, as data::

    x, S --points--> X --fx--> F --prior + second set--> Y --hx--> H --posterior + first set--> x, S

Every arrow but ``fx`` and ``hx`` is a kernel of the table :data:`squkf.kernels.table.KERNELS`.
On the default route (no hooks, no ``UT``, a second set that reproduces the
prior) a step is two kernel calls: after ``fx``, one gives the prior and the
second set; after ``hx``, one gives the posterior and the next first set. Other
routes (hooks, a user's ``UT`` or generator, the propagated set) are the same
kernels driven with the hooks' rows (:mod:`squkf.transform`,
:mod:`squkf.measurement`).

Which route a call takes is decided once per key (the plan and the hooks fix
the :class:`Route`; the second set's kind and ``UT`` given or not, its update
route, kept by :meth:`Route.update_route`; the observed components, the factor
of their ``R``, kept while they repeat), so a repeated key decides nothing.
A kernel reports a status per filter; :func:`squkf.statuses.failure` turns one
into squkf's exception, the one wording of both faces.

An :class:`Engine` computes into its :class:`Buffers`, arrays allocated once
per shape, two sets used in turn: a call writes the set no committed record
holds and makes it the committed one only when the whole call succeeded, so a
call that fails leaves the engine, and every record handed out from it, as it
was. Its phases
(``ask_*`` and ``tell_*`` are the halves of a prediction and an update)::

    idle --ask_predict--> predicting --tell_predict--> prior
    prior | idle --ask_update--> updating --tell_update--> idle
"""

from __future__ import annotations

import copy
import operator
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

from . import blas
from .angles import measurement_angles, measurement_hooks_are_data, state_angles
from .checks import check_hook_result, check_values, describe_nonfinite
from .errors import CallSequenceError, NonFiniteError, SqukfError
from .generators import SigmaSet, sigma_points_from_factor
from .kernels import table
from .kernels.phases import JointUpdate, update_outputs
from .linalg import all_finite
from .measurement import (
    gain_from_factors,
    keeps_prior_factor,
    measurement_update,
    observed_noise_factor,
)
from .plan import IDLE, PREDICTING, PRIOR, SET_KINDS, UPDATING, Hooks, Plan, SetRoutes, UpdateRoute
from .rows import RowForm
from .statuses import failure, first_status, prior_failure, singular_allowed
from .transform import transform_factor

__all__ = [
    "IDLE",
    "PREDICTING",
    "PRIOR",
    "UPDATING",
    "BLOCK",
    "POSTERIOR_OUT",
    "Block",
    "Engine",
    "Route",
    "Update",
]


_FLOAT64 = np.dtype(np.float64)

# kernel status codes (squkf.kernels.phases; squkf.statuses words them)
NOT_FINITE_IMAGES = 306


class Update(NamedTuple):
    """The last update of a block: what the gate saw and what was applied; the one record of both faces.

    One filter's update is a block of one (:class:`squkf.SquareRootUKF` drops the block axis when it
    reads a field); a fleet's is a block of K, written a chunk at a time (:class:`squkf.stacks.Chunks`),
    which keeps no factor of the innovation (``Sy``, ``L21`` and ``K`` None) and whose filters each have
    their own measured components (``observed`` None, NaN in ``y`` and ``w`` where a component was
    missing).
    Batch histories keep their rows (``squkf.boundary.records.Records.keep``).

    Attributes
    ----------
    x : ndarray, shape (B, n)
    S : ndarray, shape (B, n, n)
        The posterior (after the gate: the prior where it rejected everything).
    y : ndarray, shape (B, mo)
        The innovation of the observed components (what the gate tested); NaN where a filter had no
        measurement of a component.
    Sy : ndarray, shape (B, mo, mo), or None
    L21 : ndarray, shape (B, n, mo), or None
        The innovation factor and ``Pxy Sy^-T`` (None: not kept, a fleet's).
    log_likelihood : ndarray, shape (B,)
        Of the components that passed (0 where none did).
    nis : ndarray, shape (B,)
        Of the innovation tested.
    observed : ndarray of bool, shape (m,), or None
        The measured components, the columns of ``y`` (None: all ``m``).
    rejected : ndarray of bool, shape (B, mo)
        The observed components the gate rejected.
    K : ndarray, shape (B, n, mo), or None
        The gain applied when the gate rejected something (None: ``L21 Sy^-1``).
    m : int
        The measurement's length.
    w : ndarray, shape (B, mo)
        The whitened innovation ``Sy^-1 y`` of the innovation tested (``nis`` is its squared norm; NaN
        as in ``y``).
    log_det_S1_2 : ndarray, shape (B,)
        ``log det Sy`` of the measured block, as the kernel summed it for the log-likelihood (a fleet's:
        0 where a filter was not updated). (None only in an update pickled before the kernels wrote it,
        which :mod:`squkf.old_pickles` fills when it loads.)
    """

    x: np.ndarray
    S: np.ndarray
    y: np.ndarray
    Sy: np.ndarray | None
    L21: np.ndarray | None
    log_likelihood: np.ndarray
    nis: np.ndarray
    observed: np.ndarray | None
    rejected: np.ndarray
    K: np.ndarray | None
    m: int
    w: np.ndarray
    log_det_S1_2: np.ndarray | None = None

    def rows(self, idx) -> Update:
        """The update of the filters ``idx`` of the block (their rows of every per-filter field)."""
        fields: tuple[Any, ...] = self  # (each a (B, ...) array, None, or the block's: observed, m)
        rows = [a if a is None or name in _SHARED else a[idx] for name, a in zip(self._fields, fields)]
        return Update(*rows)


#: The fields of an :class:`Update` that are the block's, not one per filter (``Update.rows`` keeps them).
_SHARED = frozenset(("observed", "m"))


def _downdate_route(base: UpdateRoute, wc: np.ndarray, xkind: np.ndarray, residual_x: bool) -> UpdateRoute:
    """The downdate kernel's route from the set's joint or angle route ``base``: the images' rows as
    that route forms them, the state rows the set's points less the prior mean (its offsets where it
    has them, unless squkf's ``residual_x`` wraps the deviations), its covariance weights ``wc``."""
    have = base.offsets and not residual_x
    return base._replace(offsets=have, xref=not have, pair=0.0, downdate=True, wc=wc, xkind=xkind)


def _angle_out(B: int, N: int, m: int) -> tuple:
    """The angle kernel's outputs: the predicted measurement, the rows, the innovation."""
    return np.empty((B, m)), np.empty((B, N, m)), np.empty((B, m))


def _ro(a: np.ndarray) -> np.ndarray:
    return table.plan_array(a)


class _Zeros(dict):
    """Shared rows of zeros ``(1, d)`` by size ``d`` (references the kernels read), made on first use."""

    def __missing__(self, d: int) -> np.ndarray:
        z = self[d] = table.zeros_row(d)
        return z


#: No measurement for the angle kernel (a prediction's images: no innovation formed or written).
_NO_Z = np.empty((0, 0))


class _ObservedR:
    """The factor of R's observed block, kept for the last (R, observed) pair: repeated, nothing is formed.

    The pair and its factor are kept as one tuple, replaced in one assignment: a fleet's chunks on
    several threads share the route, and never see one pair's key with another's factor.
    """

    __slots__ = ("kept",)

    def __init__(self):
        self.kept: tuple = (None, b"", None)

    def of(self, R1_2: np.ndarray, observed: np.ndarray, kernels: table.KernelTable) -> np.ndarray:
        """``tria(R1_2[observed].T)`` by the route's ``kernels``: the observed block ``R[obs][:, obs]`` is
        ``R1_2[obs] R1_2[obs].T``."""
        key = observed.tobytes()
        R, kept_key, factor = self.kept
        if R is not R1_2 or kept_key != key:
            factor = observed_noise_factor(R1_2, observed, kernels=kernels)
            self.kept = (R1_2, key, factor)
        return factor


class Buffers:
    """A block's output arrays, allocated once per shape and used again: two sets of each, in turn.

    A call takes the set that no committed record holds (:meth:`take`), and :meth:`commit` makes it the
    one they hold once the whole call succeeded; a call that fails (:meth:`abandon`) leaves the other
    set, and everything that reads it, as it was.
    """

    __slots__ = ("sets", "taken")

    def __init__(self) -> None:
        self.sets: dict[tuple, list] = {}  # (make, *args) -> [set 0, set 1, the set to write next]
        self.taken: list[list] = []

    def take(self, make: Callable[..., tuple], *args) -> tuple:
        """The set ``make(*args)`` to write now (made twice, on the first call with these arguments)."""
        key = (make, *args)
        pair = self.sets.get(key)
        if pair is None:
            pair = self.sets[key] = [make(*args), make(*args), 0]
        self.taken.append(pair)
        return pair[pair[2]]

    def spare(self, held: tuple, make: Callable[..., tuple], *args) -> tuple:
        """A set ``make(*args)`` none of whose arrays is one of ``held`` (what committed records hold now).

        For results that records hold in turn (a fleet's prior and posterior estimates): the first set
        made for these arguments that nothing holds, else a new one. A failed call leaves the records on
        their own sets, so nothing is committed or abandoned: as many sets as records hold, and one more.
        """
        key = ("spare", make, *args)
        made = self.sets.get(key)
        if made is None:
            made = self.sets[key] = []
        held_ids = set(map(id, held))
        for candidate in made:
            if held_ids.isdisjoint(map(id, candidate)):
                return candidate
        candidate = make(*args)
        made.append(candidate)
        return candidate

    def commit(self) -> None:
        """The sets taken since the last call hold the committed records now: the next writes the others."""
        for pair in self.taken:
            pair[2] ^= 1
        self.taken.clear()

    def abandon(self) -> None:
        """A call failed: the sets it took are written again by the next one."""
        self.taken.clear()


class Scratch(Buffers):
    """Arrays no result outlives (a fleet chunk's points and statuses), never committed.

    One set per ``make`` and trailing arguments, made for the largest block asked for: a smaller block
    (a fleet's last chunk) gets the leading rows of each array, so that a chunk of another size costs
    no second set.
    """

    __slots__ = ()

    def take(self, make: Callable[..., tuple], B: int, *args) -> tuple:  # type: ignore[override]
        """The set ``make(B, *args)``: arrays whose first axis is the block's ``B`` filters."""
        key = (make, *args)
        made = self.sets.get(key)
        if made is None or made[0] < B:
            made = self.sets[key] = [B, make(B, *args), {}]
        size, arrays, smaller = made
        if size == B:
            return arrays
        rows = smaller.get(B)  # (made once per smaller size: a steady step makes no view)
        if rows is None:
            # the leading rows of a C-contiguous array are C-contiguous: the kernels take them as they are
            rows = smaller[B] = tuple(a[:B] if a.shape[:1] == (size,) else a for a in arrays)
        return rows


def _prior_out(B: int, n: int, N2: int, offsets: bool) -> tuple:
    """The prediction kernel's outputs: mean, factor, status, the second set and its offsets."""
    X2 = np.empty((B, N2, n))
    D2 = np.empty(X2.shape) if offsets else table.no_set(n)
    return np.empty((B, n)), np.empty((B, n, n)), np.empty(B, dtype=np.int64), X2, D2


def _points_out(B: int, N: int, n: int, offsets: bool) -> tuple:
    """A set of points ``(B, N, n)`` and their offsets (or no array for them)."""
    return np.empty((B, N, n)), np.empty((B, N, n)) if offsets else table.no_set(n)


#: The update kernels' outputs, in their order (``_posterior_out``'s): :class:`JointUpdate`'s fields, by
#: the :class:`Update` field each is or the kernel's own (``z_pred``, ``dx``, ``status``), and ``X1``, the
#: next first set. A fleet's chunk passes its step's arrays to the kernel by these names
#: (:class:`squkf.stacks.Chunks`).
POSTERIOR_OUT = (*JointUpdate._fields, "X1")
#: The fields of an :class:`Update` an update kernel gives (:class:`JointUpdate`'s of the same names)
_FROM_KERNEL = tuple(name for name in Update._fields if name in JointUpdate._fields)
_from_kernel = operator.attrgetter(*_FROM_KERNEL)


def _posterior_out(B: int, n: int, m: int, N1: int) -> tuple:
    """The update kernel's outputs (as its arguments, :data:`POSTERIOR_OUT`), and the next first set (``N1``
    points, 0: none)."""
    return (*update_outputs(B, n, m), np.empty((B, N1, n)) if N1 else table.no_set(n))


class Route:
    """One configuration's step for a block of filters, decided when it is built: which kernels run, how.

    The route is constants, as a Runge-Kutta method's tableau is: built when the filter is built or
    its configuration changes (points, scheme, hooks, gate), never re-decided per call. It owns the
    :class:`~squkf.plan.Plan` (the sets' unit points, weights and rows, and the prediction's kernel
    data: a value shared by every filter of those sets, whatever their hooks), and adds what a filter's
    configuration decides on top of it: the hooks (squkf's angle hooks as data), the gate, the kernel
    table, and the routes of the updates, fixed for every kind of set the plan's generator draws
    (:meth:`update_route`; a user's generator, whose set may change at each draw, is classified at
    each draw). Each phase takes a block's arrays and gives its results and a status per filter
    (0: success; :func:`failure` says the rest); the routes through the hooks or a ``UT`` raise
    instead (their Python checks are per call). :class:`Engine` (one filter) and
    :mod:`squkf.stacks` (a fleet's chunks) run a step with them.

    Parameters
    ----------
    plan : Plan
    hooks : Hooks
    gate : Gate or None
    single : bool
        One filter (a block of one whose hooks, ``UT`` and generator see one filter's arrays, with
        no batch axis, as filterpy's do).
    kernels : KernelTable, optional
        The kernels every phase of this route calls (default: the table installed as
        :data:`squkf.kernels.table.KERNELS` when the route is built). A filter on another backend
        is built with that backend's table; a CPU filter beside it keeps its own.

    Attributes
    ----------
    kernels : KernelTable
    z_angles : bool
        The measurement's hooks are squkf's angle hooks (exact :class:`~squkf.angles.AngleMean`,
        :class:`~squkf.angles.AngleResidual`): their indices go to the kernels, which form the
        predicted measurement, rows and innovation (:func:`squkf.kernels.phases.angle_rows_kernel`).
    x_kinds : ndarray of int64, shape (n,), or None
        The state's hooks are squkf's angle hooks (exact :class:`~squkf.angles.AngleMean`,
        :class:`~squkf.angles.AngleResidual`, :class:`~squkf.angles.AngleAdd`): per component what the
        kernels do (:func:`squkf.angles.state_angles`); ``x_angles``: the prediction's mean and rows are
        the angle kernel's.
    plain_x : bool
        The prediction has no Python hook (none, or squkf's as data).
    kernel_update : bool
        The update has no Python hook: it is one kernel's, with statuses (:meth:`update_route`).
    downdate : bool
        The updates take the downdate form whatever the set (a ``residual_x`` or ``state_add``:
        :func:`squkf.measurement.keeps_prior_factor`): the prior factor kept and the gain taken out
        of it by rank-1 downdates, never the joint QR nor the gain form. Without it, a set takes that
        form when its moments are not exact (``SigmaSet.moments_exact``; a written set:
        :meth:`squkf.generators.SigmaSet.rewritten`).
    """

    __slots__ = (
        "plan", "hooks", "gate", "single", "kernels", "plain_x", "plain_add", "downdate", "no_set", "zeros",
        "_fixed", "_observed_R", "_noise", "_prior_draws", "z_angles", "_angle_kinds", "x_kinds", "x_angles",
        "x_rows", "kernel_update",
    )  # fmt: skip

    def __init__(
        self, plan: Plan, hooks: Hooks, gate, single: bool, kernels: table.KernelTable | None = None
    ):
        self.plan, self.hooks, self.gate, self.single = plan, hooks, gate, single
        self.kernels = table.chosen(kernels)
        # squkf's angle hooks on the state are data: the kernels do what they would (x_kinds, per component)
        self.x_kinds = state_angles(hooks.x_mean_fn, hooks.residual_x, hooks.state_add, plan.n)
        self.x_angles = self.x_kinds is not None and (
            hooks.x_mean_fn is not None or hooks.residual_x is not None
        )  # the prediction's circular means and wrapped rows: the angle kernel
        if self.x_angles:  # as the Python hooks' route weighs the rows: the first set's mean form
            rows = plan.first.rows
            form = rows.mean_form
            ref = int(np.argmax(np.abs(rows.Wm)))
            self.x_rows: tuple = (ref, _ro(rows.Wm), _ro(form.scale), _ro(form.sign))
        no_x_hooks = hooks.x_mean_fn is None and hooks.residual_x is None
        self.plain_x = no_x_hooks or self.x_kinds is not None  # the prediction has no Python hook
        self.plain_add = hooks.state_add is None
        self.downdate = keeps_prior_factor(hooks.residual_x, hooks.state_add)
        # squkf's angle hooks on the measurement are data: the angle kernel does what they would
        self.z_angles = measurement_hooks_are_data(hooks.z_mean_fn, hooks.residual_z)
        # the update has no Python hook: it is one kernel's, the joint or the downdate (update_route)
        self.kernel_update = (self.z_angles or (hooks.z_mean_fn is None and hooks.residual_z is None)) and (
            not self.downdate or self.x_kinds is not None
        )
        self._angle_kinds: dict[int, np.ndarray] = {}  # per measurement size: what the kernel does
        self.no_set = table.no_set(plan.n)  # a kernel's set output when it draws none
        self._observed_R = _ObservedR()
        self.zeros = _Zeros()
        self._noise: dict[int, tuple] = {}  # per noise factor given: (that array, as the kernels take it)
        # how a prediction draws its second set, per (draw, Q given); the update routes of the sets the
        # plan's generator draws, per rows (held: compared by identity) and kind of set, from the plan's
        # (made once per configuration); a set with other rows (a user's generator's) is classified when
        # it comes. Both depend on the plan and the hooks' flags alone, without state angle hooks (whose
        # indices are data): made once per plan and flags, shared.
        key = (
            self.kernel_update, self.z_angles, self.downdate, hooks.residual_x is not None, self.plain_add,
        ) if self.x_kinds is None else None  # fmt: skip
        made: tuple[dict, tuple] | None = None if key is None else plan.route_cache.get(key)
        if made is None:
            made = (
                {(d, q): self._prior_draw(d, q) for d in (False, True) for q in (False, True)},
                tuple((r.rows, self._routes_of(r)) for r in plan.set_routes) if self.kernel_update else (),
            )
            if key is not None:
                plan.route_cache[key] = made
        self._prior_draws: dict = made[0]
        self._fixed: tuple = made[1]

    def __reduce__(self):
        # built again when unpickled (or deep-copied); a table that is not the installed one goes with it
        kernels = None if self.kernels is table.KERNELS else self.kernels
        return (Route, (self.plan, self.hooks, self.gate, self.single, kernels))

    def _one(self, a):
        """``a`` as the hooks, a ``UT`` and a generator see it: one filter's (no batch axis) if single."""
        return a[0] if self.single and a is not None else a

    def _block(self, a):
        """One filter's result as a block of one (if single)."""
        return a[None] if self.single and a is not None else a

    def stacked(self, factor: np.ndarray, which: int) -> np.ndarray:
        """A noise factor ``(d, d)`` (or ``(B, d, d)``) as the kernels take it, ``(1 or B, d, d)``.

        Kept for the last factor given as ``which`` (0: the process noise, 1: the measurement's):
        the filter's own factor, given again at every step, is stacked once.
        """
        kept = self._noise.get(which)
        if kept is not None and kept[0] is factor:
            return kept[1]
        st = table.kernel_array(factor[None] if factor.ndim == 2 else factor)
        self._noise[which] = (factor, st)
        return st

    # -- the phases -------------------------------------------------------------------------

    def first_points(self, x: np.ndarray, S: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """The first sigma-point set of ``(x, S)``, ``(B, N, n)`` (written into ``out`` where given)."""
        plan = self.plan
        add = self.hooks.state_add
        if add is not None:  # the hook sees one filter's vectors (a filter of a block at a time)
            first = plan.first
            X1 = sigma_points_from_factor(self._one(x), self._one(S), first.xi, add, kernels=self.kernels)
            return self._block(X1)
        B, n = x.shape
        N = plan.xi1.shape[0]
        X = np.empty((B, N, n)) if out is None else out
        self.kernels.points(x, S, plan.xi1, plan.gamma1, X, self.no_set)
        return X

    def _prior_draw(self, draw: bool, with_Q: bool) -> tuple:
        """How a prediction draws its second set with the prior, decided once per (``draw``, Q given).

        ``(fused, code, xi2, gamma2, N2, with_offsets)``: the plan's fused draw (None: the kernel draws
        none) and the transform kernel's arguments for it (every pair decided when the route is built).
        """
        plan = self.plan
        n, N = plan.n, plan.xi1.shape[0]
        fused = plan.fused_draw if (draw and self.plain_add) else None
        if fused is not None and fused.augmented and (not with_Q or self.x_angles):
            # the augmented set without noise is the propagated set itself; with the angle kernel's given
            # rows the transform kernel holds no propagated set to draw it from (the generator draws it)
            fused = None
        if fused is None:
            drawn: tuple = (None, 0, table.no_points(n), 0.0, 0, False)
        else:
            N2 = fused.xi.shape[0] + (N if fused.augmented else 0)
            drawn = (fused, 2 if fused.augmented else 1, fused.xi, fused.gamma, N2, not fused.augmented)
        return drawn

    def prior(
        self,
        F: np.ndarray,
        Q1_2: np.ndarray | None,
        UT: Callable | None,
        draw: bool,
        name: str = "fx values",
        buffers: Buffers | None = None,
        out: tuple | None = None,
    ):
        """The prior from the first set's images ``F`` ``(B, N, n)``, and its second set where drawn with it.

        ``F`` is checked finite: in the kernel on the plain route (no ``x_mean_fn``/``residual_x``,
        no ``UT``: status 306 for a filter whose images are not finite), here on the others (before
        the hooks see them; ``name`` says what they are). The results are written into ``out``
        (``mean, S, status`` and the second set's points and offsets, where given) or ``buffers``'
        arrays (else new ones).

        Returns
        -------
        mean : ndarray, shape (B, n)
        S : ndarray, shape (B, n, n)
        status : ndarray of int, shape (B,)
        sset : SigmaSet or None
            The second set drawn by the same kernel (``draw`` and a fused route), else None.
        """
        plan = self.plan
        B, N, n = F.shape
        if UT is None and self.plain_x:
            fused, code, xi2, gamma2, N2, with_offsets = self._prior_draws[draw, Q1_2 is not None]
            if out is not None:
                mean, S, status, X2, D2 = out
            elif buffers is None:
                mean, S, status, X2, D2 = _prior_out(B, n, N2, with_offsets)
            else:
                mean, S, status, X2, D2 = buffers.take(_prior_out, B, n, N2, with_offsets)
            if Q1_2 is None:
                noise = table.no_noise(n)
            else:  # (stacked's kept factor, looked up here: no call when it is the one given last)
                kept = self._noise.get(0)
                noise = kept[1] if kept is not None and kept[0] is Q1_2 else self.stacked(Q1_2, 0)
            if self.x_angles:  # squkf's x_mean_fn, residual_x: the angle kernel's mean and rows, given
                ref, wm, scale, sign = self.x_rows
                D = (_angle_out(B, N, n) if buffers is None else buffers.take(_angle_out, B, N, n))[1]
                self.kernels.angle_rows(F, _NO_Z, wm, ref, self.x_kinds, mean, D, _NO_Z)
                self.kernels.transform(
                    D, mean, table.GIVEN, wm, scale, sign, noise, mean, S, status, code, xi2, gamma2, X2, D2
                )
            else:
                self.kernels.transform(
                    F, self.zeros[n], plan.mode1, plan.wm1, plan.scale1, plan.sign1, noise, mean, S, status,
                    code, xi2, gamma2, X2, D2,
                )  # fmt: skip
            sset = None
            if fused is not None:
                rows = fused.rows
                offsets = None if fused.augmented else D2
                sset = SigmaSet(X2, rows.Wm, rows.Wc, fused.exact, offsets, rows, fused.axis)
            return mean, S, status, sset
        hooks = self.hooks
        rows = plan.first.rows
        Fo = self._one(F)
        if not all_finite(Fo):
            raise NonFiniteError(describe_nonfinite(Fo, name))
        if UT is None:
            mean, S = transform_factor(
                Fo,
                rows,
                Q1_2,
                hooks.x_mean_fn,
                hooks.residual_x,
                errno=301,
                hooks=("x_mean_fn", "residual_x"),
                kernels=self.kernels,
            )
        else:
            mean, S = UT(Fo, rows.Wm, rows.Wc, Q1_2, hooks.x_mean_fn, hooks.residual_x)
            mean = check_hook_result(mean, Fo.shape[:-2] + Fo.shape[-1:], "UT")
            S = check_hook_result(S, Fo.shape[:-2] + (n, n), "UT")
        if not (all_finite(mean) and all_finite(S)):
            raise NonFiniteError("the predicted mean or factor is not finite")
        return self._block(mean), self._block(S), np.zeros(B, dtype=np.int64), None

    def second_set(self, x, S, propagated, Q1_2, buffers: Buffers | None = None) -> SigmaSet:
        """The generator's second set for ``(x, S)`` (one filter's arrays to a user's generator and hooks).

        A redrawn set is drawn by the points kernel with its offsets (in ``buffers``' arrays where given).
        """
        plan = self.plan
        fused = plan.fused_draw
        if fused is not None and not fused.augmented and self.plain_add:
            B, n = x.shape
            N2 = fused.xi.shape[0]
            X2, D2 = (
                _points_out(B, N2, n, True) if buffers is None else buffers.take(_points_out, B, N2, n, True)
            )
            self.kernels.points(x, S, fused.xi, fused.gamma, X2, D2)
            rows = fused.rows
            return SigmaSet(X2, rows.Wm, rows.Wc, fused.exact, D2, rows, fused.axis)
        if not self.single:
            return plan.second.draw(x, S, propagated, Q1_2, self.hooks.state_add, kernels=self.kernels)
        one = self._one
        s = plan.second.draw(
            one(x), one(S), one(propagated), Q1_2, self.hooks.state_add, kernels=self.kernels
        )
        return s._replace(sigmas=s.sigmas[None], offsets=None if s.offsets is None else s.offsets[None])

    def update_route(self, sset: SigmaSet, UT) -> UpdateRoute | None:
        """The kernel route of an update with this set, or None for the general one (Python hooks, ``UT``).

        The joint QR where the set reproduces the prior and no ``residual_x`` or ``state_add`` is given;
        else the downdate form (``downdate``). For a set the plan's generator draws (its rows are the
        plan's), the route fixed when this route was built; for any other (a user's generator's, whose
        set may change at each draw), classified now.
        """
        rows = sset.rows
        if UT is not None or rows is None or not self.kernel_update:
            return None
        kind = (bool(sset.moments_exact), sset.offsets is not None, bool(sset.axis))
        for known, routes in self._fixed:
            if known is rows:
                return routes[kind]
        return self._classify(SetRoutes.of(rows), *kind)

    def _routes_of(self, routes: SetRoutes) -> dict:
        """Every kind of set's route (``SET_KINDS``) with the plan's ``routes`` of their rows (the downdate
        form's made once for each of its two kinds and shared)."""
        down = {have: self._classify(routes, False, have, False) for have in (False, True)}
        if self.downdate:
            return {kind: down[kind[1]] for kind in SET_KINDS}
        return {kind: self._classify(routes, *kind) if kind[0] else down[kind[1]] for kind in SET_KINDS}

    def _classify(self, routes: SetRoutes, exact: bool, have: bool, axis: bool) -> UpdateRoute:
        """The kernel route of a set with the plan's ``routes`` of its rows: moments ``exact`` or not, its
        offsets known (``have``), its points on the axes (``axis``)."""
        if self.z_angles:
            base = routes.angle[have]
        else:
            base = routes.joint[have, axis and have and exact and not self.downdate]
        if exact and not self.downdate:
            return base
        xkind = table.no_angles(self.plan.n) if self.x_kinds is None else self.x_kinds
        return _downdate_route(base, routes.wc, xkind, self.hooks.residual_x is not None)

    def posterior(
        self, sset, x, S, H, z, observed, R1_2, UT, draw_first: bool, name: str = "hx values",
        buffers: Buffers | None = None, out: tuple | None = None,
    ):  # fmt: skip
        """The update with every measured component (what a gate tests), and the next first set drawn with it.

        Parameters
        ----------
        sset : SigmaSet
        x : ndarray, shape (B, n)
        S : ndarray, shape (B, n, n)
            The prior.
        H : ndarray, shape (B, N2, m)
            Checked finite: in the kernel on the joint route (status 306), here on the others (before
            the hooks see them; ``name`` says what they are).
        z : ndarray, shape (B, m)
        observed : ndarray of bool, shape (m,), or None
        R1_2 : ndarray, shape (m, m) or (B, m, m)
        UT : callable or None
        draw_first : bool
            Draw the next first set from the posterior (the joint route only).
        name : str
            What the images are called in messages.
        buffers : Buffers, optional
            Where the kernel's results are written (default: new arrays).
        out : tuple, optional
            The kernel's outputs themselves, as its arguments (:data:`POSTERIOR_OUT`), on the joint
            route: a fleet writes into its step's arrays.

        Returns
        -------
        update : Update
            As tested (no component rejected).
        status : ndarray of int, shape (B,)
        X1 : ndarray, shape (B, N, n), or None
        """
        # update_route's fixed route, looked up here (no call for a set the plan's generator draws)
        rows = sset.rows
        route: UpdateRoute | None = None
        for known, routes in self._fixed if UT is None else ():
            if known is rows:
                route = routes[bool(sset.moments_exact), sset.offsets is not None, bool(sset.axis)]
                break
        else:
            route = self.update_route(sset, UT)
        B = x.shape[0]
        m_all = z.shape[-1]
        if route is None:
            one = self._one
            hooks = self.hooks
            Ho = one(H)
            if not all_finite(Ho):
                raise NonFiniteError(describe_nonfinite(Ho, name))
            post = measurement_update(
                one(x), one(S), _one_set(sset) if self.single else sset, Ho, one(z), R1_2,
                observed=observed, z_mean_fn=hooks.z_mean_fn, residual_x=hooks.residual_x,
                residual_z=hooks.residual_z, state_add=hooks.state_add, UT=UT, kernels=self.kernels,
            )  # fmt: skip
            given = dict(zip(_FROM_KERNEL, _from_kernel(post)))  # (the kernel's outputs an Update keeps)
            if self.single:
                given = {name: a[None] for name, a in given.items()}
            none = _NONE_REJECTED[given["y"].shape]
            update = Update(**given, observed=observed, rejected=none, K=None, m=m_all)
            return update, np.zeros(B, dtype=np.int64), None
        Ro = R1_2
        whole = None
        zref = None
        images = H
        if route.angles:  # given rows: the hooks' predicted measurement, rows and innovation, every component
            zref, H, z = self._angle_rows(route, H, z, buffers)
        if observed is not None and not observed.all():
            whole = images  # (a missing component's images count too: all of them are checked finite)
            H, z = np.ascontiguousarray(H[..., observed]), np.ascontiguousarray(z[..., observed])
            if zref is not None:
                zref = np.ascontiguousarray(zref[..., observed])
            Ro = self._observed_R.of(R1_2, observed, self.kernels)
        m = H.shape[2]
        n = x.shape[1]
        if zref is None:
            zref = self.zeros[m]
        plan = self.plan
        # (noise entering fx: the first set has a noise part; the downdate kernel draws none)
        draw = draw_first and plan.w_xi is None and not route.downdate
        N1 = plan.xi1.shape[0] if draw else 0
        if out is None:
            out = (
                _posterior_out(B, n, m, N1) if buffers is None else buffers.take(_posterior_out, B, n, m, N1)
            )
        zp, y, w, Sy, L21, dx, xo, So, ll, ww, ld, status, X1 = out
        kept = self._noise.get(1)
        Rs = kept[1] if kept is not None and kept[0] is Ro else self.stacked(Ro, 1)
        Xs = sset.offsets if route.offsets else sset.sigmas
        if route.angles and not route.offsets and not route.downdate:  # given state rows: less the prior mean
            Xs = Xs - x[:, None, :]
        f = Xs.flags
        if not (f.c_contiguous and f.writeable and Xs.dtype is _FLOAT64):  # a user generator's set
            Xs = table.kernel_array(Xs)
        if route.downdate:  # the prior factor kept and downdated: no first set drawn with it
            self.kernels.downdate_update(
                H, zref, Xs, x if route.xref else self.zeros[n], z, Rs, table.no_factor(m), S, x,
                route.mode, route.wm, route.wc, route.scale, route.sign, route.xkind, *out[:12],
            )  # fmt: skip
        else:
            self.kernels.joint_update(
                H, zref, Xs, x if route.xref else self.zeros[n], z, Rs, x, route.mode, route.wm,
                route.scale, route.sign, route.pair, *out[:12], plan.xi1, plan.gamma1, X1,
            )  # fmt: skip
        if whole is not None:
            status[~np.isfinite(whole).reshape(B, -1).all(axis=1)] = NOT_FINITE_IMAGES
        if np.count_nonzero(status):
            status = singular_allowed(status, S, Rs)
        update = Update(xo, So, y, Sy, L21, ll, ww, observed, _NONE_REJECTED[y.shape], None, m_all, w, ld)
        return update, status, (X1 if draw else None)

    def _angle_rows(self, route: UpdateRoute, H, z, buffers: Buffers | None) -> tuple:
        """The angle kernel's predicted measurement, rows and innovation of the images ``H`` ``(B, N, m)``
        and the measurement ``z`` ``(B, m)``, every component (in ``buffers``' arrays where given)."""
        B, N, m = H.shape
        kinds = self._angle_kinds.get(m)
        if kinds is None:
            made = measurement_angles(self.hooks.z_mean_fn, self.hooks.residual_z, m)
            assert made is not None
            made.setflags(write=False)  # (a plan's array: read-only, one signature)
            kinds = self._angle_kinds[m] = made
        zp, D, y = _angle_out(B, N, m) if buffers is None else buffers.take(_angle_out, B, N, m)
        self.kernels.angle_rows(H, z, route.wm, route.ref, kinds, zp, D, y)
        return zp, D, y

    def form_of(self, sset: SigmaSet, UT) -> RowForm | None:
        """The row form a failed update's status refers to (its negative weights)."""
        route = self.update_route(sset, UT)
        return None if route is None else route.form

    def gated(
        self, post: Update, status, sset, x0, S0, H, z, observed, R1_2, UT
    ) -> tuple[Update, np.ndarray]:
        """The gate's decision on the tested update, and the update applied (:mod:`squkf.gating`).

        Rejected components are missing: a filter whose whole measurement is rejected keeps its prior
        (log-likelihood 0), one with some rejected is updated again with the others. A filter whose
        update failed (``status``) is not decided.

        Returns
        -------
        update : Update
        status : ndarray of int, shape (B,)
            With the failures of the updates made again.
        """
        m = z.shape[-1]
        gate = self.gate
        if gate is None:
            return post, status
        rejected = gate.reject(post.y, post.Sy, post.nis)
        failed = status != 0
        if failed.any():
            rejected = rejected & ~failed[:, None]
        if not rejected.any():
            return post._replace(rejected=rejected), status
        n, mo = post.x.shape[-1], post.y.shape[-1]
        obs_idx = np.arange(m) if observed is None else np.flatnonzero(observed)
        x, S = post.x.copy(), post.S.copy()
        ll = np.array(post.log_likelihood, dtype=float)
        assert post.Sy is not None and post.L21 is not None  # (the tested update keeps its factors)
        K = gain_from_factors(post.Sy, post.L21, kernels=self.kernels).copy()
        none_left = rejected.all(axis=1)
        x[none_left], S[none_left] = x0[none_left], S0[none_left]
        ll[none_left], K[none_left] = 0.0, 0.0
        some = rejected.any(axis=1) & ~none_left
        if some.any():
            status = status.copy()
            patterns, which = np.unique(rejected[some], axis=0, return_inverse=True)
            some_idx = np.flatnonzero(some)
            for p, pattern in enumerate(patterns):
                ix = some_idx[which.reshape(-1) == p]
                mask = np.zeros(m, dtype=bool)
                mask[obs_idx[~pattern]] = True
                R_ix = R1_2[ix] if R1_2.ndim > 2 else R1_2
                sub = sset._replace(
                    sigmas=sset.sigmas[ix], offsets=None if sset.offsets is None else sset.offsets[ix]
                )
                part, st, _ = self.posterior(sub, x0[ix], S0[ix], H[ix], z[ix], mask, R_ix, UT, False)
                x[ix], S[ix], ll[ix], status[ix] = part.x, part.S, part.log_likelihood, st
                Kp = np.zeros((ix.size, n, mo))
                Kp[:, :, ~pattern] = gain_from_factors(part.Sy, part.L21, kernels=self.kernels)
                K[ix] = Kp
        # (y, w, nis, Sy and its log det: the tested innovation's)
        update = post._replace(x=x, S=S, log_likelihood=ll, observed=observed, rejected=rejected, K=K, m=m)
        return update, status


class Block:
    """How a block's phases run when the block is the whole call: one filter (:class:`squkf.SquareRootUKF`).

    The engine passes the model's images at the whole block; a filter's failure raises (the first
    failing filter's :func:`failure`). A fleet runs its phases a chunk at a time on threads instead,
    its failures flagged per filter (:class:`squkf.stacks.Chunks`, with the same two methods).

    Attributes
    ----------
    defers : bool
        Whether the second set is drawn at the update (a fleet's, a chunk at a time) rather than with
        the prior.
    """

    __slots__ = ()
    defers = False

    def __reduce__(self) -> str:
        return "BLOCK"  # the one runner, by name: a pickled engine gets it back (``run is BLOCK``)

    @staticmethod
    def prior(route: Route, x, S, F, X, Q1_2, UT, name: str, buffers: Buffers, held: tuple) -> tuple:
        """The numerics of a prediction: the prior and its second set (nothing committed).

        Parameters
        ----------
        route : Route
        x : ndarray, shape (B, n)
        S : ndarray, shape (B, n, n)
            The estimate predicted from (the images are its first set's, ``X``).
        F : ndarray, shape (B, N, n)
            The model's images at ``X`` (as the engine read them: float64, C-contiguous, a private copy
            where the plan keeps them).
        X : ndarray, shape (B, N, n)
        Q1_2, UT, name
            As :meth:`Engine.tell_predict` takes them.
        buffers : Buffers
        held : tuple of ndarray
            What the committed records hold (a block of one writes its buffers in turn instead).

        Returns
        -------
        x, S : ndarray
            The prior.
        sset : SigmaSet
            Its second set.
        later : None
            (What a deferred draw reads: nothing, the set is drawn.)
        """
        keep = route.plan.keeps_propagated
        mean, S, status, sset = route.prior(F, Q1_2, UT, True, name, buffers)
        if np.count_nonzero(status):
            code = first_status(status)
            raise _described(code, F, status, name) or prior_failure(code, route.plan.first.rows.best)
        if sset is None:
            sset = route.second_set(mean, S, F if keep else None, Q1_2)
        return mean, S, sset, None

    @staticmethod
    def posterior(route: Route, pending: tuple, H, z, observed, R1_2, UT, name: str, buffers: Buffers, held):
        """The numerics of an update through the gate, and the next first set (nothing committed).

        Parameters
        ----------
        route : Route
        pending : tuple
            :meth:`Engine.pending_update`'s.
        H : ndarray, shape (B, N2, m)
            The images, as the engine read them (a private copy).
        z, observed, R1_2, UT, name
            As :meth:`Engine.tell_update` takes them.
        buffers : Buffers
        held : tuple of ndarray

        Returns
        -------
        update : Update
        X1 : ndarray, shape (B, N, n), or None
            The next first set, drawn with the posterior.
        H : ndarray, shape (B, N2, m)
            The images as read (the record of ``sigmas_h``).
        """
        (xp, Sp), sset, _ = pending
        if route.single:
            z = z[None]
        tested, status, X1 = route.posterior(sset, xp, Sp, H, z, observed, R1_2, UT, True, name, buffers)
        if np.count_nonzero(status):
            code = first_status(status)
            raise _described(code, H, status, name) or failure(code, route.form_of(sset, UT))
        if route.gate is None:
            return tested, X1, H
        update, status = route.gated(tested, status, sset, xp, Sp, H, z, observed, R1_2, UT)
        if np.count_nonzero(status):
            raise failure(first_status(status), route.form_of(sset, UT))
        # a gate's change: the posterior is not the one the next first set was drawn from
        return update, (X1 if update.x is tested.x else None), H


#: The runner of a block that is the whole call (one filter).
BLOCK = Block()


class Engine:
    """A block's step as a state machine: its estimate, its pending step, its last records, its commit.

    Both faces hold one: :class:`squkf.SquareRootUKF` a block of one (``single`` routes, run by
    :data:`BLOCK`), :class:`squkf.Fleet` a block of K (run a chunk at a time on threads by
    :data:`squkf.stacks.CHUNKS`). How a phase runs is the runner's; what is pending, what is committed,
    and when, is the engine's. A call that fails raises (one filter: the first failing filter's
    :func:`failure`; a fleet flags its failing filters, or raises for them all) and leaves the engine
    as it was.

    Parameters
    ----------
    route : Route
    x : ndarray, shape (B, n)
    S : ndarray, shape (B, n, n)
        The initial estimate (kept, not copied: never written in place).
    sigmas_f, sigmas_h : ndarray or None
        What ``shown_f`` and ``H`` are before any step (None: not shown, a fleet's).
    run : Block or squkf.stacks.Chunks
        How the phases run (default :data:`BLOCK`).

    Attributes
    ----------
    x : ndarray, shape (B, n)
    S : ndarray, shape (B, n, n)
        The current estimate (replaced by each step, never written in place).
    phase : str
    route, step_route : Route
        The configuration's, and the pending step's (the one its points were drawn with).
    drawn : bool
        Whether the pending update (``prior``, ``sset``, ``later``) belongs to the current estimate: set
        by a prediction, cleared when the caller assigns an estimate.
    prior : tuple (x, S) or None
        The estimate the pending second set was (or is to be) drawn from.
    sset : SigmaSet or None
        The pending second set (None: drawn at the update, a fleet's, from ``later``).
    later : tuple (propagated, Q1_2) or None
        What a second set drawn at the update reads (the prediction's images where the plan keeps them,
        and its process-noise factor).
    prior_record, post_record : tuple (x, S)
        The last prediction's and the last update's results (the estimate before any).
    last : Update or None
        The last update.
    H : ndarray, shape (B, N2, m), or None
        The last update's images (zeros before any; None: not kept, a fleet's).
    shown_f : ndarray or None
        What filterpy shows as ``sigmas_f``: the second set after a prediction (zeros before any).
    """

    __slots__ = (
        "route", "step_route", "run", "x", "S", "phase", "X", "drawn", "prior", "sset", "later",
        "prior_record", "post_record", "last", "H", "shown_f", "_first", "_buffers",
    )  # fmt: skip

    def __init__(
        self,
        route: Route,
        x: np.ndarray,
        S: np.ndarray,
        sigmas_f: np.ndarray | None,
        sigmas_h: np.ndarray | None,
        run=BLOCK,
    ):
        self.route = self.step_route = route
        self.run = run
        self.x, self.S = table.kernel_array(x), table.kernel_array(S)
        self.phase = IDLE
        self.X: np.ndarray | None = None  # the points handed out by a pending ask_predict
        self.drawn = False
        self.prior: tuple[np.ndarray, np.ndarray] | None = None
        self.sset: SigmaSet | None = None
        self.later: tuple | None = None
        self.prior_record = self.post_record = (self.x, self.S)
        self.last: Update | None = None
        self.H, self.shown_f = sigmas_h, sigmas_f
        self._first: np.ndarray | None = None  # the first set of (x, S), drawn ahead by the last update
        self._buffers = Buffers()

    # the state and the pending step; not the buffers (scratch), nor the first set drawn ahead
    _SCRATCH = ("_first", "_buffers")

    def __getstate__(self):
        return {k: getattr(self, k) for k in self.__slots__ if k not in self._SCRATCH}

    def __setstate__(self, state) -> None:
        state.setdefault("run", BLOCK)  # (pickled before the runner was passed in)
        state.setdefault("later", None)
        if "drawn" not in state:  # (pickled when the pending update was known by identity)
            prior = state.get("prior")
            state["drawn"] = prior is not None and prior[0] is state["x"] and prior[1] is state["S"]
        for k, v in state.items():
            object.__setattr__(self, k, v)
        self._first = None
        self._buffers = Buffers()

    def __copy__(self) -> Engine:
        """An independent engine: the state's arrays copied (the buffers they live in are this engine's,
        written again by its later steps), the configuration shared."""
        new = Engine.__new__(Engine)
        memo: dict[int, object] = {}
        new.__setstate__({k: _detached(v, memo) for k, v in self.__getstate__().items()})
        return new

    def __deepcopy__(self, memo) -> Engine:
        new = copy.copy(self)
        memo[id(self)] = new
        return new

    def rows(self, idx) -> Engine:
        """A new idle engine of the filters ``idx`` (an index array): their estimate and records' rows."""
        new = Engine(self.route, self.x[idx], self.S[idx], None, None, self.run)
        new.prior_record = (self.prior_record[0][idx], self.prior_record[1][idx])
        new.post_record = (self.post_record[0][idx], self.post_record[1][idx])
        new.last = None if self.last is None else self.last.rows(idx)
        return new

    def configure(self, route: Route) -> None:
        """A new configuration (a pending step keeps the route it was drawn with)."""
        self.route = route
        self._first = None

    def assign(self, x: np.ndarray | None = None, S: np.ndarray | None = None, idle: bool = False) -> None:
        """A new estimate from the caller (validated; kept): the sets drawn for the old one are dropped.

        ``idle``: a step pending is dropped too (a fleet's rule: an assignment ends an ask/tell step).
        """
        if x is not None:
            self.x = table.kernel_array(x)  # (as the kernels take it: a factor from LAPACK is in F order)
        if S is not None:
            self.S = table.kernel_array(S)
        self._first = None
        self.drawn = False
        if idle:
            self.phase = IDLE
            self.X = None

    # -- the prediction -------------------------------------------------------------------------

    def first_set(self) -> np.ndarray:
        """The first sigma-point set of the current estimate, ``(B, N, n)`` (nothing committed).

        The set the last update drew ahead, or drawn now. The array is the engine's and is
        used once: the caller may hand it to ``fx`` (which may write on it), never keep it.
        """
        X, self._first = self._first, None
        return self.route.first_points(self.x, self.S) if X is None else X

    def ask_predict(self) -> np.ndarray:
        """Start a step (from any phase): :meth:`first_set`, kept as the points of the pending prediction."""
        X = self.first_set()
        self.step_route = self.route
        self.X = X
        self.phase = PREDICTING
        return X

    def tell_predict(
        self, F, Q1_2: np.ndarray | None, UT: Callable | None = None, points=None, name: str = "fx values",
        whole: bool = False,
    ) -> None:  # fmt: skip
        """Finish the prediction from the first set's images: the prior and the second set, committed.

        Parameters
        ----------
        F : array_like, shape (B, N, n) (single: (N, n)), or what the runner takes
            ``fx`` at the points (checked by the runner; a fleet's runner takes its call,
            :class:`squkf.stacks.Step`, and calls ``fx`` a chunk at a time).
        Q1_2 : ndarray, shape (n, n) or (B, n, n), or None
            Lower factor of the additive process noise (None: none added).
        UT : callable, optional
        points : ndarray, shape (B, N, n), optional
            The points of a whole prediction (:meth:`first_set`, with no ask pending); default:
            those of the pending :meth:`ask_predict`.
        name : str
            What the images are called in messages.
        whole : bool
            A whole prediction whose runner draws the points itself (a fleet's, a chunk at a time).
        """
        if points is None and not whole:
            if self.phase != PREDICTING:
                raise CallSequenceError(
                    f"tell_predict needs a pending ask_predict, but the step is {self.phase!r}"
                    + (" (the prediction was already told)" if self.phase == PRIOR else "")
                )
            route, X = self.step_route, self.X
        else:
            route, X = self.route, points
        if self.run is BLOCK:  # the images of the whole block, read as the kernels take them
            assert X is not None
            F = _images(F, X.shape, name, route.plan.keeps_propagated, route.single)
            held: tuple = ()
        else:  # what the step must not write: the arrays the records hold
            held = (self.x, self.S, *self.prior_record, *self.post_record)
        buffers = self._buffers
        buffers.taken.clear()  # (abandon(): what a failed call took is written again)
        limit = blas.MIN_DIM
        if limit is not None and route.plan.n >= limit:
            with blas.one_blas_thread():
                done = self.run.prior(route, self.x, self.S, F, X, Q1_2, UT, name, buffers, held)
        else:
            done = self.run.prior(route, self.x, self.S, F, X, Q1_2, UT, name, buffers, held)
        for pair in buffers.taken:  # commit(): the sets taken hold the committed records now
            pair[2] ^= 1
        buffers.taken.clear()
        mean, S, sset, later = done
        self.step_route = route
        self.x, self.S = mean, S
        self.prior = self.prior_record = (mean, S)
        self.sset, self.later = sset, later
        if sset is not None:
            self.shown_f = sset.sigmas
        self.drawn = True
        self._first = None
        self.X = None
        self.phase = PRIOR

    # -- the update ------------------------------------------------------------------------------

    def pending_update(self) -> tuple:
        """The update pending for the current estimate: ``(prior, sset, later)`` (nothing committed).

        After a prediction, its prior and the set drawn with it (or what a set drawn at the update
        reads, ``later``); if the estimate was assigned since (or no prediction precedes), the estimate
        and a set drawn from it alone (by a runner that defers the draw, at the update: None).
        """
        if self.phase == PREDICTING:
            raise CallSequenceError(
                "ask_update called while a prediction is pending: tell_predict the fx values first"
            )
        if self.drawn and self.phase != IDLE:
            return self.prior, self.sset, self.later  # drawn with the prior
        x, S = self.x, self.S
        return (x, S), None if self.run.defers else self.route.second_set(x, S, None, None), None

    def ask_update(self) -> np.ndarray:
        """:meth:`pending_update`, kept as the pending update: its second set ``(B, N2, n)`` (engine's)."""
        prior, sset, later = self.pending_update()
        if sset is None:  # a runner that draws at the update: the whole set, handed out
            propagated, Q1_2 = (None, None) if later is None else later
            sset = self.route.second_set(prior[0], prior[1], propagated, Q1_2)
        if sset is not self.sset:  # drawn from the estimate alone, by the current route
            self.step_route = self.route
        self.prior, self.sset, self.later = prior, sset, later
        self.drawn = True
        self.phase = UPDATING
        return sset.sigmas

    def tell_update(
        self, H, z: np.ndarray, observed: np.ndarray | None, R1_2: np.ndarray, UT: Callable | None = None,
        pending: tuple | None = None, name: str = "hx values",
    ) -> None:  # fmt: skip
        """Finish the update from the second set's images and the measurement, through the gate; committed.

        Parameters
        ----------
        H : array_like, shape (B, N2, m) (single: (N2, m)), or what the runner takes
            ``hx`` at the points of the second set (checked by the runner; a fleet's runner takes its
            call, :class:`squkf.stacks.Step`, and calls ``hx`` a chunk at a time).
        z : ndarray, shape (B, m) (single: (m,))
            The measurement (missing components hold NaN).
        observed : ndarray of bool, shape (m,), or None
            The measured components (None: all, or, for a fleet, those not NaN per filter).
        R1_2 : ndarray, shape (m, m) or (B, m, m)
            Lower factor of the measurement noise (zeros: none).
        UT : callable, optional
        pending : tuple, optional
            The update of a whole call (:meth:`pending_update`, with no ask pending);
            default: that of the pending :meth:`ask_update`.
        name : str
            What the images are called in messages.
        """
        if pending is None:
            if self.phase != UPDATING:
                raise CallSequenceError(
                    f"tell_update needs a pending ask_update, but the step is {self.phase!r}"
                    + (" (the update was already told)" if self.phase == IDLE else "")
                )
            pending = (self.prior, self.sset, self.later)
        route = self.route
        if self.run is BLOCK:  # the images of the whole block, read as the kernels take them
            sset = pending[1]
            H = _images(H, sset.sigmas.shape[:-1] + (z.shape[-1],), name, True, route.single)
            held: tuple = ()
        else:  # what the step must not write: the arrays the records hold
            held = (self.x, self.S, *self.prior_record, *self.post_record)
        buffers = self._buffers
        buffers.taken.clear()  # (abandon(): what a failed call took is written again)
        limit = blas.MIN_DIM
        if limit is not None and route.plan.n >= limit:
            with blas.one_blas_thread():
                update, X1, H = self.run.posterior(
                    route, pending, H, z, observed, R1_2, UT, name, buffers, held
                )
        else:
            update, X1, H = self.run.posterior(route, pending, H, z, observed, R1_2, UT, name, buffers, held)
        for pair in buffers.taken:  # commit(): the sets taken hold the committed records now
            pair[2] ^= 1
        buffers.taken.clear()
        prior, sset, later = pending
        if sset is not self.sset:
            self.step_route = route
        self.prior, self.sset, self.later = prior, sset, later
        self.x, self.S = update.x, update.S
        self.post_record = (update.x, update.S)
        self.last = update
        self.H = H
        self._first = X1
        self.phase = IDLE

    def skip_update(self, last: Update | None = None) -> None:
        """End the step without a measurement: the estimate stays, and the last update's records too.

        ``last``: the update record of the skipped step instead (a fleet's: no innovation, no likelihood).
        """
        if self.phase == PREDICTING:
            raise CallSequenceError(
                "update without a measurement called while a prediction is pending: "
                "tell_predict the fx values first"
            )
        # the record's own copies: the estimate may live in the buffers the next prediction writes
        self.post_record = (self.x.copy(), self.S.copy()) if last is None else (last.x, last.S)
        if last is not None:
            self.last = last
        self.phase = IDLE


def _one_set(sset: SigmaSet) -> SigmaSet:
    """One filter's set of a block of one."""
    return sset._replace(sigmas=sset.sigmas[0], offsets=None if sset.offsets is None else sset.offsets[0])


class _NoneRejected(dict):
    """All False, read-only, by shape: the record of an update without a gate (made once per shape)."""

    def __missing__(self, shape: tuple) -> np.ndarray:
        a = self[shape] = np.zeros(shape, dtype=bool)
        a.setflags(write=False)
        return a


_NONE_REJECTED = _NoneRejected()


def _described(code: int, images: np.ndarray, status: np.ndarray, name: str) -> SqukfError | None:
    """The error of images that are not finite (status 306), in the words of the first such filter."""
    if code != NOT_FINITE_IMAGES:
        return None
    k = int(np.flatnonzero(status == NOT_FINITE_IMAGES)[0])
    return NonFiniteError(describe_nonfinite(images[k], name))


def _images(values, shape: tuple, name: str, private: bool, single: bool = False) -> np.ndarray:
    """Model images as the kernels take them: float64, C-contiguous, of ``shape`` (a private copy when
    ``private``); finite or not (the route checks that: :meth:`Route.prior`, :meth:`Route.posterior`).

    The one reading of every image a model function returns or a caller tells. ``shape`` is a
    block's ``(B, N, d)``; for one filter (``single``) the images are one filter's ``(N, d)``.
    """
    want = shape[1:] if single else shape
    if (
        type(values) is np.ndarray
        and values.dtype is _FLOAT64
        and values.shape == want
        and values.flags.c_contiguous
        and values.flags.writeable
    ):
        A = values.copy() if private else values
    else:
        A = np.ascontiguousarray(check_values(values, want, name, finite=False))
    return A[None] if single else A


def _detached(value, memo: dict[int, object]):
    """``value`` with every writeable array in it copied (read-only ones, a plan's, shared), identity kept:
    an array referenced twice is one copy."""
    if isinstance(value, np.ndarray):
        if not value.flags.writeable:
            return value
        done = memo.get(id(value))
        if done is None:
            done = memo[id(value)] = value.copy()
        return done
    if isinstance(value, tuple):
        items = [_detached(v, memo) for v in value]
        return type(value)(*items) if hasattr(value, "_fields") else tuple(items)
    return value
