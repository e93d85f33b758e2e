"""An example gflow tracker: template matching by normalised cross-correlation (cv2.matchTemplate)
weighing a constant-velocity particle filter over the box's centre (x, y)."""

from dataclasses import dataclass, replace

import cv2
import numpy as np

from gflow_core.params import param
from gflow_core.spec import BoxStages, TrackerSpec
from gflow_core.tracker import FrameRng, UnusableFrame, box_estimate

WALK, STEP = 0x4E01, 0x4E02  # the purposes of this tracker's draws (FrameRng.stream)


@dataclass(frozen=True)
class NCCParams:
    """The NCC tracker's settings."""
    particles: int = param(300, "number of particles")
    std_xy: float = param(0.04, "position noise per frame, relative to sqrt(w h) of the initial box")
    std_v: float = param(0.02, "velocity noise per frame, relative to sqrt(w h) of the initial box")
    sharpness: float = param(20.0, "likelihood exp(sharpness * ncc)", option="--ncc-sharpness")

    def __post_init__(self) -> None:
        if self.particles < 2:
            raise ValueError(f"particles must be >= 2, got {self.particles}")


@dataclass(frozen=True)
class Obs:
    grey: np.ndarray  # (H, W) float32


@dataclass(frozen=True)
class State:
    xy: np.ndarray        # (N, 2) particle centres
    v: np.ndarray         # (N, 2) their velocities, pixels per frame
    template: np.ndarray  # (h, w) float32, the initial box's grey levels
    size0: tuple          # (w, h) of the initial box


@dataclass(frozen=True)
class Proposal:
    xy: np.ndarray  # (N, 2)
    dt: float


def alpha_of(xy):  # (N, 2) -> alpha (N, 4) = (x, y, theta 0, scale 1)
    return np.column_stack([xy, np.zeros(len(xy)), np.ones(len(xy))])


def walk(p, alpha, size0, rng, dt):
    """The random walk of the centres (the proposal stage's part of the dynamics)."""
    out = alpha.copy()
    out[:, :2] += rng.normal(0.0, p.std_xy * np.sqrt(size0[0] * size0[1] * dt), (len(alpha), 2))
    return out


class NCCTracker:
    name = "ncc"

    def observe(self, p, image):
        grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
        if grey.std() == 0:
            raise UnusableFrame("uniform frame")
        return Obs(grey.astype(np.float32))

    def _estimate(self, p, t, st, phase, ess=0.0, score=0.0, std=(0.0, 0.0)):
        (x, y), (w, h) = st.xy.mean(axis=0), st.size0
        a = np.array([x, y, 0.0, 1.0])
        state = "tracked" if score > 0.5 or phase == "init" else "occluded"
        return box_estimate(t, (x - w / 2, y - h / 2, w, h), phase, a, a, np.array([*std, 0.0, 0.0]), ess, 0.0,
                            score, p.particles, float(np.clip(score, 0, 1)) if phase != "init" else 1.0, state)

    def init(self, p, obs, box, rng, resources):
        x, y, w, h = (int(round(v)) for v in box)
        if x < 0 or y < 0 or w < 2 or h < 2 or x + w > obs.grey.shape[1] or y + h > obs.grey.shape[0]:
            raise ValueError(f"box {box} is not inside the {obs.grey.shape[1]}x{obs.grey.shape[0]} frame")
        centre = np.tile([box[0] + box[2] / 2, box[1] + box[3] / 2], (p.particles, 1))
        st = State(centre, np.zeros((p.particles, 2)), obs.grey[y:y + h, x:x + w].copy(), (float(w), float(h)))
        return st, self._estimate(p, rng.t, st, "init", ess=float(p.particles), score=1.0)

    def propose(self, p, st, obs, rng, dt=1.0):
        return Proposal(walk(p, alpha_of(st.xy), st.size0, rng.stream(WALK), dt)[:, :2], dt)

    def update(self, p, st, prop, obs, rng):
        g = rng.stream(STEP)
        (w, h), scale = st.template.shape[::-1], np.sqrt(st.size0[0] * st.size0[1])
        v = st.v + g.normal(0.0, p.std_v * scale * np.sqrt(prop.dt), st.v.shape)
        xy = prop.xy + v * prop.dt  # constant velocity
        ncc = cv2.matchTemplate(obs.grey, st.template, cv2.TM_CCOEFF_NORMED)  # (H-h+1, W-w+1)
        col = np.clip(np.round(xy[:, 0] - w / 2).astype(int), 0, ncc.shape[1] - 1)
        row = np.clip(np.round(xy[:, 1] - h / 2).astype(int), 0, ncc.shape[0] - 1)
        r = ncc[row, col].astype(np.float64)
        wts = np.exp(p.sharpness * (r - r.max()))
        wts /= wts.sum()
        mean = wts @ xy
        std = np.sqrt(wts @ (xy - mean) ** 2)
        idx = np.searchsorted(np.cumsum(wts), (g.random() + np.arange(len(wts))) / len(wts))  # systematic
        idx = np.minimum(idx, len(wts) - 1)
        new = replace(st, xy=xy[idx], v=v[idx])
        est = self._estimate(p, rng.t, replace(new, xy=mean[None]), "track", 1.0 / float(wts @ wts),
                             float(wts @ r), tuple(std))
        return new, est

    def coast(self, p, st, rng, obs=None):
        return st, self._estimate(p, rng.t, st, "coast")


def to_arrays(st):
    return {"xy": st.xy, "v": st.v, "template": st.template}, {"size0": list(st.size0)}


def from_arrays(arrays, values, p):
    return State(arrays["xy"], arrays["v"], arrays["template"], tuple(float(s) for s in values["size0"]))


TRACKER = NCCTracker()
SPEC = TrackerSpec(
    "ncc", NCCParams, lambda: TRACKER, about="normalised cross-correlation, constant-velocity particle filter",
    box=BoxStages(walk=walk, purpose=WALK, proposal=lambda xy, dt: Proposal(xy, dt), particles=lambda st: st.xy,
                  alpha_of=alpha_of, particles_of=lambda alpha: alpha[:, :2], to_arrays=to_arrays,
                  from_arrays=from_arrays))
