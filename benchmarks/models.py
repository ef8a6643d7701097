"""Benchmark scenarios: simulated truth, measurements, and per-point and vectorised models."""

from __future__ import annotations

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

    def fx(self, x, dt):
        t1, t3 = 0.5 * self.r * sum(self.phi), self.r / self.d * (self.phi[0] - self.phi[1])
        return np.array([x[0] + np.cos(x[2]) * t1, x[1] + np.sin(x[2]) * t1, x[2] + t3])

    def fx_vec(self, X, dt):
        t1, t3 = 0.5 * self.r * sum(self.phi), self.r / self.d * (self.phi[0] - self.phi[1])
        return np.c_[X[:, 0] + np.cos(X[:, 2]) * t1, X[:, 1] + np.sin(X[:, 2]) * t1, X[:, 2] + t3]

    def hx(self, x):
        return np.array([self.Delta - x[0] * np.cos(self.A) - x[1] * np.sin(self.A), x[2] - self.A])

    def hx_vec(self, X):
        return np.c_[self.Delta - X[:, 0] * np.cos(self.A) - X[:, 1] * np.sin(self.A), X[:, 2] - self.A]


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

    def fx(self, x, dt):
        return self.fx_vec(x[None], dt)[0]

    def fx_vec(self, X, dt):
        px, vx, py, vy, w = X.T
        w_safe = np.where(np.abs(w) < 1e-9, 1e-9, w)
        s, c = np.sin(w_safe * dt), np.cos(w_safe * dt)
        return np.c_[
            px + (s * vx - (1 - c) * vy) / w_safe,
            c * vx - s * vy,
            py + ((1 - c) * vx + s * vy) / w_safe,
            s * vx + c * vy,
            w,
        ]

    def hx(self, x):
        return np.array([np.hypot(x[0], x[2]), np.arctan2(x[2], x[0])])

    def hx_vec(self, X):
        return np.c_[np.hypot(X[:, 0], X[:, 2]), np.arctan2(X[:, 2], X[:, 0])]


class Lorenz96(Scenario):
    """Lorenz-96 (RK4, dt = 0.05), every other component observed."""

    def __init__(self, n=40):
        self.name, self.dim_x, self.dim_z, self.dt = f"Lorenz-96 n={n}", n, (n + 1) // 2, 0.05
        self.x_true0 = np.full(n, 8.0)
        self.x_true0[0] += 0.5
        self.x0 = np.full(n, 8.0)
        self.P0 = np.eye(n) * 0.5
        self.Q = np.eye(n) * 0.01
        self.R = np.eye(self.dim_z) * 0.1
        self.alpha, self.kappa = 0.5, 3.0 - n

    def fx(self, x, dt):
        return self.fx_vec(x[None], dt)[0]

    def fx_vec(self, X, dt):
        def f(V):
            return (np.roll(V, -1, 1) - np.roll(V, 2, 1)) * np.roll(V, 1, 1) - V + 8.0

        k1 = f(X)
        k2 = f(X + 0.5 * dt * k1)
        k3 = f(X + 0.5 * dt * k2)
        k4 = f(X + dt * k3)
        return X + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)

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
