"""The records handed out: the per-step records' registry, the results that keep them, their faces' reads.

A record of each update (the whitened innovation, ``log det S1_2``) is declared once here: a
:class:`StepRecord` in :data:`STEP_RECORDS`, its typed field in :class:`FleetResult` and
:class:`BatchResult`, and its attribute on both faces (:class:`StepRecords`, a base of
:class:`squkf.face.Face`). It is read from a field of the engine's :class:`~squkf.engine.Update`; everything
that delivers it (the faces, ``batch_filter``'s results, a fleet's run with ``keep``, :mod:`squkf.dask`)
reads the registry and names no record.

Also the arrays a fleet's run fills, the error of its failing filters, and the records formed from one
filter's update.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Generic, NamedTuple, NoReturn, TypeVar, overload

import numpy as np

from ..errors import FleetStepError
from ..linalg import solve_lower

__all__ = [
    "STEP_RECORDS",
    "BatchResult",
    "FleetResult",
    "Records",
    "StepProperty",
    "StepRecord",
    "StepRecords",
    "embed",
    "failures_error",
    "innovation_inverse",
    "new_records",
]

T = TypeVar("T")


class StepRecord(NamedTuple):
    """A record of each update, as every face and result delivers it.

    Attributes
    ----------
    name : str
        Its public name: the faces' attribute, :class:`BatchResult`'s and :class:`FleetResult`'s field.
    field : str
        The :class:`~squkf.engine.Update` field it is read from: ``(B, mo)`` over the measured
        components, or ``(B,)``.
    per_component : bool
        One value per measurement component (``(..., m)``: the measured components' in their places,
        ``fill`` elsewhere), or one number per filter.
    fill : float
        Its value where a component was not measured, or a filter not updated (nothing measured): a
        float (the arrays a fleet writes it into are float64).
    keep : str
        The word of a fleet's ``keep`` that adds it to the run's results (records may share one).
    """

    name: str
    field: str
    per_component: bool
    fill: float
    keep: str

    def missing(self, m: int) -> Any:
        """The value of a step with nothing measured: ``(m,)`` of ``fill``, or ``fill``."""
        return np.full(m, self.fill) if self.per_component else self.fill

    def shape(self, lead: tuple, m: int) -> tuple:
        """Its array's shape in a result whose leading axes are ``lead`` (steps; filters and steps)."""
        return (*lead, m) if self.per_component else lead


#: The per-step records, in the order ``BatchResult`` and ``FleetResult`` take them positionally (new ones
#: go last: a pickled ``BatchResult`` passes them in this order, and ``FleetResult`` declares its fields
#: so). Each has its typed field and docs entry in both results and its ``StepProperty`` in
#: :class:`StepRecords`, below.
STEP_RECORDS: tuple[StepRecord, ...] = (
    StepRecord("y_whitened", "w", True, np.nan, "whitened"),
    StepRecord("log_det_S1_2", "log_det_S1_2", False, 0.0, "whitened"),
)


# -- the faces' attributes --------------------------------------------------------------------------


class StepProperty(property, Generic[T]):
    """A face's attribute of a :class:`StepRecord`, read from the engine's last update (fresh each read).

    Declared in a class body by the record's name with its docstring
    (``y_whitened = StepProperty("...")``: the registry's record of that name), or given its record. A
    ``property`` (a filterpy ``Saver`` collects properties), read-only; the face forms the value
    (``Face._step_record``: one filter's without the block axis, a fleet's ``(K, ...)``).
    """

    record: StepRecord

    def __init__(self, doc: str, record: StepRecord | None = None) -> None:
        super().__init__()
        self.__doc__ = doc  # (a subclass instance's own: the class's would shadow property's)
        if record is not None:
            self.record = record

    def __set_name__(self, owner: type, name: str) -> None:
        if getattr(self, "record", None) is None:  # (declared by its name: the registry's record of it)
            found = [r for r in STEP_RECORDS if r.name == name]
            if not found:
                raise LookupError(f"{owner.__name__}.{name}: no record {name!r} in STEP_RECORDS")
            self.record = found[0]

    @overload
    def __get__(self, face: None, owner: type, /) -> StepProperty[T]: ...

    @overload
    def __get__(self, face: Any, owner: type | None = None, /) -> T: ...

    def __get__(self, face: Any, owner: type | None = None, /) -> Any:
        if face is None:
            return self
        return face._step_record(self.record)

    def __set__(self, face: Any, value: NoReturn, /) -> NoReturn:  # type: ignore[override]
        raise AttributeError(
            f"{type(face).__name__}.{self.record.name} is a record of the last update: read-only"
        )

    def __delete__(self, face: Any, /) -> NoReturn:
        raise AttributeError(
            f"{type(face).__name__}.{self.record.name} is a record of the last update: read-only"
        )


class StepRecords:
    """The faces' attributes of the per-step records (:data:`STEP_RECORDS`): a base of
    :class:`squkf.face.Face`, so that :class:`squkf.SquareRootUKF` and :class:`squkf.Fleet` have each."""

    __slots__ = ()

    y_whitened: StepProperty[np.ndarray] = StepProperty(
        """The last update's whitened innovation ``S1_2^-1 y``, ``(..., dim_z)`` (a fresh array).

        NaN where a component was not measured (or a fleet's filter not updated); ``nis`` is its
        squared norm. With ``log_det_S1_2`` it is the whole of the step's log-likelihood,
        ``-(m log 2 pi + nis) / 2 - log_det_S1_2`` over the ``m`` measured components
        (:func:`squkf.tune.fit_noise` reads them as least-squares residuals). Zeros before any update.
        """
    )
    log_det_S1_2: StepProperty[Any] = StepProperty(
        """``log det S1_2`` of the last update: the log-determinant of the innovation factor's measured
        block, the sum ``sum log|S1_2_ii|`` the log-likelihood takes (one filter's a float, a fleet's
        ``(K,)``).

        0 before any update (and where nothing was measured).
        """
    )


# -- the results that keep them ---------------------------------------------------------------------


class BatchResult(tuple):
    """``(means, covariances)``, as filterpy's ``batch_filter`` returns them, with the gate's record.

    Unpacks as the pair (``means, covs = ukf.batch_filter(zs)``) and is a
    tuple; the gate's decisions, the test statistic and each step's records
    (:data:`STEP_RECORDS`) are attributes.

    Attributes
    ----------
    rejected : ndarray of bool, shape (T, dim_z)
        The components the gate rejected at each step (all False without a
        gate, or at a step without a measurement).
    nis : ndarray, shape (T,)
        Each step's normalised innovation squared (0 without a measurement).
    log_likelihood : ndarray, shape (T,)
        Each step's log-likelihood of the components used (0 without a
        measurement, or when the gate rejected them all).
    y_whitened : ndarray, shape (T, dim_z)
        Each step's whitened innovation ``S1_2^-1 y`` (NaN where a component,
        or the whole step, was not measured): ``nis`` is its squared norm.
    log_det_S1_2 : ndarray, shape (T,)
        Each step's ``log det S1_2`` of the measured block (0 without a measurement).
    """

    rejected: np.ndarray
    nis: np.ndarray
    log_likelihood: np.ndarray
    y_whitened: np.ndarray
    log_det_S1_2: np.ndarray

    def __new__(
        cls, means: np.ndarray, covariances: np.ndarray, rejected, nis, log_likelihood, *steps, **named
    ):
        """``steps``: the registry's records in its order (as a pickle passes them), or ``named``."""
        self = super().__new__(cls, (means, covariances))
        self.rejected, self.nis, self.log_likelihood = rejected, nis, log_likelihood
        _set_steps(self, steps, named)
        return self

    def __reduce__(self):
        steps = (getattr(self, r.name) for r in STEP_RECORDS)
        return (type(self), (self[0], self[1], self.rejected, self.nis, self.log_likelihood, *steps))


def _set_steps(result: Any, steps: tuple, named: dict) -> None:
    """A result's fields of the registry's records, given in its order (``steps``) or by name; None where
    neither gives one (not kept)."""
    names = [r.name for r in STEP_RECORDS]
    kind = type(result).__name__
    if len(steps) > len(names):
        raise TypeError(f"{kind} keeps {len(names)} per-step records ({', '.join(names)}), got {len(steps)}")
    unknown = sorted(set(named).difference(names))
    if unknown:
        raise TypeError(f"{kind} keeps no per-step record {unknown[0]!r} (it keeps {', '.join(names)})")
    twice = sorted(set(names[: len(steps)]).intersection(named))
    if twice:
        raise TypeError(f"{kind} got the record {twice[0]!r} twice, by position and by name")
    given = {**dict(zip(names, steps)), **named}
    for name in names:
        setattr(result, name, given.get(name))


@dataclass
class FleetResult:
    """What :meth:`Fleet.batch_filter` returns.

    Attributes
    ----------
    means : ndarray, shape (K, T, n), or None
        Posterior means (None with ``keep="final"``).
    P1_2s : ndarray, shape (K, T, n, n), or None
        Posterior lower factors (only with ``keep="all"``).
    variances : ndarray, shape (K, T, n), or None
        The diagonals of the posterior covariances (with ``keep="all"`` or ``"diagonals"``).
    log_likelihood : ndarray, shape (K, T), or (K,) with ``keep="final"``
        Of each step's measurement (0 where a filter had no measurement or had
        failed); with ``keep="final"`` their sum over the run.
    failed : ndarray of bool, shape (K,)
        Filters flagged by the end of the run (their later entries repeat their last good state).
    x, P1_2 : ndarray, shapes (K, n) and (K, n, n)
        The final state.
    rejected : ndarray, shape (K, T, m) of bool, or (K, m) of int with ``keep="final"``
        The measurement components each filter's gate rejected at each step
        (with ``keep="final"``: how many steps each component was rejected).
        All False (zero) without a gate.
    nis : ndarray, shape (K, T), or None with ``keep="final"``
        Each step's normalised innovation squared (0 where a filter had no
        measurement or had failed).
    y_whitened : ndarray, shape (K, T, m), or None
        Each step's whitened innovation ``S1_2^-1 y`` (NaN where a component was
        not measured or a filter not updated), kept when ``keep`` names
        ``"whitened"``: with ``log_det_S1_2`` the log-likelihood as residuals
        (what :func:`squkf.tune.fit_noise` reads).
    log_det_S1_2 : ndarray, shape (K, T), or None
        Each step's ``log det S1_2`` of the measured block (0 where none), kept
        with ``y_whitened``.
    """

    means: np.ndarray | None
    P1_2s: np.ndarray | None
    variances: np.ndarray | None
    log_likelihood: np.ndarray
    failed: np.ndarray
    x: np.ndarray
    P1_2: np.ndarray
    rejected: np.ndarray | None = None
    nis: np.ndarray | None = None
    # the per-step records (STEP_RECORDS), in its order
    y_whitened: np.ndarray | None = None
    log_det_S1_2: np.ndarray | None = None


class Records(NamedTuple):
    """The arrays a fleet's batch run fills, step by step (None: not kept).

    ``steps``: the registry's records kept (``keep``'s words), by name; ``reads``: each one's
    :class:`~squkf.engine.Update` field and array, what :meth:`keep` copies at each step.
    """

    means: np.ndarray | None
    factors: np.ndarray | None
    variances: np.ndarray | None
    loglik: np.ndarray
    rejected: np.ndarray
    nis: np.ndarray | None
    steps: dict[str, np.ndarray]
    reads: tuple[tuple[str, np.ndarray], ...]

    def keep(self, t: int, update) -> None:
        """Keep step ``t``'s update: its estimates ``x (K, n)``, ``S (K, n, n)`` and its records.

        ``update`` is the engine's record of the step (:class:`squkf.engine.Update`, a block of K).
        With ``keep="final"`` (no ``nis``), the log-likelihoods and rejections are summed over the run.
        """
        x, S = update.x, update.S
        if self.nis is None:
            self.loglik[...] += update.log_likelihood
            self.rejected[...] += update.rejected
        else:
            self.loglik[:, t], self.rejected[:, t], self.nis[:, t] = (
                update.log_likelihood, update.rejected, update.nis,
            )  # fmt: skip
        for field, kept in self.reads:
            kept[:, t] = getattr(update, field)
        if self.means is not None:
            self.means[:, t] = x
        if self.factors is not None:
            self.factors[:, t] = S
        if self.variances is not None:
            self.variances[:, t] = np.einsum("kij,kij->ki", S, S)

    def so_far(self, t: int) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The means ``(K, t, n)`` and factors ``(K, t, n, n)`` before step ``t`` (copies, or None)."""
        return (
            None if self.means is None else self.means[:, :t].copy(),
            None if self.factors is None else self.factors[:, :t].copy(),
        )

    def step_records(self) -> dict[str, np.ndarray | None]:
        """Every registry record by name, as :class:`FleetResult` takes it: its array, or None (not kept)."""
        return {r.name: self.steps.get(r.name) for r in STEP_RECORDS}


def new_records(keep: str, K: int, T: int, n: int, m: int, words: tuple[str, ...] = ()) -> Records:
    """The arrays of a run of ``T`` steps of ``K`` filters that ``keep`` asks for.

    Parameters
    ----------
    keep : {"all", "diagonals", "means", "final"}
    K, T, n, m : int
        Filters, steps, state and measurement sizes.
    words : tuple of str
        ``keep``'s other words: the registry's records of these ``keep`` words are kept too, ``(K, T, m)``
        per component or ``(K, T)``.

    Returns
    -------
    Records
        ``means (K, T, n)``, ``factors (K, T, n, n)``, ``variances (K, T, n)``,
        ``loglik (K, T)`` (``(K,)`` with ``"final"``), ``rejected (K, T, m)``
        of bool (``(K, m)`` counts with ``"final"``), ``nis (K, T)``, the records asked for.
    """
    means = None if keep == "final" else np.empty((K, T, n))
    factors = np.empty((K, T, n, n)) if keep == "all" else None
    variances = np.empty((K, T, n)) if keep in ("all", "diagonals") else None
    loglik = np.zeros((K, T)) if keep != "final" else np.zeros(K)
    rejected = np.zeros((K, T, m), dtype=bool) if keep != "final" else np.zeros((K, m), dtype=np.int64)
    nis = np.zeros((K, T)) if keep != "final" else None
    kept = [r for r in STEP_RECORDS if r.keep in words]
    steps = {r.name: np.empty(r.shape((K, T), m)) for r in kept}
    reads = tuple((r.field, steps[r.name]) for r in kept)
    return Records(means, factors, variances, loglik, rejected, nis, steps, reads)


def failures_error(fails: dict[int, str], during: str = "") -> FleetStepError:
    """The error of a step (or a smoothing run) in which the filters ``fails`` failed numerically.

    Parameters
    ----------
    fails : dict
        Filter index -> the reason it failed.
    during : str
        Appended to "failed numerically" (``" while smoothing"``).

    Returns
    -------
    FleetStepError
        Naming the first five filters; ``filters`` and ``reasons`` hold all.
    """
    ks = sorted(fails)
    return FleetStepError(
        f"{len(ks)} filter(s) failed numerically{during}: "
        + "; ".join(f"filter {k}: {fails[k]}" for k in ks[:5])
        + (" ..." if len(ks) > 5 else ""),
        ks,
        [fails[k] for k in ks],
    )


def embed(block: np.ndarray, observed: np.ndarray | None, fill: float) -> np.ndarray:
    """A one-filter ``(m, m)`` record of the last update from its observed block (``fill`` elsewhere).

    Parameters
    ----------
    block : ndarray, shape (o, o)
        Over the measured components.
    observed : ndarray of bool, shape (m,), or None
        The measured components (None: all, ``o == m``).
    fill : float

    Returns
    -------
    ndarray, shape (m, m)
        A new array.
    """
    if observed is None:
        return block.copy()
    out = np.full((observed.shape[0], observed.shape[0]), fill)
    out[np.ix_(observed, observed)] = block
    return out


def innovation_inverse(Sy: np.ndarray, observed: np.ndarray | None) -> np.ndarray:
    """``S^-1`` of one filter's last update from its innovation factor, by triangular solves.

    Parameters
    ----------
    Sy : ndarray, shape (o, o)
        The innovation factor over the measured components.
    observed : ndarray of bool, shape (m,), or None

    Returns
    -------
    ndarray, shape (m, m)
        NaN outside the measured block; all NaN-embedded zeros for a singular factor.
    """
    m = Sy.shape[0]
    if not np.all(Sy.diagonal() != 0):
        return embed(np.zeros((m, m)), observed, np.nan)
    W = solve_lower(Sy, np.eye(m))
    return embed(W.T @ W, observed, np.nan)
