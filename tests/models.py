"""The tests' shared models and factories: import from here, define nothing of the kind locally.

tests/README.md lists them by kind. In the order of this file:

- the g13ej example: :func:`example_data`, :class:`Robot`, :func:`run_g13ej`, and squkf.nag's
  calling sequence (:func:`first_entry`, :func:`call`, :func:`fill`, :func:`at_exit`)
- the coordinated-turn radar (state ``[px, vx, py, vy, omega]``, range and bearing):
  :func:`ct_fx`, :func:`ct_hx`, their row-wise and ``X[..., i]`` (stacked) forms, the far scenario
  ``CT_*`` (:func:`ct_filter` and its configurations, :func:`ct_simulate`, :func:`ct_measurements`)
  and the near one ``NEAR_*`` (:func:`near_filter`, :func:`near_measurements`)
- constant velocity in the plane (state ``[px, vx, py, vy]``): :func:`cv_fx` for one point, its
  stacked forms :func:`cv_fx_stacked` and :func:`cv_fx_nudged` with :func:`positions_hx` (a fleet
  of three, :func:`make_cv3_fleet`), and the four-state radar ``CV_*`` (:func:`cv_filter`)
- the fleet tests' K filters (``FLEET_*``, :func:`fleet_data`, :func:`cv_fleet`, :func:`cv_single`,
  :func:`fleet_and_singles`, ...) and the fleet smoother's K coordinated-turn tracks (``CTF_*``)
- constant velocity on a line, for the Dask tests: :func:`line_fx`, :func:`line_hx`, the failing
  :func:`slow_line_fx`, :func:`nan_for_big_line_fx`, and :func:`line_fleet` (module level, so that
  Dask's worker processes can import them by name: the cluster fixture puts this folder on their path)
- Lorenz-96, heading models; a ``residual_x`` whose deviations wrap (the issue-35 reproducer,
  :func:`wrapped_pair_filter`, and the wide heading ``WIDE_*``, :func:`wide_heading_filter`, with its
  oracle :func:`wide_covariance_form_update`); plain-arithmetic models (bit-for-bit comparisons)
- linear models: the precise sensor ``PRECISE_*`` (filterpy's UKF fails on it), the correlated
  four-state linear model ``LIN4_*``, the one-sensor constant velocity ``LIN2_*`` of the smoother
  tests, the drifting ``DRIFT_*`` of the batch tests, :func:`random_linear_model`,
  :func:`linear_pair`, :func:`spd`
- small filters (:func:`identity_filter`, :func:`decay_filter`, :func:`one_d`, ...) and polar to
  Cartesian (:func:`polar`, :func:`polar_rows`)
- the radar with wild returns of the gating tests (``RADAR_*``, :func:`radar_track`,
  :func:`radar_configure`), the gusty pendulum and the other models of the noise tests (``PEND_*``,
  :func:`pendulum_fx`, :func:`pendulum_hx`, their additive and offset forms and
  :func:`pendulum_noise_filter`, :func:`noise_linear_model`, :func:`polar_turn_fx`),
  :func:`tanh_filter` (rank lost to rounding)
- model values of a near shape (:data:`NEAR_SHAPES`, :data:`ONE_NUMBER_SHAPES`, :func:`near_shaped`,
  the GP-UKF's :func:`gp_ukf_fx`) and :func:`raising` (a model function raising a given exception)
- checks: :func:`filter_state` / :func:`assert_filter_state`, :func:`fleet_state` /
  :func:`assert_fleet_state`, :func:`assert_results_equal`, :func:`counting`, :func:`rel`

Beside each kind are the filters the test files build from it and the helpers that step two
filters and compare them (:func:`run_and_compare`, a fleet against its single filters;
:func:`run_pair` and :func:`run_against_kf`, against filterpy's UKF and Kalman filter;
:func:`assert_same_filter`; :func:`assert_smoother_matches_single`).
"""

from __future__ import annotations

import copy
import json
import math
import time
from pathlib import Path

import numpy as np
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import (
    JulierSigmaPoints,
    KalmanFilter,
    MerweScaledSigmaPoints,
    SimplexSigmaPoints,
    UnscentedKalmanFilter,
)

from squkf import CubatureWeights, Fleet, JulierWeights, MerweScaledWeights, SimplexWeights, SquareRootUKF
from squkf.angles import AngleAdd, AngleMean, AngleResidual, wrap
from squkf.examples import g13ej_example as ex
from squkf.gating import Gate
from squkf.nag import kalman_unscented_state_revcom as g13ej

ROOT = Path(__file__).resolve().parents[1]


# -- the g13ej example -----------------------------------------------------------------------------


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


def robot_fx_stacked(X, dt, phi_r=0.4, phi_l=0.1):
    """The robot's ``fx`` at a stack of points ``(..., 3)`` (``X[..., i]``: one filter and a fleet)."""
    m = G13EJ_MODEL
    t1 = 0.5 * m["r"] * (phi_r + phi_l)
    t3 = (m["r"] / m["d"]) * (phi_r - phi_l)
    heading = X[..., 2]
    return np.stack([X[..., 0] + np.cos(heading) * t1, X[..., 1] + np.sin(heading) * t1, heading + t3], -1)


def robot_hx_stacked(X):
    """The robot's wall sensor at a stack of points: distance, and the bearing in ``[0, 2 pi)``."""
    m = G13EJ_MODEL
    distance = m["Delta"] - X[..., 0] * np.cos(m["A"]) - X[..., 1] * np.sin(m["A"])
    return np.stack([distance, (X[..., 2] - m["A"]) % (2 * np.pi)], -1)


def robot_tune_filter(q_scale=1.0, r=(1.0, 1.0)):
    """The robot as a tuning template: the example's ``Q`` times ``q_scale``, its ``R``'s variances times
    ``r``, the bearing an angle (its residual wrapped, ``AngleResidual([1])``, and its mean circular,
    ``AngleMean([1])``: the bearing wraps at 2 pi, and a plain mean of points on both sides of it is
    wrong), the model written for stacks."""
    data = ex.load_data()
    f = SquareRootUKF(3, 2, 1.0, robot_hx_stacked, robot_fx_stacked, MerweScaledWeights(1.0, 2.0, 0.0),
                      vectorized=True, residual_z=AngleResidual([1]), z_mean_fn=AngleMean([1]))  # fmt: skip
    f.x, f.P1_2 = np.array(data["x0"], dtype=float), np.array(data["st0"], dtype=float)
    f.Q1_2 = np.sqrt(q_scale) * np.array(data["lx"], dtype=float)
    ly = np.array(data["ly"], dtype=float)
    f.R = np.diag(np.asarray(r) * np.diag(ly @ ly.T))
    return f


# the g13ej calling sequence (squkf.nag): the arguments as a dict, a call, the model's images
G13EJ = ex.load_data()
G13EJ_MODEL = G13EJ["model"]


def first_entry(ropt=None, lx="default"):
    lx = np.array(G13EJ["lx"]) if lx == "default" else lx
    x = np.array(G13EJ["x0"], dtype=float)
    st = np.array(G13EJ["st0"], dtype=float)
    xt = np.zeros((3, 13))
    fxt = np.zeros((3, 13))
    comm = {}
    return dict(
        irevcm=0,
        y=G13EJ["y"][0],
        ly=np.array(G13EJ["ly"]),
        x=x,
        st=st,
        xt=xt,
        fxt=fxt,
        comm=comm,
        lx=lx,
        ropt=ropt,
    )


def call(a):
    a["irevcm"], n = g13ej(
        a["irevcm"],
        a["y"],
        a["ly"],
        a["x"],
        a["st"],
        a["xt"],
        a["fxt"],
        a["comm"],
        lx=a["lx"],
        ropt=a["ropt"],
    )
    return a["irevcm"], n


def fill(a, n):
    m = G13EJ["model"]
    if a["irevcm"] == 1:
        a["fxt"][:3, :n] = ex.f(a["xt"][:, :n], m["r"], m["d"], 0.4, 0.1)
    else:
        a["fxt"][:2, :n] = ex.h(a["xt"][:, :n], m["Delta"], m["A"])


def at_exit(k, ropt=None):
    """Arguments positioned at intermediate exit k (1 or 2)."""
    a = first_entry(ropt=ropt)
    _, n = call(a)
    if k == 2:
        fill(a, n)
        _, n = call(a)
    fill(a, n)
    return a


def run_g13ej(scheme: str, vectorized: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The g13ej example through SquareRootUKF: the state estimates and the final factor."""
    data = example_data()
    robot = Robot(data)
    if vectorized:

        def fx(X, dt, phi_r, phi_l):
            return np.array([robot.fx(x, dt, phi_r, phi_l) for x in X])

        def hx(X):
            return np.array([robot.hx(x) for x in X])
    else:
        fx, hx = robot.fx, robot.hx
    ukf = SquareRootUKF(3, 2, 1.0, hx, fx, MerweScaledWeights(), scheme=scheme, vectorized=vectorized)
    ukf.x = np.array(data["x0"])
    ukf.P1_2 = np.array(data["st0"])
    ukf.Q1_2 = np.array(data["lx"])
    ukf.R1_2 = np.array(data["ly"])
    xs = []
    for t, y in enumerate(data["y"]):
        ukf.predict(phi_r=data["phi_r"][t], phi_l=data["phi_l"][t])
        ukf.update(np.array(y))
        xs.append(ukf.x.copy())
    return np.array(xs), np.array(ukf.P1_2)


# -- the coordinated-turn radar --------------------------------------------------------------------


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


def ct_fx_rows(X, dt):
    """:func:`ct_fx` of each row of ``X`` (a ``vectorized=True`` model)."""
    return np.array([ct_fx(x, dt) for x in X])


def ct_hx_rows(X):
    """:func:`ct_hx` of each row of ``X``."""
    return np.array([ct_hx(x) for x in X])


def ct_fx_stacked(X, dt, scale=1.0, poison=0.0):
    """Coordinated turn, written with ``X[..., i]``: one point, N points or K sets of N points alike.

    ``scale`` and ``poison`` (per filter in a fleet) let a test break one filter's images.
    """
    px, vx, py, vy, w = (X[..., i] for i in range(5))
    s, c = np.sin(w * dt), np.cos(w * dt)
    out = np.stack(
        [
            px + (s * vx - (1 - c) * vy) / w,
            c * vx - s * vy,
            py + ((1 - c) * vx + s * vy) / w,
            s * vx + c * vy,
            w,
        ],
        axis=-1,
    )
    return out * np.asarray(scale)[..., None] + np.asarray(poison)[..., None]


def range_bearing_hx(X, scale=None):
    """Range and bearing of ``[X[..., 0], X[..., 2]]`` from the origin; ``scale`` 0 makes it constant."""
    h = np.stack([np.hypot(X[..., 0], X[..., 2]), np.arctan2(X[..., 2], X[..., 0])], axis=-1)
    if scale is not None:
        h = h * np.asarray(scale)[..., None]
    return h


# the far scenario: a target 3.6 km out, turning slowly
CT_Q = np.diag([0.1, 0.01, 0.1, 0.01, 1e-6])
CT_R = np.diag([25.0, 0.002**2])
CT_X0 = np.array([2000.0, 10.0, 3000.0, -5.0, 0.02])
CT_P0 = np.diag([400.0, 4.0, 400.0, 4.0, 1e-4])


def ct_filter(points, cls=SquareRootUKF, vectorized=False, **kw):
    """A ``cls`` (SquareRootUKF or a filterpy filter) on the far scenario, at ``CT_X0``, ``CT_P0``."""
    if vectorized:
        f = cls(5, 2, 1.0, ct_hx_rows, ct_fx_rows, points, vectorized=True, **kw)
    else:
        f = cls(5, 2, 1.0, ct_hx, ct_fx, points, **kw)
    f.x, f.P, f.Q, f.R = CT_X0.copy(), CT_P0, CT_Q, CT_R
    return f


def ct_negative_weight_filter(scheme="redrawn", vectorized=False):
    """The far scenario, Merwe points with alpha 0.1 (a negative central weight)."""
    return ct_filter(MerweScaledWeights(alpha=0.1, beta=2.0, kappa=0.0), scheme=scheme, vectorized=vectorized)


def ct_mid_step_filter(vectorized=False, points=None, **kw):
    """The far scenario (Merwe alpha 0.3, kappa -2 unless ``points``) stopped mid-step: a prior pending."""
    points = MerweScaledWeights(0.3, 2.0, -2.0) if points is None else points
    f = ct_filter(points, vectorized=vectorized, **kw)
    f.predict()
    f.update(ct_hx(f.x) + 1.0)
    f.predict()  # mid-step: a prior is pending
    return f


def ct_merwe_filter(cls):
    """The far scenario in ``cls`` (SquareRootUKF or filterpy's UKF), filterpy's Merwe points (0.3, 2, -2)."""
    return ct_filter(MerweScaledSigmaPoints(5, 0.3, 2.0, -2.0), cls=cls)


def ct_simulate(T=60, seed=0, missing=(5, 17, 18, 40)):
    """Measurements (``None`` at the steps ``missing``, a few by default) and true states of T noisy steps."""
    rng = np.random.default_rng(seed)
    x = CT_X0.copy()
    zs, truth = [], []
    for k in range(T):
        x = ct_fx(x, 1.0) + rng.multivariate_normal(np.zeros(5), CT_Q)
        truth.append(x)
        zs.append(None if k in missing else ct_hx(x) + rng.multivariate_normal(np.zeros(2), CT_R))
    return zs, np.array(truth)


def ct_measurements(k=30, seed=0, x0=CT_X0, sd=(5.0, 0.002), dt=1.0):
    """Noisy measurements of a noise-free track from ``x0`` (a list of k)."""
    rng = np.random.default_rng(seed)
    x = np.array(x0, dtype=float)
    zs = []
    for _ in range(k):
        x = ct_fx(x, dt)
        zs.append(ct_hx(x) + rng.normal(0, list(sd)))
    return zs


# the near scenario: a target a few units out, turning fast
NEAR_DT = 1.0
NEAR_X0 = np.array([-8.0, 0.5, 1.5, 2.0, 0.05])
NEAR_P0 = np.diag([1.0, 0.1, 1.0, 0.1, 0.01])
NEAR_Q = np.diag([1e-3, 1e-2, 1e-3, 1e-2, 1e-4])
NEAR_R = np.diag([0.05, 0.01])


def near_filter(**kw) -> SquareRootUKF:
    """The coordinated-turn radar on the near scenario."""
    f = SquareRootUKF(5, 2, NEAR_DT, ct_hx, ct_fx, MerweScaledWeights(alpha=0.5), **kw)
    f.x, f.P, f.Q, f.R = NEAR_X0, NEAR_P0, NEAR_Q, NEAR_R
    return f


def near_measurements(T: int, seed: int = 0) -> np.ndarray:
    """``(T, 2)`` measurements of the near scenario's noise-free track."""
    rng = np.random.default_rng(seed)
    x, out = NEAR_X0.copy(), []
    for _ in range(T):
        x = ct_fx(x, NEAR_DT)
        out.append(ct_hx(x) + rng.normal(0.0, [0.2, 0.1]))
    return np.array(out)


def two_updates(cls, redraw: bool, model: str):
    """``predict``, then two ``update``s with no ``predict`` between (README's "What differs" reproducer,
    or two range-bearing returns a step on the far scenario); ``redraw``: filterpy's line before the
    second update, ``sigmas_f`` drawn from the estimate that update starts from."""
    if model == "readme":
        points = MerweScaledSigmaPoints(1, alpha=0.5, beta=2.0, kappa=2.0)
        f = cls(dim_x=1, dim_z=1, dt=1.0, hx=lambda x: x + x**3 / 10, fx=lambda x, dt: x, points=points)
        f.P *= 10
        z1 = z2 = np.array([1.0])
    else:
        f = ct_filter(MerweScaledSigmaPoints(5, 0.3, 2.0, -2.0), cls=cls)
        z1 = ct_measurements(1, seed=5)[0]
        z2 = z1 + np.array([3.0, -0.001])
    f.predict()
    f.update(z1)
    if redraw:
        f.sigmas_f = f.points_fn.sigma_points(f.x, f.P)
    f.update(z2)
    return f


# -- constant velocity in the plane, state [px, vx, py, vy] ------------------------------------


def cv_fx(x, dt):
    """Constant velocity, state [px, vx, py, vy] (one point; :func:`ct_hx` measures it)."""
    return np.array([x[0] + dt * x[1], x[1], x[2] + dt * x[3], x[3]])


def cv_fx_stacked(X, dt, u=None, bad=None, kick=None):
    """Constant velocity, state [px, vx, py, vy]; ``u`` an acceleration (per filter in a fleet).

    ``bad`` (a flag per filter) makes the images NaN; ``kick`` moves every non-central point
    by the same amount (an indefinite weighted covariance with a negative weight).
    """
    out = np.stack([X[..., 0] + dt * X[..., 1], X[..., 1], X[..., 2] + dt * X[..., 3], X[..., 3]], axis=-1)
    if u is not None:
        u = np.asarray(u, dtype=float)
        out = out + dt * np.stack([0.5 * dt * u[..., 0], u[..., 0], 0.5 * dt * u[..., 1], u[..., 1]], axis=-1)
    if bad is not None:
        out = np.where(np.asarray(bad)[..., None], np.nan, out)
    if kick is not None:
        noncentral = (np.arange(X.shape[-2]) != 0)[:, None]
        out = out + np.asarray(kick)[..., None] * noncentral
    return out


def cv_fx_nudged(X, dt, u=None, bad=None):
    """Constant velocity in two axes, state [px, vx, py, vy] (``u``: an offset of vx; ``bad``: NaN)."""
    out = np.stack([X[..., 0] + dt * X[..., 1], X[..., 1], X[..., 2] + dt * X[..., 3], X[..., 3]], axis=-1)
    if u is not None:
        out[..., 1] += u
    if bad is not None:
        out = np.where(np.asarray(bad)[..., None], np.nan, out)
    return out


def positions_hx(X, scale=1.0):
    """Both positions, times ``scale``."""
    return np.asarray(scale)[..., None] * X[..., ::2]


# a fleet of three: cv_fx_nudged measured by positions_hx
CV3_K, CV3_NX, CV3_NZ, CV3_DT = 3, 4, 2, 1.0


def make_cv3_fleet(**kw) -> Fleet:
    """The fleet of three constant-velocity filters."""
    fl = Fleet(CV3_K, CV3_NX, CV3_NZ, CV3_DT, positions_hx, cv_fx_nudged, MerweScaledWeights(alpha=0.5), **kw)
    fl.x = np.array([[0.0, 1.0, 0.0, -1.0], [1.0, 0.5, 2.0, 0.0], [-1.0, 0.0, 1.0, 1.0]])
    fl.P = np.diag([1.0, 0.1, 1.0, 0.1])
    fl.Q = 1e-3 * np.eye(CV3_NX)
    fl.R = 0.1 * np.eye(CV3_NZ)
    return fl


def cv3_zs(T: int, seed: int = 1) -> np.ndarray:
    """``(K, T, 2)`` measurements for :func:`make_cv3_fleet` (pure noise)."""
    rng = np.random.default_rng(seed)
    return rng.normal(0.0, 1.0, (CV3_K, T, CV3_NZ))


# the four-state radar of the filterpy-habit tests: cv_fx measured by ct_hx (range and bearing)
CV_DT = 0.5
CV_Q = Q_discrete_white_noise(2, dt=CV_DT, var=0.05, block_size=2) + 1e-4 * np.eye(4)
CV_R = np.array([[0.5, 0.1], [0.1, 0.02]])
CV_X0 = np.array([10.0, 1.0, 20.0, -0.5])
CV_P0 = np.diag([4.0, 1.0, 4.0, 1.0])


def cv_measurements(k=6, seed=3):
    rng = np.random.default_rng(seed)
    x = CV_X0.copy()
    out = []
    for _ in range(k):
        x = cv_fx(x, CV_DT)
        out.append(ct_hx(x) + rng.normal(0, [0.5, 0.05]))
    return out


CV_Z = cv_measurements()


def cv_filter(scheme="redrawn", points=None, **kw):
    """The four-state radar (Merwe alpha 0.5 unless ``points``)."""
    points = MerweScaledWeights(alpha=0.5, beta=2.0, kappa=0.0) if points is None else points
    f = SquareRootUKF(4, 2, CV_DT, ct_hx, cv_fx, points, scheme=scheme, **kw)
    f.x, f.P, f.Q, f.R = CV_X0, CV_P0, CV_Q, CV_R
    return f


def cv_pair(cls_points=None, dt=CV_DT, **kw):
    """The four-state radar in squkf and in filterpy 2.0.0, one points object each (Merwe, alpha 0.5)."""
    points = cls_points or (lambda: MerweScaledSigmaPoints(4, 0.5, 2.0, 0.0))
    pair = []
    for cls in (SquareRootUKF, UnscentedKalmanFilter):
        f = cls(4, 2, dt, ct_hx, cv_fx, points(), **kw)
        f.x, f.P, f.Q, f.R = CV_X0.copy(), CV_P0.copy(), CV_Q.copy(), CV_R.copy()
        pair.append(f)
    return tuple(pair)


def ctrv_fx(x, dt):
    """A car's turn rate and velocity model (CTRV), state [px, py, v, yaw, yaw rate]; dt is None: 0.1."""
    dt = 0.1 if dt is None else dt
    px, py, v, yaw, w = x
    if abs(w) > 1e-6:
        px += v / w * (np.sin(yaw + w * dt) - np.sin(yaw))
        py += v / w * (np.cos(yaw) - np.cos(yaw + w * dt))
    else:
        px += v * dt * np.cos(yaw)
        py += v * dt * np.sin(yaw)
    return np.array([px, py, v, yaw + w * dt, w])


def ctrv_hx(x):
    """The car's position (a LiDAR's)."""
    return x[:2]


def ctrv_track(T=8, seed=5):
    """Noisy positions of a car turning at 0.3 rad/s at 5 m/s, every 0.1 s."""
    rng = np.random.default_rng(seed)
    x = np.array([0.0, 0.0, 5.0, 0.0, 0.3])
    zs = []
    for _ in range(T):
        x = ctrv_fx(x, 0.1)
        zs.append(x[:2] + rng.normal(0.0, 0.15, 2))
    return zs


def step(f, z):
    """One predict and one update."""
    f.predict()
    f.update(z)


def assert_same_estimate(a, b, exact=True, records=True):
    """``a`` and ``b`` hold the same estimate (and records), bit for bit or to 1e-12."""
    names = ("x", "P", "x_prior", "P1_2_prior", "x_post", "P1_2_post", "y", "K") if records else ("x", "P")
    for name in names:
        if exact:
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
        else:
            np.testing.assert_allclose(
                getattr(a, name), getattr(b, name), rtol=1e-12, atol=1e-12, err_msg=name
            )
    if exact:
        assert a.log_likelihood == b.log_likelihood


def bank_pair():
    """Two SquareRootUKFs and two filterpy UKFs, the same models (different process noise)."""
    ours, theirs = [], []
    for q in (0.01, 1.0):
        Q = Q_discrete_white_noise(2, dt=CV_DT, var=q, block_size=2) + 1e-6 * np.eye(4)
        for lst, cls in ((ours, SquareRootUKF), (theirs, UnscentedKalmanFilter)):
            f = cls(4, 2, CV_DT, ct_hx, cv_fx, MerweScaledSigmaPoints(4, 0.5, 2.0, 0.0))
            f.x, f.P, f.Q, f.R = CV_X0.copy(), CV_P0.copy(), Q.copy(), CV_R.copy()
            lst.append(f)
    return ours, theirs


def cv_placeholder_filter() -> SquareRootUKF:
    """:func:`models.cv_filter` built as filterpy allows, with ``fx=None`` and ``hx=None``."""
    f = SquareRootUKF(4, 2, CV_DT, None, None, MerweScaledWeights(alpha=0.5, beta=2.0, kappa=0.0))
    f.x, f.P, f.Q, f.R = CV_X0, CV_P0, CV_Q, CV_R
    return f


def edited_pair(edit):
    """A fleet edited in place by ``edit``, and one given the same values by assignment."""
    fl, ref = make_cv3_fleet(), make_cv3_fleet()
    edit(fl)
    for name in ("x", "P", "Q", "R"):
        setattr(ref, name, np.array(getattr(fl, name)))
    return fl, ref


# -- the fleet tests' targets: four states in range and bearing, K of them, noise per filter -------
FLEET_N_X, FLEET_N_Z, FLEET_DT = 4, 2, 0.5
FLEET_P0 = np.diag([1.0, 0.1, 1.0, 0.1])

# models (tests/models.py): cv_fx_stacked and range_bearing_hx, turn_fx_stacked and xy_radar_hx_stacked,
# written with X[..., i], so they serve a fleet (K, N, n) and one vectorised filter (N, n)

FLEET_FAMILIES = {
    "merwe": lambda: MerweScaledWeights(),
    "merwe-alpha0.3": lambda: MerweScaledWeights(alpha=0.3),
    "julier": lambda: JulierWeights(),
    "simplex": lambda: SimplexWeights(),
    "cubature": lambda: CubatureWeights(),
    "filterpy-merwe": lambda: MerweScaledSigmaPoints(FLEET_N_X, alpha=0.3, beta=2.0, kappa=-1.0),
}
SCHEMES = ("redrawn", "augmented", "propagated")


def fleet_data(K, T, seed=0, model="cv"):
    """Initial states (K, n), per-filter Q (K, n, n) and R (K, m, m), measurements (K, T, m)."""
    rng = np.random.default_rng(seed)
    if model == "cv":
        x0 = np.array([10.0, 1.0, 5.0, -0.5]) + rng.normal(0, 1.0, (K, FLEET_N_X))
        fx, hx = cv_fx_stacked, range_bearing_hx
    else:
        x0 = np.array([-8.0, 0.5, 1.5, 2.0]) + rng.normal(0, 0.3, (K, FLEET_N_X))
        fx, hx = turn_fx_stacked, xy_radar_hx_stacked
    truth = [x0 + rng.normal(0, 0.3, (K, FLEET_N_X))]
    for _ in range(T - 1):
        truth.append(fx(truth[-1], FLEET_DT))
    zs = np.stack([hx(t) for t in truth], axis=1) + rng.normal(0, 0.05, (K, T, FLEET_N_Z))
    if model == "turn":
        zs[..., 1] = np.arctan2(np.sin(zs[..., 1]), np.cos(zs[..., 1]))
    Q = np.stack([np.diag([0.01, 0.02, 0.01, 0.02]) * (1 + 0.5 * k) for k in range(K)])
    R = np.stack([np.array([[0.05, 0.01], [0.01, 0.02]]) * (1 + 0.3 * k) for k in range(K)])
    return x0, Q, R, zs


def cv_fleet(K, points, scheme="redrawn", model="cv", **kw):
    fx, hx = (cv_fx_stacked, range_bearing_hx) if model == "cv" else (turn_fx_stacked, xy_radar_hx_stacked)
    return Fleet(K, FLEET_N_X, FLEET_N_Z, FLEET_DT, hx, fx, points, scheme=scheme, **kw)


def cv_single(points, scheme="redrawn", model="cv", **kw):
    fx, hx = (cv_fx_stacked, range_bearing_hx) if model == "cv" else (turn_fx_stacked, xy_radar_hx_stacked)
    return SquareRootUKF(FLEET_N_X, FLEET_N_Z, FLEET_DT, hx, fx, points, scheme=scheme, vectorized=True, **kw)


def fleet_angle_hooks(model):
    z = {"z_mean_fn": AngleMean([1]), "residual_z": AngleResidual([1])}
    if model == "turn":
        z.update(x_mean_fn=AngleMean([2]), residual_x=AngleResidual([2]), state_add=AngleAdd([2]))
    return z


def fleet_and_singles(K, name, scheme, model="cv", per_filter=True, hooks=None, seed=0, T=6):
    x0, Q, R, zs = fleet_data(K, T, seed, model)
    hooks = hooks or {}
    fleet = cv_fleet(K, FLEET_FAMILIES[name](), scheme, model, **hooks)
    fleet.x, fleet.P = x0, FLEET_P0
    fleet.Q = Q if per_filter else Q[0]
    fleet.R = R if per_filter else R[0]
    singles = []
    for k in range(K):
        f = cv_single(FLEET_FAMILIES[name](), scheme, model, **hooks)
        f.x, f.P = x0[k].copy(), FLEET_P0.copy()
        f.Q = Q[k] if per_filter else Q[0]
        f.R = R[k] if per_filter else R[0]
        singles.append(f)
    return fleet, singles, zs


def fleet_with_and_without(K, k, scheme="redrawn", name="merwe", seed=1, **kw):
    """A fleet of K filters and one of the K-1 others, same data (per-filter Q and R)."""
    x0, Q, R, zs = fleet_data(K, 6, seed)
    keep = np.array([j for j in range(K) if j != k], dtype=int)
    big = cv_fleet(K, FLEET_FAMILIES[name](), scheme, **kw)
    small = cv_fleet(K - 1, FLEET_FAMILIES[name](), scheme, **kw)
    for fl, idx in ((big, np.arange(K)), (small, keep)):
        fl.x, fl.P, fl.Q, fl.R = x0[idx], FLEET_P0, Q[idx], R[idx]
    return big, small, keep, zs


def fleet_batch_setup(K=3, T=7, scheme="redrawn"):
    fleet, singles, zs = fleet_and_singles(K, "merwe-alpha0.3", scheme, T=T)
    zs[0, 2] = np.nan
    zs[1, T - 3, 1] = np.nan
    zs[:, T - 2] = np.nan
    return fleet, singles, zs


FLEET_RTOL = 1e-10


def assert_close(a, b, what):
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    assert a.shape == b.shape, what
    scale = max(float(np.max(np.abs(b))), 1e-300)
    err = float(np.max(np.abs(a - b)))
    assert err <= FLEET_RTOL * scale, f"{what}: max difference {err:.3g}, scale {scale:.3g}"


def run_and_compare(fleet, singles, zs, R_step=None, fx_args=None, hx_args=None):
    """Step the fleet and each single filter through ``zs`` (K, T, m), comparing every step."""
    K, T = zs.shape[:2]
    fx_args, hx_args = fx_args or {}, hx_args or {}
    for t in range(T):
        fleet.predict(**fx_args)
        fleet.update(zs[:, t], R=R_step, **hx_args)
        for k, f in enumerate(singles):
            f.predict(**{a: v[k] if isinstance(v, np.ndarray) else v for a, v in fx_args.items()})
            x_prior, S_prior = f.x.copy(), f.P1_2.copy()
            Rk = None if R_step is None else (R_step[k] if np.ndim(R_step) == 3 else R_step)
            f.update(
                zs[k, t], R=Rk, **{a: v[k] if isinstance(v, np.ndarray) else v for a, v in hx_args.items()}
            )
            where = f"t={t} k={k}"
            assert_close(fleet.x_prior[k], x_prior, "x_prior " + where)
            assert_close(fleet.P1_2_prior[k], S_prior, "P1_2_prior " + where)
            assert_close(fleet.x[k], f.x, "x " + where)
            assert_close(fleet.P1_2[k], f.P1_2, "P1_2 " + where)
            assert_close(fleet.x_post[k], f.x_post, "x_post " + where)
            assert_close(fleet.P1_2_post[k], f.P1_2_post, "P1_2_post " + where)
            if np.isnan(zs[k, t]).all():  # no measurement: nothing was updated
                assert fleet.log_likelihood[k] == 0.0 and fleet.mahalanobis[k] == 0.0
                assert fleet.likelihood[k] == 1.0
                assert np.isnan(fleet.y[k]).all()
                np.testing.assert_array_equal(fleet.x[k], fleet.x_prior[k])
            else:
                assert_close(fleet.log_likelihood[k], f.log_likelihood, "log_likelihood " + where)
                assert_close(fleet.likelihood[k], f.likelihood, "likelihood " + where)
                assert_close(fleet.mahalanobis[k], f.mahalanobis, "mahalanobis " + where)
                np.testing.assert_array_equal(np.isnan(fleet.y[k]), np.isnan(f.y))
                ok = ~np.isnan(f.y)
                assert_close(fleet.y[k][ok], f.y[ok], "y " + where)
    assert not fleet.failed.any()


def cv_fleet_and_measurements(K: int, T: int):
    fleet = cv_fleet(K, MerweScaledWeights())
    x0 = np.array([10.0, 1.0, 5.0, -0.5])
    fleet.x, fleet.P, fleet.Q, fleet.R = x0, FLEET_P0, 0.01 * np.eye(FLEET_N_X), np.diag([0.5, 0.01])
    rng = np.random.default_rng(5)
    zs = range_bearing_hx(x0) + rng.normal(0.0, 0.1, (K, T, FLEET_N_Z))
    return fleet, zs


# -- nested filters: a model function that steps another filter (issue 35) ------------------------

NESTED_T = 4  # steps of a nested run


class InnerSteps:
    """Inner filters stepped from inside an outer filter's model function, or their results played back.

    One inner filter per chunk of the outer fleet, found by the chunk's ``tag`` (its first filter's
    index; None: the outer is one filter), so that chunks on several threads never step the same
    inner filter. Each call steps that inner filter once (a predict and an update with its next
    measurement) and returns a number of its new estimate. :meth:`record` steps copies of them all
    outside any model function first, and the calls then return those numbers instead: the outer
    filter's numbers must be the same either way.
    """

    def __init__(self, inners: list, zs: list, chunk: int = 1) -> None:
        self.inners, self.zs, self.chunk = inners, zs, chunk
        self.played: list | None = None
        self.done = [0] * len(inners)

    def _step(self, f, zs, t: int) -> float:
        f.predict()
        f.update(zs[t % len(zs)])
        return float(f.x.sum() + f.P.sum())

    def record(self) -> None:
        self.played = [
            [self._step(f, zs, t) for t in range(2 * NESTED_T)]
            for f, zs in zip(copy.deepcopy(self.inners), self.zs)
        ]

    def __call__(self, tag=None) -> float:
        i = 0 if tag is None else int(np.ravel(tag)[0]) // self.chunk
        t, self.done[i] = self.done[i], self.done[i] + 1
        if self.played is not None:
            return self.played[i][t]
        return self._step(self.inners[i], self.zs[i], t)


def nested_fx(steps: InnerSteps | None):
    """``cv_fx_stacked`` plus 1e-3 of an inner filter's step, taken first (so X is read after it);
    ``steps`` None: ``cv_fx_stacked`` (``tag`` ignored)."""

    def fx(X, dt, tag=None):
        c = 0.0 if steps is None else 1e-3 * steps(tag)
        return cv_fx_stacked(X, dt) + c

    return fx


def nested_hx(steps: InnerSteps | None):
    """``range_bearing_hx`` plus 1e-3 of an inner filter's step, taken first; None: as ``nested_fx``."""

    def hx(X, tag=None):
        c = 0.0 if steps is None else 1e-3 * steps(tag)
        return range_bearing_hx(X) + c

    return hx


def nested_filters(outer: str, inner: str, where: str, c: int = 3):
    """An outer filter whose ``fx`` or ``hx`` (``where``) steps inner filters of the same ``dim_x``.

    ``outer``: "fleet" (``2 c`` filters in chunks of ``c``) or "single" (a vectorised
    ``SquareRootUKF``); ``inner``: "fleet" (``c`` filters, chunks of ``c``: the outer's chunk size),
    "single", or "copy" (a copy of the outer). Returns the outer filter, its measurements per step,
    the keyword arguments of its steps (a fleet's ``tag``: the filters' indices) and the
    :class:`InnerSteps`.
    """
    if outer == "fleet":
        f, _, zs = fleet_and_singles(2 * c, "merwe", "redrawn", T=NESTED_T)
        f.chunk = c
        z_steps, args = [zs[:, t] for t in range(NESTED_T)], {"tag": np.arange(2 * c)}
    else:
        _, singles, zs = fleet_and_singles(1, "merwe", "redrawn", T=NESTED_T)
        f, z_steps, args = singles[0], [zs[0, t] for t in range(NESTED_T)], {}
    inners, inner_zs = [], []
    for i in range(2 if outer == "fleet" else 1):
        if inner == "copy":
            inners.append(copy.copy(f))
            inner_zs.append(z_steps)
            continue
        g, singles, zs = fleet_and_singles(c, "merwe", "redrawn", T=NESTED_T, seed=5 + i)
        if inner == "fleet":
            g.chunk = c
            inners.append(g)
            inner_zs.append([zs[:, t] for t in range(NESTED_T)])
        else:
            inners.append(singles[0])
            inner_zs.append([zs[0, t] for t in range(NESTED_T)])
    steps = InnerSteps(inners, inner_zs, c)
    f.fx = nested_fx(steps if where == "fx" else None)
    f.hx = nested_hx(steps if where == "hx" else None)
    return f, z_steps, args, steps


# -- the fleet smoother's: K coordinated-turn tracks of the far scenario --------------------------

# == Fleet.rts_smoother ============================================================================

CTF_K, CTF_T = 3, 20


def ct_fleet_measurements(seed=0, dts=None):
    """``(K, T, 2)`` noisy range-bearing measurements of K coordinated-turn tracks, a few missing."""
    rng = np.random.default_rng(seed)
    dts = np.ones(CTF_T) if dts is None else dts
    zs = np.empty((CTF_K, CTF_T, 2))
    for k in range(CTF_K):
        x = CT_X0 + rng.normal(size=5) * [20, 1, 20, 1, 0.005]
        for t in range(CTF_T):
            x = ct_fx_stacked(x, dts[t]) + rng.multivariate_normal(np.zeros(5), CT_Q)
            zs[k, t] = range_bearing_hx(x) + rng.multivariate_normal(np.zeros(2), CT_R)
    zs[0, 4] = np.nan  # no measurement
    zs[1, 9, 1] = np.nan  # a missing component
    return zs


def ct_per_filter_Q():
    return np.stack([CT_Q * s for s in (0.5, 1.0, 3.0)])


def make_ct_fleet(points, scheme="redrawn", Q=CT_Q, **kw):
    fleet = Fleet(CTF_K, 5, 2, 1.0, range_bearing_hx, ct_fx_stacked, points, scheme=scheme, **kw)
    fleet.x, fleet.P, fleet.Q, fleet.R = CT_X0, CT_P0, Q, CT_R
    return fleet


def make_ct_single(points, k, scheme="redrawn", Q=CT_Q, **kw):
    """Filter ``k`` of :func:`make_fleet`, built independently (fx called once per point)."""
    f = SquareRootUKF(5, 2, 1.0, range_bearing_hx, ct_fx_stacked, points, scheme=scheme, **kw)
    f.x, f.P, f.Q, f.R = CT_X0.copy(), CT_P0, (Q if Q.ndim == 2 else Q[k]), CT_R
    return f


def assert_smoother_matches_single(points, scheme="redrawn", Q=CT_Q, dts=None, chained_tol=1e-10, **kw):
    """Each filter of the fleet's smoother against the single filter's, on the same and on its own input."""
    zs = ct_fleet_measurements(dts=dts)
    fleet = make_ct_fleet(points, scheme, Q, **kw)
    result = fleet.batch_filter(zs, dts=dts)
    out = fleet.rts_smoother(result, dts=dts)
    means, factors, gains = out
    assert not result.failed.any() and not out.failed.any()
    for k in range(CTF_K):
        f = make_ct_single(points, k, scheme, Q, **kw)
        # the same filtered input: only the smoothers' arithmetic differs (stacked QR against LAPACK's)
        xs, Ss, Gs = f.rts_smoother_factors(result.means[k], result.P1_2s[k], dts=dts)
        assert rel_unfloored(means[k], xs) < 1e-10
        assert rel_unfloored(factors[k], Ss) < 1e-10
        assert rel_unfloored(gains[k], Gs) < 1e-10
        # the single filter's own batch_filter output
        m, S = f.batch_filter(list(zs[k]), dts=dts, return_factors=True)
        xs, Ss, Gs = f.rts_smoother_factors(m, S, dts=dts)
        assert rel_unfloored(means[k], xs) < chained_tol
        assert rel_unfloored(factors[k], Ss) < chained_tol
        assert rel_unfloored(gains[k], Gs) < chained_tol
        np.testing.assert_array_equal(gains[k, -1], 0.0)
        # the smoothed factors are lower factors, as the single filter's
        assert np.all(np.triu(factors[k], 1) == 0)
        assert np.all(np.diagonal(factors[k], axis1=-2, axis2=-1) > 0)
    return fleet, result, out


# -- constant velocity on a line, for the Dask tests (worker processes import these by name) -----


def line_fx(X, dt):
    """Constant velocity in 1-D: ``[p, v]``, vectorised over any leading axes."""
    out = X.copy()
    out[..., 0] = X[..., 0] + dt * X[..., 1]
    return out


def line_hx(X):
    """Range to a point one unit off the line, and the velocity."""
    return np.stack([np.hypot(X[..., 0], 1.0), X[..., 1]], axis=-1)


def slow_line_fx(X, dt):
    """``line_fx`` that takes a while (so that a worker can be killed mid-chunk)."""
    time.sleep(0.02)
    return line_fx(X, dt)


def nan_for_big_line_fx(X, dt):
    """``line_fx``, but NaN for filters whose position exceeds 1e6 (an injected failure)."""
    out = line_fx(X, dt)
    bad = np.abs(X[..., 0]).max(axis=-1) > 1e6
    out[bad] = np.nan
    return out


def pushed_line_fx(X, dt, push):
    """``line_fx`` with the velocity changed by ``push`` (per filter: ``(K, 1)`` in a fleet)."""
    out = line_fx(X, dt)
    out[..., 1] += push
    return out


class DuckArray:
    """An array-like that is not an ndarray, list or tuple (as a dask or xarray array): numpy reads it."""

    def __init__(self, a):
        self.a = np.asarray(a)

    def __array__(self, dtype=None, copy=None):
        return self.a if dtype is None else self.a.astype(dtype)

    def __len__(self):
        return len(self.a)

    def __iter__(self):  # over the first axis (filters), as an array's
        return iter(self.a)


def line_fleet(K, fx=line_fx, seed=0, per_filter_R=False):
    rng = np.random.default_rng(seed)
    f = Fleet(K, 2, 2, 0.1, line_hx, fx, MerweScaledWeights(0.5))
    f.x = rng.normal(size=(K, 2))
    f.P = np.diag([1.0, 0.5])
    f.Q = 0.01 * np.eye(2)
    if per_filter_R:
        f.R = np.stack([np.diag([0.1 + 0.01 * k, 0.2]) for k in range(K)])
    else:
        f.R = 0.1 * np.eye(2)
    return f


def line_measurements(K, T, seed=1):
    rng = np.random.default_rng(seed)
    zs = rng.normal(size=(K, T, 2)) + 1.5
    zs[3 % K, 5 % T] = np.nan  # a missing row
    zs[7 % K, 2 % T, 1] = np.nan  # a missing component
    return zs


# -- Lorenz-96 ---------------------------------------------------------------------------------


def l96_fx(x, dt, F=8.0):
    """Lorenz-96, one RK4 step (of a state ``(n,)`` or a stack of them ``(..., n)``)."""

    def f(v):
        return (np.roll(v, -1, axis=-1) - np.roll(v, 2, axis=-1)) * np.roll(v, 1, axis=-1) - v + F

    k1 = f(x)
    k2 = f(x + 0.5 * dt * k1)
    k3 = f(x + 0.5 * dt * k2)
    k4 = f(x + dt * k3)
    return x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


def l96_hx(x):
    """Every other component observed (of a state ``(n,)`` or a stack of them ``(..., n)``)."""
    return x[..., ::2].copy()


# -- heading models: state [px, py, heading, speed], the heading an angle --------------------


def heading_fx(x, dt=0.5):
    """Heading model, state [px, py, heading, speed]; the heading is an angle."""
    return np.array([x[0] + dt * np.cos(x[2]) * x[3], x[1] + dt * np.sin(x[2]) * x[3], x[2] + 0.3 * dt, x[3]])


def xy_radar_hx(x):
    """Range and bearing of [px, py] from the origin (the bearing is an angle)."""
    return np.array([np.hypot(x[0], x[1]), np.arctan2(x[1], x[0])])


def turn_fx_stacked(X, dt):
    """State [px, py, heading, speed]: the heading is an angle and keeps turning."""
    return np.stack(
        [
            X[..., 0] + dt * np.cos(X[..., 2]) * X[..., 3],
            X[..., 1] + dt * np.sin(X[..., 2]) * X[..., 3],
            X[..., 2] + 0.8 * dt,
            X[..., 3],
        ],
        axis=-1,
    )


def xy_radar_hx_stacked(X):
    """Range and bearing of [px, py] (the bearing near +-pi, where wrapping matters)."""
    return np.stack([np.hypot(X[..., 0], X[..., 1]), np.arctan2(X[..., 1], X[..., 0])], axis=-1)


def spinning_heading(seed, T=100):
    """A vehicle turning on the spot: heading crosses +/-pi many times; bearings measured.

    Returns the true states, the measurements and the noise levels q, r.
    """
    rng = np.random.default_rng(seed)
    q, r = 0.02, 0.05
    x = np.array([rng.uniform(-np.pi, np.pi), 0.8])
    truth, zs = [], []
    for _ in range(T):
        x = np.array([wrap(x[0] + x[1]), x[1]]) + rng.normal(0, [q, q * 0.1])
        x[0] = wrap(x[0])
        truth.append(x.copy())
        zs.append(np.array([wrap(x[0] + rng.normal(0, r))]))
    return truth, zs, q, r


def spinning_heading_filter(cls, points, x0):
    """A ``cls`` (SquareRootUKF or filterpy's UKF) for :func:`spinning_heading`, with angle hooks."""

    def fx(x, dt):
        return np.array([wrap(x[0] + x[1] * dt), x[1]])

    def hx(x):
        return np.array([x[0]])

    f = cls(
        2,
        1,
        1.0,
        hx,
        fx,
        points,
        x_mean_fn=AngleMean([0]),
        z_mean_fn=AngleMean([0]),
        residual_x=AngleResidual([0]),
        residual_z=AngleResidual([0]),
        **({"state_add": AngleAdd([0])} if cls is SquareRootUKF else {}),
    )
    f.x, f.P = x0, np.diag([0.1, 0.01])
    f.Q, f.R = np.diag([0.02**2, 0.002**2]), np.eye(1) * 0.05**2
    return f


# -- residual_x with wrapped deviations: P is filterpy's P_prior - K S K^T (issue 35, item 4) --------


def residual_wrap_first(a, b):
    """``a - b`` with component 0 wrapped into ``(-pi, pi]`` (the issue's ``residual_x``)."""
    d = np.subtract(a, b)
    d[0] = np.pi - (np.pi - d[0]) % (2 * np.pi)
    return d


def pair_fx(x, dt):
    """The issue's ``fx(x, dt) = x`` (any leading axes)."""
    return x


def pair_hx(x):
    """The issue's ``hx = x[1:]`` (any leading axes)."""
    return x[..., 1:]


def wrapped_pair_filter(cls, points, R=1.0):
    """The issue's reproducer (``R = [[1]]``): a residual_x wrapping ``x[0]``, whose spread passes pi.

    With ``R = 0.1`` filterpy's ``P_prior - K S K^T`` is indefinite (its smallest eigenvalue -0.033).
    """
    f = cls(2, 1, 1.0, pair_hx, pair_fx, points, residual_x=residual_wrap_first)
    f.x, f.P = np.zeros(2), np.array([[1.0, 0.5], [0.5, 1.0]])
    f.Q, f.R = np.diag([4.0, 1e-3]), np.array([[R]])
    return f


def wrapped_pair_fleet(K, points, R):
    """K filters of :func:`wrapped_pair_filter`, measurement noise ``R[k]`` each."""
    fleet = Fleet(K, 2, 1, 1.0, pair_hx, pair_fx, points, residual_x=residual_wrap_first)
    fleet.x, fleet.P = np.zeros((K, 2)), np.array([[1.0, 0.5], [0.5, 1.0]])
    fleet.Q, fleet.R = np.diag([4.0, 1e-3]), np.asarray(R, dtype=float).reshape(K, 1, 1)
    return fleet


# a wide heading: [heading, turn rate, speed]; its heading's sigma points pass pi (at one step to all six)
WIDE_X0 = np.array([3.0, 0.4, 2.0])
WIDE_P0 = np.array([[2.0, 0.5, 0.0], [0.5, 1.0, 0.1], [0.0, 0.1, 1.0]])
WIDE_Q = np.diag([2.5, 0.01, 0.05])
WIDE_R = np.diag([0.3, 0.3, 0.1])

#: Families on the wide heading, each with its filterpy points (``subtract``: how they add a deviation).
WIDE_FAMILIES = {
    "merwe": (
        lambda: MerweScaledWeights(1.0, 2.0, 0.0),
        lambda sub: MerweScaledSigmaPoints(3, 1.0, 2.0, 0.0, subtract=sub),
    ),
    "julier": (lambda: JulierWeights(kappa=1.0), lambda sub: JulierSigmaPoints(3, 1.0, subtract=sub)),
    "simplex": (lambda: SimplexWeights(), lambda sub: SimplexSigmaPoints(3, subtract=sub)),
    "filterpy-merwe": (
        lambda: MerweScaledSigmaPoints(3, 1.0, 2.0, 0.0),
        lambda sub: MerweScaledSigmaPoints(3, 1.0, 2.0, 0.0, subtract=sub),
    ),
    "filterpy-julier": (
        lambda: JulierSigmaPoints(3, 1.0),
        lambda sub: JulierSigmaPoints(3, 1.0, subtract=sub),
    ),
    "filterpy-simplex": (lambda: SimplexSigmaPoints(3), lambda sub: SimplexSigmaPoints(3, subtract=sub)),
}


def wide_fx(x, dt):
    """The heading advanced by the turn rate (wrapped); rate and speed held (any leading axes)."""
    return np.stack([wrap(x[..., 0] + x[..., 1] * dt), x[..., 1], x[..., 2]], axis=-1)


def wide_hx(x):
    """The velocity vector and the turn rate: periodic in the heading (any leading axes)."""
    return np.stack([x[..., 2] * np.cos(x[..., 0]), x[..., 2] * np.sin(x[..., 0]), x[..., 1]], axis=-1)


def wide_measurements(T, seed=0):
    """T measurements of a true wide-heading track, shape ``(T, 3)``."""
    rng = np.random.default_rng(seed)
    x, zs = WIDE_X0.copy(), []
    for _ in range(T):
        x = wide_fx(x, 1.0)
        zs.append(wide_hx(x) + rng.normal(0.0, np.sqrt(np.diag(WIDE_R))))
    return np.array(zs)


def wide_hooks(state_add=False):
    """The wide heading's hooks: circular mean, wrapping ``residual_x`` (and ``state_add``)."""
    hooks = {"x_mean_fn": AngleMean([0]), "residual_x": AngleResidual([0])}
    if state_add:
        hooks["state_add"] = AngleAdd([0])
    return hooks


def wide_heading_filter(cls, points, state_add=False, **kw):
    """A ``cls`` (SquareRootUKF or filterpy's UKF) for the wide heading, with :func:`wide_hooks`.

    For filterpy's UKF with ``state_add``, give points whose ``subtract`` wraps the heading (its
    points are ``subtract(x, -dx)``), as squkf draws them with ``state_add``.
    """
    f = cls(3, 3, 1.0, wide_hx, wide_fx, points, **wide_hooks(state_add), **kw)
    f.x, f.P, f.Q, f.R = WIDE_X0.copy(), WIDE_P0.copy(), WIDE_Q, WIDE_R
    return f


def wide_covariance_form_update(x_prior, P_prior, sigmas, H, Wm, Wc, z, state_add=False):
    """filterpy's update written out on any second set ``sigmas`` and its images ``H``, the wide
    heading's hooks: ``x`` and ``P_prior - K S K^T`` (the oracle of the schemes filterpy lacks)."""
    zp = Wm @ H
    dz = H - zp
    dx = np.array([AngleResidual([0])(s, x_prior) for s in sigmas])
    S = (dz.T * Wc) @ dz + WIDE_R
    K = np.linalg.solve(S, ((dx.T * Wc) @ dz).T).T
    x = (AngleAdd([0]) if state_add else np.add)(x_prior, K @ (z - zp))
    return x, P_prior - K @ S @ K.T


def wide_heading_fleet(K, points, state_add=False, scheme="redrawn"):
    """K wide headings (their starts ``WIDE_X0 + k [0.05, 0, 0.1]``) in a Fleet, and the K single
    filters (``vectorized``, as the fleet calls the model) that it must equal."""
    x0 = WIDE_X0 + np.arange(K)[:, None] * np.array([0.05, 0.0, 0.1])
    fleet = Fleet(K, 3, 3, 1.0, wide_hx, wide_fx, points, scheme=scheme, **wide_hooks(state_add))
    fleet.x, fleet.P, fleet.Q, fleet.R = x0, WIDE_P0, WIDE_Q, WIDE_R
    singles = []
    for k in range(K):
        f = wide_heading_filter(SquareRootUKF, points, state_add, scheme=scheme, vectorized=True)
        f.x = x0[k]
        singles.append(f)
    return fleet, singles


# -- plain arithmetic models (no transcendental function), for bit-for-bit comparisons -------------


def plain_fx(X, dt):
    """A nonlinear constant-velocity model in plain arithmetic (vectorised over leading axes)."""
    Y = np.array(X, dtype=float, copy=True)
    Y[..., 0] += dt * X[..., 1]
    Y[..., 2] += dt * X[..., 3]
    Y[..., 1] -= dt * 0.01 * X[..., 1] * np.abs(X[..., 1])
    return Y


def plain_hx(X):
    """Squared range and a cross term: nonlinear, no transcendental function."""
    return np.stack([X[..., 0] * X[..., 0] + X[..., 2] * X[..., 2], X[..., 0] * X[..., 2] * 1e-2], axis=-1)


def plain_scenario(K, T=6, seed=0):
    """K filters of the plain model: x0 (K, 4), P0 (K, 4, 4), Q, R (K, 2, 2), zs (T, K, 2), some NaN."""
    rng = np.random.default_rng(seed)
    x0 = np.array([30.0, 1.0, 20.0, -1.0]) + rng.normal(size=(K, 4))
    A = rng.normal(size=(K, 4, 4)) * 0.3
    P0 = A @ np.swapaxes(A, -1, -2) + np.eye(4)
    Q = np.eye(4) * 0.01 + np.diag(rng.uniform(0, 0.01, 4))
    R = np.stack([np.diag(rng.uniform(0.5, 2.0, 2)) for _ in range(K)])
    zs = plain_hx(x0[:, None, :])[:, 0] + rng.normal(size=(T, K, 2))
    zs[2 % T, ::3, 1] = np.nan  # missing components for a third of the filters at one step
    zs[(T - 1), 1::5] = np.nan  # and whole measurements missing for others
    return x0, P0, Q, R, zs


def plain_fleet(K, fx=plain_fx, chunk=None, seed=0):
    """A fleet of the plain model (Merwe points) at :func:`plain_scenario`'s start, and its zs (T, K, 2)."""
    x0, P0, Q, R, zs = plain_scenario(K, seed=seed)
    fleet = Fleet(K, 4, 2, 0.1, plain_hx, fx, MerweScaledWeights(1.0, 2.0, 0.0), chunk=chunk)
    fleet.x, fleet.P, fleet.Q, fleet.R = x0, P0, Q, R
    return fleet, zs


# -- linear models -------------------------------------------------------------------------------

# the precise sensor: position measured to 1e-6, almost no process noise (filterpy's UKF fails)
PRECISE_F = np.array([[1.0, 1.0], [0.0, 1.0]])
PRECISE_H = np.array([[1.0, 0.0]])
PRECISE_Q = np.eye(2) * 1e-14
PRECISE_R = np.eye(1) * 1e-12


def precise_fx(x, dt):
    return PRECISE_F @ x


def precise_hx(x):
    return x[:1]


def precise_fx_rows(X, dt):
    return X @ PRECISE_F.T


def precise_hx_rows(X):
    return X[:, :1]


def precise_filter(cls, P0):
    """A ``cls`` (SquareRootUKF or filterpy's UKF) on the precise sensor, P = P0 I."""
    ukf = cls(2, 1, 1.0, precise_hx, precise_fx, MerweScaledSigmaPoints(2, 0.1, 2.0, 0.0))
    ukf.x = np.array([0.0, 1.0])
    ukf.P = np.eye(2) * P0
    ukf.Q = PRECISE_Q
    ukf.R = PRECISE_R
    return ukf


# four states (constant velocity in two axes), three correlated measurements of which one mixes
LIN4_DT = 1.0
LIN4_F = np.array([[1.0, LIN4_DT, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, LIN4_DT], [0, 0, 0, 1.0]])
LIN4_H = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0], [0, 1.0, 0, 1.0]])
LIN4_Q = Q_discrete_white_noise(2, dt=LIN4_DT, var=0.2, block_size=2) + 1e-3 * np.eye(4)
LIN4_R = np.array([[1.0, 0.4, 0.1], [0.4, 2.0, -0.3], [0.1, -0.3, 0.5]])  # correlated
LIN4_X0 = np.array([0.0, 1.0, 5.0, -0.5])
LIN4_P0 = np.diag([10.0, 2.0, 10.0, 2.0])
LIN4_T = 8


def lin4_fx(x, dt):
    return LIN4_F @ x


def lin4_hx(x):
    return LIN4_H @ x


def lin4_ukf():
    f = SquareRootUKF(4, 3, LIN4_DT, lin4_hx, lin4_fx, MerweScaledWeights(alpha=1.0, beta=2.0, kappa=0.0))
    f.x, f.P, f.Q, f.R = LIN4_X0, LIN4_P0, LIN4_Q, LIN4_R
    return f


def lin4_kf():
    """filterpy's KalmanFilter on the same model."""
    kf = KalmanFilter(4, 3)
    kf.x, kf.P, kf.F, kf.H, kf.Q, kf.R = LIN4_X0.copy(), LIN4_P0.copy(), LIN4_F, LIN4_H, LIN4_Q, LIN4_R
    return kf


def lin4_measurements(seed=0):
    rng = np.random.default_rng(seed)
    x, out = LIN4_X0.copy(), []
    L = np.linalg.cholesky(LIN4_R)
    for _ in range(LIN4_T):
        x = LIN4_F @ x + rng.normal(0, 0.3, 4)
        out.append(LIN4_H @ x + L @ rng.normal(size=3))
    return out


# constant velocity on a line, its position measured: the smoother-input tests' model
LIN2_T = 12
LIN2_Q = np.array([[0.01, 0.002], [0.002, 0.02]])
LIN2_H = np.array([[1.0, 0.0]])


def lin2_F(dt):
    return np.array([[1.0, dt], [0.0, 1.0]])


def lin2_fx(x, dt, bad=False):
    """``bad``: NaN images."""
    return np.full(2, np.nan) if bad else lin2_F(dt) @ x


def lin2_filter(fx=lin2_fx):
    f = SquareRootUKF(2, 1, 1.0, lambda x: LIN2_H @ x, fx, MerweScaledWeights(0.5, 2.0, 0.0))
    f.x, f.P, f.Q, f.R = np.array([0.0, 1.0]), np.eye(2) * 4.0, LIN2_Q, 0.5
    return f


# constant velocity on a line with a drift, the position and the sine of the velocity measured
DRIFT_Q = np.array([[0.02, 0.01], [0.01, 0.05]])
DRIFT_R = np.array([[0.5, 0.1], [0.1, 0.3]])


def drift_fx(x, dt, drift=0.0):
    return np.array([x[0] + dt * x[1], x[1] + drift])


def sine_hx(x, scale=1.0, flat=False):
    """``flat``: a constant measurement."""
    if flat:
        return np.zeros(2)
    return np.array([x[0], scale * np.sin(x[1])])


def drift_filter(fx=drift_fx, hx=sine_hx):
    f = SquareRootUKF(2, 2, 1.0, hx, fx, MerweScaledWeights(0.5, 2.0, 0.0))
    f.x, f.P, f.Q, f.R = np.array([0.0, 1.0]), np.eye(2), DRIFT_Q, DRIFT_R
    return f


def drift_measurements(T, seed=0, missing=()):
    """T measurements, ``None`` at the steps ``missing``."""
    rng = np.random.default_rng(seed)
    zs = [np.array([k + rng.normal(), np.sin(1.0) + 0.3 * rng.normal()]) for k in range(T)]
    return [None if k in missing else z for k, z in enumerate(zs)]


def random_linear_model(seed=0, n=4, m=2):
    """F, H, Q, R of a random well-conditioned linear-Gaussian model."""
    rng = np.random.default_rng(seed)
    F = np.eye(n) + 0.1 * rng.standard_normal((n, n))
    H = rng.standard_normal((m, n))
    A = rng.standard_normal((n, n))
    Q = 0.01 * (A @ A.T) + 0.001 * np.eye(n)
    B = rng.standard_normal((m, m))
    R = 0.5 * (B @ B.T) + 0.1 * np.eye(m)
    return F, H, Q, R


def linear_pair(n=3, m=2, alpha=1.0, x0=None, seed=3):
    """filterpy's KalmanFilter and a SquareRootUKF on one random linear model, and the rng after it."""
    rng = np.random.default_rng(seed)
    F = np.eye(n) + 0.05 * rng.standard_normal((n, n))
    H = rng.standard_normal((m, n))
    Q, R = 0.01 * np.eye(n), 0.2 * np.eye(m)
    x0 = np.ones(n) if x0 is None else x0
    kf = KalmanFilter(n, m)
    kf.F, kf.H, kf.Q, kf.R, kf.P, kf.x = F, H, Q, R, np.eye(n) * 2.0, x0.copy()
    ukf = SquareRootUKF(n, m, 1.0, lambda x: H @ x, lambda x, dt: F @ x, MerweScaledWeights(alpha, 2.0, 0.0))
    ukf.x, ukf.P, ukf.Q, ukf.R = x0.copy(), np.eye(n) * 2.0, Q, R
    return kf, ukf, rng


def spd(rng, n, log10_cond):
    """A random symmetric positive-definite matrix with the given condition number."""
    U, _ = np.linalg.qr(rng.standard_normal((n, n)))
    w = np.logspace(0, -log10_cond, n) if n > 1 else np.ones(1)
    return (U * w) @ U.T


def lower_factors(rng, shape, n, log10_cond=2.0):
    """``shape`` random lower factors ``(*shape, n, n)`` of covariances of condition up to ``10**log10_cond``,
    scaled by up to 10 either way, each column's sign drawn at random (any lower factor, not only
    Cholesky's)."""
    size = int(np.prod(shape, dtype=int))
    P = [spd(rng, n, rng.uniform(0, log10_cond)) * 10.0 ** rng.uniform(-1, 1) for _ in range(size)]
    S = np.linalg.cholesky(np.array(P).reshape(size, n, n)) * rng.choice([-1.0, 1.0], (size, 1, n))
    return S.reshape(tuple(shape) + (n, n))


KF_RTOL = 1e-9


def run_against_kf(points, scheme, seed=0, steps=100, n=4, m=2, vectorized=False):
    F, H, Q, R = random_linear_model(seed, n, m)
    rng = np.random.default_rng(seed + 100)
    kf = KalmanFilter(n, m)
    kf.F, kf.H, kf.Q, kf.R = F, H, Q, R
    kf.P = np.eye(n) * 2.0
    kf.x = np.ones(n)
    if vectorized:
        ukf = SquareRootUKF(
            n, m, 1.0, lambda X: X @ H.T, lambda X, dt: X @ F.T, points, scheme=scheme, vectorized=True
        )
    else:
        ukf = SquareRootUKF(n, m, 1.0, lambda x: H @ x, lambda x, dt: F @ x, points, scheme=scheme)
    ukf.x = np.ones(n)
    ukf.P = kf.P
    ukf.Q, ukf.R = Q, R
    worst = 0.0
    for k in range(steps):
        z = rng.standard_normal(m) * 2.0
        kf.predict()
        ukf.predict()
        kf.update(z)
        ukf.update(z)
        for a, b in ((ukf.x, kf.x), (ukf.P, kf.P)):
            worst = max(worst, np.max(np.abs(a - b)) / np.max(np.abs(b)))
        assert worst < KF_RTOL, (k, worst)
    return worst


# -- small filters -------------------------------------------------------------------------------


def first_of(x):
    """The first component (a measurement of a state of any size)."""
    return x[:1]


def identity_fx(x, dt):
    return x


def identity_filter(points, dim_x=2):
    """A SquareRootUKF whose model does nothing, to check what ``points`` accepts."""
    return SquareRootUKF(dim_x, 1, 1.0, first_of, identity_fx, points)


def decay_fx(x, dt):
    return 0.9 * x


def half_hx(x):
    return 0.5 * x


def decay_filter(n, fx=None, hx=None):
    """An n-state filter (x decays by 0.9 a step unless ``fx``), its first two components measured."""
    fx = fx or (lambda x, dt: 0.9 * x)
    hx = hx or (lambda x: x[:2])
    f = SquareRootUKF(n, 2, 1.0, hx, fx, MerweScaledWeights(0.5, 2.0, 0.0))
    f.Q = np.eye(n) * 0.01
    return f


def one_d(cls):
    """A one-state filter: x decays by 0.9 a step and is measured times 0.5."""
    return cls(1, 1, 1.0, half_hx, decay_fx, MerweScaledWeights(alpha=0.5))


def one_d_filterpy():
    """:func:`one_d` in filterpy."""
    return UnscentedKalmanFilter(1, 1, 1.0, half_hx, decay_fx, MerweScaledSigmaPoints(1, 0.5, 2.0, 0.0))


def one_d_measured():
    """A one-state filter measured as it is, at x = 1, P = 2."""
    f = SquareRootUKF(1, 1, 1.0, lambda x: x, lambda x, dt: 0.9 * x, MerweScaledWeights())
    f.x, f.P = np.array([1.0]), np.array([[2.0]])
    return f


def polar(v):
    """Polar to Cartesian, one point ``[r, theta]``."""
    return np.array([v[0] * np.cos(v[1]), v[0] * np.sin(v[1])])


def polar_rows(V):
    """:func:`polar` of each row."""
    return np.c_[V[:, 0] * np.cos(V[:, 1]), V[:, 0] * np.sin(V[:, 1])]


def line_cv_fx(x, dt):
    return np.array([x[0] + dt * x[1], x[1]])


def line_cv_template(vectorized=False):
    if vectorized:
        fx = lambda X, dt: np.stack([X[..., 0] + dt * X[..., 1], X[..., 1]], axis=-1)  # noqa: E731
        hx = lambda X: X[..., :1]  # noqa: E731
    else:
        fx, hx = line_cv_fx, (lambda x: x[:1])
    f = SquareRootUKF(2, 1, 1.0, hx, fx, MerweScaledWeights(), vectorized=vectorized)
    f.x, f.P = np.array([1.0, 0.5]), np.diag([4.0, 1.0])
    f.Q = Q_discrete_white_noise(2, 1.0, 0.5)
    f.R = [[4.0]]
    return f


# -- checks --------------------------------------------------------------------------------------


def rel(a, b):
    """The normwise relative difference of ``a`` from ``b`` (``b`` all zero: divided by 1e-300)."""
    return np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300)


def rel_unfloored(a, b):
    """:func:`rel` without the floor (``b`` all zero: inf or nan, a failed comparison)."""
    return np.max(np.abs(a - b)) / np.max(np.abs(b))


def assert_results_equal(a, b):
    """Two tuples of arrays (batch or smoother results) are equal, shapes and all."""
    assert len(a) == len(b)
    for u, v in zip(a, b):
        assert u.shape == v.shape
        np.testing.assert_array_equal(u, v)


def counting(fn):
    """``fn`` wrapped to count its calls, and the list the calls are counted in."""
    calls = []

    def wrapped(*args, **kwargs):
        calls.append(1)
        return fn(*args, **kwargs)

    return wrapped, calls


def counted_table(base) -> tuple:
    """A kernel table whose entries are ``base``'s, each naming itself, in order, in the list returned with
    it when called (a second table, as another backend gives)."""
    from squkf.kernels import table

    calls: list[str] = []

    def counted(name, kernel):
        def call(*args):
            calls.append(name)
            return kernel(*args)

        return call

    return table.KernelTable(*(counted(n, k) for n, k in zip(base._fields, base))), calls


def counting_kernels(monkeypatch) -> list:
    """The installed kernel table replaced by a :func:`counted_table` of it (filters built after this call
    take it): the list of its calls."""
    from squkf.kernels import table

    counting, calls = counted_table(table.KERNELS)
    monkeypatch.setattr(table, "KERNELS", counting)
    return calls


FILTERPY_RTOL = 1e-8


def run_pair(points, fx, hx, dim_x, dim_z, dt, x0, P0, Q, R, truth_fn, steps, seed, fx_args=None):
    rng = np.random.default_rng(seed)
    fp = UnscentedKalmanFilter(dim_x, dim_z, dt, hx, fx, points)
    sq = SquareRootUKF(dim_x, dim_z, dt, hx, fx, points)
    for f in (fp, sq):
        f.x = x0.copy()
        f.P = P0
        f.Q = Q
        f.R = R
    xt = truth_fn.x0.copy()
    worst = 0.0
    for _ in range(steps):
        xt = truth_fn.step(xt, rng)
        z = hx(xt) + rng.multivariate_normal(np.zeros(dim_z), R)
        for f in (fp, sq):
            f.predict(**(fx_args or {}))
        worst = max(worst, rel(sq.x_prior, fp.x_prior), rel(sq.P_prior, fp.P_prior))
        for f in (fp, sq):
            f.update(z)
        worst = max(worst, rel(sq.x, fp.x), rel(sq.P, fp.P))
        assert worst < FILTERPY_RTOL
    return worst


def assert_same_filter(f, g, z=(1.0, 0.5)):
    """``f`` and ``g`` hold the same state and take the same next step."""
    for name in ("x", "P1_2", "x_prior", "P1_2_prior", "x_post", "P1_2_post", "y", "S1_2", "z"):
        np.testing.assert_array_equal(getattr(f, name), getattr(g, name), err_msg=name)
    assert f.log_likelihood == g.log_likelihood or (np.isnan(f.log_likelihood) and np.isnan(g.log_likelihood))
    for h in (f, g):
        h.predict()
        h.update(np.array(z))
    np.testing.assert_array_equal(f.x, g.x)
    np.testing.assert_array_equal(f.P1_2, g.P1_2)


# -- the radar with wild returns (the gating tests) --------------------------------------------------


RADAR_DT = 1.0
RADAR_R_RANGE, RADAR_R_BEARING = 0.5, 0.01


def radar_track(T: int, seed: int, wild: float = 0.1):
    """A target's true states and its radar returns, a fraction ``wild`` of them far off."""
    rng = np.random.default_rng(seed)
    x = np.array([50.0, 1.0, 40.0, -0.5])
    truth, zs = [], []
    for _ in range(T):
        x = cv_fx_stacked(x, RADAR_DT) + rng.normal(scale=[0.05, 0.05, 0.05, 0.05])
        z = range_bearing_hx(x) + rng.normal(scale=[math.sqrt(RADAR_R_RANGE), math.sqrt(RADAR_R_BEARING)])
        if rng.random() < wild:
            z = z + rng.choice([-1.0, 1.0], 2) * np.array([15.0, 0.4])
        truth.append(x)
        zs.append(z)
    return np.array(truth), np.array(zs)


def radar_configure(f):
    """The radar track's prior and noise, set on a filter or a fleet (returned)."""
    f.x = np.array([50.0, 1.0, 40.0, -0.5])
    f.P = np.diag([4.0, 1.0, 4.0, 1.0])
    f.Q = np.eye(4) * 0.0025
    f.R = np.diag([RADAR_R_RANGE, RADAR_R_BEARING])
    return f


def radar_gated_filter(front: str):
    """The radar with a per-component gate, as a filter or a fleet of 2."""
    gate = Gate(0.99, per_component=True)
    if front == "fleet":
        return radar_configure(
            Fleet(2, 4, 2, RADAR_DT, range_bearing_hx, cv_fx_stacked, MerweScaledWeights(), gate=gate)
        )
    return radar_configure(
        SquareRootUKF(
            4, 2, RADAR_DT, range_bearing_hx, cv_fx_stacked, MerweScaledWeights(), vectorized=True, gate=gate
        )
    )


def radar_filterpy():
    pts = MerweScaledSigmaPoints(4, alpha=0.5, beta=2.0, kappa=0.0)
    return radar_configure(UnscentedKalmanFilter(4, 2, RADAR_DT, range_bearing_hx, cv_fx_stacked, pts))


def radar_squkf(gate, **kw):
    pts = MerweScaledSigmaPoints(4, alpha=0.5, beta=2.0, kappa=0.0)
    return radar_configure(
        SquareRootUKF(4, 2, RADAR_DT, range_bearing_hx, cv_fx_stacked, pts, gate=gate, **kw)
    )


def radar_fleet(K, gate, per_filter_R=False):
    fleet = radar_configure(
        Fleet(K, 4, 2, RADAR_DT, range_bearing_hx, cv_fx_stacked, MerweScaledWeights(alpha=0.5), gate=gate)
    )
    if per_filter_R:
        fleet.R = np.stack([np.diag([RADAR_R_RANGE, RADAR_R_BEARING]) * (1 + 0.1 * k) for k in range(K)])
    return fleet


# -- noise entering the model (fx_noise, hx_noise) ---------------------------------------------------


PEND_DT = 0.1
PEND_G = 9.81


def pendulum_fx(x, w, dt):
    """A pendulum driven by a gust ``w`` (a torque through cos(theta): non-additive), stacked points."""
    th, om = x[..., 0], x[..., 1]
    om_new = om - PEND_G * np.sin(th) * dt + np.cos(th) * w[..., 0] * dt
    return np.stack([th + om * dt + 0.5 * w[..., 1] * dt * dt, om_new], axis=-1)


def pendulum_hx(x, v):
    """Horizontal position of the bob with a multiplicative error ``(1 + v0)`` and an offset ``v1``."""
    return (np.sin(x[..., 0]) * (1.0 + v[..., 0]) + v[..., 1])[..., None]


PEND_QW = np.diag([0.25, 0.04])
PEND_RV = np.diag([0.0025, 0.0004])


def pendulum_simulate(T, seed):
    """A pendulum's measurements with gusts and a multiplicative sensor error, shape (T, 1)."""
    rng = np.random.default_rng(seed)
    x = np.array([0.6, 0.0])
    zs = []
    for _ in range(T):
        x = pendulum_fx(x, rng.normal(size=2) * [0.5, 0.2], PEND_DT)
        zs.append(pendulum_hx(x, rng.normal(size=2) * [0.05, 0.02]))
    return np.array(zs)


def noise_linear_model(dw, dv):
    """A linear model, noise entering through G (process) and D (sensor): F, G, H, D."""
    F = np.array([[1.0, PEND_DT, 0.5 * PEND_DT * PEND_DT], [0.0, 1.0, PEND_DT], [0.0, 0.0, 0.9]])
    G = np.array([[0.0, 0.1], [0.3, 0.0], [1.0, 0.2]])[:, :dw]
    H = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    D = np.array([[1.0, 0.5, 0.0], [0.0, 1.0, 2.0]])[:, :dv]
    return F, G, H, D


def polar_turn_fx(x, dt):
    """A nonlinear model (coordinated turn in polar form) with additive noise; stacked points."""
    r, th, v, w = x[..., 0], x[..., 1], x[..., 2], x[..., 3]
    return np.stack([r + v * np.cos(w) * dt, th + v * np.sin(w) * dt / np.maximum(r, 1e-3), v, w], axis=-1)


def polar_range_hx(x):
    """Range and sin(bearing) of a polar state [r, theta, ...]; stacked points."""
    return np.stack([x[..., 0], np.sin(x[..., 1])], axis=-1)


def pendulum_fx_calm(x, dt):
    """:func:`pendulum_fx` with no gust: additive process noise (the form without ``fx_noise``)."""
    return pendulum_fx(x, np.zeros(np.shape(x)[:-1] + (2,)), dt)


def pendulum_hx_plain(x):
    """Horizontal position of the bob, additive sensor noise (the form without ``hx_noise``)."""
    return np.sin(x[..., :1])


def pendulum_hx_offset(x, v):
    """Horizontal position of the bob plus an offset ``v`` of dimension 1 (``hx_noise=1``)."""
    return np.sin(x[..., :1]) + v[..., :1]


def pendulum_noise_filter(points, fx_noise=None, hx_noise=None, cls=SquareRootUKF, **kw):
    """The pendulum with noise entering ``fx`` (``fx_noise`` 2 or None), ``hx`` (``hx_noise`` 1, 2 or None).

    ``cls`` SquareRootUKF (vectorised) or Fleet (three filters); ``Q``, ``R`` of the noise's dimension.
    """
    fx = pendulum_fx if fx_noise else pendulum_fx_calm
    hx = {None: pendulum_hx_plain, 1: pendulum_hx_offset, 2: pendulum_hx}[hx_noise]
    if cls is SquareRootUKF:
        f = cls(2, 1, PEND_DT, hx, fx, points, vectorized=True, fx_noise=fx_noise, hx_noise=hx_noise, **kw)
    else:
        f = cls(3, 2, 1, PEND_DT, hx, fx, points, fx_noise=fx_noise, hx_noise=hx_noise, **kw)
    f.x, f.P = np.array([0.5, 0.1]), np.diag([0.04, 0.25])
    f.Q = PEND_QW if fx_noise else np.diag([1e-4, 4e-3])
    f.R = {None: np.eye(1) * 0.0025, 1: np.eye(1) * 0.0004, 2: PEND_RV}[hx_noise]
    return f


class OddPoints:
    """A filterpy-style points object of no known kind, built for n = 2."""

    n = 2
    Wm = np.array([0.5, 0.25, 0.25])
    Wc = Wm

    def num_sigmas(self):
        return 3

    def sigma_points(self, x, P):
        return np.vstack([x, x + 1.0, x - 1.0])


def pendulum_filter(points, **kw):
    f = SquareRootUKF(
        2, 1, PEND_DT, pendulum_hx, pendulum_fx, points, vectorized=True, fx_noise=2, hx_noise=2, **kw
    )
    f.x, f.P, f.Q, f.R = np.array([0.5, 0.1]), np.diag([0.04, 0.25]), PEND_QW, PEND_RV
    return f


def range_noise_filter(points):
    def fx(x, dt):
        return np.array([x[0] + dt * x[1], x[1]])

    def hx(x, v):
        return np.array([np.hypot(x[0], 2.0) + v[0]])

    f = SquareRootUKF(2, 1, 1.0, hx, fx, points, hx_noise=1)
    f.x, f.P, f.Q, f.R = np.array([1.0, 0.5]), np.eye(2), 0.01 * np.eye(2), 0.1
    return f


# -- a posterior that loses rank to rounding ---------------------------------------------------------


def tanh_filter():
    """Q of 8e256 everywhere: the prior's small directions fall below rounding."""
    f = SquareRootUKF(3, 2, 1.0, lambda x: np.tanh(x[:2]), lambda x, dt: x + dt, MerweScaledWeights())
    f.x, f.P, f.Q, f.R = np.ones(3), np.eye(3), np.full((3, 3), 8.071510225007634e256), np.eye(2)
    return f


# -- model values of a near shape, and model functions that raise (issue 29) ------------------------


# what a per-point model function may return for its value v of shape (d,), as filterpy's
# ``sigmas_f[i] = fx(...)`` takes it (a column (d, 1) is squkf's own)
NEAR_SHAPES = {
    "row": lambda v: v,
    "(1, d)": lambda v: v[None],
    "(1, 1, d)": lambda v: v[None, None],
    "column": lambda v: v[:, None],
    "list": lambda v: v.tolist(),
    "tuple": lambda v: tuple(v),
}
# the value's first number alone: its value for d = 1; for d > 1 numpy would broadcast it into the
# row, and squkf refuses it
ONE_NUMBER_SHAPES = {
    "number": lambda v: float(v[0]),
    "0-d array": lambda v: np.asarray(v[0]),
    "(1,)": lambda v: v[:1],
}


def near_shaped(fn, forms):
    """``fn`` (one point) whose k-th call returns its value in the form ``forms[k % len(forms)]``.

    A form is a key of :data:`NEAR_SHAPES` or :data:`ONE_NUMBER_SHAPES`.
    """
    calls = [0]

    def shaped(*args, **kwargs):
        form = forms[calls[0] % len(forms)]
        calls[0] += 1
        shape = NEAR_SHAPES[form] if form in NEAR_SHAPES else ONE_NUMBER_SHAPES[form]
        return shape(np.asarray(fn(*args, **kwargs), dtype=float))

    return shaped


def gp_ukf_fx(x, dt):
    """A GP-UKF program's fx: the turn model plus a learned residual, shape (1, 5) by ``np.array([x])``."""
    return np.add(np.array([ct_fx(x, dt)]), 1e-3 * np.tanh(x))


def gp_ukf_fx_row(x, dt):
    """:func:`gp_ukf_fx` as a row (5,)."""
    return gp_ukf_fx(x, dt)[0]


def raising(exc):
    """A model function of any arguments that raises ``exc`` (that very object)."""

    def fn(*args, **kwargs):
        raise exc

    return fn


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
    "rejected",
    "nis",
)


def phase_of(f) -> str:
    """The phase of a filter's or a fleet's pending ask/tell step (its engine's)."""
    return f._engine.phase


def filter_state(f) -> dict:
    """Copies of everything a failed call must leave unchanged."""
    snap = {k: np.array(getattr(f, k), copy=True) for k in FILTER_STATE}
    snap["phase"] = phase_of(f)
    snap["log_likelihood"] = f.log_likelihood
    return snap


def assert_filter_state(f, snap: dict) -> None:
    """The filter is bit for bit as in ``snap``."""
    for k in FILTER_STATE:
        np.testing.assert_array_equal(np.asarray(getattr(f, k)), snap[k], err_msg=k)
    assert phase_of(f) == snap["phase"]
    assert f.log_likelihood == snap["log_likelihood"]


FLEET_STATE = (
    "x",
    "P1_2",
    "Q1_2",
    "R1_2",
    "x_prior",
    "x_post",
    "P1_2_prior",
    "P1_2_post",
    "y",
    "log_likelihood",
    "mahalanobis",
    "nis",
    "rejected",
    "failed",
    "failure",
)


def fleet_state(fleet) -> dict:
    """Copies of everything a failed call must leave unchanged."""
    snap = {a: np.array(getattr(fleet, a), copy=True) for a in FLEET_STATE}
    snap["failure list"] = list(fleet.failure)
    snap["phase"] = phase_of(fleet)
    return snap


def assert_fleet_state(fleet, snap: dict) -> None:
    """The fleet is bit for bit as in ``snap``."""
    for a in FLEET_STATE:
        np.testing.assert_array_equal(np.asarray(getattr(fleet, a)), snap[a], err_msg=a)
    assert list(fleet.failure) == snap["failure list"]
    assert phase_of(fleet) == snap["phase"]


# -- a [range, bearing, heading] sensor: hooks that index a fixed component of z ------------------

RBH_X0 = np.array([-100.0, 0.4, 0.1, 2.0])  # bearing near +pi: the sigma points' bearings wrap
RBH_P0 = np.diag([4.0, 4.0, 0.01, 0.25])
RBH_Q = np.diag([0.1, 0.1, 1e-4, 0.01])
RBH_R = np.diag([0.25, 0.003**2 * 100, 0.02**2])


def range_bearing_heading_hx(X):
    """Range and bearing of [px, py] (an angle, near +-pi here) and the heading, for ``X[..., i]``."""
    return np.stack([np.hypot(X[..., 0], X[..., 1]), np.arctan2(X[..., 1], X[..., 0]), X[..., 2]], axis=-1)


def bearing_heading_hx(X):
    """:func:`range_bearing_heading_hx` without the range: the oracle of a missing range."""
    return range_bearing_heading_hx(X)[..., 1:]


def rbh_filter(gate=None, m: int = 3, vectorized: bool = False):
    """A filter of the [range, bearing, heading] sensor (``m = 2``: without the range, the bearing first)."""
    hx = range_bearing_heading_hx if m == 3 else bearing_heading_hx
    b = 1 if m == 3 else 0  # the bearing's index in z
    f = SquareRootUKF(
        4, m, 1.0, hx, turn_fx_stacked, MerweScaledWeights(alpha=0.5),
        z_mean_fn=AngleMean([b]), residual_z=AngleResidual([b]), gate=gate, vectorized=vectorized,
    )  # fmt: skip
    f.x, f.P, f.Q = RBH_X0, RBH_P0, RBH_Q
    f.R = RBH_R if m == 3 else RBH_R[1:, 1:]
    return f


class SubclassedMean(AngleMean):
    """squkf's AngleMean as a user's hook (a subclass): called in Python, the oracle of the kernels' route."""


class SubclassedResidual(AngleResidual):
    """squkf's AngleResidual as a user's hook (a subclass): called in Python."""


class SubclassedAdd(AngleAdd):
    """squkf's AngleAdd as a user's hook (a subclass): called in Python."""


#: The heading predicted near +pi at the first step and every eighth (its points pass pi): the state's
#: angle hooks matter.
RBH_TURNING_X0 = np.array([-100.0, 0.4, np.pi - 0.82, 2.0])
RBH_TURNING_P0 = np.diag([4.0, 4.0, 0.04, 0.25])


def rbh_state_hooks(python: bool = False) -> dict:
    """The heading's hooks on the state (x[2]) and the bearing's and heading's on z (z[1], z[2]): every
    hook squkf has; subclasses (called in Python) if ``python``."""
    if python:
        mean, residual, add = SubclassedMean, SubclassedResidual, SubclassedAdd
    else:
        mean, residual, add = AngleMean, AngleResidual, AngleAdd
    return {
        "x_mean_fn": mean([2]), "residual_x": residual([2]), "state_add": add([2]),
        "z_mean_fn": mean([1, 2]), "residual_z": residual([1, 2]),
    }  # fmt: skip


def rbh_turning(hooks: dict, points=None, **kw) -> SquareRootUKF:
    """:func:`rbh_single` with the heading near +pi (:data:`RBH_TURNING_X0`)."""
    f = rbh_single(hooks, points, **kw)
    f.x, f.P = RBH_TURNING_X0, RBH_TURNING_P0
    return f


def rbh_turning_measurements(T: int, seed: int = 0) -> np.ndarray:
    """``(T, 3)`` noisy measurements of the track from :data:`RBH_TURNING_X0` (its heading wraps), a
    range missing at step 2 and nothing at step 3."""
    rng = np.random.default_rng(seed)
    x, zs = RBH_TURNING_X0, []
    for _ in range(T):
        x = turn_fx_stacked(x, 1.0)
        z = range_bearing_heading_hx(x) + rng.normal(size=3) * np.sqrt(np.diag(RBH_R))
        z[1:] = wrap(z[1:])  # (the angles as a sensor reports them; not the range)
        zs.append(z)
    zs = np.array(zs)
    zs[2 % T, 0] = np.nan
    zs[3 % T] = np.nan
    return zs


def rbh_hooks(which: str = "both", python: bool = False) -> dict:
    """The bearing's hooks (z[1]): ``"residual"``, ``"mean"`` or ``"both"``; subclasses if ``python``."""
    mean, residual = (SubclassedMean, SubclassedResidual) if python else (AngleMean, AngleResidual)
    hooks = {}
    if which in ("residual", "both"):
        hooks["residual_z"] = residual([1])
    if which in ("mean", "both"):
        hooks["z_mean_fn"] = mean([1])
    return hooks


def rbh_single(hooks: dict, points=None, **kw) -> SquareRootUKF:
    """One vectorised filter of the [range, bearing, heading] sensor with ``hooks``, at ``RBH_X0``."""
    f = SquareRootUKF(
        4, 3, 1.0, range_bearing_heading_hx, turn_fx_stacked, points or MerweScaledWeights(alpha=0.5),
        vectorized=True, **hooks, **kw,
    )  # fmt: skip
    f.x, f.P, f.Q, f.R = RBH_X0, RBH_P0, RBH_Q, RBH_R
    return f


def rbh_starts(K: int) -> np.ndarray:
    """K starts about ``RBH_X0`` (their bearings either side of pi), ``(K, 4)``."""
    return RBH_X0 + np.outer(np.arange(K) - K // 2, [0.0, 1.5, 0.02, 0.05])


def rbh_fleet_and_singles(K: int, hooks: dict, points=None, **kw):
    """A Fleet of K [range, bearing, heading] filters from :func:`rbh_starts`, and the K single filters."""
    make = points or (lambda: MerweScaledWeights(alpha=0.5))
    fleet = Fleet(K, 4, 3, 1.0, range_bearing_heading_hx, turn_fx_stacked, make(), **hooks, **kw)
    x0 = rbh_starts(K)
    fleet.x, fleet.P, fleet.Q, fleet.R = x0, RBH_P0, RBH_Q, RBH_R
    singles = []
    for k in range(K):
        f = rbh_single(hooks, make(), **{a: v for a, v in kw.items() if a in ("gate", "scheme")})
        f.x = x0[k]
        singles.append(f)
    return fleet, singles


def rbh_measurements(K: int, T: int, seed: int = 0) -> np.ndarray:
    """``(K, T, 3)`` noisy measurements of the K tracks from :func:`rbh_starts`, some missing."""
    rng = np.random.default_rng(seed)
    x, zs = rbh_starts(K), []
    for _ in range(T):
        x = turn_fx_stacked(x, 1.0)
        z = range_bearing_heading_hx(x) + rng.normal(size=(K, 3)) * np.sqrt(np.diag(RBH_R))
        z[:, 1:] = wrap(z[:, 1:])  # (the bearing and heading as a sensor reports them; not the range)
        zs.append(z)
    zs = np.stack(zs, axis=1)
    zs[0, 2 % T, 0] = np.nan  # a missing range
    zs[K - 1, 1 % T, 1] = np.nan  # a missing bearing
    zs[K // 2, 3 % T] = np.nan  # no measurement
    return zs


# -- tuning and consistency (issue 37): the 2-D constant-velocity model, where the UKF is the Kalman filter

TUNE_Q0 = Q_discrete_white_noise(2, 1.0, 1.0, block_size=2)
TUNE_TRUE = {"q": 0.1, "r1": 1.0, "r2": 4.0}


def tune_cv_fx(X, dt):
    """Constant velocity in two axes, state [px, vx, py, vy], stacked points ``(..., 4)``."""
    F = np.kron(np.eye(2), np.array([[1.0, 1.0 if dt is None else dt], [0.0, 1.0]]))
    return X @ F.T


def tune_cv_hx(X):
    """Both positions."""
    return X[..., ::2]


def tune_cv_filter(q=TUNE_TRUE["q"], r1=TUNE_TRUE["r1"], r2=TUNE_TRUE["r2"], **kw):
    """The 2-D constant-velocity filter (vectorised), x0 and P0 known, ``Q = q Q0``, ``R = diag(r1, r2)``."""
    f = SquareRootUKF(4, 2, 1.0, tune_cv_hx, tune_cv_fx, MerweScaledWeights(), vectorized=True, **kw)
    f.x, f.P = np.array([0.0, 1.0, 0.0, 1.0]), np.eye(4)
    f.Q, f.R = q * TUNE_Q0, np.diag([r1, r2])
    return f
