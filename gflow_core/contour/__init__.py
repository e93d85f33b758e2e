"""The contour trackers (``--tracker chamfer`` and ``--tracker m2``): a particle filter over the
transform alpha of an edge template or of learned M2 exemplars, scored by chamfer distance (Toyama
& Blake, IJCV 2002; the exemplar mathematics is :mod:`gflow_core.m2`).

* :mod:`.tracker` -- the filter's step: resampling, the likelihood, the estimate, the template
  update and the lost guard (its docstring gives the departures from the paper);
* :mod:`.params` -- :class:`~.params.ChamferParams` and :class:`~.params.M2Params`, every
  parameter and its default;
* :mod:`.dynamics` -- the proposal's dynamics, kept apart so the proposal stage does not import the filter;
* :mod:`.template` -- the chamfer tracker's template update with drift correction;
* :mod:`.protocol` -- both trackers on the protocol of :mod:`gflow_core.tracker` (``CHAMFER``, ``M2``).

Nothing is imported here, so a caller that needs only the parameters does not load the mathematics.
"""
