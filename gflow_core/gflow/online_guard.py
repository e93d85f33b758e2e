"""An online model of the face for G-flow's lost guard: a discriminative correlation filter learnt
while the experts are on the face, that vouches for their box where the lost guard's first-frame
templates no longer recognise it and, optionally, re-seats them where it places the face elsewhere
(``online_guard``, off by default; ``online_patience``, re-seating, off by default).

A departure from Marks et al. (NIPS 2004), which is silent on losing the target, and from the lost
guard it sits beside (:mod:`.guard`), whose templates are the first frame's: the guard judges the
estimate by an edge template of the frontal first box and the first frame's colour, and a face
that turns and walks into bright light matches neither (on david_indoor the edges' correlation at
the true box falls to -0.01..0.18 against 0.22-0.31 for the clutter from frame 312), so it calls the
face occluded, then lost. This model is learnt online instead, as the correlation-filter trackers
learn theirs (KCF, DSST, BACF, CSR-DCF: Henriques et al. 2015, Danelljan et al. 2014, Galoogahi et
al. 2017, Lukezic et al. 2017), with the default tracker's own pieces, called as a library
(:mod:`gflow_core.dcf.model`: fHOG and intensity cells, a filter held to the box by ADMM, the first
frame's filter kept as an anchor, DSST's scale filter), on grey levels alone (G-flow reads no colour):

* **Where the face is.** Each frame the filter's response over its window about where it last placed
  the face (:func:`gflow_core.dcf.model.respond`: the target plus ``padding`` mean sides, every shift
  at once by FFT) is searched for its peak over centres within ``window + growth * dt`` box sizes of
  that place: the search grows with ``dt``, the frame periods since the last frame seen (up to the
  window, 1.5 box sizes each way with dcf's padding of 3, which the cosine window tapers).
* **Is it the face?** The distance rho = 1 - y at the peak against two distributions learnt by
  running moments (Toyama & Blake 2002, eq. 10; :func:`gflow_core.visibility.visibility`): the
  face's, on frames it is learnt from, and the clutter's, the best response more than half a box
  from the peak. The face is *placed* where P(visible) >= 1/2.
* **Learnt where the experts agree.** A frame the model judges the face (fully or partly: P(visible)
  + P(partial) >= P(hidden)) whose peak lies within the experts' box teaches the filter at the rate
  ``1 - (1 - eta)^dt`` (``eta`` dcf's ``rate``, compounded over the ``dt`` periods the step spans;
  DSST eq. 5 / BACF sec. 3.3) and the scale filter at the scale it finds; the first ``warmup`` frames
  teach it unconditionally. dcf learns on P(visible) >= 1/2 alone; here the experts' agreement is the
  second cue, and a turning face, which the model judges partly visible, is learnt as it turns
  (learning on P(visible) >= 1/2 alone, the model stopped learning at frame 315 of david_indoor and
  had lost the face by frame 348).
* **Vouching** (a witness, as :func:`.guard.witnessed` is): where the lost guard calls the estimate
  occluded or lost and the model places the face within the experts' box, the frame is reported
  ``tracked`` with the experts' box; the guard's state, its hold on the experts and its search are as
  without it, so the experts move exactly as they would without the model.
* **Re-seating** (``patience`` > 0): where the model places the face farther than ``apart`` box
  sizes from the experts' box in x or y, at one place, for ``patience`` frame periods (frames on which
  it is not placed neither count nor end the count), every expert is re-seated at the face's box as
  after a loss (:func:`.guard.settle`, :func:`.guard.reseat`). On david_indoor it helps at every 3rd
  frame and hurts at every frame, where the model loses the face in profile and re-seats the experts,
  who had kept it, on the wall (docs/gflow-development.md, "An online model of the face"): off by default.
* **As a likelihood** (``cue`` > 0, :func:`cue`): the model's response at each pose sample's box, as the
  default tracker turns it into a likelihood (``exp(kappa y)``) and mixed with a uniform density of weight
  ``floor``, multiplies the sample's importance weight (Marks et al. eq. 16), a second cue as in the
  multi-cue fusion of Perez, Vermaak & Blake (Proc. IEEE 2004), where a cue that may fail is mixed with a
  uniform density; the paper's likelihood is the texture's alone. It only reweights the samples the experts
  drew: at david_indoor's turn every expert's chain leaves the face for the collar, and no sample is left
  on the face to prefer (docs/gflow-development.md, "The online model as a likelihood"): off by default.
* **As a detector** (``online_mix`` of :class:`.params.GFlowParams`, :mod:`.mixture`): where it judges the face
  present (:func:`place`), a share of each expert's samples is drawn about its place and every weight is
  corrected for the mixture proposal (ICONDENSATION); off by default.

Nothing here draws a random number. No I/O. The model travels in a snapshot as :mod:`.online_fields`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..dcf import filter as cf
from ..dcf import model as tm
from ..dcf.params import DCFParams
from ..visibility import ChiSquare, Visibility, visibility
from .guard import GuardStep

__all__ = ["OnlineParams", "OnlineFace", "OnlineSeen", "start", "response", "cue", "place", "look", "overrule"]

Box = tuple[float, float, float, float]


@dataclass(frozen=True)
class OnlineParams:
    """The online guard's settings.

    window, growth : the search covers centres within ``window + growth * dt`` box sizes of the
        face's last place (``dt`` frame periods since the last frame seen).
    patience : frame periods the face must be placed away from the experts before they are re-seated (0: never).
    apart : away from the experts: its centre farther than this many box sizes from theirs in x or y.
    warmup : frames learnt from without the visibility gate (the experts start on the face).
    dcf : the filter's settings (:class:`gflow_core.dcf.params.DCFParams`, no colour; the small target's scale
        sampling and the roll at detection off, as the guard was measured with).
    cue : sharpness kappa of the model's likelihood ``exp(kappa y)`` in the experts' importance weights
        (0: not a cue; :func:`cue`).
    floor : the weight of the uniform density the cue is mixed with (a cue that may fail).
    """

    window: float = 0.5
    growth: float = 0.25
    patience: float = 0.0
    apart: float = 0.25
    warmup: int = 5
    dcf: DCFParams = DCFParams(colour_weight=0.0, scale_upsample=False, roll_detect=False)
    cue: float = 0.0
    floor: float = 0.1


@dataclass(frozen=True)
class OnlineFace:
    """The online model of the face.

    geom : the filter's window (its size at scale 1: the box it started from); model : the filter;
    centre : (x, y) where it last placed the face; log_s : its log scale; target, clutter : the
    distance distributions; learnt : frames learnt from; apart : frame periods in a row the face was
    placed away from the experts.
    """

    geom: tm.Geometry
    model: tm.TargetModel
    centre: tuple[float, float]
    log_s: float
    target: ChiSquare
    clutter: ChiSquare
    learnt: int = 0
    apart: float = 0.0

    def box(self) -> Box:
        """(x, y, w, h) of the face's box."""
        s = float(np.exp(self.log_s))
        w, h = self.geom.size0[0] * s, self.geom.size0[1] * s
        return (self.centre[0] - (w - 1) / 2.0, self.centre[1] - (h - 1) / 2.0, w, h)


@dataclass(frozen=True)
class OnlineSeen:
    """One frame's look: the model after it, the face's box, P(visible) there, whether the face is
    placed (P(visible) >= 1/2), and whether it is within the experts' box."""

    face: OnlineFace
    box: Box
    visible: float
    placed: bool
    agree: bool


def _prior(mean_std: tuple[float, float], count: int) -> ChiSquare:
    m, s = mean_std
    # count pseudo-samples of the given mean and std (the moments of Toyama & Blake's eq. 10)
    return ChiSquare(m, s * s + m * m, count)


def _centre(box: Box) -> tuple[float, float]:
    return (box[0] + (box[2] - 1) / 2.0, box[1] + (box[3] - 1) / 2.0)


def start(grey: np.ndarray, box: Box, p: OnlineParams) -> OnlineFace:
    """The model of the face in ``box`` (x, y, w, h) of the grey frame ``grey`` (H, W) uint8."""
    d = p.dcf
    geom = tm.geometry((float(box[2]), float(box[3])), d)
    c = _centre(box)
    model = tm.init_model(grey, grey, True, c, geom, d)
    return OnlineFace(geom, model, c, 0.0, _prior(d.prior_target, d.prior_count),
                      _prior(d.prior_clutter, d.prior_count), learnt=1)


def _within(c: tuple[float, float], box: Box, f: float) -> bool:
    """Whether ``c`` lies within ``f`` box sizes of ``box``'s centre in x and y."""
    b = _centre(box)
    return abs(c[0] - b[0]) <= f * box[2] and abs(c[1] - b[1]) <= f * box[3]


def _peak_near(resp: tm.Response, c: np.ndarray, hx: float, hy: float) -> tuple[int, int, float]:
    """(row, col, value) of the response's maximum over centres within ``hx``, ``hy`` px of ``c`` (x, y)."""
    h, w = resp.y.shape
    xs = resp.origin[0] + np.arange(w) / resp.q[0]
    ys = resp.origin[1] + np.arange(h) / resp.q[1]
    near = (np.abs(ys - c[1]) <= hy)[:, None] & (np.abs(xs - c[0]) <= hx)[None, :]
    y = np.where(near, resp.y, -np.inf)
    return cf.peak(y)


def response(face: OnlineFace, grey: np.ndarray, p: OnlineParams) -> tm.Response:
    """The filter's response on ``grey`` (H, W) uint8 over its window about the face's last place (the
    target plus ``padding`` mean sides each way, :func:`gflow_core.dcf.model.respond`)."""
    return tm.respond(face.model, grey, grey, face.centre, face.log_s, face.geom, p.dcf)


def cue(resp: tm.Response, centres: np.ndarray, p: OnlineParams) -> np.ndarray:
    """The model's log-likelihood of boxes centred at ``centres`` (N, 2) (x, y) px, a cue of the
    experts' importance weights (module docstring), (N,).

    ``p(y | u) = floor + (1 - floor) exp(kappa (y(u) - y_max))``: the correlation filter's likelihood
    of the default tracker (``exp(kappa y)``, y the response at the box's centre; the map's minimum
    outside the window) over its maximum ``y_max`` on the window, mixed with a uniform density of
    weight ``floor``, as a cue that may fail is in multi-cue fusion (Perez, Vermaak & Blake 2004,
    sec. 3): the factor a cue can give one box over another is at most ``1 / floor``.
    """
    y = resp.at(np.asarray(centres, dtype=np.float64).reshape(-1, 2))
    # p(y | u) = eps + (1 - eps) exp(kappa (y(u) - y_max))          (a cue mixed with a uniform density)
    lik = p.floor + (1.0 - p.floor) * np.exp(p.cue * (y - float(resp.y.max())))
    return np.log(lik)


def place(face: OnlineFace, resp: tm.Response, dt: float, p: OnlineParams
          ) -> tuple[tuple[float, float], float, Visibility]:
    """Where the model places the face on a frame whose :func:`response` is ``resp``, ``dt`` frame periods
    after the last frame seen: the response's peak over the centres within ``window + growth * dt`` box
    sizes of the face's last place, (x, y) px; the peak's distance rho = 1 - y; and the visibility judged
    from it (P(visible) >= 1/2: the face is placed there; module docstring)."""
    s = float(np.exp(face.log_s))
    size = (face.geom.size0[0] * s, face.geom.size0[1] * s)
    reach = p.window + p.growth * max(float(dt), 1.0)
    # the filter's window about the face's last place (the target plus 3 mean sides each way: wider than
    # the search at the rates met), its peak over the centres within reach of that place
    i, j, y = _peak_near(resp, np.asarray(face.centre), reach * size[0], reach * size[1])
    c = resp.point(i, j)
    # rho = 1 - y, the distance of the peak; the clutter's, the best response half a box or more away
    rho = 1.0 - y
    vis = visibility(rho, face.target, face.clutter, p.dcf.min_std)
    return (float(c[0]), float(c[1])), rho, vis


def look(face: OnlineFace, grey: np.ndarray, experts_box: Box, dt: float, p: OnlineParams,
         resp: tm.Response | None = None) -> OnlineSeen:
    """Place the face on ``grey`` (H, W) uint8, ``dt`` frame periods after the last frame seen, judge
    it, and learn from it where it is judged visible within ``experts_box`` (module docstring).
    ``resp``: the model's :func:`response` on ``grey``, when made already."""
    d, geom = p.dcf, face.geom
    if resp is None:
        resp = response(face, grey, p)
    centre, rho, vis = place(face, resp, dt, p)
    s = float(np.exp(face.log_s))
    size = (geom.size0[0] * s, geom.size0[1] * s)
    away = resp.best_away(np.asarray(centre), (0.5 * size[0], 0.5 * size[1]))
    agree = _within(centre, experts_box, 0.5)
    warm = face.learnt < p.warmup
    placed = bool(vis.visible >= 0.5)
    out = dataclasses.replace(face, centre=centre)
    if agree and (vis.present or warm):
        log_s = float(np.clip(face.log_s + tm.scale_change(face.model, grey, centre, face.log_s, geom, d),
                              -d.max_log_scale, d.max_log_scale))
        # the running average's rate compounded over the dt periods the step spans: 1 - (1 - eta)^dt
        rate = 1.0 - (1.0 - d.rate) ** max(float(dt), 1.0)
        model = tm.learn(face.model, grey, grey, centre, log_s, geom, d, rate)
        clutter = face.clutter if away is None else face.clutter.update(1.0 - away[0], d.clutter_rate)
        out = dataclasses.replace(out, model=model, log_s=log_s, target=face.target.update(rho, d.target_rate),
                                  clutter=clutter, learnt=face.learnt + 1)
    far = not _within(centre, experts_box, p.apart)
    # periods the face was placed away from the experts at one place (within a box of the last); a frame on
    # which it is not placed there neither counts nor ends the count
    steady = _within(centre, face.box(), 1.0)
    apart = 0.0
    if far and steady:
        apart = face.apart + (float(dt) if placed else 0.0)
    elif far and placed:
        apart = float(dt)
    out = dataclasses.replace(out, apart=apart)
    return OnlineSeen(out, out.box(), float(vis.visible), placed, agree)


def overrule(g: GuardStep, seen: OnlineSeen, box: Box, pose: np.ndarray, p: OnlineParams,
             place: Callable[[Box], np.ndarray]) -> tuple[GuardStep, OnlineFace]:
    """The lost guard's step ``g`` on the estimate ``box`` of pose ``pose`` (P,), overruled by the
    online model's look ``seen`` (module docstring): the experts re-seated at its box (``place(box)``
    (P,), :func:`.guard.settle`) where it has placed the face away from them for ``patience`` periods;
    else ``tracked``, with ``box`` reported, where it places the face within the experts' box. Returns
    the step and the online model."""
    face = seen.face
    if p.patience > 0 and seen.placed and face.apart >= p.patience:
        face = dataclasses.replace(face, apart=0.0)
        new_box = seen.box
        new_pose = place(new_box)
        held = (*new_box, *(float(v) for v in new_pose))
        lost = dataclasses.replace(g.lost, lost_run=0, held=held)
        return GuardStep(lost, new_box, new_pose, seen.visible, "tracked", "redetect", g.level, None,
                         g.look_clutter), face
    if seen.placed and seen.agree:
        if g.target_state == "tracked":
            return g, face
        # a witness, as the first look's (.guard.witnessed): the estimate reported, tracked; the lost guard's
        # state, its search, its hold on the experts and its re-detections are as without it
        return GuardStep(g.lost, box, g.pose, seen.visible, "tracked", g.phase, g.level, None, g.look_clutter), face
    return g, face
