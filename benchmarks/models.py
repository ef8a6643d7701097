"""Benchmark scenarios: simulated truth, measurements, and per-point and vectorised models.

The model functions are written as a user who cares about speed would write
them: per-point functions with scalar ``math`` on one state, vectorised ones
with whole-column numpy expressions (no ``np.c_``, no ``np.roll``). Every
implementation calls the same functions, so their cost is common to all and
reported separately (the "library" time excludes it).
"""

from __future__ import annotations

import math

import numpy as np


class Scenario:
    """A model with its filter set-up; subclasses give fx/hx (per point) and fx_vec/hx_vec (rows)."""

    name = ""
    dim_x = dim_z = 0
    dt = 1.0
    alpha, beta, kappa = 1.0, 2.0, 0.0

    def simulate(self, steps: int, seed: int):
        rng = np.random.default_rng(seed)
        x = self.x_true0.copy()
        truth, zs = [], []
        LQ, LR = np.linalg.cholesky(self.Q_true), np.linalg.cholesky(self.R)
        for _ in range(steps):
            x = self.fx(x, self.dt) + LQ @ rng.standard_normal(self.dim_x)
            truth.append(x)
            zs.append(self.hx(x) + LR @ rng.standard_normal(self.dim_z))
        return np.array(truth), zs

    @property
    def Q_true(self):
        return self.Q


class Robot(Scenario):
    """The g13ej robot (n=3) and its wall sensor."""

    name, dim_x, dim_z = "g13ej robot n=3", 3, 2
    r, d, Delta, A, phi = 3.0, 4.0, 5.814, 0.464, (0.4, 0.1)

    def __init__(self):
        self.x0 = np.zeros(3)
        self.x_true0 = np.zeros(3)
        self.P0 = np.eye(3) * 0.01
        self.Q = np.eye(3) * 0.01
        self.R = np.eye(2) * 1e-4
        self.alpha, self.kappa = 1.0, 0.0
        self.t1 = 0.5 * self.r * sum(self.phi)
        self.t3 = self.r / self.d * (self.phi[0] - self.phi[1])
        self.cA, self.sA = math.cos(self.A), math.sin(self.A)

    def fx(self, x, dt):
        x0, x1, x2 = x.tolist()
        return np.array([x0 + math.cos(x2) * self.t1, x1 + math.sin(x2) * self.t1, x2 + self.t3])

    def fx_vec(self, X, dt):
        th = X[:, 2]
        return np.stack(
            [X[:, 0] + np.cos(th) * self.t1, X[:, 1] + np.sin(th) * self.t1, th + self.t3], axis=1
        )

    def hx(self, x):
        x0, x1, x2 = x.tolist()
        return np.array([self.Delta - x0 * self.cA - x1 * self.sA, x2 - self.A])

    def hx_vec(self, X):
        return np.stack([self.Delta - X[:, 0] * self.cA - X[:, 1] * self.sA, X[:, 2] - self.A], axis=1)


class CoordinatedTurn(Scenario):
    """Coordinated-turn target, range-bearing radar; Merwe alpha = 0.1 (negative central weight)."""

    name, dim_x, dim_z = "coordinated turn n=5", 5, 2

    def __init__(self):
        self.x_true0 = np.array([2000.0, 10.0, 3000.0, -5.0, 0.02])
        self.x0 = self.x_true0 + np.array([20.0, 1.0, -20.0, 1.0, 0.0])
        self.P0 = np.diag([400.0, 4.0, 400.0, 4.0, 1e-4])
        self.Q = np.diag([0.1, 0.01, 0.1, 0.01, 1e-6])
        self.R = np.diag([25.0, 0.002**2])
        self.alpha, self.kappa = 0.1, 0.0

    @staticmethod
    def _turn(px, vx, py, vy, w, s, c):
        # the same expressions for floats (one point) and for columns (all points)
        return [
            px + (s * vx - (1 - c) * vy) / w,
            c * vx - s * vy,
            py + ((1 - c) * vx + s * vy) / w,
            s * vx + c * vy,
            w,
        ]

    def fx(self, x, dt):
        px, vx, py, vy, w = x.tolist()
        if abs(w) < 1e-9:
            w = math.copysign(1e-9, w)
        return np.array(self._turn(px, vx, py, vy, w, math.sin(w * dt), math.cos(w * dt)))

    def fx_vec(self, X, dt):
        px, vx, py, vy, w = X.T
        w = np.where(np.abs(w) < 1e-9, np.copysign(1e-9, w), w)
        return np.stack(self._turn(px, vx, py, vy, w, np.sin(w * dt), np.cos(w * dt)), axis=1)

    def hx(self, x):
        px, py = x[0], x[2]
        return np.array([math.hypot(px, py), math.atan2(py, px)])

    def hx_vec(self, X):
        return np.stack([np.hypot(X[:, 0], X[:, 2]), np.arctan2(X[:, 2], X[:, 0])], axis=1)


class Lorenz96(Scenario):
    """Lorenz-96 (one RK4 step of dt = 0.05 per prediction), every other component observed."""

    def __init__(self, n=40):
        self.name, self.dim_x, self.dim_z, self.dt = f"Lorenz-96 n={n}", n, (n + 1) // 2, 0.05
        self.x_true0 = np.full(n, 8.0)
        self.x_true0[0] += 0.5
        self.x0 = np.full(n, 8.0)
        self.P0 = np.eye(n) * 0.5
        self.Q = np.eye(n) * 0.01
        self.R = np.eye(self.dim_z) * 0.1
        self.alpha, self.kappa = 0.5, 3.0 - n
        i = np.arange(n)
        self.ip1, self.im1, self.im2 = (i + 1) % n, (i - 1) % n, (i - 2) % n

    def _rk4(self, X, dt, f):
        k1 = f(X)
        k2 = f(X + 0.5 * dt * k1)
        k3 = f(X + 0.5 * dt * k2)
        k4 = f(X + dt * k3)
        return X + dt / 6.0 * (k1 + 2.0 * (k2 + k3) + k4)

    def fx(self, x, dt):
        ip1, im1, im2 = self.ip1, self.im1, self.im2
        return self._rk4(x, dt, lambda v: (v[ip1] - v[im2]) * v[im1] - v + 8.0)

    def fx_vec(self, X, dt):
        ip1, im1, im2 = self.ip1, self.im1, self.im2
        return self._rk4(X, dt, lambda V: (V[:, ip1] - V[:, im2]) * V[:, im1] - V + 8.0)

    def hx(self, x):
        return x[::2].copy()

    def hx_vec(self, X):
        return X[:, ::2].copy()


class NearSingular(Scenario):
    """Constant velocity, position measured: R = 1e-12 I, Q = 1e-14 I, P0 = p0 I."""

    dim_x, dim_z = 2, 1

    def __init__(self, p0):
        self.name = f"near-singular P0={p0:.0e}"
        self.F = np.array([[1.0, 1.0], [0.0, 1.0]])
        self.x_true0 = np.array([0.0, 1.0])
        self.x0 = np.array([0.0, 1.0])
        self.P0 = np.eye(2) * p0
        self.Q = np.eye(2) * 1e-14
        self.R = np.eye(1) * 1e-12
        self.alpha, self.kappa = 0.1, 0.0

    def fx(self, x, dt):
        return self.F @ x

    def fx_vec(self, X, dt):
        return X @ self.F.T

    def hx(self, x):
        return x[:1]

    def hx_vec(self, X):
        return X[:, :1]


def near_singular(p0) -> Scenario:
    return NearSingular(p0)


def SCENARIOS():  # noqa: N802 - a constant-like factory
    return [Robot(), CoordinatedTurn(), Lorenz96(40)]
