"""g13ej's own calling sequence: ``kalman_unscented_state_revcom``.

A thin adapter over one filter's engine (:class:`squkf.engine.Engine`, the same core as
:class:`squkf.SquareRootUKF`) with the argument order of NAG's Python
interface (``naginterfaces.library.tsa.kalman_unscented_state_revcom``)::

    irevcm, n = kalman_unscented_state_revcom(irevcm, y, ly, x, st, xt, fxt, comm, lx=None, ropt=None)

- ``irevcm`` is 0 on the first time point and 3 on later ones. Intermediate
  exits return 1 (evaluate F on the columns of ``xt`` into ``fxt``) and 2
  (evaluate H on the columns of ``xt`` into ``fxt``); the final exit returns 3.
  On re-entry pass back the ``irevcm`` returned.
- ``n`` is the number of sigma points in use at an intermediate exit (the
  documents' N); at the final exit it is the number of columns of ``xt``.
- ``x`` ``(mx,)``, ``st`` ``(>=mx, >=mx)`` and ``xt`` ``(>=mx, >=n_max)`` are
  float64 arrays updated in place; ``xt`` and ``fxt`` hold one sigma point
  per **column**. ``n_max`` is ``2 mx + 1`` for the redrawn second set and
  ``4 mx + 1`` for the augmented one. ``fxt`` needs ``>= mx`` rows at the
  first exit and ``>= my`` at the second, and at least ``n`` columns.
- ``st``, ``ly`` and ``lx`` are lower factors; only their leading lower
  triangles are read (``st``'s strict upper triangle is never written).
- ``comm`` is a dict the caller creates empty and passes back unchanged.
- ``lx=None`` means no process noise (the documents' LDLX = 0).
- ``ropt`` has up to 7 entries: ROPT(1) 1 = redrawn, 2 = augmented; ROPT(2..4)
  kappa, alpha, beta of the first set (defaults ``3 - mx``, 1, 2); ROPT(5..7)
  of the second set (defaults: kappa ``3 - 2 mx`` -- generally the first
  set's kappa minus ``mx`` -- when augmented with process noise, else the
  first set's; alpha and beta the first set's).

Section 9 of the documents: with ``lx=None``, stopping at the exit with
``irevcm == 2`` leaves the unscented transform of F in ``x`` and ``st``.

Errors raise an exception from :mod:`squkf.errors` whose ``errno`` is the
documented IFAIL number, with the documented message and the values filled
in: 11, 21, 22, 31, 32, 61, 81, 111, 121, 122, 123, 141, 161, 162, 171, 172,
173, 181, 191, 211, 301, 302, 303. After an error ``x``, ``st``, ``xt`` and
``comm`` are exactly as they were.

An argument that is not what the documents' types make it gets the number of
that argument's constraint: ``x`` 21, ``y`` 31, ``lx`` 61, ``ly`` 81, ``st``
111, ``xt`` 141, ``fxt`` 161/162 (a complex, string, bool or object array is
refused, never cast to real), an ROPT entry that is not a real number 171,
172 or 173 by its position, ROPT not a flat sequence 181. Non-finite kappa or
alpha are 172 and 173; so are a kappa and alpha whose ``L + lambda =
alpha**2 (L + kappa)`` is 0 or inf in floating point (173). A non-finite beta
(ROPT(4), ROPT(7)) and NaN or inf in ``x``, ``y``, ``st``, ``lx`` or ``ly``
have no documented number: they raise ParameterError and NonFiniteError with
``errno`` None.

``comm`` holds a digest of everything it keeps, so any change to it between
calls (a key removed, a value replaced, the state inside the kept machine or
options changed) is 191, and a change to ``x``, ``st`` or ``xt`` is 211; a
``comm`` that is not a dict is 191.

IFAIL 301 (a failed rank-1 downdate for a negative weight) is rarer than in
g13ej: the weighted covariance is written with non-negative weights whenever
``beta >= alpha**2`` (deviations from the central point; see
:mod:`squkf.transform`), so no downdate is needed there, however small alpha
is. It remains possible with ``beta < alpha**2`` and a negative central weight.

Documented errors that do not apply in Python:

- 201/202 (LICOMM/LRCOMM too small) and the array-length constraints on
  ICOMM/RCOMM: ``comm`` is a dict that holds whatever it needs.
- LDST/LDXT/LDFXT/LDLX/LDLY are the arrays' own shapes; the constraints on
  them become 61, 81, 111, 141, 161, 162 on the shapes.
- N as an input: the capacity is the number of columns of ``xt`` (121/122),
  and a change of that capacity between calls is 123.
- -99 (unexpected error), -399 (licence) and -999 (allocation) have no
  counterpart; Python's own exceptions propagate.

Examples
--------
A scalar random walk, ``F(x) = x`` and ``H(x) = x``, over two time points; on a
linear model the filter is the Kalman filter (here: means 0.992063 and
1.192296):

>>> import numpy as np
>>> from squkf.nag import kalman_unscented_state_revcom
>>> x, st = np.array([0.0]), np.array([[1.0]])
>>> lx, ly = np.array([[0.5]]), np.array([[0.1]])
>>> xt, fxt, comm = np.zeros((1, 3)), np.zeros((1, 3)), {}
>>> irevcm = 0
>>> for y in ([1.0], [1.2]):
...     while True:
...         irevcm, n = kalman_unscented_state_revcom(irevcm, y, ly, x, st, xt, fxt, comm, lx=lx)
...         if irevcm == 1:
...             fxt[:, :n] = xt[:, :n]  # F at the columns of xt
...         elif irevcm == 2:
...             fxt[:, :n] = xt[:, :n]  # H at the columns of xt
...         else:
...             break
...     print(irevcm, np.round(x, 6), np.round(st, 6))
3 [0.992063] [[0.099602]]
3 [1.192296] [[0.09813]]
"""

from __future__ import annotations

import copy
import hashlib

import numpy as np

from .engine import Engine, Route
from .errors import (
    CallSequenceError,
    CommunicationError,
    NonFiniteError,
    ParameterError,
    ShapeError,
    SqukfError,
)
from .generators import Augmented, Redrawn
from .plan import Hooks, build_plan
from .weights import MerweScaledWeights, real_array, real_number

__all__ = ["kalman_unscented_state_revcom"]


def _digest(*arrays) -> str:
    h = hashlib.sha1()
    for a in arrays:
        if a is None:
            h.update(b"none")
            continue
        a = np.ascontiguousarray(a)
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


# the error number of each ROPT entry's constraint (beta, ROPT(4) and ROPT(7), has none)
_ROPT_ERRNO = (171, 172, 173, None, 172, 173, None)


def _ropt_values(ropt) -> list[float]:
    """ROPT as a list of at most 7 floats (errors 181, or 171-173 for an entry that is not a real number)."""
    if ropt is None:
        return []
    flat: np.ndarray | list  # a list below when the entries are kept as given
    try:
        flat = np.asarray(ropt).reshape(-1)
    except Exception as exc:  # ragged nesting and the like
        raise ParameterError(
            f"On entry, ROPT = {ropt!r}. Constraint: ROPT is a sequence of at most 7 real numbers ({exc}).",
            errno=181,
        ) from None
    if len(flat) > 7:
        raise ParameterError(f"On entry, LROPT = {len(flat)}. Constraint: 0 <= LROPT <= 7.", errno=181)
    if flat.dtype.kind in "iuf":
        return [float(v) for v in flat]
    if isinstance(ropt, (list, tuple)) and len(ropt) == flat.size:
        flat = list(ropt)  # the entries as given: one string among numbers makes an all-string array
    elif flat.dtype.kind == "c":  # name the first entry that is complex in value, not only in type
        imag = np.flatnonzero(flat.imag)
        flat = flat.astype(object)
        if imag.size:
            flat[: imag[0]] = [v.real for v in flat[: imag[0]]]
    values = []
    for i, v in enumerate(flat, 1):
        try:
            values.append(real_number(v, f"ROPT({i})"))
        except ParameterError:
            what = "" if _ROPT_ERRNO[i - 1] else " (beta)"  # an error without a number says which it is
            raise ParameterError(
                f"On entry, ROPT({i}) = {v!r}. Constraint: ROPT({i}){what} is a real number.",
                errno=_ROPT_ERRNO[i - 1],
            ) from None
    return values


def _ropt_family(kappa: float, alpha: float, beta: float, first: int, n: int) -> MerweScaledWeights:
    """The family of ROPT(first..first+2) = kappa, alpha, beta, checked at dimension ``n``."""
    if not np.isfinite(beta):
        raise ParameterError(f"On entry, ROPT({first + 2}) = {beta:g}. Constraint: beta is finite.")
    try:
        family = MerweScaledWeights(alpha, beta, kappa)
        family.weights(n)  # L + lambda in floating point, and finite weights
    except ParameterError as exc:
        raise ParameterError(
            f"On entry, ROPT({first}) = {kappa:g}, ROPT({first + 1}) = {alpha:g} and "
            f"ROPT({first + 2}) = {beta:g}: {exc}",
            errno=exc.errno,
        ) from None
    return family


def _options(ropt, mx: int, has_lx: bool):
    """Parse ROPT into the two sets' families and the scheme (errors 171-173, 181)."""
    ropt = _ropt_values(ropt)
    scheme = ropt[0] if len(ropt) > 0 else 1.0
    if scheme not in (1.0, 2.0):
        raise ParameterError(f"On entry, ROPT(1) = {scheme:g}. Constraint: ROPT(1) = 1 or 2.", errno=171)
    augmented = scheme == 2.0
    kx = ropt[1] if len(ropt) > 1 else 3.0 - mx
    ax = ropt[2] if len(ropt) > 2 else 1.0
    bx = ropt[3] if len(ropt) > 3 else 2.0
    if len(ropt) > 4:
        ky = ropt[4]
    else:
        ky = kx - mx if (augmented and has_lx) else kx
    ay = ropt[5] if len(ropt) > 5 else ax
    by = ropt[6] if len(ropt) > 6 else bx
    if not (kx > -mx and np.isfinite(kx)):
        raise ParameterError(
            f"On entry, ROPT(2) = {kx:g}. Constraint: kappa > {-mx} (and finite).", errno=172
        )
    ky_min = -2 * mx if (augmented and has_lx) else -mx
    if not (ky > ky_min and np.isfinite(ky)):
        raise ParameterError(
            f"On entry, ROPT(5) = {ky:g}. Constraint: kappa > {ky_min} (and finite).", errno=172
        )
    for i, a in ((3, ax), (6, ay)):
        if not (a > 0 and np.isfinite(a)):
            raise ParameterError(
                f"On entry, ROPT({i}) = {a:g}. Constraint: alpha > 0 (and finite).", errno=173
            )
    first = _ropt_family(kx, ax, bx, 2, mx)
    second = _ropt_family(ky, ay, by, 5, 2 * mx if augmented else mx)
    generator = Augmented(weights=second) if augmented else Redrawn(weights=second)
    return first, generator, augmented


def _lower(a, rows: int, name: str, errno: int, what: str, need: int):
    arr = real_array(a, name, errno=errno, error=ShapeError)
    if arr.ndim != 2 or arr.shape[0] < need or arr.shape[1] < need:
        shape = arr.shape if arr.ndim == 2 else (arr.shape + (0, 0))[:2]
        raise ShapeError(
            f"On entry, {what} = {shape[0]} and {name.upper()}'s order = {need}. "
            f"Constraint: {what} >= {need} (shape of {name} is {arr.shape}).",
            errno=errno,
        )
    S = np.tril(arr[:need, :need])
    if not np.all(np.isfinite(S)):
        raise NonFiniteError(f"{name} contains NaN or inf in its lower triangle")
    neg = S.diagonal() < 0
    if neg.any():
        S[:, neg] *= -1.0
    return S


def kalman_unscented_state_revcom(irevcm, y, ly, x, st, xt, fxt, comm, lx=None, ropt=None):
    """One call of g13ej's reverse-communication sequence (see the module docstring).

    Parameters
    ----------
    irevcm : int
        0 (first time point) or 3 (later ones) on initial entry; on re-entry
        the value returned by the previous call (1 or 2).
    y : array_like, shape (my,)
        The observation at the current time point.
    ly : array_like, shape (>=my, >=my)
        Lower factor of the observation noise covariance.
    x : ndarray, shape (mx,)
        State estimate, updated in place.
    st : ndarray, shape (>=mx, >=mx)
        Lower factor of the state covariance, updated in place.
    xt : ndarray, shape (>=mx, >=n_max)
        Receives the sigma points, one per column.
    fxt : array_like, shape (>=mx or >=my, >=n)
        On re-entry, F (irevcm 1) or H (irevcm 2) of the columns of ``xt``.
    comm : dict
        Communication state; created empty, passed back unchanged.
    lx : array_like, shape (>=mx, >=mx), optional
        Lower factor of the process noise covariance; None for none.
    ropt : sequence of float, optional
        Up to 7 options (see the module docstring).

    Returns
    -------
    irevcm : int
        1 or 2 at an intermediate exit, 3 at the final exit.
    n : int
        Number of sigma points in use (the capacity ``xt.shape[1]`` at the final exit).
    """
    if isinstance(irevcm, bool) or not isinstance(irevcm, (int, np.integer)) or irevcm not in (0, 1, 2, 3):
        raise ParameterError(f"On entry, IREVCM = {irevcm!r}. Constraint: IREVCM = 0, 1, 2 or 3.", errno=11)
    if not isinstance(comm, dict):
        raise CommunicationError("comm must be the dict created empty and passed back unchanged", errno=191)
    for name, arr, errno in (("x", x, 21), ("st", st, 111), ("xt", xt, 141)):
        if not (isinstance(arr, np.ndarray) and arr.dtype == np.float64 and arr.flags.writeable):
            got = f"a {arr.dtype} array" if isinstance(arr, np.ndarray) else f"a {type(arr).__name__}"
            if isinstance(arr, np.ndarray) and arr.dtype == np.float64:
                got = "a read-only array"
            raise ShapeError(
                f"{name} must be a writeable float64 numpy array (it is updated in place), got {got}",
                errno=errno,
            )
    mx = x.shape[0] if x.ndim == 1 else 0
    if mx < 1:
        raise ParameterError(f"On entry, MX = {mx}. Constraint: MX >= 1.", errno=21)
    yv = real_array(y, "y", errno=31, error=ShapeError).reshape(-1)
    my = yv.shape[0]
    if my < 1:
        raise ParameterError(f"On entry, MY = {my}. Constraint: MY >= 1.", errno=31)
    if irevcm in (0, 3):
        return _initial_entry(irevcm, yv, ly, x, st, xt, comm, lx, ropt, mx, my)
    try:
        return _re_entry(irevcm, yv, ly, x, st, xt, fxt, comm, lx, mx, my)
    except SqukfError:
        raise
    except (
        TypeError,
        ValueError,
        ArithmeticError,
        LookupError,
        AttributeError,
        np.linalg.LinAlgError,
    ) as exc:
        # every argument has been checked by now; what is left is the state kept in comm
        raise CommunicationError(
            f"ICOMM has been corrupted between calls (the state kept in comm cannot be used: "
            f"{type(exc).__name__}: {exc}).",
            errno=191,
        ) from exc


def _check_common(yv, ly, x, st, xt, lx, mx, my, n_max, augmented):
    if lx is not None:
        Lx = _lower(lx, mx, "lx", 61, "LDLX", mx)
        if not np.any(Lx):
            Lx = None
    else:
        Lx = None
    Ly = _lower(ly, my, "ly", 81, "LDLY", my)
    S = _lower(st, mx, "st", 111, "LDST", mx)
    if xt.ndim != 2 or xt.shape[0] < mx:
        raise ShapeError(
            f"On entry, LDXT = {xt.shape[0] if xt.ndim == 2 else 0} and MX = {mx}. Constraint: LDXT >= MX.",
            errno=141,
        )
    if xt.shape[1] < n_max:
        kind, num = ("augmented", 121) if augmented else ("redrawn", 122)
        raise ShapeError(
            f"On entry, {kind} sigma points requested, N = {xt.shape[1]} and MX = {mx}. "
            f"Constraint: N >= {n_max} (the number of columns of xt).",
            errno=num,
        )
    if not np.all(np.isfinite(x)):
        raise NonFiniteError(f"x contains NaN or inf: {x!r}")
    if not np.all(np.isfinite(yv)):
        raise NonFiniteError(f"y contains NaN or inf: {yv!r}")
    return Lx, Ly, S


def _initial_entry(irevcm, yv, ly, x, st, xt, comm, lx, ropt, mx, my):
    family, generator, augmented = _options(ropt, mx, lx is not None)
    n_max = 4 * mx + 1 if augmented else 2 * mx + 1
    Lx, Ly, S = _check_common(yv, ly, x, st, xt, lx, mx, my, n_max, augmented)
    plan = build_plan(family, generator, mx)
    machine = _machine(plan, x.copy(), S, my)
    X = machine.ask_predict()[0]
    N = X.shape[0]
    # commit
    xt[:mx, :N] = X.T
    _save(comm, machine, plan, mx, my, xt.shape[1], 1, N, x, st, xt, irevcm)
    return 1, N


def _machine(plan, x: np.ndarray, S: np.ndarray, my: int) -> Engine:
    """The step kept between calls: one filter's engine (no hooks, no gate) at the estimate ``(x, S)``."""
    N = plan.num_sigmas
    n = x.shape[0]
    return Engine(
        Route(plan, Hooks(), None, single=True), x[None], S[None], np.zeros((1, N, n)), np.zeros((1, N, my))
    )


def _save(comm, machine, plan, mx, my, ncap, expect, n, x, st, xt, first_irevcm):
    ints = (mx, my, ncap, expect, n, first_irevcm)
    comm.clear()
    comm.update(
        {
            "icomm": ints,
            "machine": machine,
            "family": plan.family,
            "generator": plan.generator,
            "digest_i": _digest_i(ints, machine, plan.family, plan.generator),
            "digest_r": _digest(x, np.tril(st[:mx, :mx]), xt[:mx, :n]),
        }
    )


def _fingerprint(h, value) -> None:
    """Feed ``value`` (arrays, plain scalars and tuples of them; other objects by type) to ``h``."""
    if isinstance(value, np.ndarray):
        h.update(f"{value.dtype.str}{value.shape}".encode())
        h.update(np.ascontiguousarray(value).tobytes())
    elif isinstance(value, (tuple, list)):
        h.update(f"{type(value).__name__}[{len(value)}]".encode())
        for v in value:
            _fingerprint(h, v)
    elif value is None or isinstance(value, (bool, int, float, str, np.generic)):
        h.update(f"{type(value).__name__}:{value!r};".encode())
    else:
        h.update(f"<{type(value).__name__}>".encode())


def _digest_i(ints, machine, family, generator) -> str:
    """The digest of the integer state, the options and the machine's state kept in comm."""
    h = hashlib.sha1()
    _fingerprint(h, tuple(int(v) for v in ints))
    h.update(f"{type(family).__name__}:{family!r}|{type(generator).__name__}:{generator!r}".encode())
    for name, value in sorted(machine.__getstate__().items()):
        h.update(name.encode())
        _fingerprint(h, value)
    return h.hexdigest()


def _load(comm, irevcm, x, st, xt, mx, my):
    try:
        ints = comm["icomm"]
        machine = comm["machine"]
        family = comm["family"]
        generator = comm["generator"]
        ok = (
            type(ints) is tuple
            and len(ints) == 6
            and all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in ints)
            and isinstance(machine, Engine)
            and type(family) is MerweScaledWeights
            and type(generator) in (Redrawn, Augmented)
            and type(generator.weights) is MerweScaledWeights
            and isinstance(comm["digest_i"], str)
            and isinstance(comm["digest_r"], str)
            and comm["digest_i"] == _digest_i(ints, machine, family, generator)
        )
    except Exception:  # whatever was put in comm: a missing key, an object whose repr fails
        ok = False
    if not ok:
        raise CommunicationError("ICOMM has been corrupted between calls.", errno=191)
    cmx, cmy, ncap, expect, n, _ = ints
    if mx != cmx:
        raise CommunicationError(
            f"MX has changed between calls. On intermediate entry, MX = {mx}. On initial entry, MX = {cmx}.",
            errno=22,
        )
    if my != cmy:
        raise CommunicationError(
            f"MY has changed between calls. On intermediate entry, MY = {my}. On initial entry, MY = {cmy}.",
            errno=32,
        )
    if xt.ndim != 2 or xt.shape[1] != ncap:
        got = xt.shape[1] if xt.ndim == 2 else 0
        raise CommunicationError(
            f"N has changed between calls. On intermediate entry, N = {got}. "
            f"On intermediate exit, N = {ncap}.",
            errno=123,
        )
    if irevcm != expect:
        raise CallSequenceError(
            f"On entry, IREVCM = {irevcm}, but the last exit returned {expect}: on intermediate "
            "re-entry irevcm must remain unchanged.",
            errno=11,
        )
    if xt.shape[0] < mx or comm["digest_r"] != _digest(x, np.tril(st[:mx, :mx]), xt[:mx, :n]):
        raise CommunicationError(
            "RCOMM has been corrupted between calls (x, st or xt changed; they must remain unchanged "
            "between intermediate exits and re-entries).",
            errno=211,
        )
    # a copy: the one kept in comm stays as it is unless this call succeeds
    return copy.copy(machine), build_plan(family, generator, mx), ints


def _read_fxt(fxt, rows: int, n: int, irevcm: int, mx: int, my: int):
    F = real_array(fxt, f"fxt (with IREVCM = {irevcm})", errno=160 + irevcm, error=ShapeError)
    if F.ndim != 2 or F.shape[0] < rows or F.shape[1] < n:
        first = F.shape[0] if F.ndim == 2 else 0
        if irevcm == 1:
            raise ShapeError(
                f"On entry, LDFXT = {first} and MX = {mx}. Constraint: if IREVCM = 1, LDFXT >= MX "
                f"(and fxt needs >= {n} columns; its shape is {F.shape}).",
                errno=161,
            )
        raise ShapeError(
            f"On entry, LDFXT = {first} and MY = {my}. Constraint: if IREVCM = 2, LDFXT >= MY "
            f"(and fxt needs >= {n} columns; its shape is {F.shape}).",
            errno=162,
        )
    return F[:rows, :n].T


def _re_entry(irevcm, yv, ly, x, st, xt, fxt, comm, lx, mx, my):
    machine, plan, ints = _load(comm, irevcm, x, st, xt, mx, my)
    _, _, ncap, _, n, first_irevcm = ints
    augmented = isinstance(plan.generator, Augmented)
    Lx, Ly, _ = _check_common(yv, ly, x, st, xt, lx, mx, my, xt.shape[1], augmented)
    if irevcm == 1:
        F = _read_fxt(fxt, mx, n, 1, mx, my)
        machine.tell_predict(F, Lx, name="fxt (F at the sigma points)")
        Y = machine.ask_update()[0]
        xbar, Sbar = machine.x[0], machine.S[0]
        N2 = Y.shape[0]
        if N2 > ncap:  # pragma: no cover - guarded by 121/122 at initial entry
            raise ShapeError(f"xt has {ncap} columns, {N2} needed", errno=121)
        # commit
        x[:] = xbar
        _write_lower(st, Sbar, mx)
        xt[:mx, :N2] = Y.T
        _save(comm, machine, plan, mx, my, ncap, 2, N2, x, st, xt, first_irevcm)
        return 2, N2
    H = _read_fxt(fxt, my, n, 2, mx, my)
    machine.tell_update(H, yv, None, Ly, name="fxt (H at the sigma points)")
    # commit
    x[:] = machine.x[0]
    _write_lower(st, machine.S[0], mx)
    comm.clear()
    return 3, ncap


def _write_lower(st, S, mx):
    il = np.tril_indices(mx)
    st[il] = S[il]
