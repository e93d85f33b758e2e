"""The target's roll: in-plane rotation searched as DSST searches scale.

The correlation filter is learnt on an upright window, so a target that rolls decorrelates from it
and the tracker loses it (a roll of 35 degrees is enough). Here the target's roll angle ``theta`` is
part of the state, and every window the tracker samples of the target -- to detect it
(:func:`.model.respond`) and to learn it (:func:`.model.learn`) -- is sampled rolled by ``theta``
about its centre (:func:`.features.sample`), so the filter keeps seeing the target upright. The
reported box stays the axis-aligned box of the target's size at its centre.

:func:`angle_change` updates ``theta`` on a frame the target is present: the detection filter is
applied to the windows at the estimate rolled by ``theta + i roll_step`` (``i = -roll_steps ..
roll_steps``), each scored by its response's maximum within ``roll_reach`` cells of the window's
centre (the placement may differ a little with the angle), and the best angle is refined by the
parabola through it and its two neighbours (as DSST's and SAMF's scale search, here over the roll;
the rotation-aware correlation trackers of Zhang et al. 2015 and Li & Zhu's LDES, AAAI 2019, which
estimates scale and rotation jointly by phase correlation in log-polar coordinates, estimate the
same angle differently). A prior pulls ``theta`` back towards upright: each angle's score is
lowered by ``roll_prior`` times its squared angle in radians. The held angle is kept unless another
scores more than ``roll_margin`` above it (hysteresis): a parabola through three nearly equal
scores leans one way or the other, and on a target that changes its look rather than its roll
those leans walked the window round by 20 degrees (caviar1's ``look`` stress case).

With ``roll_explain`` the search's answer is a test of hypotheses (:func:`explained`) on the
distribution of the filter's distance rho = 1 - score the tracker learns on present frames (Toyama &
Blake's chi-square model, eq. 10 of :mod:`gflow_core.visibility`): the gate has found the look unusual
at the held roll; the held roll is kept while its own window (the placement free within
``roll_reach``) is within ``roll_explain`` standard deviations of the target's mean (H0, "not
rolled", is not refused), and a new roll is taken only when H0 is refused and the rolled window's
distance is back within that level (the roll explains the unusual look) and beats the held roll by
``roll_margin``. When no roll explains the frame -- the face turning out of plane, a change of look,
the box on something else -- the held roll relaxes ``roll_relax`` degrees towards upright, the prior's
angle, instead of following the best of several poor scores. On grey david_indoor a window rolled
by -10 degrees scored a little better than the upright one as the man walked into a lit room (0.617
against 0.566, the target's usual 0.60 +- 0.04) and was taken; when he turned to profile the box slid
off the face, the roll walked on to -20 degrees on scores no roll explained (0.27-0.36), and the
rolled filter never came back to the face the upright one found again 25 frames later. Departure: the papers' rotation searches (above) take the best
angle; here an angle must also fit the target's learnt distribution, as the tracker's presence
judgement does, and the relaxation is a fixed step, not a posterior over the roll.

With ``roll_best`` as well the held roll has no privilege beyond ``roll_margin``: the roll is the best
scoring of those that explain the frame, the held one among them, as the papers' searches take the
best angle, with the test of fit deciding only which angles may be taken (and the relaxation when
none may). Without it H0 is kept whenever the held window is within the level, and the level follows
the target's distances learnt on every present frame: a target whose distance spreads widely (tiger1's
toy, 0.65 +- 0.11) keeps an upright window within 2 sd long after the window rolled by 10 degrees
scores far better (tiger1's ``roll-camera-20``: 0.183 upright against 0.226 rolled at frame 46, the
level at a score of 0.13), and a target that rolls steadily drags the mean with it (caviar1's
``roll-target-35``: the rolled window 0.227 against the held 0.185, within the level at 0.16), so
the box leaves the target while the roll stays put.

:func:`angle_change` runs only on frames the target was judged present, after the particles were
weighed by the held roll's response. A roll fast enough to collapse the filter's score at the held
angle is judged a disappearance instead (tiger1's ``roll-camera-20`` with seed 2's draws: hidden on
frames 47-50 with the box still on the toy, then the search takes clutter). With ``roll_detect`` the
roll is also searched when the target is detected (:func:`detect`): on a confirmed track's frame whose
filter score at the response's peak is beyond ``roll_gate``, the windows rolled ``roll_step`` either
way are read as well, and the best whose own peak explains the look beats the held one by more than
``roll_margin``, its response weighs the particles and judges the target's presence -- SAMF's joint
search of place and scale (Li & Zhu, ECCV workshops 2014), over the roll. Departure: SAMF searches
its scales on every frame; here only on frames the held roll's look is unusual, and the scale filter
stays DSST's.

Departures: the scale filter (:mod:`.scale`) and the search for a hidden target
(:func:`.model.search`) keep their windows upright; the first frame's filter (the anchor) is
the first box upright, so the target is taken to be upright when it is given. Everything is
deterministic (no random draws).
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from . import filter as cf
from .model import Geometry, Response, TargetModel, detection_filter, names_of, window
from .gate import within
from .params import DCFParams
from ..visibility import ChiSquare

__all__ = ["angle_scores", "refine", "angle_change", "explained", "held", "detect"]


def angle_scores(model: TargetModel, image: np.ndarray, grey: np.ndarray, centre: tuple[float, float], log_s: float,
                 angles: np.ndarray, geom: Geometry, p: DCFParams) -> np.ndarray:
    """(A,) float64: for each roll ``angles`` (A,) radians, the detection filter's response to the window
    at ``centre``, scale exp(``log_s``), rolled by it: the maximum of the response within ``roll_reach``
    cells of the window's centre (on the cells, no upsampling)."""
    k = geom.k(log_s)
    det = detection_filter(model, p.anchor_weight, p.channel_intensity)
    wc, hc = geom.cells
    r = p.roll_reach
    out = np.empty(len(angles))
    for i, a in enumerate(angles):
        win = window(image, grey, centre, geom.template, k, geom.cell, None, float(a), names_of(model.colour_mode, p))
        # Y = sum_l D_l Z_l                                                          (DSST eq. 6)
        y = cf.centred(np.fft.irfft2(cf.respond(det, cf.spectrum(win.x, geom.window)), s=(hc, wc)))
        out[i] = float(y[hc // 2 - r: hc // 2 + r + 1, wc // 2 - r: wc // 2 + r + 1].max())
    return out


def refine(angles: np.ndarray, scores: np.ndarray) -> float:
    """The angle of the best score, refined by the parabola through it and its neighbours (equally spaced
    ``angles``; at the ends of the range, the end itself)."""
    j = int(np.argmax(scores))
    if j == 0 or j == len(scores) - 1:
        return float(angles[j])
    ym, y0, yp = float(scores[j - 1]), float(scores[j]), float(scores[j + 1])
    curv = ym - 2.0 * y0 + yp
    if curv >= 0.0:
        return float(angles[j])
    step = float(angles[j + 1] - angles[j])
    # the vertex of the parabola through (-1, ym), (0, y0), (1, yp): x* = (ym - yp) / (2 (ym - 2 y0 + yp))
    return float(angles[j]) + step * min(max(0.5 * (ym - yp) / curv, -0.5), 0.5)


def angle_change(model: TargetModel, image: np.ndarray, grey: np.ndarray, centre: tuple[float, float], log_s: float,
                 theta: float, geom: Geometry, p: DCFParams, target: ChiSquare | None = None) -> float:
    """The target's roll (radians) after a frame it is present at ``centre``: the best of the rolls
    ``theta + i roll_step`` (module docstring), within ``roll_max`` degrees of upright; ``theta``
    itself without ``roll_step``. With ``roll_explain`` and the target's distance distribution
    ``target``, a roll is taken only when it explains the frame (:func:`explained`)."""
    if p.roll_step <= 0:
        return theta
    step, lim = math.radians(p.roll_step), math.radians(p.roll_max)
    angles = np.clip(theta + step * np.arange(-p.roll_steps, p.roll_steps + 1), -lim, lim)
    angles = np.unique(angles)
    raw = angle_scores(model, image, grey, centre, log_s, angles, geom, p)
    # the roll's prior: score(a) - roll_prior a^2
    scores = raw - p.roll_prior * angles ** 2
    held_at = int(np.argmin(np.abs(angles - theta)))
    if p.roll_explain > 0 and target is not None:
        return explained(angles, raw, scores, held_at, theta, target, p)
    j = int(np.argmax(scores))
    if j == held_at or scores[j] <= scores[held_at] + p.roll_margin:
        # the held roll scores best, or another beats it by no more than roll_margin: held, so that
        # neither a parabola's lean nor noise walks the window round
        return theta
    if len(angles) < 3:
        return float(angles[j])
    return refine(angles, scores)


def explained(angles: np.ndarray, raw: np.ndarray, scores: np.ndarray, held_at: int, theta: float,
              target: ChiSquare, p: DCFParams) -> float:
    """The roll after a frame whose look was unusual at the held roll ``theta`` (the gate opened), as a
    test of hypotheses on the target's distance distribution ``target`` (rho = 1 - score).

    ``angles`` (A,) radians, ``raw`` (A,) their scores (:func:`angle_scores`), ``scores`` (A,) with the
    prior, ``held_at`` the index of the held roll. H0, "the target has not rolled": the held roll's
    distance is within ``roll_explain`` standard deviations above the target's mean (the look is
    usual there once the placement is free within ``roll_reach``): ``theta`` is kept. H1, "it rolled
    by a": H0 is refused and a's distance is within that level (the roll explains the unusual look),
    and a beats the held roll by more than ``roll_margin``: the best such a is taken (refined by the
    parabola when it is the best of all). With ``roll_best`` the held roll is not kept for being within
    the level alone: it is one of the rolls that explain the frame, and is kept only when no other of
    them beats it by more than ``roll_margin``. Neither (an out-of-plane turn, a change of look, another
    object): no roll explains the frame, and the held roll relaxes ``roll_relax`` degrees towards
    upright, the prior's angle."""
    ms, lvl = p.min_std, p.roll_explain
    ok = np.array([within(target, 1.0 - float(r), lvl, ms) for r in raw])
    # H0: rho(theta) <= E[rho] + roll_explain sd[rho]; with roll_best, the held roll is one explained roll
    # among the others and is kept only when none beats it by roll_margin
    if ok[held_at] and not p.roll_best:
        return theta
    if ok.any():
        j = int(np.flatnonzero(ok)[np.argmax(scores[ok])])
        if scores[j] <= scores[held_at] + p.roll_margin:
            return theta
        if len(angles) >= 3 and j == int(np.argmax(scores)):
            return refine(angles, scores)
        return float(angles[j])
    # no roll explains the frame: theta <- theta - sign(theta) min(|theta|, roll_relax)
    return math.copysign(max(abs(theta) - math.radians(p.roll_relax), 0.0), theta)


def held(target: ChiSquare, rho: float, p: DCFParams, theta: float = 0.0) -> bool:
    """Whether the frame keeps the held roll ``theta`` unsearched: always without ``roll_step``; with
    ``roll_gate``, when the filter's distance ``rho`` at the estimate is at most the target's mean on
    present frames plus ``roll_gate`` standard deviations (the target looks as usual, so it has not
    rolled away from the held angle; :func:`.gate.within`) -- with ``roll_return``, only while the
    held roll is upright: the filter learns a rolled window as it goes, so a target that rolls back
    may keep looking usual at the old angle."""
    if p.roll_step <= 0:
        return True
    return p.roll_gate > 0 and (theta == 0.0 or not p.roll_return) and within(target, rho, p.roll_gate, p.min_std)


def _filter_peak(resp: Response) -> float:
    """The filter's own response (not merged with colour) at the merged response's peak."""
    xy, _ = resp.peak()
    return float(resp.at(xy[None, :], "cf")[0])


def detect(resp: Response, respond: Callable[[float], Response], theta: float, target: ChiSquare,
           p: DCFParams, verify: Callable[[Response, float], bool] | None = None) -> tuple[Response, float]:
    """With ``roll_detect``, the roll searched when the target is detected, before the particles are weighed
    and its presence judged (SAMF's joint search of place and scale, Li & Zhu 2014, over the roll): when
    the filter's score at the peak of ``resp`` (the response of the window rolled by the held ``theta``)
    is unusual (beyond ``roll_gate`` standard deviations of the target's distance ``target``), the
    windows rolled ``roll_step`` either way (``respond(angle)``) are read too, and the best of those whose
    score at their own peak explains the look (within ``roll_explain`` standard deviations; any without
    ``roll_explain``) and beats the held one by more than ``roll_margin`` (each lowered by the prior
    ``roll_prior`` a^2) is taken: (its response, its angle). Otherwise (``resp``, ``theta``). With ``verify``
    (``verify(response, angle)``, :mod:`.verify`), a rolled window that would be taken must also pass it:
    refused, the next best is tried."""
    if p.roll_step <= 0 or not p.roll_detect:
        return resp, theta
    held_score = _filter_peak(resp)
    if within(target, 1.0 - held_score, p.roll_gate, p.min_std):
        return resp, theta
    step, lim = math.radians(p.roll_step), math.radians(p.roll_max)
    best, best_resp, best_angle = held_score - p.roll_prior * theta ** 2 + p.roll_margin, resp, theta
    for i in range(1, p.roll_steps + 1):
        for a in (theta - i * step, theta + i * step):
            a = float(np.clip(a, -lim, lim))
            if a == theta:
                continue
            r = respond(a)
            sc = _filter_peak(r)
            if p.roll_explain > 0 and not within(target, 1.0 - sc, p.roll_explain, p.min_std):
                continue
            # the roll's prior: score(a) - roll_prior a^2
            if sc - p.roll_prior * a ** 2 > best and (verify is None or verify(r, a)):
                best, best_resp, best_angle = sc - p.roll_prior * a ** 2, r, a
    return best_resp, best_angle
