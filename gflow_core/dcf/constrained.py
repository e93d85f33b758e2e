"""A correlation filter whose support is the target: ridge regression under a spatial mask, by ADMM.

A filter as large as its window learns the background inside the window too: on a fixed camera
the static background pulls the response toward where the target was, and a wide window (to
follow fast motion) is mostly background. Galoogahi, Fagg & Lucey ("Learning
background-aware correlation filters", ICCV 2017, BACF) and Lukezic et al. (CSR-DCF, CVPR
2017) keep the window wide -- every real shift of the background is a negative example -- but
constrain the filter to the target's region:

    min_h  1/2 || y - sum_l x_l * h_l ||^2 + lambda/2 sum_l || h_l ||^2   s.t.  h_l = m . h_l,

m a binary mask over the window's cells. The problem is split (ADMM, BACF eq. 5-12; CSR-DCF eq.
4-10) with an unconstrained copy g = h, a Lagrange multiplier zeta and a penalty mu:

* g-step, per frequency t (the data term's matrix is the rank-one x x^H, inverted by
  Sherman-Morrison, BACF eq. 10-11): with u = conj(X(t)) and F = conj(G(t)) the filter as
  detection applies it (:func:`gflow_core.dcf.filter.respond`),

      (u u^H + mu I) F = r,   r = u Y(t) + mu K(t) - Xi(t),
      F = (r - u (u^H r) / (mu + u^H u)) / mu,

  K = conj(H), Xi = conj(Z) the constrained filter's and the multiplier's spectra;
* h-step, in the spatial domain: h = m . (mu g + zeta) / (lambda + mu)  (BACF eq. 12);
* multiplier: zeta <- zeta + mu (g - h); mu <- min(beta mu, mu_max).

The training sample is the running average of the windowed samples' spectra (BACF sec. 3.3),
solved again every frame it is updated, ``iterations`` times from zero. Units: unnormalised
DFTs, so that the data term, lambda and mu weigh alike per frequency as in the spatial
objective; mu starts at ``mu0`` times the sample's mean energy per frequency, mean_t u^H u (so
that it does not depend on the features' scale), grows by beta = 3 an iteration and stops at
1e4 times that energy. With few iterations the solution depends on mu0: a larger one holds the
filter closer to zero (a lower, flatter response). Measured on caviar1's first frame with two
iterations, the target moved by 6 px scored 0.54 with mu0 = 0.03 and the best placement three cells
or more from it 0.20 (0.19 and 0.10 with mu0 = 1; the closed form without a mask: 0.84 and 0.06).

Departures: the mask is a box of the target's size times ``mask`` (not the target's own size in
cells as BACF, nor CSR-DCF's colour segmentation, which ``segment``, off by default, adds within the box:
:mod:`.reliability`); the detection uses h, which meets the
constraint exactly, rather than BACF's g.
"""

from __future__ import annotations

import numpy as np

__all__ = ["box_mask", "solve_masked"]


def box_mask(cells: tuple[int, int], box_cells: tuple[float, float], scale: float) -> np.ndarray:
    """(hc, wc) float64: 1 on the cells of a centred box of ``box_cells`` (bw, bh) times ``scale`` (at
    least one cell each way), 0 elsewhere."""
    wc, hc = cells
    bw = min(wc, max(1, int(round(box_cells[0] * scale))))
    bh = min(hc, max(1, int(round(box_cells[1] * scale))))
    m = np.zeros((hc, wc))
    y0, x0 = (hc - bh) // 2, (wc - bw) // 2
    m[y0:y0 + bh, x0:x0 + bw] = 1.0
    return m


def solve_masked(x_hat: np.ndarray, y_hat: np.ndarray, mask: np.ndarray, lam: float, mu0: float, iterations: int,
                 beta: float = 3.0, mu_max: float = 1e4) -> np.ndarray:
    """The masked filter of sample spectrum ``x_hat`` (hc, wc // 2 + 1, C) for label spectrum ``y_hat``
    (hc, wc // 2 + 1), as detection applies it: D (hc, wc // 2 + 1, C) with Y = sum_l D_l Z_l (module
    docstring). ``mask`` (hc, wc) in the window's own cells (centred, as the sample)."""
    hc, wc = mask.shape
    u = np.conj(x_hat)
    # u^H u = sum_l |X_l|^2 per frequency
    uu = np.einsum("ijc,ijc->ij", x_hat.real, x_hat.real) + np.einsum("ijc,ijc->ij", x_hat.imag, x_hat.imag)
    uy = u * y_hat[..., None]
    # the mask is centred in the window; the spatial filter's cells are the window's own (module .filter)
    k = np.zeros_like(x_hat)
    xi = np.zeros_like(x_hat)
    # mu starts at mu0 times the data's mean energy per frequency, mean_t u^H u (scale-free)
    mu = mu0 * float(uu.mean())
    mu_cap = mu_max * float(uu.mean())
    f = k
    for _ in range(iterations):
        # g-step: r = u Y + mu K - Xi;  F = (r - u (u^H r) / (mu + u^H u)) / mu     (Sherman-Morrison)
        r = uy + mu * k - xi
        ur = np.einsum("ijc,ijc->ij", np.conj(u), r)
        f = (r - u * (ur / (mu + uu))[..., None]) / mu
        # h-step: h = m (mu g + zeta) / (lambda + mu), g = F^-1{conj(F)}, zeta = F^-1{conj(Xi)}
        h = np.fft.irfft2(np.conj(mu * f + xi), s=(hc, wc), axes=(0, 1)) * mask[..., None] / (lam + mu)
        k = np.conj(np.fft.rfft2(h, axes=(0, 1)))
        # zeta <- zeta + mu (g - h)
        xi = xi + mu * (f - k)
        mu = min(beta * mu, mu_cap)
    return k
