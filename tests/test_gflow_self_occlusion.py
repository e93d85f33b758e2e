"""G-flow's self-occlusion (``GFlowConfig.self_occlusion``, :mod:`gflow_core.gflow.visibility`): a vertex
the head itself turns away from the camera is not scored against the frame, nor learnt from it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from gflow_core.gflow.filter import GFlowConfig, _learn_texels, init_state, propose
from gflow_core.gflow.geometry import make_pose
from gflow_core.gflow.head_model import EllipsoidHead
from gflow_core.gflow.image import prepare_frame
from gflow_core.gflow.params import GFlowParams
from gflow_core.gflow.pose_opinion import TextureView, gauss_newton_objective, log_likelihood
from gflow_core.gflow.visibility import facing, vertex_normals, visibility_weights

SIGMA_W = 1e-2


def _head() -> tuple[EllipsoidHead, np.ndarray]:
    head = EllipsoidHead(semi_axes=(1.0, 1.2, 0.9), n_lon=13, n_lat=11, lon_max_deg=80.0, lat_max_deg=70.0)
    return head, head.model().bases


def test_the_normals_of_an_ellipsoid_are_its_surface_normals() -> None:
    """The normals fitted to each vertex's neighbours match the ellipsoid's (x / a^2 direction), pointing
    outward, away from the camera's side for none of the front vertices."""
    head, bases = _head()
    p = bases[:, :, 0]
    a = np.asarray(head.semi_axes)
    true = p / a ** 2
    true /= np.linalg.norm(true, axis=1, keepdims=True)
    n = vertex_normals(bases)
    cos = (n * true).sum(axis=1)
    # the grid's border vertices fit a one-sided neighbourhood: allow them more
    assert np.median(cos) > 0.99 and cos.min() > 0.8
    assert (facing(n, make_pose(None, (0, 0), [1.0])[None]) > 0).all()


def test_a_turned_head_hides_its_far_side_and_keeps_its_near_side() -> None:
    """Turned by 60 degrees about the vertical axis: the vertices beyond 40 degrees of longitude on the far
    side face away (weight 0), those on the near side stay visible (weight 1)."""
    _, bases = _head()
    n = vertex_normals(bases)
    p = bases[:, :, 0]
    lon = np.degrees(np.arctan2(p[:, 0], -p[:, 2]))
    for sign in (1.0, -1.0):
        u = make_pose((0.0, sign * np.radians(60.0), 0.0), (0, 0), [1.0])[None]
        v = visibility_weights(n, u, 0.2)[0]
        # a rotation by +w_y about y brings +x toward -z (the camera): the -x side hides
        far = sign * lon < -40.0
        near = sign * lon > 0.0
        assert far.any() and near.any()
        assert (v[far] == 0.0).all() and (v[near] == 1.0).all()
    with pytest.raises(ValueError, match="cosine"):
        visibility_weights(n, u, 0.0)


def _flat_scene():
    g = (np.arange(6) - 2.5) * 4.0
    xx, yy = np.meshgrid(g, g)
    bases = np.stack([xx.ravel(), yy.ravel(), np.zeros(36)], axis=1)[:, :, None]
    rng = np.random.default_rng(4)
    img = np.clip(0.5 + 0.2 * rng.standard_normal((60, 60)), 0.0, 1.0)
    pose = make_pose(None, (30.0, 30.0), [1.0])
    pts = np.rint(bases[:, :2, 0] + pose[3:5]).astype(int)
    mu = img[pts[:, 1], pts[:, 0]] + 0.02 * rng.standard_normal(36)
    return bases, img, pose, pts, mu


def test_a_hidden_vertex_is_not_scored_and_costs_its_expectation() -> None:
    """With visibility 0 at one vertex, what the frame shows there changes neither the likelihood (eq. 13)
    nor the objective (eq. 14); its term is the texel's expected cost (1), so experts that hide different
    vertices compare. Without visibility the same change moves both."""
    bases, img, pose, pts, mu = _flat_scene()
    vis = np.ones((1, 36))
    vis[0, 7] = 0.0
    changed = img.copy()
    changed[pts[7, 1] - 1:pts[7, 1] + 2, pts[7, 0] - 1:pts[7, 0] + 2] += 0.3
    tv = TextureView(mean=mu[None], var=np.full((1, 36), 1e-3))
    tvv = dataclasses.replace(tv, vis=vis)
    std = np.full(6, 5.0)

    def both(image, view):
        fd = prepare_frame(np.clip(image, 0, 1))
        return (log_likelihood(bases, fd, pose[None, None], view, SIGMA_W)[0, 0],
                gauss_newton_objective(bases, fd, pose[None], pose[None], view, SIGMA_W, std)[0])

    (l0, f0), (l1, f1) = both(img, tvv), both(changed, tvv)
    assert l0 == pytest.approx(l1, abs=1e-12) and f0 == pytest.approx(f1, abs=1e-12)
    (p0, g0), (p1, g1) = both(img, tv), both(changed, tv)
    assert abs(p0 - p1) > 1.0 and abs(g0 - g1) > 0.5
    # the hidden vertex's term: its expectation 1 instead of its residual (its normalising term stays)
    fd = prepare_frame(img)
    r2 = (img[pts[7, 1], pts[7, 0]] - mu[7]) ** 2 / (1e-3 + SIGMA_W)
    assert l0 - p0 == pytest.approx(-0.5 * (1.0 - r2), abs=1e-9)
    assert log_likelihood(bases, fd, pose[None, None], dataclasses.replace(tv, vis=np.ones((1, 36))),
                          SIGMA_W)[0, 0] == pytest.approx(p0, abs=1e-12)


def test_a_hidden_texel_keeps_its_prediction_and_a_visible_one_learns() -> None:
    """The texel update (eq. 7, 8) of a vertex of weight 0 keeps the prediction; weight 1 is the paper's
    update; a weight between them learns less."""
    from gflow_core.gflow.filter import Proposals

    bases, img, pose, pts, mu = _flat_scene()
    from gflow_core.gflow.head_model import MorphableModel

    model = MorphableModel(bases)
    cfg = GFlowParams(model="", n_experts=1, outlier_sigmas=np.inf, texture_decay=1.0).config()
    state = init_state(model, pose, np.full_like(img, 0.2), cfg)
    P = pose.size
    props = Proposals(expert_indices=np.arange(1), u_hat=pose[None], sigma_hat=np.eye(P)[None],
                      samples=pose[None, None], log_weights=np.zeros((1, 1)), log_evidence=np.zeros(1),
                      gn_objective=np.zeros(1), reset=np.zeros(1, dtype=bool))
    pts2 = (bases[:, :2, 0] + pose[3:5])[None]
    vis = np.ones((1, 36))
    vis[0, 3], vis[0, 9] = 0.0, 0.5
    full, full_var, _ = _learn_texels(state, props, np.zeros(1, dtype=np.int64), pts2, img, cfg)
    part, part_var, _ = _learn_texels(state, props, np.zeros(1, dtype=np.int64), pts2, img, cfg, vis)
    pred = state.tex_mean[0, 3]
    assert part[0, 3] == pred and part_var[0, 3] == state.tex_var[0, 3] + cfg.psi_v
    assert abs(full[0, 3] - pred) > 1e-3
    assert abs(part[0, 9] - pred) < abs(full[0, 9] - pred) and part[0, 9] != pred
    keep = np.ones(36, dtype=bool)
    keep[[3, 9]] = False
    np.testing.assert_array_equal(part[0, keep], full[0, keep])


def _synthetic_experts(n_experts: int, jitter: float = 0.0, **changes):
    """A synthetic head's first two frames (:mod:`gflow_core.gflow.synthetic_head`), the model placed in its
    box and the experts at the first frame (their rotation jittered by ``jitter`` radians): ``(setup,
    state, y1)``."""
    from gflow_core.gflow import model_setup
    from gflow_core.gflow.synthetic_head import synthetic_sequence
    from gflow_core.gflow.tracker import observation
    from gflow_scenes import SYNTH

    seq = synthetic_sequence(np.random.default_rng(3), n_frames=2, image_shape=(60, 80))
    grey = np.rint(seq.frames * 255).astype(np.uint8)
    setup = model_setup(GFlowParams(**dict(SYNTH, n_experts=n_experts, **changes)), seq.box, grey.shape[1:])
    y0, y1 = (observation(g, setup.contrast_sigma) for g in grey)
    std = np.r_[np.full(3, jitter), np.full(2, 2.0), 0.02 * abs(setup.pose0[5:])] if jitter else None
    state = init_state(setup.model, setup.pose0, y0, setup.cfg, rng=np.random.default_rng(1), pose_jitter_std=std)
    return setup, state, y1


def _rngs(idx):
    return [np.random.default_rng([7, int(i)]) for i in idx]


def test_every_vertex_seen_is_the_paper_bit_for_bit_and_a_turned_expert_proposes_otherwise() -> None:
    """Off by default. At the first pose every vertex of the head faces the camera, so with a tiny ``C``
    every weight is 1 and the proposals are bit for bit those without self-occlusion; an expert turned by
    50 degrees hides part of its head and proposes differently."""
    assert GFlowConfig.__dataclass_fields__["self_occlusion"].default == 0.0
    assert GFlowParams().self_occlusion == 0.0
    setup, state, y1 = _synthetic_experts(4)

    def both(st, c):
        return (propose(st, y1, setup.model, setup.cfg, _rngs(range(4))),
                propose(st, y1, setup.model, dataclasses.replace(setup.cfg, self_occlusion=c), _rngs(range(4))))

    off, seen = both(state, 1e-9)
    for name in ("u_hat", "samples", "log_weights", "log_evidence", "gn_objective"):
        np.testing.assert_array_equal(getattr(seen, name), getattr(off, name))
    turned = np.array(state.poses)
    turned[:, 1] = np.radians(50.0)
    off, on = both(dataclasses.replace(state, poses=turned), 0.3)
    assert not np.array_equal(on.log_weights, off.log_weights)


@pytest.mark.parametrize("value", [-0.1, 1.5, float("nan"), True])
def test_a_bad_self_occlusion_is_refused_in_one_line(value) -> None:
    with pytest.raises(ValueError, match="self_occlusion must be") as e:
        GFlowParams(self_occlusion=value)
    assert "\n" not in str(e.value)


def test_shards_of_the_experts_propose_as_one_batch_with_self_occlusion() -> None:
    """Each expert's visibility is its own pose's: proposals made for two shards of the experts are
    those of one call, bit for bit (the pipeline's proposal processes)."""
    setup, state, y1 = _synthetic_experts(6, jitter=0.3, self_occlusion=0.3)
    whole = propose(state, y1, setup.model, setup.cfg, _rngs(range(6)), None, 3.0)
    parts = [propose(state, y1, setup.model, setup.cfg, _rngs(ix), ix, 3.0) for ix in ([0, 1, 2], [3, 4, 5])]
    for name in ("u_hat", "samples", "log_weights", "log_evidence", "gn_objective"):
        np.testing.assert_array_equal(np.concatenate([getattr(p, name) for p in parts]), getattr(whole, name))
