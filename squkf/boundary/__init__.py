"""The boundary every face shares: covariances and edits, records, the batch loop, configuration.

One layer between the callers and the engine (:mod:`squkf.engine`), used by
:class:`squkf.SquareRootUKF` (batch shape ``()``), :class:`squkf.Fleet`
(batch shape ``(K,)``) and :mod:`squkf.dask` (before anything is scheduled):

- :mod:`squkf.boundary.attributes`: the storage of a filter's attributes: a
  covariance held as its factor and read as a matrix (``FactorSlot``), the
  edits in place of what is handed out (``Handed``, ``HandOut``), and one
  filter's attributes in its ``__dict__`` as filterpy keeps them (its
  ``Saver`` copies them: ``Estimate``, ``Covariance``, ``Hook``, ...);
- :mod:`squkf.boundary.records`: what a fleet's run hands out
  (:class:`FleetResult`), the error of its failing filters, the records formed
  from one filter's last update;
- :mod:`squkf.boundary.loop`: the batch loop's option checks, its progress
  bar and its transaction (the filter as it was, on any error), with
  :mod:`squkf.batch` (the per-step arguments and the single filter's run);
- :mod:`squkf.boundary.config`: a filter's configuration as one record
  (:class:`Config`), its parts checked against each other, and filters into a
  fleet and out of it (``fleet[k]``, ``Fleet.from_filters``).

The checks of what a caller gives (single values, a call's sizes, states,
measurements, model images, covariances and factors) are :mod:`squkf.checks`'s,
below the boundary, where every layer can use them.
"""

from .config import Config, filter_kwargs
from .records import FleetResult, failures_error

__all__ = ["Config", "FleetResult", "failures_error", "filter_kwargs"]
