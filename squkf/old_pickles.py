"""What older versions of squkf pickled the faces as, read as today's layout (``Face.__getstate__``).

Each function takes a pickle's state and returns it in today's layout; a layout already today's is
returned as it is.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .boundary.attributes import FactorSlot
from .engine import Engine, Route, Update
from .stacks import CHUNKS

__all__ = ["filter_state", "fleet_engine", "fleet_state"]

#: what a fleet pickled before it held an engine kept in its ``__dict__``
BEFORE_ENGINE = (
    "_x", "_S", "_pending", "_route", "_x_prior", "_S_prior", "_x_post", "_S_post", "_y", "_loglik", "_nis",
    "_rejected", "_y_whitened", "_log_det",
)  # fmt: skip


def filter_state(state: Any) -> dict:
    """A ``SquareRootUKF``'s pickled state: before both faces shared one layout, a tuple of its
    ``__dict__``, its carried slots, its engine and the gain of its last update."""
    if isinstance(state, tuple):
        d, own, engine, gain = state
        state = {**d, **own, "_engine": engine, "_gain_of": (engine.last, gain)}
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
    y, w, ld = old["_y"], old["_y_whitened"], old["_log_det"]
    w = np.full(y.shape, np.nan) if w is None else w
    ld = np.zeros(y.shape[0]) if ld is None else ld
    engine.last = Update(
        old["_x_post"], old["_S_post"], y, None, None, old["_loglik"], old["_nis"], None, old["_rejected"],
        None, y.shape[1], w, ld,
    )  # fmt: skip
    return engine
