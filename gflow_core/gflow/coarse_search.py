"""The texture term of the coarse translation search (:func:`.pose_opinion.coarse_to_fine_peak`).

For each expert ``e`` with vertices at ``x_i`` (the start pose, on the coarsest pyramid level)
and each trial translation ``o_g`` the search needs::

    C(e, g) = sum_i w_i (y(x_i + o_g) - mu_i)^2                      (eq. 14, foreground term)

with ``y`` the bilinear interpolant of the level's image (border replicated, as in
:mod:`.image`), ``mu_i`` the predicted texel means and ``w_i = 1 / (sigma_v + sigma_w)``.
That is ``E x G x n`` bilinear samples (20 experts, 81 translations, 225 vertices: 364,500).

When every ``o_g`` is a whole number of the level's pixels (the default grid: 8 px steps on
level 2 are 2 px there), ``x_i + o_g`` has the fractional part of ``x_i`` whatever ``g``, so the
bilinear weights are computed once per vertex and each translation only shifts the four
corner indices. The border is handled by sampling a copy of the image padded by replicating
its edge (``np.pad(mode="edge")``), in which bilinear interpolation at any point of the padded
band equals the clamped interpolation of :mod:`.image`; vertices far outside are first moved
to the band, where every translation still lands in the padding. The values equal those of
sampling each ``x_i + o_g`` through :func:`.image.bilinear_stencil` up to rounding (the
weights come from ``x_i`` rather than from ``x_i + o_g``). Other translations (not whole
pixels) are sampled one by one through :func:`.image.stencil_xy`.

Each expert's costs depend only on its own rows: the experts may be split into blocks (memory)
or shards (processes) and give the same numbers bit for bit.
"""

from __future__ import annotations

import numpy as np

from .image import stencil_xy

__all__ = ["translation_costs"]


def translation_costs(image: np.ndarray, x: np.ndarray, y: np.ndarray, shifts: np.ndarray, mu: np.ndarray,
                      w: np.ndarray, block_vertices: int = 1 << 16) -> np.ndarray:
    """``C(e, g) = sum_i w_i (y(x_i + o_g) - mu_i)^2`` for every expert and translation.

    Parameters
    ----------
    image : (h, w) float64
        The level's image.
    x, y : (E, m) float64
        Vertex positions (the level's pixels) without translation.
    shifts : (G, 2) float64
        Translations ``o_g`` ``(dx, dy)`` in the level's pixels.
    mu, w : (E, m) float64
        Predicted texel means and weights.
    block_vertices : int
        At most this many (expert, translation, vertex) triples are sampled at once (about 80
        bytes of temporaries each); blocks of experts give the same numbers as one batch.
        Small blocks are faster: 2^16 took 5.4 ms for 20 experts x 81 translations x 225
        vertices against 14 ms for 2^18 (temporaries of 0.5 rather than 2 MB, which the
        allocator reuses and the cache holds, instead of fresh pages every block).

    Returns
    -------
    (E, G) float64
    """
    E, m = x.shape
    G = shifts.shape[0]
    out = np.empty((E, G))
    block = max(1, block_vertices // max(1, G * m))
    whole = np.all(shifts == np.round(shifts)) and np.isfinite(shifts).all()
    if whole:
        lattice = _Lattice(image, shifts.astype(np.intp))
    for b0 in range(0, E, block):
        bs = slice(b0, min(E, b0 + block))
        if whole:
            vals = lattice.sample(x[bs], y[bs])
        else:
            vals = stencil_xy(x[bs, None, :] + shifts[None, :, 0, None], y[bs, None, :] + shifts[None, :, 1, None],
                              image.shape).sample(image.reshape(-1))
        r = vals - mu[bs, None, :]
        r *= r
        # sum_i w_i r_i^2 for each translation (numpy's own reduction, not a BLAS gemv: the same
        # order whatever the block, and no BLAS threads spinning in the proposal process)
        r *= w[bs, None, :]
        out[bs] = r.sum(axis=-1)
    return out


class _Lattice:
    """Bilinear samples of an image at points shifted by whole pixels (see the module docstring)."""

    def __init__(self, image: np.ndarray, shifts: np.ndarray) -> None:
        h, w = image.shape
        self.reach = int(np.abs(shifts).max()) + 1 if shifts.size else 1
        pad = 2 * self.reach + 1
        self.pad, self.h, self.w = pad, h, w
        self.flat = np.pad(image, pad, mode="edge").reshape(-1)
        self.width = w + 2 * pad
        # flat index offset of each translation in the padded image
        self.offsets = shifts[:, 1] * self.width + shifts[:, 0]

    def sample(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """``(E, m)`` points without translation -> ``(E, G, m)`` bilinear values."""
        if not (np.isfinite(x).all() and np.isfinite(y).all()):
            # as image.bilinear_stencil: non-finite coordinates sample pixel 0
            finite = np.isfinite(x) & np.isfinite(y)
            x, y = np.where(finite, x, 0.0), np.where(finite, y, 0.0)
        # into the band where every translation stays inside the padding (beyond it the
        # clamped samples are the border's values anyway)
        reach = self.reach
        xc = np.minimum(np.maximum(x, -reach), self.w - 1 + reach)
        yc = np.minimum(np.maximum(y, -reach), self.h - 1 + reach)
        x0, y0 = np.floor(xc), np.floor(yc)
        fx = (xc - x0)[:, None, :]
        fy = (yc - y0)[:, None, :]
        base = (y0.astype(np.intp) + self.pad) * self.width + (x0.astype(np.intp) + self.pad)
        idx = base[:, None, :] + self.offsets[None, :, None]  # (E, G, m)
        f, W = self.flat, self.width
        v00 = f.take(idx)
        v01 = f[1:].take(idx)
        v10 = f[W:].take(idx)
        v11 = f[W + 1:].take(idx)
        # the arithmetic of image.BilinearStencil.sample
        top = v01 - v00
        top *= fx
        top += v00
        bot = v11 - v10
        bot *= fx
        bot += v10
        bot -= top
        bot *= fy
        bot += top
        return bot
