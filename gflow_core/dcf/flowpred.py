"""The target's own displacement, matched frame to frame, as a second mode of the motion prior (``flow_mix``;
off at 0).

The constant-velocity prediction c_{t-1} + v dt is the past's guess of where the target went. When
the target speeds up, turns, or is seen only every third frame (a live run that skips frames), it
overshoots or falls short by more than the motion prior's spread, the filter's window is centred
where the target is not, and the particles are pulled there (tiger1 at every 3rd frame, the toy
jumping 20-40 px a frame). The frames themselves say where the box went: the last frame's box, cut
from its grey levels, matched over this frame by normalised cross-correlation within ``REACH`` box
sides each way (:func:`matched`), its peak refined to a sub-pixel place by a parabola on each axis.
That displacement d enters as a second mode of a mixture prior beside the constant-velocity one, as
the two modes of a mixed-state particle filter (:mod:`.modes`; Isard & Blake, ICCV 1998):

    p(c_t) = pi_t(0) N(c_t; c_{t-1} + v dt, S_0) + pi_t(1) N(c_t; c_{t-1} + d, S_1),     (eq. 1)

S_0 = (sigma_p sqrt(dt) + beta |v| dt)^2 I as without the mode, S_1 = (sigma_p sqrt(dt))^2 I (the
measured displacement carries no speed's share), both widened by the place's spread in quadrature;
and the second mode's prior probability follows a Markov chain that leaves a mode with probability
q = ``flow_mix`` a frame,

    pi_t(1) = (1 - q) mu_{t-1}(1) + q (1 - mu_{t-1}(1)),                                  (eq. 2)

mu_{t-1}(1) its posterior after frame t-1, the particles' weighted responsibilities (the tracker keeps
it in the state's ``manoeuvre``, as :mod:`.modes` does). Each particle of the proposal draws its mode
from pi_t and moves by it; the filter's window is centred at the mixture's mean
c_{t-1} + pi_t(0) v dt + pi_t(1) d. The likelihood picks the mode.

The match is used only when it is reliable (:meth:`Match.reliable`): NCC at least ``MIN_NCC``, and
Lowe's ratio test (IJCV 2004, sec. 7.1) against the best placement half a box or more away, at Lowe's
0.8 on distances (``flow_ratio`` = 0.64 on the squared distances 2 (1 - NCC)): a box that matches a
look-alike, a repeated texture or mostly its own background as well as itself says nothing of where
the target went. Only when the target was judged present on the last frame; else the prior is the
constant-velocity one alone, as with ``flow_mix`` 0.

Departures: Median Flow (Kalal et al., ICPR 2010) moves its box by the median flow of a grid of
points; here the box's displacement is one match of the whole box (the grid of 11 px Lucas-Kanade windows
of :mod:`.coherence` misses a 30 x 36 px target that moved 20 px on a textured background, the windows'
background outweighing it: ``tests/core/test_dcf_flow.py``), and it
only proposes: the filter's likelihood weighs. Isard & Blake's modes are two dynamics learnt from
training motion; here the second is a measurement of this frame, and the mode's posterior is collapsed
after each frame (IMM's mixing, as :mod:`.modes`).

Off by default: over the nine shared sequences and five variants of them (three seeds each) it gains
at every 3rd frame and loses on the sequences as they are and on noisy frames (``docs/dcf-development.md``,
"The target's own displacement as a second motion mode").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from .camera import grey8
from .modes import Motion
from .params import DCFParams
from .state import DCFObservation, DCFState

__all__ = ["Match", "matched", "observed", "mixture", "REACH", "MIN_NCC"]

#: the search region of frame t: the last box widened by this many times its longer side each way
REACH = 1.5
#: the least NCC of the best match for the displacement to be used (two unrelated patches of n pixels
#: have NCC about 0, std 1 / sqrt(n): 0.03 for a 30 x 36 box)
MIN_NCC = 0.5


@dataclass(frozen=True)
class Match:
    """The last box's best match in frame t: ``shift`` (2,) float64 its displacement (x, y) px, sub-pixel,
    ``ncc`` the match's normalised cross-correlation and ``second`` the runner-up's, the best placement
    outside half a box of it (-1 with none)."""

    shift: np.ndarray
    ncc: float
    second: float

    def reliable(self, ratio: float) -> bool:
        """NCC at least ``MIN_NCC``, and Lowe's ratio test (IJCV 2004, sec. 7.1) on squared distances:
        d^2 <= ``ratio`` d2^2, d^2 = 2 (1 - NCC) the squared distance of two patches normalised to zero mean and
        unit norm, d2 the runner-up's (Lowe's 0.8 on distances is 0.64 here)."""
        # 2 (1 - ncc) <= ratio 2 (1 - second)
        return self.ncc >= MIN_NCC and (1.0 - self.ncc) <= ratio * (1.0 - self.second)


def _vertex(a: float, b: float, c: float) -> float:
    """The offset in (-1/2, 1/2) of the vertex of the parabola through (-1, a), (0, b), (1, c) (0 when b is
    no maximum)."""
    d = a - 2.0 * b + c
    # x* = (a - c) / (2 (a - 2 b + c))
    return 0.0 if d >= 0 else float(np.clip(0.5 * (a - c) / d, -0.5, 0.5))


def matched(prev: np.ndarray, cur: np.ndarray, box: tuple[float, float, float, float]) -> Match | None:
    """The box ``box`` (x, y, w, h) of the (H, W) uint8 frame ``prev`` matched over frame ``cur`` within
    ``REACH`` of its longer side each way: the displacement of the NCC's peak, refined by a parabola on each
    axis; None for a box not wholly inside the frame or smaller than 4 px a side."""
    H, W = prev.shape
    x0, y0 = int(round(box[0])), int(round(box[1]))
    x1, y1 = x0 + int(round(box[2])), y0 + int(round(box[3]))
    if x0 < 0 or y0 < 0 or x1 > W or y1 > H or x1 - x0 < 4 or y1 - y0 < 4:
        return None
    r = int(round(REACH * max(box[2], box[3])))
    rx0, ry0, rx1, ry1 = max(0, x0 - r), max(0, y0 - r), min(W, x1 + r), min(H, y1 + r)
    # NCC(u, v) = sum (T - mean T)(I_uv - mean I_uv) / (|T - mean T| |I_uv - mean I_uv|) over the region's placements
    ncc = cv2.matchTemplate(cur[ry0:ry1, rx0:rx1], prev[y0:y1, x0:x1], cv2.TM_CCOEFF_NORMED)
    _, top, _, (px, py) = cv2.minMaxLoc(ncc)
    dx = _vertex(*ncc[py, px - 1:px + 2]) if 0 < px < ncc.shape[1] - 1 else 0.0
    dy = _vertex(*ncc[py - 1:py + 2, px]) if 0 < py < ncc.shape[0] - 1 else 0.0
    hw, hh = (x1 - x0) // 2, (y1 - y0) // 2
    rest = ncc.copy()
    rest[max(0, py - hh):py + hh + 1, max(0, px - hw):px + hw + 1] = -1.0
    return Match(np.array([rx0 + px + dx - x0, ry0 + py + dy - y0], dtype=np.float64), float(top),
                 float(rest.max()))


def observed(st: DCFState, obs: DCFObservation, ratio: float) -> np.ndarray | None:
    """(2,) px the displacement of the last frame's box to frame t by its best match (:func:`matched`), or None
    when there is no last frame kept, the target was not judged present on it, or the match is not reliable
    (:meth:`Match.reliable` with ``ratio``)."""
    if st.last_grey is None or st.last_grey.shape != obs.grey.shape or st.hidden_run > 0 or st.spread > 0:
        return None
    s = float(np.exp(st.log_s))
    w, h = st.geom.size0[0] * s, st.geom.size0[1] * s
    box = (float(st.centre[0] - (w - 1) / 2.0), float(st.centre[1] - (h - 1) / 2.0), w, h)
    m = matched(st.last_grey, grey8(obs.grey), box)
    return m.shift if m is not None and m.reliable(ratio) else None


def mixture(p: DCFParams, mu: float, centre: np.ndarray, velocity: np.ndarray, shift: np.ndarray,
            box: tuple[float, float], extra: float, spread: float, dt: float) -> Motion:
    """The two modes' prior of frame t (eq. 1, 2): constant velocity ``velocity`` (2,) px / frame with the
    speed's share ``extra`` = beta |v| dt of the noise, and the flow's displacement ``shift`` (2,) px; ``mu``
    the flow mode's posterior after frame t-1, ``centre`` (2,) the last estimate, ``box`` (w, h) px, ``spread``
    px the place's spread (in quadrature), ``dt`` frame periods."""
    q = p.flow_mix
    # eq. 2: pi_t(1) = (1 - q) mu_{t-1}(1) + q (1 - mu_{t-1}(1))
    pi1 = (1.0 - q) * mu + q * (1.0 - mu)
    pi = np.array([1.0 - pi1, pi1])
    c = centre.astype(np.float64)
    pred = np.stack([c + velocity * dt, c + shift])
    noise = np.array([extra, 0.0])
    base = p.motion_prior * math.sqrt(dt) * np.asarray(box, dtype=np.float64)
    # eq. 1: S_m = (sigma_p sqrt(dt) + noise_m)^2, widened by the spread in quadrature
    std = np.hypot(base[None, :] + noise[:, None], spread)
    # the mixture's mean: c_{t-1} + pi_t(0) v dt + pi_t(1) d
    mean = c + pi[0] * velocity * dt + pi[1] * shift
    return Motion(pi, pred, std, noise, mean, c)
