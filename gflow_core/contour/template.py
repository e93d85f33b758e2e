"""The chamfer tracker's template update with drift correction (Matthews, Ishikawa & Baker,
"The template update problem", PAMI 2004: their strategy 3,
"template update with drift correction"), on chamfer templates.

The K = 1 chamfer tracker's template is the edge pixels of the first box. A target whose outline
changes for good (dollar: the note is folded in two by frame 60) then matches its own template
less well than a look-alike of its first outline (dollar, frame 130: an identical unfolded note
laid beside it), and the filter and the lost guard both move to the look-alike. Matthews et al.
update the template from the current match, T_{n+1} = I_n(p_n), but only where that does not
drift: the first template T_1 is aligned again, starting at the current match p_n, giving p*_n,
and

    T_{n+1} = I_n(p*_n)   if ||p*_n - p_n|| <= epsilon,   else   T_{n+1} = T_n

Here the "image" is the frame's edge map and the alignment is the chamfer distance (M2 eq. 5):

* :func:`align_first` -- p*_n: the translation (and, if asked, the log s step) minimising the
  filter's cost lambda rho(T_p T_1, z_n) + (log s)^2 / (2 scale_prior^2) over a grid of whole
  pixels within ``reach`` of the current match (theta kept: a local exhaustive search stands in
  for the paper's gradient descent, which the truncated chamfer profile would stop at the first
  plateau);
* the update is made only where it is needed: where T_1 fits the target at p*_n more than
  ``template_gain`` times worse than it fitted it on the first frames (its mean rho over the first
  ``template_every`` frames). Where the first template still explains the target, as on the
  sequences whose target keeps its outline, an update would only add the risk of drift;
* :func:`template_at` -- I_n(p*_n): the edge pixels of the box at p*_n, carried back into the
  template's frame by T_{p*_n}^{-1} (as many points at most as the first template was allowed).

Departures: the paper updates every frame and compares the two alignments' parameters; here the
filter (:mod:`.tracker`) updates after ``template_every`` frames in a row that the lost
guard judged found, only where T_1 has come to fit badly (above), compares the centres in units of
the box's size (and, with ``template_scale``, requires the same size), and takes the lost guard's
anchor again from the same corrected box (the guard then verifies against the look the filter
follows), where the first anchor, aligned again by correlation (:func:`anchor_peak`), lands as near.
"""

from __future__ import annotations

import numpy as np

from .. import redetect, similarity
from ..m2.chamfer import chamfer_distance
from ..m2.tracking import template_from_edges
from ..regions import region

__all__ = ["align_first", "fit", "still_fits", "template_at", "anchor_region", "anchor_peak"]


def fit(chamfer_img: np.ndarray, pts: np.ndarray, alpha: np.ndarray) -> float:
    """rho(T_alpha x~, z): the chamfer distance (M2 eq. 5) of the template ``pts`` (P, 2) under ``alpha`` (4,)."""
    return float(chamfer_distance(chamfer_img, similarity.apply_many(np.asarray(alpha, dtype=np.float64)[None], pts),
                                  np.array([pts.shape[0]]), outside=float(np.max(chamfer_img)))[0])


def still_fits(chamfer_img: np.ndarray, pts: np.ndarray, alpha: np.ndarray, first_fit: tuple[float, int],
               gain: float) -> bool:
    """Whether the template ``pts`` (P, 2) under ``alpha`` (4,) fits the frame's edges within ``gain``
    times the first template's mean fit on the first frames, ``first_fit`` (sum of rho, count):

        rho(T_alpha x~, z_n) <= gain * mean(rho_1)                                    (M2 eq. 5)

    False while no first frame has been measured (count 0). The same test, with the same ``gain``,
    as the one that opens the template update (there on T_1, here on the current template)."""
    n = int(first_fit[1])
    return n > 0 and fit(chamfer_img, pts, alpha) <= gain * float(first_fit[0]) / n


def align_first(chamfer_img: np.ndarray, first: np.ndarray, alpha: np.ndarray, reach: int,
                log_steps: tuple[float, ...] = (0.0,), lam: float = 1.0, scale_prior: float = 0.0
                ) -> tuple[np.ndarray, float]:
    """p*_n: the first template aligned again from the current match ``alpha``.

    Parameters
    ----------
    chamfer_img : (H, W) float, the frame's chamfer image gamma(z_n, .).
    first : (P, 2) float64, T_1 in its own frame.
    alpha : (4,) float64, the current match p_n = (ux, uy, theta, s).
    reach : int, half-width of the grid of whole-pixel translations searched, px.
    log_steps : changes of log s searched at every translation.
    lam, scale_prior : the filter's lambda and the std of its prior on log s (0: none): the cost
        minimised is its negative log-likelihood, lambda rho + (log s)^2 / (2 scale_prior^2).

    Returns
    -------
    (4,) float64 : alpha with the centre (and s) moved to the grid point of least cost (the nearest
    such point on ties, the unchanged scale first, so a flat neighbourhood keeps p_n);
    float : rho(T_{p*} T_1, z_n) there.
    """
    r = np.arange(-reach, reach + 1, dtype=np.float64)
    dx, dy = np.meshgrid(r, r)
    d2 = np.tile(dx.ravel() ** 2 + dy.ravel() ** 2, len(log_steps))
    rank = np.repeat(np.argsort(np.argsort(np.abs(np.asarray(log_steps)), kind="stable")), dx.size)
    grid = np.repeat(np.asarray(alpha, dtype=np.float64)[None], dx.size * len(log_steps), axis=0)
    grid[:, 0] += np.tile(dx.ravel(), len(log_steps))
    grid[:, 1] += np.tile(dy.ravel(), len(log_steps))
    grid[:, 3] *= np.exp(np.repeat(np.asarray(log_steps, dtype=np.float64), dx.size))
    # lambda rho(T_p T_1, z_n) at every p of the grid                          (M2 eq. 5)
    rho = chamfer_distance(chamfer_img, similarity.apply_many(grid, first), np.full(len(grid), first.shape[0]),
                           outside=float(np.max(chamfer_img)))
    cost = lam * rho
    if scale_prior > 0:
        # + (log s)^2 / (2 scale_prior^2), the filter's prior on the size
        cost = cost + np.log(grid[:, 3]) ** 2 / (2.0 * scale_prior ** 2)
    # the least cost, then the nearest to the start, then the smallest change of scale
    best = int(np.lexsort((rank, d2, cost))[0])
    return grid[best], float(rho[best])


def template_at(edges: np.ndarray, alpha: np.ndarray, size: np.ndarray, max_points: int) -> np.ndarray | None:
    """I_n(p*_n): the edge pixels of the box of ``size`` (w, h) * s centred at ``alpha``'s centre, in
    the template's frame (T_alpha^{-1} applied), at most ``max_points`` of them.

    Parameters
    ----------
    edges : (H, W) uint8, non-zero on edges.
    alpha : (4,) float64, p*_n.
    size : (2,) float64, the first box's (w, h).

    Returns
    -------
    (P, 2) float64, or None where the box holds no edge pixel or lies off the frame.
    """
    w, h = (float(v) * float(alpha[3]) for v in size)
    box = (float(alpha[0]) - (w - 1) / 2.0, float(alpha[1]) - (h - 1) / 2.0, w, h)
    try:
        pts = template_from_edges(edges, box, max_points)
    except ValueError:
        return None
    # x~ = T_alpha^{-1} z: the box's edge pixels (relative to its centre) back in the template frame
    inv = similarity.invert(np.array([0.0, 0.0, alpha[2], alpha[3]]))
    return similarity.apply(inv, pts)


def anchor_region(feat: np.ndarray, res: tuple[int, int], size: tuple[float, float], alpha: np.ndarray
                  ) -> np.ndarray:
    """The lost guard's anchor channels (th, tw, C) float32 taken at the box of ``size`` (w, h) * s
    centred at ``alpha``'s centre, resampled to the anchor's resolution ``res`` (tw, th), as
    :func:`gflow_core.m2.lost.observe` samples the region of an estimate."""
    tw, th = res
    k = tw / (size[0] * float(alpha[3]))
    z = region(feat, np.asarray(alpha[:2], dtype=np.float64), (tw / k, th / k), k)
    return np.ascontiguousarray(z[:th, :tw])


def anchor_peak(feat: np.ndarray, first: np.ndarray, size: tuple[float, float], alpha: np.ndarray, reach: float
                ) -> tuple[np.ndarray, float]:
    """The first anchor aligned again from the estimate: the centre (x, y) of the best normalised
    correlation of the channels ``first`` (th, tw, C) of the first box (of ``size`` (w, h)) over
    centres within ``reach`` image pixels of ``alpha``'s centre, at the scale s of ``alpha`` (the
    nearest to it among equals), and the image pixels one step of that search spans.

    Parameters
    ----------
    feat : (H, W, C) float32, the frame's orientation channels.
    """
    th, tw = first.shape[:2]
    k = tw / (size[0] * float(alpha[3]))
    c = np.asarray(alpha[:2], dtype=np.float64)
    win = region(feat, c, (tw / k + 2.0 * reach, th / k + 2.0 * reach), k)
    r = redetect.ncc(win, first)
    Wn, Hn = win.shape[1], win.shape[0]
    # response (u, v) has the anchor's centre at window pixel (u + (tw - 1) / 2, v + (th - 1) / 2)
    origin = c + (np.array([(tw - 1) / 2.0, (th - 1) / 2.0]) - np.array([(Wn - 1) / 2.0, (Hn - 1) / 2.0])) / k
    xs, ys = redetect.response_centres(origin, k, r.shape)
    d2 = (xs[None, :] - c[0]) ** 2 + (ys[:, None] - c[1]) ** 2
    best = np.lexsort((d2.ravel(), -r.ravel().astype(np.float64)))[0]
    i, j = divmod(int(best), r.shape[1])
    return np.array([xs[j], ys[i]]), 1.0 / k
