"""squkf: the square-root Unscented Kalman Filter of NAG's g13ej, with filterpy's interface.

``from squkf import SquareRootUKF as UnscentedKalmanFilter`` upgrades a filterpy
program; :mod:`squkf.nag` keeps g13ej's reverse-communication calling sequence.
"""

from . import consistency as consistency
from . import tune as tune
from ._version import __version__ as __version__
from .errors import (
    CallSequenceError,
    CommunicationError,
    DowndateError,
    GainError,
    NonFiniteError,
    NotPositiveDefiniteError,
    ParameterError,
    PosteriorFactorError,
    ShapeError,
    SqukfError,
    SqukfValueError,
    UnsetError,
    UnsupportedEnvironmentError,
)
from .first_use import Precompiled, precompile
from .fleet import Fleet, FleetResult, FleetStepError
from .gating import Gate
from .generators import Augmented, Propagated, Redrawn, SigmaSet
from .kernels.threads import get_num_threads, set_num_threads
from .simulate import simulate
from .transform import sqrt_unscented_transform
from .ukf import SquareRootUKF
from .ut import unscented_transform
from .weights import (
    CubatureWeights,
    FilterpyPoints,
    JulierWeights,
    MerweScaledWeights,
    SigmaPointFamily,
    SimplexWeights,
)

__all__ = [
    "SquareRootUKF",
    "Fleet",
    "FleetResult",
    "FleetStepError",
    "Gate",
    "sqrt_unscented_transform",
    "unscented_transform",
    "simulate",
    "tune",
    "MerweScaledWeights",
    "JulierWeights",
    "SimplexWeights",
    "CubatureWeights",
    "FilterpyPoints",
    "SigmaPointFamily",
    "Redrawn",
    "Augmented",
    "Propagated",
    "SigmaSet",
    "set_num_threads",
    "get_num_threads",
    "precompile",
    "Precompiled",
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
    "CommunicationError",
    "UnsetError",
    "UnsupportedEnvironmentError",
]
