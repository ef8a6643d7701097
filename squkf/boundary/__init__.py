"""The boundary every front end shares: checks, given covariances as factors, the batch loop, records.

One layer between the callers and the step (:mod:`squkf.step`), used by
:class:`squkf.SquareRootUKF` (batch shape ``()``), :class:`squkf.Fleet`
(batch shape ``(K,)``) and :mod:`squkf.dask` (before anything is scheduled):

- :mod:`squkf.boundary.inputs`: the checks of sizes, states, measurements and
  model-function arguments, for one filter and for a stack of ``K``;
- :mod:`squkf.boundary.factors`: a covariance or factor the caller gave
  (``P``, ``Q``, ``R``, shared or per filter) as its lower factor;
- :mod:`squkf.boundary.config`: a filter's configuration as one record
  (:class:`Config`), what ``Fleet.from_filters``, ``fleet[k]``, the smoothers and
  :mod:`squkf.dask` read instead of a facade's private members;
- :mod:`squkf.boundary.model_form`: ``fx_noise``, ``hx_noise`` and ``gate``, the
  model's form as both faces show it;
- :mod:`squkf.boundary.edits`: edits in place of the arrays handed out, seen
  at the next call and taken through the validating setter (both faces);
- :mod:`squkf.boundary.attributes`: one filter's attributes in its
  ``__dict__`` (filterpy's ``Saver``), their copies and pickles;
- :mod:`squkf.boundary.one_filter`: the single filter's step at its boundary,
  under the public face of :class:`squkf.SquareRootUKF`;
- :mod:`squkf.boundary.stacking`: ``fleet[k]`` and ``Fleet.from_filters``;
- :mod:`squkf.boundary.records`: what a fleet's run hands out
  (:class:`FleetResult`), the error of its failing filters, one filter's last
  update;
- :mod:`squkf.boundary.loop`: the batch loop's option checks, its progress
  bar and its transaction (the filter as it was, on any error).

The rest of the boundary is in :mod:`squkf.validate` (the checks of single
values: arrays, ``dt``, model-function images), :mod:`squkf.covariance`
(``FactorSlot``) and :mod:`squkf.batch` (the per-step arguments and the single
filter's batch run).
"""

from .config import Config, filter_kwargs
from .records import FleetResult, failures_error

__all__ = ["Config", "FleetResult", "failures_error", "filter_kwargs"]
