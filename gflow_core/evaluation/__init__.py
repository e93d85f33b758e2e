"""Evaluation of trackers against ground truth, the mathematics only (no files, no runs).

* :mod:`.metrics` -- centre location error, IoU, success and precision curves, size kept and the
  scores of the tracker's judgement of the target's state (``gflow eval``, ``gflow benchmark``);
* :mod:`.stress` -- the stress cases: a sequence with ground truth turned into a harder one
  (occlusion, blur, darkness, dropped frames ...) by pure functions (``gflow benchmark --stress``);
* :mod:`.variants` -- every frame of a sequence changed the same way (grey footage) by pure
  functions (``gflow benchmark --variant``).

The runs and tables that use them are in ``pipeline/evaluation/``.
"""
