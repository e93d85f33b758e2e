"""Filter stage of the contour particle filter: weighs proposals by eq. 7 and resamples.

Inputs: ``features`` of frame t (the chamfer image) and ``proposals`` for frame t.
Outputs: ``particles`` (the resampled posterior of t, which the proposal stage turns into
the proposals of t+1) and ``estimate`` (MAP state, box, posterior summary, ESS).

Initialisation (first frame): with no learned model this is the chamfer tracker of the
runtime issue: the template contour is the edge pixels inside ``init`` (x, y, w, h), the
model is M2 with K = 1 and likelihood exp(-lambda rho). With a learned M2 model (resource
``model``) the exemplars, sigma_k and d_k come from the model and ``init`` places it.

Bad input: a missing or unusable feature frame makes the filter coast (the proposals
become the posterior unweighted) and the problem is reported; it never stops the stream.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from gflow_core import similarity
from gflow_core.m2 import dynamics as dyn
from gflow_core.m2.tracking import ContourExemplars, ParticleCloud, init_particles, posterior, template_from_edges, weigh

from .base import Output, Params, Stage, StageInputError
from .messages import Estimate, Features, Message, MessageError, NDArray, Particles
from .particle_proposal import cloud_of, particles_msg
from .rng import frame_rng

__all__ = ["FilterStage", "FilterParams"]

PURPOSE_INIT = 0x1417
PURPOSE_RESAMPLE = 0x2E5A


class FilterParams(Params):
    """Particle filter settings.

    init : (x, y, w, h) initial box of the target, 0-based pixels.
    particles : number of particles N.
    lam : lambda of the K = 1 chamfer likelihood exp(-lambda rho).
    max_points : template points kept from the edges inside the box.
    init_spread : std of (ux, uy, theta, log s) of the initial cloud.
    """

    init: tuple[float, float, float, float] | None = None
    particles: int = 500
    lam: float = 0.5
    max_points: int = 200
    init_spread: tuple[float, float, float, float] = (2.0, 2.0, 0.01, 0.01)
    seed: int = 0
    model: str = ""

    def __post_init__(self) -> None:
        if self.particles < 1:
            raise ValueError(f"particles must be >= 1, got {self.particles}")
        if not self.lam > 0:
            raise ValueError(f"lam must be positive, got {self.lam}")
        if self.init is not None and not (self.init[2] > 0 and self.init[3] > 0):
            raise ValueError(f"init box must have positive width and height, got {self.init}")


class FilterStage(Stage):
    kind = "particle.filter"
    Params = FilterParams
    inputs = {"features": Features, "proposals": Particles}
    outputs = {"particles": Particles, "estimate": Estimate}
    drivers = frozenset({"features"})

    def __init__(self, params: FilterParams, ctx) -> None:
        super().__init__(params, ctx)
        if params.init is None:
            raise ValueError("the filter stage needs an initial box: set init: [x, y, w, h]")
        self.model: ContourExemplars | None = None
        self.last_cloud: ParticleCloud | None = None
        self.ref_size = np.array(params.init[2:], dtype=np.float64)
        self.last: dict = {}
        self.steps = 0

    # the first frame only needs features; afterwards both
    def required(self, seq: int) -> frozenset[str]:
        return frozenset({"features"}) if self.model is None else frozenset(self.inputs)

    def _chamfer(self, feat: Features | None, seq: int) -> np.ndarray | None:
        if feat is None:
            self.report("missing_features", f"frame {seq}: no features arrived; coasting on the dynamics", seq)
            return None
        try:
            cham = feat.chamfer.array()
        except MessageError as e:
            self.report("bad_features", f"frame {seq}: {e}; coasting", seq)
            return None
        if cham.ndim != 2 or cham.size == 0 or not np.isfinite(cham).all():
            self.report("bad_features", f"frame {seq}: chamfer image is {cham.shape} {cham.dtype} with "
                        f"non-finite values or wrong shape; coasting", seq)
            return None
        return cham

    def _initialise(self, seq: int, feat: Features) -> list[Output]:
        p: FilterParams = self.params  # type: ignore[assignment]
        x, y, w, h = p.init  # type: ignore[misc]
        try:
            edges = feat.edges.array()
        except MessageError as e:
            raise StageInputError(f"frame {seq}: {e}") from None
        H, W = edges.shape
        if x >= W or y >= H or x + w <= 0 or y + h <= 0:
            raise StageInputError(f"initial box {p.init} lies outside the {W}x{H} frame")
        try:
            pts = template_from_edges(edges, p.init, p.max_points)  # type: ignore[arg-type]
        except ValueError as e:
            raise StageInputError(f"frame {seq}: {e}") from None
        self.model = ContourExemplars.single(pts, p.lam, dyn.random_walk(1.0, 0.01, 0.01))
        alpha0 = np.array([x + (w - 1) / 2.0, y + (h - 1) / 2.0, 0.0, 1.0])
        rng = frame_rng(p.seed, self.ctx.stream, seq, PURPOSE_INIT)
        cloud = init_particles(alpha0, 0, p.particles, np.array(p.init_spread), rng)
        self.last_cloud = cloud
        est = self._estimate(feat.header, alpha0, 0, alpha0, np.zeros(4), float(p.particles), 0.0, "init")
        return [("particles", particles_msg(feat.header, "posterior", cloud)), ("estimate", est)]

    def _box(self, alpha: np.ndarray) -> tuple[float, float, float, float]:
        # the initial box carried by T_alpha: centre u, size s * (w0, h0)
        w, h = self.ref_size * alpha[3]
        return (float(alpha[0] - (w - 1) / 2.0), float(alpha[1] - (h - 1) / 2.0), float(w), float(h))

    def _estimate(self, header, alpha, k, mean, std, ess, log_ev, state) -> Estimate:
        assert self.model is not None
        contour = similarity.apply(alpha, self.model.curves[k, : self.model.n_points[k]]).astype(np.float32)
        self.last = {"seq": header.seq, "alpha": np.round(alpha, 3).tolist(), "ess": round(ess, 1), "state": state}
        return Estimate(header=header, box=self._box(alpha), alpha=tuple(float(v) for v in alpha), k=int(k),
                        mean=tuple(float(v) for v in mean), std=tuple(float(v) for v in std), ess=float(ess),
                        n=self.params.particles, log_evidence=float(log_ev), contour=NDArray.of(contour), state=state)  # type: ignore[attr-defined]

    def step(self, seq: int, inputs: Mapping[str, Message | None]) -> list[Output]:
        feat = inputs.get("features")
        if self.model is None:
            if not isinstance(feat, Features):
                raise StageInputError(f"frame {seq}: cannot initialise without features")
            return self._initialise(seq, feat)
        prop = inputs.get("proposals")
        if isinstance(prop, Particles):
            cloud = cloud_of(prop)
        else:
            # The proposals of this frame were lost: weigh the last posterior instead, so the
            # proposal -> filter cycle keeps turning.
            self.report("missing_proposals", f"frame {seq}: no proposals arrived; reusing the last posterior", seq)
            cloud = self.last_cloud
        p: FilterParams = self.params  # type: ignore[assignment]
        rng = frame_rng(p.seed, self.ctx.stream, seq, PURPOSE_RESAMPLE)
        cham = self._chamfer(feat if isinstance(feat, Features) else None, seq)
        if cham is None:
            log_lik = np.zeros(cloud.n)
            state = "coast"
        else:
            log_lik, _ = weigh(cloud, self.model, cham)
            state = "track"
        post = posterior(cloud, log_lik, self.model.K, rng, p.particles)
        header = feat.header if isinstance(feat, Features) else self.header(seq, 0)
        self.last_cloud = post.resampled
        self.steps += 1
        est = self._estimate(header, post.map_alpha, post.map_k, post.mean_alpha, post.std_alpha, post.ess,
                             post.log_evidence, state)
        return [("particles", particles_msg(header, "posterior", post.resampled)), ("estimate", est)]

    def summary(self) -> dict:
        return dict(self.last, steps=self.steps)
