"""Exceptions raised by squkf.

Every exception derives from :class:`SqukfError`, and also from the built-in
class a caller is likely to catch already: bad arguments are ``ValueError``s,
lost positive-definiteness is a ``numpy.linalg.LinAlgError``, misuse of the
ask/tell protocol is a ``RuntimeError``, a process squkf cannot run in is an
``ImportError`` (raised by ``import squkf``).

Where an error corresponds to one of the error exits documented for NAG's
routine g13ej, the exception carries that number as ``errno`` (``None``
otherwise), so code ported from NAG can keep testing ``IFAIL`` values.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = [
    "SqukfError",
    "SqukfValueError",
    "ShapeError",
    "NonFiniteError",
    "ParameterError",
    "NotPositiveDefiniteError",
    "DowndateError",
    "GainError",
    "PosteriorFactorError",
    "CallSequenceError",
    "UnsetError",
    "CommunicationError",
    "FleetStepError",
    "UnsupportedEnvironmentError",
]


class SqukfError(Exception):
    """Base class of every exception raised by squkf.

    Parameters
    ----------
    message : str
        What went wrong, naming the argument and the offending value.
    errno : int, optional
        The number of the matching g13ej error exit (IFAIL), if any.

    Examples
    --------
    Each error is also the built-in exception a caller already catches, and
    carries g13ej's IFAIL number where it has one:

    >>> import numpy as np
    >>> from squkf import MerweScaledWeights, ParameterError, SquareRootUKF, SqukfError
    >>> try:
    ...     MerweScaledWeights(alpha=0.0)
    ... except ValueError as exc:
    ...     print(type(exc).__name__, exc.errno, isinstance(exc, SqukfError))
    ParameterError 173 True

    Bad input raises and leaves the filter as it was:

    >>> ukf = SquareRootUKF(2, 1, 1.0, hx=lambda x: x[:1], fx=lambda x, dt: x, points=MerweScaledWeights())
    >>> ukf.x = [1.0, 2.0]
    >>> try:
    ...     ukf.P = -np.eye(2)
    ... except np.linalg.LinAlgError as exc:
    ...     print(type(exc).__name__)
    NotPositiveDefiniteError
    >>> try:
    ...     ukf.update([np.inf])
    ... except ValueError as exc:
    ...     print(type(exc).__name__)
    NonFiniteError
    >>> print(ukf.x, ukf.P.diagonal())
    [1. 2.] [1. 1.]
    """

    def __init__(self, message: str, errno: int | None = None):
        super().__init__(message)
        self.errno = errno

    def __reduce__(self):
        return (type(self), (self.args[0], self.errno))


class SqukfValueError(SqukfError, ValueError):
    """An argument has an invalid value."""


class ShapeError(SqukfValueError):
    """An array argument, or a value returned by a model function, has the wrong shape."""


class NonFiniteError(SqukfValueError):
    """An array argument, or a value returned by a model function, holds NaN or inf."""


class ParameterError(SqukfValueError):
    """A sigma-point parameter or an option is outside its domain."""


class NotPositiveDefiniteError(SqukfError, np.linalg.LinAlgError):
    """A covariance or factor is not (numerically) positive definite."""


class DowndateError(NotPositiveDefiniteError):
    """A negative weight's rank-1 downdate would lose positive-definiteness (g13ej IFAIL 301)."""


class GainError(NotPositiveDefiniteError):
    """The innovation factor is singular, so the Kalman gain cannot be formed (IFAIL 302)."""


class PosteriorFactorError(NotPositiveDefiniteError):
    """The posterior factor cannot be formed by downdating (g13ej IFAIL 303)."""


class CallSequenceError(SqukfError, RuntimeError):
    """The ask/tell (or reverse-communication) calls came in an order that is not allowed."""


class UnsetError(CallSequenceError):
    """A step met ``x`` or ``P`` not set yet: a placeholder (``None`` or all NaN) a program assigned before a
    track starts. Assign the initial value first; nothing was changed."""


class CommunicationError(CallSequenceError):
    """Reverse-communication state was changed between calls (g13ej IFAIL 191/211 and friends)."""


class FleetStepError(SqukfError, ArithmeticError):
    """A fleet step with ``on_error="raise"`` in which some filters failed numerically.

    No filter was changed. ``filters`` holds the indices of the failing
    filters and ``reasons`` what went wrong with each.
    """

    def __init__(self, message: str, filters: Sequence[int] = (), reasons: Sequence[str] = ()):
        super().__init__(message)
        self.filters = tuple(int(k) for k in filters)
        self.reasons = tuple(reasons)

    def __reduce__(self):
        return (type(self), (self.args[0], self.filters, self.reasons))


class UnsupportedEnvironmentError(SqukfError, ImportError):
    """The process is set up in a way squkf cannot run in; raised by ``import squkf``.

    ``NUMBA_DISABLE_JIT`` is one: the kernels rely on being compiled by numba.
    An ``ImportError``, so code that treats squkf as optional
    (``try: import squkf`` / ``except ImportError``) goes on without it.
    """
