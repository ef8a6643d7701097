"""What older versions of squkf pickled the faces as, read as today's layout (``Face.__getstate__``).

Each function takes a pickle's state and returns it in today's layout; a layout already today's is
returned as it is.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .boundary.attributes import FactorSlot
from .engine import Engine, Route
from .stacks import CHUNKS, not_updated

__all__ = ["filter_state", "fleet_engine", "fleet_state"]

#: what a fleet pickled before it held an engine kept in its ``__dict__``
BEFORE_ENGINE = (
    "_x", "_S", "_pending", "_route", "_x_prior", "_S_prior", "_x_post", "_S_post", "_y", "_loglik", "_nis",
    "_rejected", "_y_whitened", "_log_det",
)  # fmt: skip


def filter_state(state: Any) -> dict:
    """A ``SquareRootUKF``'s pickled state: before both faces shared one layout, a tuple of its
    ``__dict__``, its carried slots, its engine and the gain of its last update; before the update kernel
    wrote ``log det S1_2``, a last update without it (formed from its factor, the records current with
    that update kept current with the one that has it)."""
    if isinstance(state, tuple):
        d, own, engine, gain = state
        state = {**d, **own, "_engine": engine, "_gain_of": (engine.last, gain)}
    engine = state.get("_engine")
    last = None if engine is None else engine.last
    if last is not None and last.log_det_S1_2 is None:  # pickled before the update kernel wrote it
        new = engine.last = last._replace(log_det_S1_2=_log_det(last.Sy))
        # what was current with the last update (written records, the gain) is with its record still
        state["_written"] = {
            k: (new, *held[1:]) if held[0] is last else held for k, held in state.get("_written", {}).items()
        }
        stamp, gain = state.get("_gain_of", (None, None))
        state["_gain_of"] = (new if stamp is last else stamp, gain)
    return state


def fleet_state(state: dict) -> dict:
    """A ``Fleet``'s pickled ``__dict__``, with its older forms converted: the points a plain attribute,
    no placeholders, no ``vectorized_hooks``, bare noise factors, the failures a ``(K,)`` array of
    reasons. A fleet pickled before it held an engine gets no ``_engine`` but ``_before_engine``, what
    it kept instead (:func:`fleet_engine`)."""
    if "points_fn" in state:  # pickled when the points were a plain attribute
        state = {("_points" if k == "points_fn" else k): v for k, v in state.items()}
    K = state["_K"]
    state.setdefault("_unset_x", np.zeros(K, dtype=bool))  # pickled before placeholders
    state.setdefault("_unset_P", np.zeros(K, dtype=bool))
    state.setdefault("_vectorized_hooks", False)  # pickled before the option
    if "_Q1_2" in state:  # pickled when the noise factors were kept bare
        Q, R = state.pop("_Q1_2"), state.pop("_R1_2")
        state["_Q"] = FactorSlot("Q", state.get("_qd", state["_n"]), True, Q, filters=K)
        state["_R"] = FactorSlot("R", state.get("_rd", state["_m"]), True, R, filters=K, zero=True)
    failure = state["_failure"]
    if isinstance(failure, np.ndarray):  # pickled before the reasons were kept as a dict
        state["_failure"] = {int(k): str(failure[k]) for k in np.flatnonzero(failure != "")}
    old = {k: state.pop(k, None) for k in BEFORE_ENGINE}
    if "_engine" not in state:
        state["_before_engine"] = old
    return state


def fleet_engine(route: Route, old: dict) -> Engine:
    """The idle engine of a fleet pickled before it held one, on ``route``: its state and records
    (``old``: what it kept in their place; the whitened record NaN and 0 where it was pickled before
    that record)."""
    engine = Engine(route, old["_x"], old["_S"], None, None, CHUNKS)
    engine.prior_record = (old["_x_prior"], old["_S_prior"])
    engine.post_record = (old["_x_post"], old["_S_post"])
    y = old["_y"]
    kept = {"y": y, "log_likelihood": old["_loglik"], "nis": old["_nis"], "rejected": old["_rejected"]}
    # (the whitened record by its names then; each record pickled before it was kept: a filter not updated's)
    for field, name in (("w", "_y_whitened"), ("log_det_S1_2", "_log_det")):
        if old[name] is not None:
            kept[field] = old[name]
    engine.last = not_updated(old["_x_post"], old["_S_post"], y.shape[1])._replace(**kept)
    return engine


def _log_det(Sy: np.ndarray) -> np.ndarray:
    """``log det Sy`` ``(B,)`` of a stack of triangular factors ``(B, o, o)`` (the kernels sum it in their own
    order: the same to rounding)."""
    return np.log(np.abs(np.diagonal(Sy, axis1=1, axis2=2))).sum(axis=1)
