"""The tiled background replica (gflow_core.gflow.background) holds bit for bit the numbers of
dense (E, H, W) arrays updated by texture.background_predict_update, in less memory; and the
translation search done in blocks of experts gives the numbers of one batch."""

from __future__ import annotations

import numpy as np
import pytest

from gflow_core.gflow import paper_config, expert_rngs, fit_head_model_to_box, init_state, propose, step
from gflow_core.gflow import background, pose_opinion
from gflow_core.gflow.background import TileLayout, TiledBackground
from gflow_core.gflow.image import bilinear_stencil
from gflow_core.gflow.synthetic_head import synthetic_sequence
from gflow_core.gflow.texture import background_predict_update


def _masks(rng, E, H, W):
    """Random rectangles, some experts sharing one, some empty."""
    m = np.zeros((E, H, W), bool)
    for e in range(E):
        if e % 4 == 3:
            continue
        y0, x0 = rng.integers(0, H - 5), rng.integers(0, W - 5)
        m[e, y0:y0 + rng.integers(3, 20), x0:x0 + rng.integers(3, 25)] = True
    m[1] = m[0]
    return m


@pytest.mark.parametrize("shape,block", [((37, 45), 1024), ((32, 48), 5)])
def test_advance_and_predict_equal_the_dense_update_bit_for_bit(shape, block, monkeypatch) -> None:
    monkeypatch.setattr(background, "ADVANCE_BLOCK_TILES", block)  # 5: the update runs in several blocks
    rng = np.random.default_rng(0)
    E, (H, W) = 7, shape
    frame0 = rng.random((H, W))
    masks0 = _masks(rng, E, H, W)
    bank = TiledBackground.initial(frame0, masks0, 1e-3, 1.0)
    mean = np.broadcast_to(frame0, (E, H, W)).copy()
    var = np.where(masks0, 1.0, 1e-3)
    np.testing.assert_array_equal(np.asarray(bank.mean), mean)
    np.testing.assert_array_equal(np.asarray(bank.var), var)
    for t in range(6):
        parents = np.sort(rng.integers(0, E, E))
        frame = rng.random((H, W))
        masks = _masks(rng, E, H, W)
        if t == 3:  # a frame not seen: prediction only
            bank = bank.predict(parents, 1e-4)
            mean, var = mean[parents], var[parents] + 1e-4
        else:
            bank = bank.advance(parents, masks, frame, 1e-4, 1e-3)
            mean, var = background_predict_update(mean, var, frame, 1e-4, 1e-3, list(masks), parents,
                                                  (np.empty_like(mean), np.empty_like(var)))
        assert np.array_equal(np.asarray(bank.mean), mean) and np.array_equal(np.asarray(bank.var), var), t
        for e in range(E):
            assert np.array_equal(bank.mean[e], mean[e]) and np.array_equal(bank.var[e], var[e])
    # bilinear sampling through the tiles reads the same texels as through the flat arrays
    pts = rng.uniform(-3, [W + 3, H + 3], (E, 50, 2))
    st = bilinear_stencil(pts, (H, W))
    rows = np.arange(E)[:, None]
    assert np.array_equal(st.sample(bank.mean.flat_view(), rows), st.sample(mean.reshape(-1), rows))
    assert np.array_equal(st.sample(bank.var.flat_view(), rows), st.sample(var.reshape(-1), rows))
    # and the same bank comes back from the dense arrays
    again = TiledBackground.from_dense(mean, var)
    assert np.array_equal(np.asarray(again.mean), mean) and again.pool_mean.shape[0] <= bank.pool_mean.shape[0]


def test_bad_tables_are_refused() -> None:
    lay = TileLayout((20, 20), 16)
    pool = np.zeros((2, 256))
    with pytest.raises(ValueError, match="tile ids"):
        TiledBackground(lay, np.full((3, 4), 2, np.int32), pool, pool.copy())
    with pytest.raises(ValueError, match="do not fit"):
        TiledBackground(lay, np.zeros((3, 5), np.int32), pool, pool.copy())
    with pytest.raises(ValueError, match="tile side"):
        TileLayout((20, 20), 0)


def test_the_replica_of_many_experts_is_a_fraction_of_the_dense_arrays() -> None:
    """30 experts resampled every frame on a moving head: the distinct tiles are those near the head."""
    seq = synthetic_sequence(np.random.default_rng(3), 8, (120, 160))
    model, pose0 = fit_head_model_to_box(seq.box, seq.frames.shape[1:])
    cfg = paper_config(n_experts=30, n_samples=4, background=True)
    state = init_state(model, pose0, seq.frames[0], cfg)
    for t in range(1, 8):
        state, _ = step(state, seq.frames[t], model, cfg, seed=1, t=t)
    dense = 2 * 30 * 120 * 160 * 8
    held = state.bg_mean.bank.nbytes
    print(f"\nbackground replica, 30 experts, 160x120: {held / 1e6:.2f} MB held, dense {dense / 1e6:.2f} MB")
    assert held < dense / 4


def test_the_search_in_blocks_equals_one_batch(monkeypatch) -> None:
    seq = synthetic_sequence(np.random.default_rng(5), 3, (120, 160))
    model, pose0 = fit_head_model_to_box(seq.box, seq.frames.shape[1:])
    cfg = paper_config(n_experts=9, n_samples=3, background=True, pyramid_levels=2, search_radius=8.0,
                      search_step=4.0, photometric=True, outlier_sigmas=3.0, max_rotation_deg=30.0)
    state = init_state(model, pose0, seq.frames[0], cfg)
    outs = []
    for block in (1 << 30, 1):  # one batch; then one expert at a time
        monkeypatch.setattr(pose_opinion, "SEARCH_BLOCK_VERTICES", block)
        outs.append(propose(state, seq.frames[1], model, cfg, expert_rngs(0, 1, 1, range(9))))
    for f in ("u_hat", "sigma_hat", "samples", "log_weights", "log_evidence"):
        assert np.array_equal(getattr(outs[0], f), getattr(outs[1], f)), f
