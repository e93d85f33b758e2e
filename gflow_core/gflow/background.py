"""The experts' background texels stored once per distinct tile (sec. 3.1, eq. 7-10).

With the background model every expert ``d`` holds a Gaussian over each background pixel,
``(E, H, W)`` means and variances: 123 MB in float64 for 100 experts at 320x240, and a
second copy while a frame's update is written. Most of it is the same numbers many times:
all experts start from the same frame, the Kalman update of a pixel depends only on its
parent's texel, the frame and whether the child's object covers the pixel, and resampling
(sec. 3.4) makes children share parents. So the images are cut into ``T x T`` tiles and
each distinct tile is stored once; an expert is a row of tile ids (``table``).

The arithmetic is the dense one, texel for texel (the same operations in the same order
as :func:`.texture.background_predict_update`), so the values are bit for bit those of
dense ``(E, H, W)`` arrays; only the storage changes. A tile of a child is computed once
per distinct *(parent tile, object mask over the tile)*: a tile no child's object touches
is computed once for all the children of one parent.

Memory: the distinct tiles are those on which the experts' histories since their last
common ancestor differ, i.e. around the object. Worst case (experts that never share a
parent, e.g. ``resample_ess_fraction < 1`` with a high ESS for a long time, and objects
moving over the whole frame) it is the dense size plus the tile table.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["TILE", "TileLayout", "TiledBackground", "TiledTexels"]

#: Tile side in pixels.
TILE = 16

#: :meth:`TiledBackground.advance` updates at most this many tiles at once (2 MB per temporary).
ADVANCE_BLOCK_TILES = 1024


@dataclass(frozen=True)
class TileLayout:
    """How an ``(H, W)`` image is cut into ``K = Kh x Kw`` tiles of ``T x T`` (padded at the
    bottom and right to a whole number of tiles)."""

    shape: tuple[int, int]
    tile: int = TILE

    def __post_init__(self) -> None:
        if len(self.shape) != 2 or min(self.shape) < 1 or not 1 <= int(self.tile) <= 1024:
            raise ValueError(f"tile layout: need an (H, W) image and a tile side in [1, 1024], got {self.shape}, "
                             f"{self.tile}")

    @property
    def grid(self) -> tuple[int, int]:
        H, W = self.shape
        return -(-H // self.tile), -(-W // self.tile)

    @property
    def n_tiles(self) -> int:
        kh, kw = self.grid
        return kh * kw

    @property
    def tile_size(self) -> int:
        return self.tile * self.tile

    def to_tiles(self, img: np.ndarray, fill=0) -> np.ndarray:
        """``(..., H, W)`` -> ``(..., K, T*T)`` (a copy; padding = ``fill``)."""
        H, W = self.shape
        kh, kw = self.grid
        T = self.tile
        lead = img.shape[:-2]
        if (kh * T, kw * T) != (H, W):
            pad = np.full(lead + (kh * T, kw * T), fill, dtype=img.dtype)
            pad[..., :H, :W] = img
            img = pad
        t = img.reshape(lead + (kh, T, kw, T))
        t = np.moveaxis(t, -3, -2)  # (..., kh, kw, T, T)
        return np.ascontiguousarray(t).reshape(lead + (kh * kw, T * T))

    def from_tiles(self, tiles: np.ndarray) -> np.ndarray:
        """``(K, T*T)`` -> ``(H, W)`` (a new array)."""
        H, W = self.shape
        kh, kw = self.grid
        T = self.tile
        img = tiles.reshape(kh, kw, T, T).transpose(0, 2, 1, 3).reshape(kh * T, kw * T)
        return np.ascontiguousarray(img[:H, :W])

    def pixel_maps(self) -> tuple[np.ndarray, np.ndarray]:
        """For each flat pixel index ``r * W + c``: its tile and its offset in the tile."""
        H, W = self.shape
        T = self.tile
        r, c = np.divmod(np.arange(H * W, dtype=np.intp), W)
        tile = (r // T) * self.grid[1] + c // T
        off = (r % T) * T + c % T
        return tile, off


def _unique_tiles(src: np.ndarray, masks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distinct ``(src tile id, mask bits)`` pairs of ``(E, K)`` tiles.

    Returns ``first`` (U,) flat indices into ``E * K`` of one occurrence of each, and
    ``inverse`` (E * K,) the distinct pair of every tile.
    """
    E, K = src.shape
    bits = np.packbits(masks.reshape(E, K, -1), axis=-1)
    key = np.concatenate([np.ascontiguousarray(src, dtype="<i8").view(np.uint8).reshape(E, K, 8), bits], axis=-1)
    key = np.ascontiguousarray(key.reshape(E * K, -1))
    void = key.view(np.dtype((np.void, key.shape[1]))).ravel()
    _, first, inverse = np.unique(void, return_index=True, return_inverse=True)
    return first, inverse.reshape(-1)


class TiledBackground:
    """Background texel posteriors of ``E`` experts, each distinct tile stored once.

    Attributes
    ----------
    layout : TileLayout
    table : (E, K) int32, read-only
        Tile id of each expert's tile ``k``.
    pool_mean, pool_var : (U, T*T) float64, read-only
        The distinct tiles.
    """

    def __init__(self, layout: TileLayout, table: np.ndarray, pool_mean: np.ndarray, pool_var: np.ndarray) -> None:
        table = np.asarray(table)
        U = pool_mean.shape[0]
        if (table.ndim != 2 or table.shape[1] != layout.n_tiles or pool_mean.shape != (U, layout.tile_size)
                or pool_var.shape != pool_mean.shape or pool_mean.dtype != np.float64 or pool_var.dtype != np.float64):
            raise ValueError(f"tiled background: table {table.shape} / pools {pool_mean.shape} {pool_mean.dtype}, "
                             f"{pool_var.shape} {pool_var.dtype} do not fit {layout.n_tiles} tiles of "
                             f"{layout.tile_size} float64 texels")
        if table.size and (table.min() < 0 or table.max() >= U):
            raise ValueError(f"tiled background: tile ids must lie in [0, {U})")
        for a in (table, pool_mean, pool_var):
            a.setflags(write=False)
        self.layout, self.table, self.pool_mean, self.pool_var = layout, table, pool_mean, pool_var
        self._maps: tuple[np.ndarray, np.ndarray] | None = None

    # -- construction ----------------------------------------------------------------------
    @classmethod
    def initial(cls, frame: np.ndarray, masks: np.ndarray, b_init_var: float, unknown_var: float,
                tile: int = TILE) -> "TiledBackground":
        """``B_1``: the frame with variance ``b_init_var``, ``unknown_var`` under each expert's
        object ``masks`` (E, H, W) bool."""
        lay = TileLayout((int(frame.shape[0]), int(frame.shape[1])), tile)
        E, K = masks.shape[0], lay.n_tiles
        mt = lay.to_tiles(masks, False)  # (E, K, TT)
        first, inverse = _unique_tiles(np.broadcast_to(np.arange(K), (E, K)), mt)
        k = first % K
        pool_mean = lay.to_tiles(frame)[k]
        pool_var = np.full(pool_mean.shape, float(b_init_var))
        pool_var[mt.reshape(E * K, -1)[first]] = unknown_var
        return cls(lay, inverse.reshape(E, K).astype(np.int32), pool_mean, pool_var)

    @classmethod
    def from_dense(cls, mean: np.ndarray, var: np.ndarray, tile: int = TILE) -> "TiledBackground":
        """From ``(E, H, W)`` arrays (identical tiles stored once)."""
        mean = np.asarray(mean, dtype=np.float64)
        var = np.asarray(var, dtype=np.float64)
        if mean.ndim != 3 or var.shape != mean.shape:
            raise ValueError(f"background mean and variance must be (E, H, W) alike, got {mean.shape}, {var.shape}")
        lay = TileLayout((int(mean.shape[1]), int(mean.shape[2])), tile)
        E, K = mean.shape[0], lay.n_tiles
        tm, tv = lay.to_tiles(mean).reshape(E * K, -1), lay.to_tiles(var).reshape(E * K, -1)
        rows = np.ascontiguousarray(np.concatenate([tm, tv], axis=1))
        void = rows.view(np.dtype((np.void, rows.shape[1] * 8))).ravel()
        _, first, inverse = np.unique(void, return_index=True, return_inverse=True)
        return cls(lay, inverse.reshape(E, K).astype(np.int32), tm[first], tv[first])

    # -- the filter's steps ----------------------------------------------------------------
    def advance(self, parents: np.ndarray, masks: np.ndarray, frame: np.ndarray, psi_b: float,
                sigma_w: float) -> "TiledBackground":
        """Each child ``e``: its parent's background predicted (eq. 9, 10) and updated with
        ``frame`` outside its object ``masks[e]`` (eq. 7, 8). A new object; this one is unchanged.

        The same operations as :func:`.texture.background_predict_update`, per texel.
        """
        lay = self.layout
        E, K = masks.shape[0], lay.n_tiles
        ptab = self.table[np.asarray(parents)]
        mt = lay.to_tiles(masks, False)
        first, inverse = _unique_tiles(ptab, mt)
        src = ptab.reshape(-1)[first]
        frame_tiles = lay.to_tiles(frame)
        mt = mt.reshape(E * K, -1)
        U = first.size
        new_mean, new_var = np.empty((U, lay.tile_size)), np.empty((U, lay.tile_size))
        # in blocks of tiles, so that the temporaries stay small whatever the number of tiles
        for b0 in range(0, U, ADVANCE_BLOCK_TILES):
            b = slice(b0, min(U, b0 + ADVANCE_BLOCK_TILES))
            m0, v, m = self.pool_mean[src[b]], new_var[b], new_mean[b]
            # Var(B_t | u_{1:t-1}, y_{1:t-1}) = Var(B_{t-1} | ...) + Psi_b          (eq. 10)
            np.add(self.pool_var[src[b]], psi_b, out=v)
            # K = sigma / (sigma + sigma_w), 0 on object pixels (a_b = I - a_v a_v^T)
            gain = np.add(v, sigma_w)
            np.divide(v, gain, out=gain)
            gain[mt[first[b]]] = 0.0
            # mu' = mu + K (y - mu)                                                  (eq. 8)
            diff = frame_tiles[first[b] % K]
            np.subtract(diff, m0, out=diff)
            diff *= gain
            np.add(m0, diff, out=m)
            # sigma' = (1 - K) sigma  = (sigma^-1 + sigma_w^-1)^-1                   (eq. 7)
            np.subtract(1.0, gain, out=gain)
            v *= gain
        return TiledBackground(lay, inverse.reshape(E, K).astype(np.int32), new_mean, new_var)

    def predict(self, parents: np.ndarray, psi_b: float) -> "TiledBackground":
        """Prediction only (eq. 9, 10): child ``e`` gets its parent's means and variances + ``Psi_b``."""
        ptab = self.table[np.asarray(parents)]
        used, inverse = np.unique(ptab, return_inverse=True)
        return TiledBackground(self.layout, inverse.reshape(ptab.shape).astype(np.int32), self.pool_mean[used],
                               np.add(self.pool_var[used], psi_b))

    # -- reading ---------------------------------------------------------------------------
    @property
    def n_experts(self) -> int:
        return self.table.shape[0]

    @property
    def shape(self) -> tuple[int, int, int]:
        return self.n_experts, self.layout.shape[0], self.layout.shape[1]

    @property
    def nbytes(self) -> int:
        """Bytes held (tables and distinct tiles)."""
        return self.table.nbytes + self.pool_mean.nbytes + self.pool_var.nbytes

    @property
    def mean(self) -> "TiledTexels":
        return TiledTexels(self, self.pool_mean)

    @property
    def var(self) -> "TiledTexels":
        return TiledTexels(self, self.pool_var)

    def take(self, pool: np.ndarray, index: np.ndarray) -> np.ndarray:
        """Texels at flat indices ``row * H * W + y * W + x`` of the ``(E, H, W)`` stack."""
        if self._maps is None:
            self._maps = self.layout.pixel_maps()
        tile_of, off_of = self._maps
        hw = self.layout.shape[0] * self.layout.shape[1]
        row, pix = np.divmod(np.asarray(index, dtype=np.intp), hw)
        at = self.table[row, tile_of[pix]].astype(np.intp)
        at *= self.layout.tile_size
        at += off_of[pix]
        return pool.reshape(-1)[at]

    def dense(self) -> tuple[np.ndarray, np.ndarray]:
        """``(E, H, W)`` means and variances (new arrays)."""
        return np.asarray(self.mean), np.asarray(self.var)


class TiledTexels:
    """One of a :class:`TiledBackground`'s ``(E, H, W)`` stacks (means or variances), read
    like an array: ``x[e]`` is expert ``e``'s ``(H, W)`` image (a new array),
    ``x.take_flat(i)`` the texels at flat indices, ``np.asarray(x)`` the whole stack."""

    def __init__(self, bank: TiledBackground, pool: np.ndarray) -> None:
        self.bank, self.pool = bank, pool

    @property
    def shape(self) -> tuple[int, int, int]:
        return self.bank.shape

    @property
    def ndim(self) -> int:
        return 3

    @property
    def dtype(self) -> np.dtype:
        return self.pool.dtype

    @property
    def nbytes(self) -> int:
        """Bytes of the distinct tiles (plus the shared table, counted with the means)."""
        return self.pool.nbytes + (self.bank.table.nbytes if self.pool is self.bank.pool_mean else 0)

    def __len__(self) -> int:
        return self.bank.n_experts

    def __getitem__(self, e) -> np.ndarray:
        if not isinstance(e, (int, np.integer)):  # a whole (E, H, W) copy must be asked for: np.asarray
            raise TypeError(f"tiled background texels are indexed by one expert, not {type(e).__name__}")
        return self.bank.layout.from_tiles(self.pool[self.bank.table[int(e)]])

    def take_flat(self, index: np.ndarray) -> np.ndarray:
        return self.bank.take(self.pool, index)

    def flat_view(self) -> "_FlatView":
        """What ``reshape(-1)`` is for an array: ``v[i]`` = the texels at flat indices ``i``."""
        return _FlatView(self)

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        out = np.stack([self[e] for e in range(len(self))]) if len(self) else np.empty(self.shape)
        return out if dtype is None else out.astype(dtype)


class _FlatView:
    """``TiledTexels`` seen as a flat ``(E * H * W,)`` array, for indexing only."""

    def __init__(self, texels: TiledTexels) -> None:
        self.texels = texels

    def __getitem__(self, index: np.ndarray) -> np.ndarray:
        return self.texels.take_flat(index)

    def take(self, index: np.ndarray) -> np.ndarray:
        return self.texels.take_flat(index)
