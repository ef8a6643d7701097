"""Models shared by the tests: the g13ej robot, a coordinated-turn radar, Lorenz-96."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def example_data() -> dict:
    """The g13ej example (inputs, NAG's published output, true trajectory)."""
    for path in (
        ROOT / "squkf" / "examples" / "g13ej_example.json",
        ROOT.parent / "shared" / "data" / "g13ej_example.json",
    ):
        if path.exists():
            return json.loads(path.read_text())
    raise FileNotFoundError("g13ej_example.json not found")


class Robot:
    """The g13ej example's two-wheeled robot and its wall sensor."""

    def __init__(self, data: dict):
        m = data["model"]
        self.r, self.d, self.Delta, self.A = m["r"], m["d"], m["Delta"], m["A"]

    def fx(self, x, dt, phi_r=0.4, phi_l=0.1):
        t1 = 0.5 * self.r * (phi_r + phi_l)
        t3 = (self.r / self.d) * (phi_r - phi_l)
        return np.array([x[0] + np.cos(x[2]) * t1, x[1] + np.sin(x[2]) * t1, x[2] + t3])

    def hx(self, x):
        a = x[2] - self.A
        if a < 0:
            a += 2 * np.pi
        return np.array([self.Delta - x[0] * np.cos(self.A) - x[1] * np.sin(self.A), a])


def ct_fx(x, dt):
    """Coordinated turn with unknown turn rate; state [px, vx, py, vy, omega]."""
    px, vx, py, vy, w = x
    if abs(w) < 1e-9:
        return np.array([px + vx * dt, vx, py + vy * dt, vy, w])
    s, c = np.sin(w * dt), np.cos(w * dt)
    return np.array(
        [
            px + (s * vx - (1 - c) * vy) / w,
            c * vx - s * vy,
            py + ((1 - c) * vx + s * vy) / w,
            s * vx + c * vy,
            w,
        ]
    )


def ct_hx(x):
    """Range and bearing from a radar at the origin."""
    return np.array([np.hypot(x[0], x[2]), np.arctan2(x[2], x[0])])


def l96_fx(x, dt, F=8.0):
    """Lorenz-96, one RK4 step."""

    def f(v):
        return (np.roll(v, -1) - np.roll(v, 2)) * np.roll(v, 1) - v + F

    k1 = f(x)
    k2 = f(x + 0.5 * dt * k1)
    k3 = f(x + 0.5 * dt * k2)
    k4 = f(x + dt * k3)
    return x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


def l96_hx(x):
    """Every other component observed."""
    return x[::2].copy()


FILTER_STATE = (
    "x",
    "P1_2",
    "Q1_2",
    "R1_2",
    "x_prior",
    "P1_2_prior",
    "x_post",
    "P1_2_post",
    "K",
    "y",
    "S1_2",
    "sigmas_f",
    "sigmas_h",
)


def filter_state(f) -> dict:
    """Copies of everything a failed call must leave unchanged."""
    snap = {k: np.array(getattr(f, k), copy=True) for k in FILTER_STATE}
    snap["phase"] = f._state.phase
    snap["log_likelihood"] = f.log_likelihood
    return snap


def assert_filter_state(f, snap: dict) -> None:
    """The filter is bit for bit as in ``snap``."""
    for k in FILTER_STATE:
        np.testing.assert_array_equal(np.asarray(getattr(f, k)), snap[k], err_msg=k)
    assert f._state.phase == snap["phase"]
    assert f.log_likelihood == snap["log_likelihood"]
