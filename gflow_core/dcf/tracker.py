"""The correlation-filter tracker on the tracker protocol of :mod:`gflow_core.tracker`.

:class:`DCFTracker` is the tracker's :class:`~gflow_core.tracker.TrackingFilter`:

* ``observe`` -- the frame, its grey levels and whether it is grey (:func:`.features.is_grey`);
* ``init`` -- the target model of the user's box (:func:`.model.init_model`) and the particles
  about it;
* ``propose`` -- the random walk about the posterior's particles (:func:`.dynamics.walk`);
* ``update`` -- :func:`step`: the response over the window at the prediction, the particles weighed
  by it, the estimate, whether the target is present, hidden or lost, the search for a hidden one,
  the model's update and resampling;
* ``coast`` -- the posterior carried over a frame with no evidence.

Random draws of frame ``t`` (:class:`~gflow_core.tracker.FrameRng`): the initial particles from
``stream(PURPOSE_INIT)``, the proposal from ``stream(PURPOSE_WALK)``, the update's draws (the
speed's share of the noise, the particles at the peak, resampling) from ``stream(PURPOSE_STEP)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Mapping

import numpy as np

from ..features import to_grey
from ..particles import LogWeights, systematic_resample
from ..tracker import Box, Estimate, FrameRng, UnusableFrame, box_estimate, box_step_estimate
from ..visibility import ChiSquare, Cue, visibility
from . import camera as cam
from . import drift
from . import model as tm
from .confirm import remember, taken, tentative
from .cues import may_fail
from .dynamics import PURPOSE_WALK, alpha_of, particles_of, speed_noise, walk
from .features import is_grey
from .gate import within
from . import modes as mm
from . import motion_fit
from . import flowpred
from . import heavytail
from .longterm import LongTerm, init_longterm, learn_longterm, reliable, view
from .params import DCFParams
from .proposal import assign, detections
from .rates import adapted, filter_rate, recent
from .lookalike import beside
from . import negatives as neg
from .reacquire import log_truncation, search_peaks
from . import trackscore as ts
from .rotation import angle_change, detect, held
from . import sizeprior
from .state import DCFObservation, DCFProposal, DCFState
from .verify import accepted, conservative, learn_conservative, recognised

__all__ = ["DCFTracker", "TRACKER", "StepResult", "Search", "step", "box_of", "PURPOSE_INIT", "PURPOSE_STEP"]

#: the streams of a frame's draws: the initial particles, the update (the proposal's: PURPOSE_WALK)
PURPOSE_INIT, PURPOSE_STEP = 0xDCF0, 0xDCF2


def box_of(centre: np.ndarray, log_s: float, size0: tuple[float, float]) -> tuple[float, float, float, float]:
    """(x, y, w, h) of the box of scale exp(log_s) times ``size0`` centred at ``centre``."""
    s = float(np.exp(log_s))
    w, h = size0[0] * s, size0[1] * s
    return (float(centre[0] - (w - 1) / 2.0), float(centre[1] - (h - 1) / 2.0), float(w), float(h))


def _prior(mean_std: tuple[float, float], count: int) -> ChiSquare:
    """A distance distribution before any frame: ``count`` pseudo-samples of the given mean and std (the
    moments of Toyama & Blake's eq. 10)."""
    m, s = mean_std
    return ChiSquare(m, s * s + m * m, count)


@dataclass(frozen=True)
class StepResult:
    """One frame's answer: the new state, the box, the posterior's mean and std of (x, y, log s), the ESS,
    the log evidence, ``score`` the response at the estimate, ``confidence`` P(visible), ``target_state``
    and whether the search found a hidden target again this frame."""

    state: DCFState
    box: tuple[float, float, float, float]
    mean: np.ndarray
    std: np.ndarray
    ess: float
    log_evidence: float
    score: float
    confidence: float
    target_state: str
    redetected: bool


def _tail(st: DCFState, p: DCFParams) -> float:
    """The weight pi of the motion prior's t (:mod:`.heavytail`): the learnt one with ``motion_tail_rate`` once a
    frame was tracked, else ``motion_tail_weight``."""
    return st.tail if p.motion_tail_rate > 0 and st.tail > 0 else p.motion_tail_weight


def _innovation(resp: Any, centre: np.ndarray, pred: np.ndarray, bw: float, bh: float) -> np.ndarray:
    """(2,) px the frame's innovation: the response's peak less the prediction where the peak is within half
    a box of the estimate (the measurement, not pulled by the prior), else the estimate less it."""
    peak, _ = resp.peak()
    at = peak if abs(peak[0] - centre[0]) <= 0.5 * bw and abs(peak[1] - centre[1]) <= 0.5 * bh else centre
    return np.asarray(at, dtype=np.float64) - pred


def _log_place(c: np.ndarray, pred: np.ndarray, sx: float, sy: float, area: float, nu: float = 0.0,
               pi: float = 1.0) -> float:
    """log N(c; pred, diag(sx^2, sy^2)) - log(1 / area): how much likelier the target's motion prior puts
    it at ``c`` than clutter, which is anywhere in the ``area`` (px^2) searched (with ``nu`` > 0 the
    Student-t of the same scale in N's place, or their mixture of weight ``pi``: :mod:`.heavytail`)."""
    # log N = -((c_x - pred_x)^2 / 2 sx^2 + (c_y - pred_y)^2 / 2 sy^2) - log(2 pi sx sy)
    log_n = heavytail.log_density(float(c[0] - pred[0]), float(c[1] - pred[1]), sx, sy, nu, pi)
    return log_n + math.log(area)



def _particles(st: DCFState, proposed: np.ndarray, peak_xy: np.ndarray, extra: float, p: DCFParams,
               rng: np.random.Generator, dt: float, mot: mm.Motion | None = None) -> np.ndarray:
    """The (N, 3) particles of frame t: the proposal's walk moved by the velocity and the speed's share of
    the noise (with ``mot``, by each particle's motion mode: :mod:`.modes`), a ``detect_fraction`` of them
    drawn about the response's peaks ``peak_xy`` (K, 2) instead, in equal shares (:mod:`.proposal`); log s
    is the state's."""
    dyn = proposed.copy()
    if mot is None:
        # x_t = x~_t + g v dt + beta |v| dt w_2: the speed's share of the dynamics' noise (module .dynamics;
        # g the gain learnt with motion_fit, module .motion_fit, else 1)
        dyn[:, :2] += _velocity(st, p) * dt + extra * rng.standard_normal((len(dyn), 2))
    else:
        # each particle's mode m ~ pi_t, and x_t = x~_t + (pred_m - c_t-1) + noise_m w_2 (.modes)
        dyn[:, :2] = mm.move(mot, dyn[:, :2], mm.draw(mot, len(dyn), rng), rng)
    # x_t ~ (1 - b) p(x_t | x_t-1) + b (1 / K) sum_k N(peak_k, detect_std^2)   (mixture proposal, b = detect_fraction;
    # the K = detect_peaks best separate peaks of the response: .proposal, Okuma et al. 2004 eq. 2)
    n_det = int(round(p.detect_fraction * len(dyn)))
    if n_det:
        at = peak_xy[assign(n_det, len(peak_xy))]
        det = np.column_stack([at[:, 0] + rng.normal(0.0, p.detect_std, n_det),
                               at[:, 1] + rng.normal(0.0, p.detect_std, n_det),
                               np.full(n_det, st.log_s)])
        parts = np.vstack([dyn[: len(dyn) - n_det], det])
    else:
        parts = dyn
    parts[:, 2] = st.log_s
    return parts


def _velocity(st: DCFState, p: DCFParams) -> np.ndarray:
    """(2,) px / frame the prediction carries on: g v, g the gain learnt with ``motion_fit`` (.motion_fit), else v."""
    return st.velocity if p.motion_fit <= 0 else motion_fit.gain(st.motion_fit) * st.velocity


def _motion(st: DCFState, obs: DCFObservation, p: DCFParams, bw: float, bh: float, dt: float
            ) -> tuple[np.ndarray, float, float, float, mm.Motion | None]:
    """The motion's prediction of frame t (the window's centre), the speed's share beta |v| dt of the noise,
    the motion prior's std (sx, sy) px, and with ``motion_switch`` the two modes' prior (:mod:`.modes`), with
    ``flow_mix`` and a reliable match of the last box in ``obs`` the displacement's mixture (:mod:`.flowpred`)."""
    extra = speed_noise(p, st.velocity, dt)
    # the motion prior N(x; pred, diag(sx^2, sy^2)), sx = prior w sqrt(dt) + beta |v| dt, widened while the
    # target is unseen by the spread its place has gathered since (added in quadrature)
    sx = float(np.hypot(p.motion_prior * bw * math.sqrt(dt) + extra, st.spread))
    sy = float(np.hypot(p.motion_prior * bh * math.sqrt(dt) + extra, st.spread))
    shift = flowpred.observed(st, obs, p.flow_ratio) if p.flow_mix > 0 else None
    if shift is not None:
        # the displacement's mode beside constant velocity: the window at c + pi_0 v dt + pi_1 d (.flowpred)
        mot = flowpred.mixture(p, st.manoeuvre, st.centre, _velocity(st, p), shift, (bw, bh), extra, st.spread, dt)
        return mot.mean, extra, sx, sy, mot
    if p.motion_switch <= 0:
        # constant velocity: the prediction c_{t-1} + v dt (g v dt with motion_fit)
        return st.centre + _velocity(st, p) * dt, extra, sx, sy, None
    # two motion modes: the window at their mixture's mean prediction c_{t-1} + pi_t(0) v dt
    mot = mm.predict(p, st.manoeuvre, st.centre, st.velocity, (bw, bh), extra, st.spread, dt)
    return mot.mean, extra, sx, sy, mot


def _log_prior(parts: np.ndarray, pred: np.ndarray, sx: float, sy: float, mot: mm.Motion | None,
               nu: float = 0.0, pi: float = 1.0) -> tuple[np.ndarray, np.ndarray | None]:
    """(N,) the motion prior's log density of the (N, 3) particles up to a constant: -d^2 / 2 about ``pred``
    of std (sx, sy) (with ``nu`` > 0 the Student-t's, or their mixture of weight ``pi``: :mod:`.heavytail`), or with the modes ``mot`` the
    mixture's log sum_m pi_m N(x; pred_m, S_m), and then (N,) the manoeuvre's responsibility of each (else None)."""
    if mot is None:
        # -d^2 / 2, d^2 = (x - pred_x)^2 / sx^2 + (y - pred_y)^2 / sy^2; the t: -(nu + 2) / 2 log(1 + d^2 / nu)
        return heavytail.log_kernel(parts[:, 0] - pred[0], parts[:, 1] - pred[1], sx, sy, nu, pi), None
    return mm.log_prior(mot, parts[:, :2])


def _map_posterior(resp: tm.Response, pred: np.ndarray, sx: float, sy: float, mot: mm.Motion | None, p: DCFParams,
                   pi: float, frame: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The particles' target density read exactly at the response map's positions: (w,) the map's x
    and (h,) y in image px, (h * w, 2) the positions, and (h * w,) the log density kappa y(x) + the
    motion prior's log density (:func:`_log_prior`), -inf at a position whose centre is outside the frame."""
    h, w = resp.y.shape
    xs = resp.origin[0] + np.arange(w) / resp.q[0]
    ys = resp.origin[1] + np.arange(h) / resp.q[1]
    gx, gy = np.meshgrid(xs, ys)
    pts = np.stack([gx.ravel(), gy.ravel()], axis=1)
    lp, _ = _log_prior(pts, pred, sx, sy, mot, p.motion_tail, pi)
    # log p(x | z) + const = kappa y(x) + log p(x), over the positions whose centre lies in the frame
    score = p.kappa * resp.y.ravel() + lp
    inside = (pts[:, 0] >= 0) & (pts[:, 0] <= frame[0] - 1) & (pts[:, 1] >= 0) & (pts[:, 1] <= frame[1] - 1)
    return xs, ys, pts, np.where(inside, score, -np.inf)


def _in_frame(pred: np.ndarray, frame: tuple[int, int]) -> np.ndarray:
    """(2,) ``pred`` clipped to the frame: the estimate when no map position lies in it."""
    return np.array([np.clip(pred[0], 0.0, frame[0] - 1.0), np.clip(pred[1], 0.0, frame[1] - 1.0)])


def _map_mean(resp: tm.Response, pred: np.ndarray, sx: float, sy: float, mot: mm.Motion | None, p: DCFParams,
              pi: float, frame: tuple[int, int]) -> np.ndarray:
    """(2,) the posterior's mean over the response map's positions within the frame (``estimate_mean``):
    the particles' weighted mean (the MMSE estimate) computed by quadrature on the map instead of by
    Monte Carlo, so the estimate keeps the mean's averaging over a broad posterior without the sampler's
    noise."""
    _, _, pts, score = _map_posterior(resp, pred, sx, sy, mot, p, pi, frame)
    if not np.isfinite(score).any():
        return _in_frame(pred, frame)
    # E[x | z] = sum_x x exp(score(x)) / sum_x exp(score(x)), in einsum for the same bits in every thread
    wts = np.exp(score - score.max())
    return np.einsum("i,ij->j", wts / wts.sum(), pts)


def _mode(resp: tm.Response, pred: np.ndarray, sx: float, sy: float, mot: mm.Motion | None, p: DCFParams,
          pi: float, frame: tuple[int, int], start: np.ndarray | None = None) -> np.ndarray:
    """(2,) the posterior's mode over the response map's positions within the frame: the maximum of
    log p(z | x) + log p(x) = kappa y(x) + the motion prior's log density (:func:`_log_prior`), the
    particles' target density read exactly where the map is computed (``estimate_mode``)."""
    h, w = resp.y.shape
    xs, ys, pts, score = _map_posterior(resp, pred, sx, sy, mot, p, pi, frame)
    if not np.isfinite(score).any():
        return _in_frame(pred, frame)
    if start is None:
        return pts[int(np.argmax(score))].copy()
    # from the map position nearest ``start``, to the best of its 8 neighbours until none is better
    m = score.reshape(h, w)
    i = int(np.clip(round((start[1] - resp.origin[1]) * resp.q[1]), 0, h - 1))
    j = int(np.clip(round((start[0] - resp.origin[0]) * resp.q[0]), 0, w - 1))
    while True:
        nb = m[max(i - 1, 0): i + 2, max(j - 1, 0): j + 2]
        a, b = np.unravel_index(int(np.argmax(nb)), nb.shape)
        ni, nj = max(i - 1, 0) + int(a), max(j - 1, 0) + int(b)
        if not m[ni, nj] > m[i, j]:  # a strict ascent: a plateau ends the climb
            break
        i, j = ni, nj
    return np.array([xs[j], ys[i]]) if np.isfinite(m[i, j]) else start.copy()


def _estimate(resp: tm.Response, pred: np.ndarray, spread: tuple[float, float], mot: mm.Motion | None,
              p: DCFParams, pi: float, frame: tuple[int, int], mean: np.ndarray, std: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """(2,) the frame's estimate and (2,) where the model learns: the particles' weighted ``mean`` (2,) for
    both by default; with ``estimate_mean`` the posterior's mean on the map (:func:`_map_mean`); with
    ``estimate_mode`` its mode (:func:`_mode`, climbed to from the mean with ``estimate_local``), for the
    model alone with ``estimate_learn``. ``std`` (3,) the particles' spread."""
    sx, sy = spread
    if p.estimate_mean:
        exact = _map_mean(resp, pred, sx, sy, mot, p, pi, frame)
        return exact, exact
    if not p.estimate_mode:
        return mean, mean
    mode = _mode(resp, pred, sx, sy, mot, p, pi, frame, mean if p.estimate_local else None)
    # with estimate_reach, a climb that ends beyond reach std of the mean keeps the mean
    if p.estimate_local and p.estimate_reach > 0 and bool(np.any(
            np.abs(mode - mean) > p.estimate_reach * np.maximum(std[:2], 1e-9))):
        return mean, mean
    return (mean, mode) if p.estimate_learn else (mode, mode)


def _hidden_prior(back: float, reappear: float) -> tuple[float, float, float]:
    """Forward filtering over (visible, partial, hidden): after a hidden frame the prior that the target
    is back is ``reappear``, plus the probability ``back`` that it was present on the last frame."""
    b, q = back, reappear
    return (b / 3.0 + (1.0 - b) * 0.5 * q, b / 3.0 + (1.0 - b) * 0.5 * q, b / 3.0 + (1.0 - b) * (1.0 - q))


@dataclass(frozen=True)
class Search:
    """What the search for a hidden target found: ``found`` the first candidate judged visible (or None),
    its P(visible), whether the search covered the whole frame, and ``rho`` the filter's distance at the
    best placement at the held size (None: nothing searched), ``rho_lt`` the long-term filter's, ``best``
    the adaptive filter's best placement over every size and peak: its centre (2,) and distance; ``top``
    that placement's candidate, its signal log likelihood ratio (the filter's and colour's terms of
    :func:`_judge` without the prior and the place) and its place term (``search_track``; else None)."""

    found: Any
    confidence: float
    covers: bool
    rho: float | None = None
    rho_lt: float | None = None
    best: tuple[np.ndarray, float] | None = None
    top: tuple[Any, float, float] | None = None


@dataclass(frozen=True)
class Dists:
    """The distributions a search candidate's filter distance is judged by: the target's on present
    frames, the window's clutter and the search's own best placements while hidden (of the adaptive
    filter, or of the long-term one when it is the search's template)."""

    target: ChiSquare
    clutter: ChiSquare
    sclutter: ChiSquare


def _dists(st: DCFState, lt: LongTerm | None) -> Dists:
    return Dists(st.target, st.clutter, st.sclutter) if lt is None else Dists(lt.target, lt.clutter, lt.sclutter)


def _hidden_log_pdf(st: Dists, rho: float, trials: float, p: DCFParams) -> float:
    """log p(rho | hidden) of the search's best placement: the best of ``trials`` draws of the window's
    clutter (:meth:`ChiSquare.log_pdf_min`) or, with ``search_clutter`` and ``search_min`` searches or
    more since the target was last seen, the density of the search's own best placements on those
    frames (one-sided, as the clutter's), whichever is lower: placements the search gave while the
    target stayed hidden are its clutter (TLD's negatives, Kalal et al. 2012 sec. 5), but a target that
    was in view and not taken back is among them too, so they may only lower the clutter's density."""
    lh = st.clutter.log_pdf_min(rho, max(trials, 1.0), p.min_std)
    sc = st.sclutter
    if p.search_clutter and sc.n >= p.search_min:
        lh = min(lh, sc.log_pdf(min(rho, sc.mode(p.min_std)), p.min_std))
    return lh


def _judge(st: DCFState, ds: Dists, cand: Any, trials: float, place: float, p: DCFParams,
           negs: tuple[neg.Place, ...] = ()) -> float:
    """P(visible) of a search candidate against "hidden" (the prior ``reappear`` that a hidden target is
    back), from the filter's distance (:func:`_hidden_log_pdf` under "hidden", or the density of the
    clutter at a place of ``negs`` the candidate is at, if larger: :mod:`.negatives`), the colour score and
    the place term; the rules of :func:`gflow_core.visibility.visibility` with no partial hypothesis."""
    return _p_visible(*_log_joint(st, ds, cand, trials, place, p, negs))


def _p_visible(lv: float, lh: float) -> float:
    """P(visible) = 1 / (1 + exp(lh - lv)) of the log joint probabilities of "visible" and "hidden"."""
    d = lh - lv
    return 0.0 if d > 700.0 else 1.0 / (1.0 + math.exp(d))


def _log_joint(st: DCFState, ds: Dists, cand: Any, trials: float, place: float, p: DCFParams,
               negs: tuple[neg.Place, ...] = ()) -> tuple[float, float]:
    """log p(candidate, visible) and log p(candidate, hidden) of :func:`_judge`, up to one constant."""
    ms, rho = p.min_std, 1.0 - cand.r
    # log pi_v + log p_t(max(rho, mode_t)) + log_place  against  log pi_h + log p(rho | hidden)
    lv = math.log(p.reappear) + ds.target.log_pdf(max(rho, ds.target.mode(ms)), ms) + place
    lh_rho = _hidden_log_pdf(ds, rho, trials, p)
    if negs:
        # log p(rho | hidden) = max(log p_search(rho), log p_place(rho)): a remembered place may only add clutter
        lh_rho = max(lh_rho, neg.log_pdf(negs, cand.centre, rho, _half(st), p.search_negatives, ms))
    lh = math.log(1.0 - p.reappear) + lh_rho
    if cand.r_colour is not None and st.ctarget.n and st.cclutter.n:
        rc = 1.0 - cand.r_colour
        eps = max(p.colour_outlier, p.search_colour_outlier)
        ct, cc = may_fail(st.ctarget, eps), may_fail(st.cclutter, eps)
        lv += ct.log_pdf(max(rc, ct.mode(ms)), ms)
        lh += cc.log_pdf_min(rc, 1.0, ms)
    return lv, lh


def _search(st: DCFState, obs: DCFObservation, p: DCFParams, pred: np.ndarray, s_xy: tuple[float, float],
            spread: float, clutter_seen: Any, lt: LongTerm | None = None, size_sd: float = 0.0) -> Search:
    """The search for a hidden target over three standard deviations of its place's prior (the motion
    prior's (sx, sy) widened by ``spread``, in quadrature) and of its log size's prior (std ``size_sd``
    about the held size: the sizes ``search_size_step`` apart within three of it, at most
    ``search_sizes``); with ``lt``, the long-term filter is slid too, after the adaptive one, each
    judged by its own distributions."""
    Hh, Ww = obs.grey.shape
    sx, sy = float(np.hypot(s_xy[0], spread)), float(np.hypot(s_xy[1], spread))
    margin = (3.0 * sx + 10.0, 3.0 * sy + 10.0)
    covers = (pred[0] - margin[0] <= 0 and pred[0] + margin[0] >= Ww - 1
              and pred[1] - margin[1] <= 0 and pred[1] + margin[1] >= Hh - 1)
    # the sizes searched: search_size_step apart in log size about the held one, within 3 size_sd
    k = min(p.search_sizes // 2, int(3.0 * size_sd / p.search_size_step))
    sizes = tuple(float(i * p.search_size_step) for i in sorted(range(-k, k + 1), key=abs))
    templates = [(st.model, _dists(st, None))] + ([] if lt is None else [(view(st.model, lt), _dists(st, lt))])
    rhos: list[float | None] = [None, None]
    top: tuple[np.ndarray, float] | None = None
    top_cand: tuple[Any, float, float] | None = None
    # with search_truncate, the place prior is conditioned on the region searched (.reacquire)
    log_z = log_truncation(pred, sx, sy, margin, (Ww, Hh)) if p.search_truncate else 0.0
    for which, (searched, ds) in enumerate(templates):
        best: Search | None = None
        for cand in (tm.search(searched, obs.image, obs.grey, pred, margin, st.log_s, st.geom, p, sizes)
                     if p.search_peaks == 1 else
                     search_peaks(searched, obs.image, obs.grey, pred, margin, st.log_s, st.geom, p, sizes,
                                  p.search_peaks)):
            # the search had more chances than the window the clutter was learnt on: under "hidden" its
            # distance is the best of that many clutter draws, anywhere in the area searched by every
            # template; under "visible" the candidate is placed by the target's prior: log N(x; pred, S) + log A
            trials = len(templates) * cand.area / clutter_seen[1] if clutter_seen is not None else 1.0
            if p.search_refine:
                # the refined placement is the best of a lattice half a cell apart near the peak: four times
                # the placements a lattice of whole cells has, each a draw of clutter under "hidden"
                trials *= 4.0
            place = _log_place(cand.centre, pred, sx, sy, cand.area, p.motion_tail, _tail(st, p)) + log_z
            if k > 0:
                # the size's prior against clutter's, uniform over the sizes searched (as the place's):
                # log N(log f; 0, size_sd^2) + log((2 k + 1) step); with search_size_volume, log step alone:
                # log A above already sums the area over the 2 k + 1 sizes, so clutter is uniform over the
                # volume searched, sum(A_i) step, and the sizes' number is not counted twice
                n_sizes = 1 if p.search_size_volume else 2 * k + 1
                place += -cand.log_f ** 2 / (2.0 * size_sd * size_sd) - 0.5 * math.log(2.0 * math.pi * size_sd * size_sd) \
                    + math.log(n_sizes * p.search_size_step)
            if rhos[which] is None:
                rhos[which] = 1.0 - cand.r
            better = which == 0 and (top is None or 1.0 - cand.r < top[1])
            if better:
                top = (cand.centre, 1.0 - cand.r)
            if p.search_clutter:
                lv, lh = _log_joint(st, ds, cand, trials, place, p, st.negatives if which == 0 else ())
                visible = _p_visible(lv, lh)
                if better and p.search_track:
                    # the signal: lv - lh less the prior's log odds and the place (.trackscore)
                    top_cand = (cand, lv - lh - ts.logit(p.reappear) - place, place)
            else:
                # the colour score of the filter's pick: one draw of the colour clutter
                ccue = () if cand.r_colour is None else (_colour_cue(st, 1.0 - cand.r_colour, p),)
                visible = visibility(1.0 - cand.r, ds.target, ds.clutter, p.min_std,
                                     prior=(p.reappear, 0.0, 1.0 - p.reappear), trials=max(trials, 1.0),
                                     log_place=place, cues=ccue).visible
            if visible >= 0.5 and cand.log_f != 0.0 and p.search_size_track:
                continue  # with search_size_track, another size only as a candidate track (_track)
            if visible >= 0.5 and cand.log_f != 0.0 and not _verified(st, obs, cand.centre, st.log_s + cand.log_f,
                                                                      st.angle, p):
                continue  # with verify, a placement at another size is taken only if the first filter agrees
            if visible >= 0.5 and p.search_peaks == 1:
                return Search(cand, visible, covers, rhos[0], rhos[1])
            if visible >= 0.5 and (best is None or visible > best.confidence):
                # several placements judged: the likeliest target among them (.reacquire)
                best = Search(cand, visible, covers)
        if best is not None:
            return replace(best, rho=rhos[0], rho_lt=rhos[1])
    return Search(None, 0.0, covers, rhos[0], rhos[1], top, top_cand)


def _colour_cue(st: DCFState, rho: float, p: DCFParams) -> Cue:
    """The colour score's distance ``rho`` as a cue that may fail (:mod:`.cues`, ``colour_outlier``)."""
    return Cue(rho, may_fail(st.ctarget, p.colour_outlier), may_fail(st.cclutter, p.colour_outlier))


def _scores(resp: Any, centre: np.ndarray, bw: float, bh: float) -> tuple[float, Any, Any]:
    """The estimate's two cues, each to be read as a distance rho = 1 - score against its own learnt
    target and clutter distributions (gflow_core.visibility): (the filter's response at ``centre``, the
    best response half a box away or more, and (the colour score at ``centre``, its best a box away or
    more) or None without a colour model; a box that overlaps the target shares its colours)."""
    r_est = float(resp.at(centre[None, :], "cf")[0])
    clutter_seen = resp.best_away(centre, (0.5 * bw, 0.5 * bh), "cf")
    colour_seen = None
    if resp.colour is not None:
        colour_seen = (float(resp.at(centre[None, :], "colour")[0]), resp.best_away(centre, (bw, bh), "colour"))
    return r_est, clutter_seen, colour_seen


def _learn_clutter(st: DCFState, clutter_seen: Any, colour_seen: Any, rate: float) -> dict[str, ChiSquare]:
    """The clutter's moments after a frame the target is present (while it is not, the best away from the
    held box may be the target itself): the filter's and the colour's, as keywords of the state."""
    clutter, cclutter = st.clutter, st.cclutter
    if clutter_seen is not None:
        clutter = clutter.update(1.0 - clutter_seen[0], rate)
    if colour_seen is not None and colour_seen[1] is not None:
        cclutter = cclutter.update(1.0 - colour_seen[1][0], rate)
    return {"clutter": clutter, "cclutter": cclutter}


def _learn(st: DCFState, obs: DCFObservation, p: DCFParams, centre: np.ndarray, r_est: float, colour_seen: Any,
           confident: bool) -> tuple[float, dict[str, Any]]:
    """A frame the target is present at ``centre``: (its log scale, the state's learnt parts as keywords).
    The target's distributions follow it on every such frame, so a lasting change of look becomes the usual
    look; the model and the scale learn on confident frames only."""
    c = (float(centre[0]), float(centre[1]))
    log_s, mdl = st.log_s, st.model
    # with learn_level, a frame teaches the model only when the target was seen as well as usual (.gate)
    confident = confident and (p.learn_level <= 0 or within(st.target, 1.0 - r_est, p.learn_level, p.min_std))
    # with roll_step, the target's roll searched about the held one (.rotation)
    angle = st.angle if held(st.target, 1.0 - r_est, p, st.angle) or tentative(st.target, p) \
        else angle_change(mdl, obs.image, obs.grey, c, log_s, st.angle, st.geom, p, st.target)
    if confident and mdl.scale is not None:
        # with scale_prior, the pick under a prior on the size (.sizeprior)
        d = (sizeprior.scale_change if p.scale_prior > 0 else tm.scale_change)(mdl, obs.grey, c, log_s, st.geom, p)
        log_s = float(np.clip(log_s + d, -p.max_log_scale, p.max_log_scale))
    learnt: dict[str, Any] = {"target": st.target.update(1.0 - r_est, p.target_rate), "angle": angle}
    if p.rate_adapt > 0:
        # with rate_adapt, the distance's short-run mean S_t (.rates)
        learnt["recent"] = recent(p, st.recent, st.target, 1.0 - r_est)
    if colour_seen is not None:
        learnt["ctarget"] = st.ctarget.update(1.0 - colour_seen[0], p.target_rate)
    if confident:
        learnt["model"] = tm.learn(mdl, obs.image, obs.grey, c, log_s, st.geom, p,
                                   adapted(p, filter_rate(p, st.target.n - p.prior_count), st.target,
                                           learnt.get("recent", 0.0)), angle=angle)
        if p.verify > 0 or p.drift_gate > 0:
            # with verify (or drift_gate), the anchor's distances at the target and about it on confident frames (.verify)
            learnt["vtarget"], learnt["vclutter"] = learn_conservative(*_conservative_of(st, p), conservative(
                mdl, obs.image, obs.grey, c, log_s, angle, st.geom, p), p)
    return log_s, learnt


def _longterm_of(st: DCFState, p: DCFParams) -> LongTerm | None:
    """The state's long-term filter with ``longterm`` (made from the adaptive model when the state has none,
    as a snapshot from before it); None without."""
    if not p.longterm:
        return None
    if st.longterm is not None:
        return st.longterm
    return init_longterm(st.model, _prior(p.prior_target, p.prior_count), _prior(p.prior_clutter, p.prior_count))


def _learn_longterm(st: DCFState, lt: LongTerm, seen: Any, obs: DCFObservation, p: DCFParams, centre: np.ndarray,
                    log_s: float, present: bool, confident: bool) -> LongTerm:
    """The long-term filter after a frame (:mod:`.longterm`): on a present frame its distances learnt; on a
    confident one whose long-term distance is reliable against the run's (judged before this frame
    counts), the filter learnt at the estimate."""
    if not present or seen is None:
        return lt
    rho, away = seen
    ok = confident and reliable(lt, rho, p)
    new = replace(lt, target=lt.target.update(rho, p.target_rate),
                  clutter=lt.clutter if away is None else lt.clutter.update(1.0 - away[0], p.clutter_rate))
    if ok:
        c = (float(centre[0]), float(centre[1]))
        new = learn_longterm(new, st.model, obs.image, obs.grey, c, log_s, st.geom, p)
    return new


def _longterm_seen(resp: tm.Response, centre: np.ndarray, bw: float, bh: float, lt: LongTerm | None, p: DCFParams
                   ) -> tuple[tuple[float, tuple[float, float] | None] | None, tuple[Cue, ...]]:
    """The long-term filter's distance at the estimate and its best half a box away (as the adaptive
    one's), and its cue of presence when ``longterm_witness`` asks for one (none without the filter)."""
    if lt is None:
        return None, ()
    lt_seen = (1.0 - float(resp.at(centre[None, :], "lt")[0]), resp.best_away(centre, (0.5 * bw, 0.5 * bh), "lt"))
    if not p.longterm_witness:
        return lt_seen, ()
    return lt_seen, (Cue(lt_seen[0], may_fail(lt.target, p.longterm_outlier), may_fail(lt.clutter, p.longterm_outlier)),)


def _learn_search_clutter(st: DCFState, lt: LongTerm | None, srch: Search, hid: bool, p: DCFParams,
                          learnt: dict[str, Any]) -> LongTerm | None:
    """The search's best placement on a frame the target stayed hidden (``hid``) is clutter's (TLD's
    negatives): learnt into ``learnt["sclutter"]``, the long-term filter's into the returned ``lt``, and with
    ``search_negatives`` its place into ``learnt["negatives"]``."""
    learnt["sclutter"] = st.sclutter.update(srch.rho, p.clutter_rate) if hid and srch.rho is not None \
        else ChiSquare()
    if lt is not None:
        lt = replace(lt, sclutter=lt.sclutter.update(srch.rho_lt, p.clutter_rate) if hid and srch.rho_lt is not None
                     else ChiSquare())
    if p.search_negatives:
        # ... and where it was: a place of the search's negatives (.negatives); forgotten once the target is seen
        learnt["negatives"] = neg.learn(st.negatives, srch.best[0], srch.best[1], _half(st), p.clutter_rate) \
            if hid and srch.best is not None else ()
    return lt


def _half(st: DCFState) -> tuple[float, float]:
    """Half the held box's (width, height), px: how near a placement is to a remembered place to be at it."""
    s = 0.5 * float(np.exp(st.log_s))
    return st.geom.size0[0] * s, st.geom.size0[1] * s


def _unseen(st: DCFState, obs: DCFObservation, p: DCFParams, pred: np.ndarray, s_xy: tuple[float, float],
            clutter_seen: Any, lt: LongTerm | None, run: int, s: float, dt: float
            ) -> tuple[Search, float, ts.Track | None]:
    """On a frame the target is unseen (``run`` > 0 frames in a row), the search for it (:func:`_search`), its
    place's spread and, with ``search_track``, the candidate track (:func:`_track`); else nothing searched."""
    if run <= 0:
        return Search(None, 0.0, False), 0.0, None
    bw, bh = st.geom.size0[0] * s, st.geom.size0[1] * s
    # unseen, the target's place spreads by search_growth mean sides a frame
    spread = st.spread + p.search_growth * 0.5 * (bw + bh) * dt
    # unseen, the target's log size spreads by search_size_growth a frame
    srch = _search(st, obs, p, pred, s_xy, spread, clutter_seen, lt, p.search_size_growth * run)
    if srch.found is not None or srch.top is None:
        return srch, spread, None
    # with search_track, the search's best placements as a candidate track judged over its frames
    track, srch = _track(st, obs, srch, p, s, bw, bh, dt)
    return srch, spread, track


def _track(st: DCFState, obs: DCFObservation, srch: Search, p: DCFParams, s: float, bw: float, bh: float, dt: float
           ) -> tuple[ts.Track, Search]:
    """The candidate track extended by the search's best placement (:mod:`.trackscore`), and the search
    with it as ``found`` when the track's probability is ``search_track`` or more over two frames or more
    (and with ``verify``, the first frame's filter agrees: :mod:`.verify`)."""
    assert srch.top is not None
    cand, signal, place = srch.top
    geom = st.geom
    cell = (geom.cell / geom.k0[0] * s, geom.cell / geom.k0[1] * s)
    track = ts.extend(st.track, cand.centre, signal, place, 0.5 * (bw + bh), cell, st.speed2, cand.area, dt, p)
    odds = ts.log_odds(track, p)
    # P(visible) >= search_track: log odds >= logit(search_track)
    if (track.n >= 2 and odds >= ts.logit(p.search_track)
            and _verified(st, obs, cand.centre, st.log_s + cand.log_f, st.angle, p)):
        # P(visible) = 1 / (1 + exp(-log odds))
        return track, replace(srch, found=cand, confidence=1.0 / (1.0 + math.exp(-odds)))
    return track, srch


def _take_found(st: DCFState, found: Any, p: DCFParams, parts: np.ndarray, mean: np.ndarray, hidden_before: bool,
                spread: float) -> tuple[np.ndarray, float, float]:
    """A target the search found again: its centre, its log size, and the next frame's spread of its
    place; ``parts`` ((N, 3) resampled particles) move with it, in place."""
    centre = found.centre.copy()
    log_s = float(np.clip(st.log_s + found.log_f, -p.max_log_scale, p.max_log_scale))
    parts[:, :2] += centre - mean[:2]
    if p.redetect_speed and hidden_before:
        # after the target was judged hidden its velocity is unknown, v ~ N(0, (E|v|^2 / 2) I): the next
        # frame's prior is wider by its std (a frame in doubt only: the velocity was known a frame ago)
        spread = math.sqrt(0.5 * st.speed2)
    return centre, log_s, spread


def _drift_corrected(st: DCFState, resp: tm.Response, centre: np.ndarray, parts: np.ndarray, p: DCFParams,
                     bw: float, bh: float, confident: bool) -> tuple[np.ndarray, bool]:
    """The estimate after drift correction (:mod:`.drift`) and whether the frame may teach the model. With
    ``drift_correct`` on a ``confident`` frame, the first frame's filter's alignment p* within epsilon =
    drift_correct sqrt(w h) of ``centre`` is the estimate (``parts`` (N, 3), resampled, move with it, in
    place); beyond, the estimate stays and, with ``drift_hold``, the frame teaches nothing (Matthews et
    al. 2004, strategy 3). Otherwise (``centre``, ``confident``) as they are."""
    if p.drift_correct <= 0 or not confident:
        return centre, confident
    # epsilon = drift_correct sqrt(w h)
    star = drift.aligned(resp, centre, p.drift_correct * math.sqrt(bw * bh))
    if star is not None and p.drift_gate > 0:
        # with drift_gate, the peak only where the first frame's filter sees the target (.verify.recognised)
        vt, vc = _conservative_of(st, p)
        star = star if recognised(vt, vc, 1.0 - float(resp.at(star[None, :], "an")[0]), p.drift_gate,
                                        p.min_std) else None
    if star is None:
        return centre, not p.drift_hold
    parts[:, :2] += star - centre
    return star, True


def _respond(st: DCFState, obs: DCFObservation, p: DCFParams, pred: np.ndarray, lt: LongTerm | None
             ) -> tuple[tm.Response, DCFState]:
    """The response of the window at the prediction ``pred`` rolled by the held roll; with ``roll_detect``
    on a confirmed track, the roll searched at detection (:func:`.rotation.detect`), the state returned
    holding the roll taken."""
    c = (float(pred[0]), float(pred[1]))

    def respond(angle: float) -> tm.Response:
        return tm.respond(st.model, obs.image, obs.grey, c, st.log_s, st.geom, p, None if lt is None else lt.det,
                          angle, anchor=p.drift_correct > 0)

    resp = respond(st.angle)
    if not p.roll_detect or tentative(st.target, p):
        return resp, st
    resp, angle = detect(resp, respond, st.angle, st.target, p,
                         None if p.verify <= 0 else lambda r, a: _verified(st, obs, r.peak()[0], st.log_s, a, p))
    return resp, replace(st, angle=angle)


def _conservative_of(st: DCFState, p: DCFParams) -> tuple[ChiSquare, ChiSquare]:
    """The anchor's distance distributions on confident frames, the target's and the clutter's (``verify``;
    :mod:`.verify`); the priors of the filter's before any frame (or in a state from before the option)."""
    if not st.vtarget.n:
        return _prior(p.prior_target, p.prior_count), _prior(p.prior_clutter, p.prior_count)
    return st.vtarget, st.vclutter


def _verified(st: DCFState, obs: DCFObservation, centre: np.ndarray, log_s: float, angle: float, p: DCFParams) -> bool:
    """With ``verify``, whether a re-detection at ``centre`` (x, y), log scale ``log_s``, roll ``angle`` is the
    target by the first frame's filter (:func:`.verify.accepted`); always without."""
    if p.verify <= 0:
        return True
    ls = float(np.clip(log_s, -p.max_log_scale, p.max_log_scale))
    rho_c, _ = conservative(st.model, obs.image, obs.grey, (float(centre[0]), float(centre[1])), ls, angle, st.geom, p)
    return accepted(*_conservative_of(st, p), rho_c, p)


def _compensate(st: DCFState, obs: DCFObservation, proposed: np.ndarray, p: DCFParams) -> tuple[DCFState, np.ndarray]:
    """With ``camera_motion``, the state and the proposal's (N, 3) particles (x, y, log s) moved by the camera's
    motion from the last frame to ``obs`` (:func:`.camera.estimate`: the background's similarity x_t = A x_{t-1}
    + b, A = s R(phi)): the last estimate's centre and the particles through it, their log size by log s, the
    velocity turned by A and, with ``roll_step``, the held roll by phi (within ``roll_max``). Unchanged without
    the option, without the last frame's grey levels, when the fit is refused or the camera still, when it neither
    rolls nor zooms and shifts the target's centre by less than the motion prior's std (``motion_prior`` sqrt(w h):
    the prior covers it, and the fit's own errors would enter the prediction in full), while the
    target is judged hidden -- the camera is then taken to follow it, its place held in the frame (as without the
    option), since a camera that pans after a target would carry the prediction away with the background -- and
    while its box is not inside the frame (its centre is clipped to the frame, so not where the target is)."""
    box = box_of(st.centre, st.log_s, st.geom.size0)
    H, W = obs.grey.shape
    if not p.camera_motion or st.last_grey is None or st.last_grey.shape != obs.grey.shape \
            or st.hidden_run >= p.hidden_after or not (box[0] >= 0 and box[1] >= 0 and box[0] + box[2] <= W
                                                       and box[1] + box[3] <= H):
        return st, proposed
    mo = cam.estimate(st.last_grey, cam.grey8(obs.grey), box)
    c = st.centre
    # with neither roll nor zoom, a shift |A c + b - c| within the motion prior's std (motion_prior sqrt(w h)) is left to it
    if mo.still or (mo.angle == 0.0 and mo.log_scale == 0.0
                    and np.hypot(*(mo.apply(c[None, :])[0] - c)) < p.motion_prior * math.sqrt(box[2] * box[3])):
        return st, proposed
    lim, ls = p.max_log_scale, mo.log_scale
    moved = proposed.copy()
    # x_t = A x_{t-1} + b, log s_t = log s_{t-1} + log s   (.camera, eq. 1)
    moved[:, :2] = mo.apply(proposed[:, :2])
    moved[:, 2] = np.clip(proposed[:, 2] + ls, -lim, lim)
    angle = st.angle
    if p.roll_step > 0:
        # theta_t = theta_{t-1} + phi: the target rolls with the frame (.rotation samples its window rolled by it)
        angle = float(np.clip(st.angle + mo.angle, -math.radians(p.roll_max), math.radians(p.roll_max)))
    # v_t = A v_{t-1}: the velocity seen in the new frame
    return replace(st, centre=mo.apply(st.centre[None, :])[0], log_s=float(np.clip(st.log_s + ls, -lim, lim)),
                   velocity=mo.linear @ st.velocity, angle=angle), moved


def _learn_motion(st: DCFState, p: DCFParams, resp: Any, centre: np.ndarray, velocity: np.ndarray, pred: np.ndarray,
                  sxy: tuple[float, float], box: tuple[float, float], dt: float) -> dict[str, Any]:
    """What a tracked frame teaches the motion model: with ``motion_fit`` the velocity's gain (.motion_fit), with
    ``motion_tail_rate`` the weight of the prior's heavy tail (.heavytail), with ``redetect_speed`` E|v|^2."""
    sx, sy = sxy
    learnt: dict[str, Any] = {}
    if p.motion_fit > 0:
        # the regression d_t = g v_{t-1} dt + e, e ~ N(0, sx sy I), at rate motion_fit (.motion_fit)
        learnt["motion_fit"] = motion_fit.update(st.motion_fit, centre - st.centre, st.velocity * dt, sx * sy,
                                                 p.motion_fit)
    if p.motion_tail > 0 and p.motion_tail_rate > 0:
        # pi <- (1 - a) pi + a r, r the t's responsibility for the innovation (.heavytail)
        learnt["tail"] = heavytail.learn(_tail(st, p), _innovation(resp, centre, pred, *box), sx, sy,
                                         p.motion_tail, p.motion_tail_rate)
    if p.redetect_speed:
        # E|v|^2 <- (1 - a) E|v|^2 + a |v|^2 on tracked frames, a = target_rate
        learnt["speed2"] = (1.0 - p.target_rate) * st.speed2 + p.target_rate * float(velocity @ velocity)
    return learnt


def step(st: DCFState, obs: DCFObservation, proposed: np.ndarray, p: DCFParams, rng: np.random.Generator,
         dt: float = 1.0) -> StepResult:
    """One frame: the response at the prediction, the particles weighed, the estimate, the target's
    state, the search for a hidden target, the model's update, resampling.

    Parameters
    ----------
    st, obs : the posterior after frame t-1, and frame t.
    proposed : (N, 3) float64 particles (x, y, log s) of the proposal's random walk about the posterior
        of t-1; the velocity and the speed's share of the noise are added here (:mod:`.dynamics`).
    rng, dt : the update's generator of frame t, and the frame periods since frame t-1.
    """
    n = p.particles
    if proposed.ndim != 2 or proposed.shape[1] != 3 or not np.isfinite(proposed).all():
        raise ValueError(f"proposals must be finite (N, 3) = (x, y, log s), got {proposed.shape}")
    st, proposed = _compensate(st, obs, proposed, p)  # with camera_motion, the camera's motion (.camera)
    geom = st.geom
    Hh, Ww = obs.grey.shape
    s = float(np.exp(st.log_s))
    bw, bh = geom.size0[0] * s, geom.size0[1] * s
    pred, extra, sx, sy, mot = _motion(st, obs, p, bw, bh, dt)
    lt = _longterm_of(st, p)
    resp, st = _respond(st, obs, p, pred, lt)
    parts = _particles(st, proposed, detections(resp, (0.5 * bw, 0.5 * bh), p.detect_peaks), extra, p, rng, dt,
                       mot)
    y = resp.at(parts[:, :2])
    # log p(z | X) = kappa y(X): the response read at the particle
    log_lik = p.kappa * y
    log_prior, resp1 = _log_prior(parts, pred, sx, sy, mot, p.motion_tail, _tail(st, p))
    lw = LogWeights(log_lik + log_prior)
    W = lw.W
    # weighted sums by einsum, not BLAS: the same bits in one thread and in many
    mean = np.einsum("i,ij->j", W, parts)
    std = np.sqrt(np.maximum(np.einsum("i,ij->j", W, (parts - mean) ** 2), 0.0))
    centre = np.array([np.clip(mean[0], 0.0, Ww - 1.0), np.clip(mean[1], 0.0, Hh - 1.0)])
    centre, learn_at = _estimate(resp, pred, (sx, sy), mot, p, _tail(st, p), (Ww, Hh), centre, std)
    log_s = st.log_s
    # is the estimate the target? two cues (the filter's response, the colour score): _scores
    r_est, clutter_seen, colour_seen = _scores(resp, centre, bw, bh)
    cues: tuple[Cue, ...] = () if colour_seen is None else (_colour_cue(st, 1.0 - colour_seen[0], p),)
    lt_seen, lt_cues = _longterm_seen(resp, centre, bw, bh, lt, p)
    cues = cues + lt_cues
    hidden_before = st.hidden_run >= p.hidden_after
    # the estimate's place under the target's motion prior against clutter's, uniform over the window:
    # log N(c; pred, S) + log A (a place of a likelier prior and a wider window both favour the target)
    log_place = _log_place(centre, pred, sx, sy, resp.area(), p.motion_tail, _tail(st, p)) if mot is None else mm.log_place(mot, centre, resp.area())
    prior = _hidden_prior(float(st.back), p.reappear) if hidden_before else (1.0, 1.0, 1.0)
    vis = visibility(1.0 - r_est, st.target, st.clutter, p.min_std, prior=prior, log_place=log_place, cues=cues)
    present = vis.present or taken(st, obs, p)  # a tentative track's frame in doubt, if its box moved (.confirm)
    doubt = p.lookalike_doubt and present and beside(st.target, st.clutter, clutter_seen, p.min_std)  # .lookalike
    confident = vis.visible >= 0.5
    confidence = vis.visible
    run = 0 if present else st.hidden_run + 1
    hidden = run >= p.hidden_after
    srch, spread, track = _unseen(st, obs, p, pred, (sx, sy), clutter_seen, lt, run, s, dt)
    if srch.found is not None:
        confidence, run, spread = srch.confidence, 0, 0.0
    found = srch.found
    new_parts = parts[systematic_resample(lw.lw, rng, n)]
    learnt: dict[str, Any] = {}
    if found is not None:
        centre, log_s, spread = _take_found(st, found, p, new_parts, mean, hidden_before, spread)
        velocity, state = np.zeros(2), "tracked"
    elif not present:
        # hidden, or in doubt: the box holds the prediction, nothing is learnt, the velocity decays
        centre = np.array([np.clip(pred[0], 0.0, Ww - 1.0), np.clip(pred[1], 0.0, Hh - 1.0)])
        velocity = p.coast_velocity ** dt * st.velocity
        state = ("lost" if srch.covers else "occluded") if hidden else "tracked"
    elif doubt:  # a look-alike beside it: tracked, but the model, size, clutter and velocity learn nothing
        velocity, state = st.velocity, "tracked"
    else:
        centre, confident = _drift_corrected(st, resp, centre, new_parts, p, bw, bh, confident)  # .drift
        # v <- m v + (1 - m) (c_t - c_{t-1}) / dt
        velocity = p.velocity_memory * st.velocity + (1.0 - p.velocity_memory) * (centre - st.centre) / dt
        state = "tracked"
        # the model learns at the estimate; with estimate_learn at the mode (drift_correct moves the estimate only)
        log_s, learnt = _learn(st, obs, p, learn_at if p.estimate_learn else centre, r_est, colour_seen, confident)
        learnt.update(_learn_motion(st, p, resp, centre, velocity, pred, (sx, sy), (bw, bh), dt))
    if present and not doubt:
        learnt.update(_learn_clutter(st, clutter_seen, colour_seen, p.clutter_rate))
    if p.search_clutter:
        lt = _learn_search_clutter(st, lt, srch, run > 0 and found is None, p, learnt)
    if lt is not None:
        learnt["longterm"] = _learn_longterm(st, lt, lt_seen, obs, p, centre, log_s,
                                             present and found is None, confident and present and found is None)
    new_parts[:, 2] = log_s
    if mot is not None and resp1 is not None:
        # mu_t(1): the weighted responsibilities on a frame the target was tracked; else pi_t(1) (.modes)
        learnt["manoeuvre"] = mm.posterior(W, resp1) if present and found is None else float(mot.pi[1])
    back = (vis.visible + vis.partial) if hidden_before and run > 0 and found is None else 0.0
    new = replace(st, particles=new_parts, centre=centre, log_s=log_s, velocity=velocity, hidden_run=run, back=back,
                  target_state=state, spread=spread, track=track if srch.found is None else None,
                  last_grey=_last_grey(learnt.get("target", st.target), obs, p), **learnt)
    return StepResult(state=new, box=box_of(centre, log_s, geom.size0), mean=mean, std=std, ess=lw.ess,
                      log_evidence=lw.log_mean, score=r_est, confidence=float(min(max(confidence, 0.0), 1.0)),
                      target_state=state, redetected=found is not None)


def _last_grey(target: ChiSquare, obs: DCFObservation, p: DCFParams) -> np.ndarray | None:
    """The frame's grey levels kept for the next frame: always with ``camera_motion`` (:mod:`.camera`) and
    ``flow_mix`` (:mod:`.flowpred`), else while a tentative track's flow needs them (:func:`.confirm.remember`)."""
    return cam.grey8(obs.grey) if p.camera_motion or p.flow_mix > 0 else remember(target, obs, p)


def initialise(obs: DCFObservation, box: Box, p: DCFParams, rng: np.random.Generator) -> DCFState:
    """The model of ``box`` (x, y, w, h) and the particles about its centre (``ValueError`` for a box
    outside the frame)."""
    x, y, w, h = (float(v) for v in box)
    if not (w > 0 and h > 0):
        raise ValueError(f"initial box must have positive width and height, got {box}")
    Hh, Ww = obs.grey.shape
    if x >= Ww or y >= Hh or x + w <= 0 or y + h <= 0:
        raise ValueError(f"initial box {box} lies outside the {Ww}x{Hh} frame")
    centre = np.array([x + (w - 1) / 2.0, y + (h - 1) / 2.0])
    geom = tm.geometry((w, h), p)
    mdl = tm.init_model(obs.image, obs.grey, obs.is_grey, (float(centre[0]), float(centre[1])), geom, p)
    n = p.particles
    lt = init_longterm(mdl, _prior(p.prior_target, p.prior_count), _prior(p.prior_clutter, p.prior_count)) \
        if p.longterm else None
    # x_0 ~ N(centre, 1 px), log s_0 = 0
    parts = np.column_stack([centre[0] + rng.normal(0.0, 1.0, n), centre[1] + rng.normal(0.0, 1.0, n), np.zeros(n)])
    return DCFState(geom=geom, model=mdl, particles=parts, centre=centre, log_s=0.0, velocity=np.zeros(2),
                    target=_prior(p.prior_target, p.prior_count), clutter=_prior(p.prior_clutter, p.prior_count),
                    ctarget=_prior(p.prior_colour_target, p.prior_count),
                    cclutter=_prior(p.prior_colour_clutter, p.prior_count), longterm=lt,
                    last_grey=_last_grey(_prior(p.prior_target, p.prior_count), obs, p))


class DCFTracker:
    """The correlation-filter tracker's :class:`gflow_core.tracker.TrackingFilter` (stateless: everything
    is in :class:`.state.DCFState`)."""

    name = "dcf"
    Params = DCFParams

    def observe(self, params: DCFParams, image: np.ndarray) -> DCFObservation:
        """The frame (``(H, W, 3)`` BGR or ``(H, W)`` grey uint8), its grey levels and whether it is grey.

        Raises :class:`UnusableFrame` for a uniform frame and ``ValueError`` for one that is not an image."""
        grey = to_grey(image)
        if grey.size == 0 or int(grey.max()) == int(grey.min()):
            raise UnusableFrame("uniform frame, no evidence")
        if grey.shape[0] < 2 * params.cell or grey.shape[1] < 2 * params.cell:
            raise ValueError(f"frame {grey.shape[1]}x{grey.shape[0]} is smaller than two cells")
        g = is_grey(image) if image.ndim == 3 else True
        img = grey if g else np.ascontiguousarray(image[..., :3])
        return DCFObservation(img, grey.astype(np.float32), g)

    def init(self, params: DCFParams, obs: DCFObservation, box: Box, rng: FrameRng,
             resources: Mapping[str, Any]) -> tuple[DCFState, Estimate]:
        """The model of ``box`` and the particles about it (``ValueError`` for a box outside the frame)."""
        st = initialise(obs, box, params, rng.stream(PURPOSE_INIT))
        a = np.array([st.centre[0], st.centre[1], 0.0, 1.0])
        est = self.estimate(params, rng.t, box_of(st.centre, 0.0, st.geom.size0), "init", a, a, np.zeros(4),
                            float(params.particles), 0.0, 1.0, 1.0, "tracked")
        return st, est

    def propose(self, params: DCFParams, state: DCFState, obs: DCFObservation | None, rng: FrameRng,
                dt: float = 1.0) -> DCFProposal:
        """The random walk about the posterior's particles (:func:`.dynamics.walk`) from
        ``rng.stream(PURPOSE_WALK)`` (the frame is not read)."""
        alpha = walk(params, alpha_of(state.particles), state.geom.size0, rng.stream(PURPOSE_WALK), dt)
        return DCFProposal(particles_of(alpha), dt)

    def update(self, params: DCFParams, state: DCFState, proposal: DCFProposal, obs: DCFObservation,
               rng: FrameRng) -> tuple[DCFState, Estimate]:
        """:func:`step` of the proposal on the frame. The estimate's phase is ``track``, ``redetect`` (the
        search found a hidden target again this frame), ``occluded`` or ``lost``."""
        res = step(state, obs, proposal.particles, params, rng.stream(PURPOSE_STEP), proposal.dt)
        return res.state, box_step_estimate(rng.t, res, params.particles)

    def coast(self, params: DCFParams, state: DCFState, rng: FrameRng,
              obs: DCFObservation | None = None) -> tuple[DCFState, Estimate]:
        """No evidence from frame ``rng.t``: the posterior unchanged; the target is where it was judged to
        be, with no confidence."""
        a = np.array([state.centre[0], state.centre[1], 0.0, float(np.exp(state.log_s))])
        judged = "tracked" if state.hidden_run == 0 else state.target_state
        est = self.estimate(params, rng.t, box_of(state.centre, state.log_s, state.geom.size0), "coast", a, a,
                            np.zeros(4), float(params.particles), 0.0, 0.0, 0.0, judged)
        return replace(state, target_state=judged), est

    def estimate(self, params: DCFParams, t: int, box: tuple[float, float, float, float], phase: str,
                 alpha: np.ndarray, mean: np.ndarray, std: np.ndarray, ess: float, log_evidence: float,
                 score: float, confidence: float, target_state: str) -> Estimate:
        """The tracker's estimate of frame ``t``. ``extras``: ``alpha`` (4,) the estimate (x, y, 0, s);
        ``mean``, ``std`` (4,) the posterior's mean and std of alpha (std of log s); ``ess``;
        ``log_evidence``; ``score``, the response at the estimate; ``n``, the number of particles."""
        return box_estimate(t, box, phase, alpha, mean, std, ess, log_evidence, score, params.particles, confidence,
                            target_state)


#: the one instance (it keeps no state)
TRACKER = DCFTracker()
