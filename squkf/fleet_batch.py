"""A fleet's runs over a recording: ``Fleet.batch_filter`` and the fleet's RTS smoother.

``batch_filter`` steps every filter over ``T`` steps of measurements inside one transaction (the
loop of both faces, :func:`squkf.boundary.loop.run_steps`), keeping what ``keep`` asks for in a
:class:`~squkf.boundary.records.FleetResult`; each step is the fleet's own whole predict and update
(``Fleet._step``). ``rts_smoother`` runs the backward recursion of :mod:`squkf.smoother` on a
result kept with its factors.
"""

from __future__ import annotations

import numpy as np

from . import checks
from .batch import model_kwargs, per_step
from .boundary.loop import check_keep, check_progress, run_steps
from .boundary.records import FleetResult, Records, new_records
from .face import Face
from .smoother import fleet_rts_smoother

__all__ = ["FleetBatch"]


class FleetBatch(Face):
    """``batch_filter`` and ``rts_smoother`` of :class:`squkf.Fleet`.

    A base class of the fleet, holding no state of its own; a step of the run is the fleet's
    ``_step``.
    """

    __slots__ = ()

    _K: int
    _n: int
    _m: int
    _failed: np.ndarray

    # -- many steps ---------------------------------------------------------------

    def batch_filter(
        self, zs, *, dts=None, keep: str | tuple[str, ...] = "all", fx_args=None, hx_args=None, progress=False
    ) -> FleetResult:
        """Filter ``T`` steps of measurements for every filter.

        Parameters
        ----------
        zs : array_like, shape (K, T, dim_z), or an iterable of (K, dim_z) arrays
            NaN rows and entries are missing measurements, as are masked ones
            (a ``numpy.ma.MaskedArray``), as for :meth:`update`.
            Any other iterable (a generator, ``tqdm(...)``) yields one step's
            measurements at a time, each checked as for :meth:`update` (a wrong
            shape, ``None`` or text is a ShapeError naming the step, ``zs[t]``);
            it is read to its end before the run starts. Lists and tuples are
            read as the ``(K, T, dim_z)`` array; a string, a dict or a set is a
            ShapeError.
        dts : float or array_like of shape (T,), optional
            Time step of each prediction (default: the constructor's), as
            :ref:`promise-dt` says.
        keep : {"all", "diagonals", "means", "final"} or tuple
            What to store: everything; means and the covariances' diagonals;
            means only; or only the final state (for long runs). A tuple of
            one of the first three and the ``keep`` words of per-step records
            keeps those too: ``"whitened"`` (``("means", "whitened")``), each
            step's whitened innovations and ``log det S1_2``
            (``FleetResult.y_whitened``, ``log_det_S1_2``).
        fx_args, hx_args : dict, optional
            Passed to ``fx`` and ``hx`` at every step, and to nothing else: a
            key that names an argument of the step (``dt``, ``z``, ``R``, ...,
            see :func:`squkf.batch.model_kwargs`) is a ParameterError.
        progress : bool or callable
            ``True`` shows a tqdm bar (the ``progress`` extra); a callable is
            called with the step index after each step.

        Returns
        -------
        FleetResult
            The fleet itself is left after the last step, as after a loop of
            ``predict`` and ``update``; an error leaves it as it was before the call.
        """
        state, words = check_keep(keep)
        check_progress(progress)
        Z = checks.measurement_series(zs, self._K, self._m)
        T = Z.shape[1]
        # step-major: each step's (K, m) contiguous, read by the kernels as it is (no copy per step)
        Z = np.ascontiguousarray(np.swapaxes(Z, 0, 1))
        dt_list = per_step(dts, T, "dts", "dt", default=self._dt, ref="zs")
        fx_args, hx_args = model_kwargs(fx_args, "fx_args"), model_kwargs(hx_args, "hx_args")
        records = new_records(state, self._K, T, self._n, self._m, words)
        self._take_edits()

        def step(t: int, z: np.ndarray) -> None:
            self._step(t, z, dt_list[t], fx_args, hx_args, records)

        # an error at any step leaves the fleet as it was before the call
        run_steps(self.transaction(), Z, step, records.so_far, progress, T)
        r = records
        return FleetResult(
            r.means, r.factors, r.variances, r.loglik, self._failed.copy(), self._engine.x.copy(),
            self._engine.S.copy(), r.rejected, r.nis, **r.step_records(),
        )  # fmt: skip

    def _step(self, t: int, z: np.ndarray, dt: float, fx_args: dict, hx_args: dict, records: Records) -> None:
        """Step ``t`` of :meth:`batch_filter`, its records kept (the fleet's)."""
        raise NotImplementedError

    # -- smoothing --------------------------------------------------------------------

    def rts_smoother(self, result: FleetResult, dts=None, fx_args=None):
        """Square-root unscented RTS smoother for every filter at once.

        The same backward recursion as :meth:`squkf.SquareRootUKF.rts_smoother_factors`
        (one function, ``squkf.smoother._backward``, on stacked arrays), with
        ``fx`` called once per backward step with the points of all filters,
        ``(K, N, dim_x)``, and the fleet's ``Q`` (shared or per filter). The fleet
        itself is not changed.

        Parameters
        ----------
        result : FleetResult
            From :meth:`batch_filter` with ``keep="all"`` (its means and factors).
        dts : float or array_like of shape (T,), optional
            ``dts[k]``: time step of the prediction into step ``k``, as given to
            :meth:`batch_filter` (default: the constructor's), as
            :ref:`promise-dt` says.
        fx_args : dict, optional
            Passed to ``fx`` at every step (per-filter arrays as for :meth:`predict`).

        Returns
        -------
        FleetSmoothed
            Unpacks as ``(means, P1_2s, Gs)`` of shapes ``(K, T, dim_x)``,
            ``(K, T, dim_x, dim_x)`` (lower factors) and ``(K, T, dim_x, dim_x)``
            (gains, zero at the last step); ``failed`` ``(K,)`` and ``failure``
            are attached. A filter flagged in ``result.failed``, or one that fails
            numerically while smoothing, is returned unsmoothed (its filtered
            values, zero gains) and flagged; the others are unaffected. With
            ``on_error="raise"``, a smoothing failure raises instead.

        Raises
        ------
        ParameterError
            ``result`` is not a FleetResult, or was kept without factors (``keep``
            other than ``"all"``); ``fx_args`` not a dict; a non-finite ``dts`` entry.
        ShapeError, NonFiniteError
            ``result`` does not fit this fleet, or holds NaN or inf; ``dts`` of
            the wrong length; ``fx`` values of the wrong shape.
        FleetStepError
            With ``on_error="raise"``, if some filters failed numerically.
        """
        checks.refuse_smoother_noise(self._fx_noise, "fleet")
        return fleet_rts_smoother(self, result, dts=dts, fx_args=fx_args)
