"""The g13ej example program, written with :mod:`squkf.nag`.

A two-wheeled robot moves past a wall; it measures its distance and angle to
the wall. Run ``python -m squkf.examples.g13ej_example`` to print the same
results table NAG publishes for its routine g13ej, with a last line comparing
it with NAG's.

The state is ``(xi, eta, theta)``: the robot's x and y position and its
heading, the angle (radians) from the x-axis in which it faces.

The inputs (and NAG's published output, and the simulated true trajectory)
are in ``g13ej_example.json`` beside this file.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from squkf.nag import kalman_unscented_state_revcom

DATA_FILE = Path(__file__).with_name("g13ej_example.json")

#: Names of the state components (x position, y position, heading), as in NAG's documents.
STATE_NAMES = ("ξ", "η", "θ")
#: The same names spelled in ASCII, for an output that cannot encode Greek letters.
ASCII_STATE_NAMES = ("xi", "eta", "theta")


def load_data() -> dict:
    """The example's inputs, NAG's published results and the true trajectory."""
    return json.loads(DATA_FILE.read_text())


def f(xt: np.ndarray, r: float, d: float, phi_r: float, phi_l: float) -> np.ndarray:
    """State transition of every column of ``xt`` (shape (3, n)), as in the documents."""
    t1 = 0.5 * r * (phi_r + phi_l)
    t3 = (r / d) * (phi_r - phi_l)
    return np.vstack([xt[0] + np.cos(xt[2]) * t1, xt[1] + np.sin(xt[2]) * t1, xt[2] + t3])


def h(yt: np.ndarray, delta: float, a: float) -> np.ndarray:
    """Distance and angle to the wall for every column of ``yt`` (shape (3, n)) -> (2, n)."""
    angle = yt[2] - a
    # the angle is kept in the same range as the observations, [0, 2 pi)
    angle = np.where(angle < 0, angle + 2 * np.pi, angle)
    return np.vstack([delta - yt[0] * np.cos(a) - yt[1] * np.sin(a), angle])


def run(data: dict | None = None, ropt=None) -> tuple[np.ndarray, np.ndarray]:
    """Run the example.

    Parameters
    ----------
    data : dict, optional
        As returned by :func:`load_data` (the default).
    ropt : sequence of float, optional
        g13ej's options (e.g. ``[2]`` for the augmented second set).

    Returns
    -------
    states : ndarray, shape (ntime, 3)
        The state estimate after each time point.
    st : ndarray, shape (3, 3)
        Lower factor of the state covariance at the last time point.
    """
    data = load_data() if data is None else data
    m = data["model"]
    lx = np.array(data["lx"])
    ly = np.array(data["ly"])
    x = np.array(data["x0"], dtype=float)
    st = np.array(data["st0"], dtype=float)
    mx = x.shape[0]
    xt = np.zeros((mx, 4 * mx + 1))
    fxt = np.zeros((max(mx, len(ly)), 4 * mx + 1))
    comm: dict = {}
    irevcm = 0
    states = []
    for t, y in enumerate(data["y"]):
        while True:
            irevcm, n = kalman_unscented_state_revcom(irevcm, y, ly, x, st, xt, fxt, comm, lx=lx, ropt=ropt)
            if irevcm == 1:
                fxt[:mx, :n] = f(xt[:, :n], m["r"], m["d"], data["phi_r"][t], data["phi_l"][t])
            elif irevcm == 2:
                fxt[: len(ly), :n] = h(xt[:, :n], m["Delta"], m["A"])
            else:
                break
        states.append(x.copy())
    return np.array(states), np.tril(st)


def results_table(states: np.ndarray, st: np.ndarray, names: tuple[str, ...] = STATE_NAMES) -> str:
    """The results in the layout of NAG's published example output, with the columns named.

    Parameters
    ----------
    states : ndarray, shape (ntime, 3)
        The state estimate after each time point.
    st : ndarray, shape (3, 3)
        Lower factor of the state covariance at the last time point.
    names : tuple of str, optional
        Names of the state components (x position, y position, heading).
    """
    mx = states.shape[1]
    pad = " " * -(-(11 * mx - 16) // 2)
    head = f"  Time  {pad} Estimate of State{pad}"
    lines = ["g13ej example results", "", head, " " * 8 + "".join(f" {name:>10}" for name in names)]
    lines.append("-" * len(head))
    for t, row in enumerate(states, start=1):
        lines.append(f"  {t:3d}   " + "".join(f" {v:10.3f}" for v in row))
    x, y, heading = names
    lines += [
        "",
        f"{x}, {y}: the robot's x and y position; {heading}: its heading (angle from the x-axis, radians)",
        "",
        "Estimate of Cholesky Factorisation of the State",
        "Covariance Matrix at the Last Time Point",
    ]
    for i in range(mx):
        lines.append("".join(f" {st[i, j]:10.2e}" for j in range(i + 1)))
    return "\n".join(lines)


def comparison_line(states: np.ndarray, data: dict, names: tuple[str, ...] = STATE_NAMES) -> str:
    """One line comparing the state estimates with NAG's published table.

    Parameters
    ----------
    states : ndarray, shape (ntime, 3)
        The state estimate after each time point.
    data : dict
        As returned by :func:`load_data`; holds the published estimates and their decimals.
    names : tuple of str, optional
        Names of the state components, used to point at the first value that differs.
    """
    published = np.array(data["published_state_estimates"]["x"], dtype=float)
    decimals = data["published_state_estimates"]["decimals"]
    diff = np.abs(states - published)
    # a value agrees when it rounds to the printed one (the tolerance absorbs the binary spelling)
    agrees = np.abs(np.round(states, decimals) - published) < 1e-9
    n = agrees.size
    if agrees.all():
        return (
            f"All {n} values agree with NAG's published results to the {decimals} decimal places printed "
            f"(max abs difference from the printed values {diff.max():.1e})"
        )
    t, i = np.argwhere(~agrees)[0]
    return (
        f"{int(agrees.sum())} of {n} values agree with NAG's published results to the {decimals} decimal "
        f"places printed; the first that differs is {names[i]} at time {t + 1} "
        f"({states[t, i]:.6f} against {published[t, i]:.{decimals}f}; max abs difference {diff.max():.1e})"
    )


def main() -> None:
    """Print the example's results table and how it compares with NAG's."""
    try:
        "".join(STATE_NAMES).encode(sys.stdout.encoding or "ascii")
        names = STATE_NAMES
    except (LookupError, UnicodeEncodeError):
        names = ASCII_STATE_NAMES
    data = load_data()
    states, st = run(data)
    print(results_table(states, st, names))
    print()
    print(comparison_line(states, data, names))


if __name__ == "__main__":
    main()
