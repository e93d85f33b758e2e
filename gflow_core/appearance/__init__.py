"""The appearance tracker (``--tracker appearance``): M2 with online appearance exemplars, a particle
filter over (x, y, log s), a colour cue and occlusion and re-detection.

* :mod:`.filter` -- the mathematics: the exemplar model, its likelihood, the mixture proposal and
  one filter step (its docstring gives the method and its departures from Toyama & Blake);
* :mod:`.params` -- :class:`~.params.AppearanceParams`, every parameter and its default;
* :mod:`.dynamics` -- the proposal's random walk, kept apart so the proposal stage does not import the filter;
* :mod:`.tracker` -- the tracker on the protocol of :mod:`gflow_core.tracker`;
* :mod:`.spec` -- its registration (:class:`gflow_core.spec.TrackerSpec`).

Nothing is imported here, so a caller that needs only the parameters does not load the mathematics.
"""
