"""Stress cases: real frames perturbed over a window, with the ground truth carried along.

A stress case takes a sequence with ground truth and derives a shorter one: ``lead`` frames
before a window, the window perturbed (an occluder, a roll, a change of look, darkening and
noise, motion blur, dropped frames, the target leaving the frame), and ``tail`` frames after
it, so a tracker can be scored on whether it gets the target back. The derived ground truth is
the original's, moved where the perturbation moves the image.

Ground truth may be sparse (a box on every 5th frame, as in the MIL dataset): the plan then
places its occluders, rolls and shifts by the truth interpolated between the labelled frames
(:func:`fill_truth`), starts every run on a labelled frame, and says which derived frames show
a labelled one (``StressPlan.labelled``); only those are scored.

The work is split in two pure steps:

* :func:`plan_case` turns a case, the original ground truth and the frame size into a
  :class:`StressPlan`: which original frame each derived frame shows and every per-frame
  parameter (occluder rectangle, roll angle, shift, blur, gain, noise), with the derived
  truth and how much of the target is visible. No image is touched.
* :func:`render_frame` applies one derived frame's parameters to its original image.

Boxes are (x, y, w, h): top-left corner and size in 0-based pixels, as in ``../shared/data``.
Angles are in degrees, counter-clockwise on screen (OpenCV's convention).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from .metrics import HIDDEN_BELOW

__all__ = ["KINDS", "StressCase", "CASES", "SPAN", "StressPlan", "plan_case", "render_frame", "visible_fraction",
           "occluder_size", "fill_truth", "HIDDEN_BELOW", "motion_kernel", "COPY_KINDS", "target_copy", "flakes_at"]

#: the kinds of perturbation
KINDS = ("none", "occlude", "sweep", "partial", "slide", "roll-target", "roll-camera", "look", "dark", "blur", "fast",
         "leave", "distract", "confetti")

#: kinds that paste an image patch (the occluder, or the new part of the look)
PATCH_KINDS = ("none", "occlude", "sweep", "partial", "slide", "look")

#: kinds whose patch is the target itself (a copy cut from the sequence, not a donor's patch)
COPY_KINDS = ("distract",)



@dataclass(frozen=True)
class StressCase:
    """One perturbation of a window of frames.

    Parameters
    ----------
    name : short unique name, e.g. ``"occlude-60"``.
    kind : one of :data:`KINDS`:

        * ``none``: nothing changes (the control: the same frames, untouched);
        * ``occlude``: a real image patch, still, covering every place the target takes in
          the window (full occlusion);
        * ``sweep``: a patch three target-widths wide crossing the target horizontally
          (full occlusion in the middle of the window);
        * ``partial``: a patch covering the fraction ``amount`` of the box from one side,
          moving with the target;
        * ``slide``: a patch of the target's size sliding up across it (it enters from below,
          covers it, leaves above), so a tracker that locks on its edge is dragged along;
        * ``roll-target``: the target (a disc around it) rolls by up to ``amount`` degrees
          and back;
        * ``roll-camera``: the whole frame rolls about the target by up to ``amount``
          degrees and back;
        * ``look``: the top ``amount`` of the target is replaced by a patch for good (a hat
          put on during the window, kept on after it);
        * ``dark``: the frame darkens to ``amount`` of its brightness with Gaussian noise,
          and recovers;
        * ``blur``: linear motion blur of up to ``amount`` pixels, and back;
        * ``fast``: only every ``amount``-th frame of the window is kept;
        * ``leave``: the image shifts sideways until the target is out of the frame, stays
          out, and comes back (the uncovered strip is black);
        * ``distract``: a mirrored copy of the target, of its size, walks in a straight line at a
          steady pace in front of it, from one side to the other, covering it in the window's
          middle (a second face or walker crossing the first), and walks on after the window, so a
          tracker that follows the look rather than the target leaves with it;
        * ``confetti``: a shower of small flakes of bright colours (grey levels on grey footage), each
          tumbling as it falls, drifts across the whole frame in front of the target for the window;
          ``amount`` is the fraction of the frame the flakes cover (a celebration, snow or sparks: the
          target stays in view, broken up by many small moving occluders and colours that are not its own).
    length : length of the window in original frames.
    amount : the kind's strength (see ``kind``).
    """

    name: str
    kind: str
    length: int
    amount: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"stress case {self.name!r}: unknown kind {self.kind!r} (known: {', '.join(KINDS)})")
        if self.length < 1:
            raise ValueError(f"stress case {self.name!r}: the window needs at least one frame, got {self.length}")
        if self.kind in ("partial", "look") and not 0.0 < self.amount < 1.0:
            raise ValueError(f"stress case {self.name!r}: amount is a fraction of the box in (0, 1), got {self.amount}")
        if self.kind in ("roll-target", "roll-camera") and not 0.0 < abs(self.amount) <= 90.0:
            raise ValueError(f"stress case {self.name!r}: amount is an angle in (0, 90] degrees, got {self.amount}")
        if self.kind == "dark" and not 0.0 <= self.amount < 1.0:
            raise ValueError(f"stress case {self.name!r}: amount is the darkest gain in [0, 1), got {self.amount}")
        if self.kind == "blur" and self.amount < 2:
            raise ValueError(f"stress case {self.name!r}: amount is a blur length of at least 2 px, got {self.amount}")
        if self.kind == "confetti" and not 0.0 < self.amount < 0.5:
            raise ValueError(f"stress case {self.name!r}: amount is the fraction of the frame the flakes cover, in "
                             f"(0, 0.5), got {self.amount}")
        if self.kind == "fast" and (self.amount != int(self.amount) or self.amount < 2):
            raise ValueError(f"stress case {self.name!r}: amount is the frame step, an integer >= 2, got {self.amount}")

    @property
    def persistent(self) -> bool:
        """Whether the change stays after the window (a change of look)."""
        return self.kind in ("look", "distract")

    def describe(self) -> str:
        """One line saying what the case does."""
        a = self.amount
        n = self.length
        text = {
            "none": f"nothing changes: the frames of every case, untouched ({n}-frame window)",
            "occlude": f"a still image patch hides the target for {n} frames",
            "sweep": f"an image patch sweeps across the target in {n} frames, hiding it in the middle",
            "partial": f"an image patch hides {a:.0%} of the box, from one side, for {n} frames",
            "slide": f"a patch of the target's size slides up across it in {n} frames",
            "roll-target": f"the target rolls to {a:g} degrees and back in {n} frames",
            "roll-camera": f"the frame rolls about the target to {a:g} degrees and back in {n} frames",
            "look": f"the top {a:.0%} of the target is replaced for good (put on in {n} frames)",
            "dark": f"the frame darkens to {a:.0%} with noise and back in {n} frames",
            "blur": f"motion blur up to {a:g} px and back in {n} frames",
            "fast": f"one frame in {int(a)} of {n} kept (motion {int(a)}x faster)",
            "leave": f"the target leaves the frame and comes back in {n} frames",
            "distract": f"a mirrored copy of the target passes in front of it in {n} frames and walks on",
            "confetti": f"a shower of tumbling flakes covering {a:.0%} of the frame falls in front of it for {n} frames",
        }[self.kind]
        return text


#: the default cases: together they cover every kind once or a few times, without near-duplicates;
#: ``none`` is the control, as long as the longest case, so its run holds the frames of every case
CASES: tuple[StressCase, ...] = (
    StressCase("none", "none", 150),
    StressCase("occlude-10", "occlude", 10),
    StressCase("occlude-25", "occlude", 25),
    StressCase("occlude-60", "occlude", 60),
    StressCase("occlude-150", "occlude", 150),
    StressCase("sweep-40", "sweep", 40),
    StressCase("partial-33", "partial", 40, 1 / 3),
    StressCase("partial-67", "partial", 40, 2 / 3),
    StressCase("slide-60", "slide", 60),
    StressCase("roll-target-35", "roll-target", 40, 35.0),
    StressCase("roll-camera-20", "roll-camera", 40, 20.0),
    StressCase("roll-camera-35", "roll-camera", 40, 35.0),
    StressCase("roll-camera-45", "roll-camera", 40, 45.0),
    StressCase("look", "look", 10, 0.25),
    StressCase("dark-40", "dark", 40, 0.25),
    StressCase("blur-30", "blur", 30, 21.0),
    StressCase("fast-2", "fast", 60, 2),
    StressCase("fast-3", "fast", 60, 3),
    StressCase("leave-40", "leave", 40),
    StressCase("distract-40", "distract", 40),
    StressCase("confetti-40", "confetti", 40, 0.25),
)


@dataclass(frozen=True)
class StressPlan:
    """Everything a derived sequence is, frame by frame, before any image is made.

    Attributes
    ----------
    case : the case.
    source : (T,) int64, the original frame each derived frame shows.
    window : (start, stop), the derived frames of the window.
    boxes : (T, 4) float64, the derived ground truth.
    occluder : (T, 4) float64, the pasted patch's rectangle (x, y, w, h); NaN where none.
    angle : (T,) float64, roll in degrees about the target's centre (0: none).
    region : (T,) float64, radius of the rolled disc (0: the whole frame rolls).
    shift : (T,) float64, horizontal shift of the image content in pixels.
    blur : (T,) float64, motion blur length in pixels (below 2: none).
    gain : (T,) float64, brightness factor.
    noise : (T,) float64, standard deviation of Gaussian noise in grey levels.
    visible : (T,) float64, the fraction of the true box that is in view (in the frame and
        not under the patch).
    perturbed : (T,) bool, whether the case changes the frame (or, for ``fast``, drops
        frames around it).
    labelled : (T,) bool, whether the original frame shown has a ground-truth box (the
        others' boxes are interpolated for the plan and are not scored).
    blur_angle : direction of the motion blur, degrees.
    image_size : (W, H).
    flakes : (K, 9) float64, ``confetti``'s flakes (none for the other kinds): each row x0, y0 (its
        centre at the window's first frame, px), vx, vy (px a frame), a (half its length, px), phase,
        spin (its tumble: the half width is a |cos(phase + spin t)| 0.6, t frames into the window, rad),
        tilt (degrees) and hue (OpenCV's 0-180); :func:`flakes_at` places them on a frame.
    shower : (T,) bool, the frames the flakes fall on (None: none).
    """

    case: StressCase
    source: np.ndarray
    window: tuple[int, int]
    boxes: np.ndarray
    occluder: np.ndarray
    angle: np.ndarray
    region: np.ndarray
    shift: np.ndarray
    blur: np.ndarray
    gain: np.ndarray
    noise: np.ndarray
    visible: np.ndarray
    perturbed: np.ndarray
    labelled: np.ndarray
    blur_angle: float
    image_size: tuple[int, int]
    flakes: np.ndarray = field(default_factory=lambda: np.zeros((0, 9)))
    shower: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.source.shape[0])

    def changed(self, i: int) -> bool:
        """Whether derived frame ``i``'s image differs from its original frame's."""
        return bool(not np.isnan(self.occluder[i, 0]) or self.angle[i] != 0.0 or self.shift[i] != 0.0
                    or self.blur[i] >= 2.0 or self.gain[i] != 1.0 or self.noise[i] > 0.0
                    or (self.shower is not None and bool(self.shower[i])))


def _check_truth(truth: np.ndarray) -> np.ndarray:
    t = np.asarray(truth, dtype=np.float64)
    if t.ndim != 2 or t.shape[1] != 4 or t.shape[0] < 2:
        raise ValueError(f"ground truth must be (N, 4) boxes with N >= 2, got shape {t.shape}")
    if not np.isfinite(t).all():
        raise ValueError("ground truth has NaN or inf")
    if (t[:, 2:] <= 0).any():
        raise ValueError("ground truth has a box with zero or negative size")
    return t


def _reflect(j: np.ndarray, n: int) -> np.ndarray:
    """Indices played forwards, then backwards, then forwards ... over ``n`` frames."""
    if n == 1:
        return np.zeros_like(j)
    period = 2 * (n - 1)
    m = np.mod(j, period)
    return np.where(m < n, m, period - m)


def _bump(u: np.ndarray) -> np.ndarray:
    """0 -> 1 -> 0 over u in [0, 1]: sin(pi u)."""
    return np.sin(np.pi * np.clip(u, 0.0, 1.0))


def visible_fraction(box: np.ndarray, image_size: tuple[int, int], occluder: np.ndarray | None = None) -> float:
    """The fraction of ``box``'s area that is inside the image and not under ``occluder``.

    Parameters
    ----------
    box : (4,) x, y, w, h.
    image_size : (W, H).
    occluder : (4,) x, y, w, h, or None (or NaN) for none.
    """
    x, y, w, h = (float(v) for v in box)
    area = w * h
    if area <= 0:
        return 0.0
    W, H = image_size
    # the part of the box inside the image
    x0, y0, x1, y1 = max(x, 0.0), max(y, 0.0), min(x + w, float(W)), min(y + h, float(H))
    if x1 <= x0 or y1 <= y0:
        return 0.0
    inside = (x1 - x0) * (y1 - y0)
    if occluder is None or np.isnan(occluder[0]):
        return min(inside / area, 1.0)
    ox, oy, ow, oh = (float(v) for v in occluder)
    cx0, cy0, cx1, cy1 = max(x0, ox), max(y0, oy), min(x1, ox + ow), min(y1, oy + oh)
    covered = max(cx1 - cx0, 0.0) * max(cy1 - cy0, 0.0)
    return min(max(inside - covered, 0.0) / area, 1.0)


#: the window length every run is placed for: the longest default case
SPAN = max(c.length for c in CASES)


def fill_truth(truth: dict[int, tuple[float, float, float, float]]) -> tuple[np.ndarray, np.ndarray]:
    """The truth of every frame from the first labelled one to the last, from sparse labels.

    Parameters
    ----------
    truth : frame -> (x, y, w, h), at least two frames.

    Returns
    -------
    boxes : (N, 4) float64, frame ``first + i`` in row i (N = last - first + 1); between two
        labelled frames each coordinate is interpolated linearly.
    labelled : (N,) bool, the rows that are labelled.
    """
    frames = np.array(sorted(truth), dtype=np.int64)
    if frames.shape[0] < 2:
        raise ValueError(f"the ground truth needs at least two labelled frames, got {frames.shape[0]}")
    known = np.array([truth[int(f)] for f in frames], dtype=np.float64)
    idx = np.arange(frames[0], frames[-1] + 1)
    boxes = np.stack([np.interp(idx, frames, known[:, k]) for k in range(4)], axis=1)
    labelled = np.zeros(idx.shape[0], dtype=bool)
    labelled[frames - frames[0]] = True
    return boxes, labelled


def _source_frames(case: StressCase, n: int, lead: int, tail: int, span: int,
                   labelled: np.ndarray) -> tuple[np.ndarray, tuple[int, int]]:
    """The original frame of each derived frame, and the window in derived frames.

    Every case starts from the same frame, chosen to centre a run with a window of ``span``
    frames in the sequence (moved back to the labelled frame at or before it, where the truth
    is sparse, so the tracker starts from a true box), so one untouched run (``none``) holds the
    frames of every case. A sequence too short is played forwards and backwards (its frames and
    truth reversed are real frames and truth too)."""
    step = int(case.amount) if case.kind == "fast" else 1
    need = lead + max(span, case.length) + tail
    first = (n - need) // 2 if n >= need else 0
    first = int(np.flatnonzero(labelled[:first + 1])[-1])
    need = lead + case.length + tail
    before = np.arange(first, first + lead)
    during = np.arange(first + lead, first + lead + case.length, step)
    after = np.arange(first + lead + case.length, first + need)
    src = _reflect(np.concatenate([before, during, after]), n).astype(np.int64)
    return src, (lead, lead + during.shape[0])


def _check_plan_inputs(truth: np.ndarray, image_size: tuple[int, int], lead: int, tail: int,
                       labelled: np.ndarray | None) -> tuple[np.ndarray, tuple[int, int], np.ndarray]:
    """Check :func:`plan_case`'s inputs before any planning.

    Returns
    -------
    t : (N, 4) float64, the truth.
    size : (W, H) as ints.
    lab : (N,) bool, the labelled frames (every frame when ``labelled`` is None).
    """
    t = _check_truth(truth)
    W, H = (int(v) for v in image_size)
    if W < 8 or H < 8:
        raise ValueError(f"image size must be at least 8x8, got {W}x{H}")
    if lead < 1 or tail < 1:
        raise ValueError(f"lead and tail need at least one frame each, got {lead} and {tail}")
    lab = np.ones(t.shape[0], dtype=bool) if labelled is None else np.asarray(labelled, dtype=bool)
    if lab.shape != (t.shape[0],) or not lab[0]:
        raise ValueError(f"labelled must be (N,) = ({t.shape[0]},) bool with frame 0 labelled")
    return t, (W, H), lab


@dataclass
class _Perturbation:
    """The per-frame parameters of a derived sequence, as :class:`StressPlan` holds them (T frames).

    boxes : (T, 4) float64, the derived truth (moved by ``shift``).
    occluder : (T, 4) float64, NaN where no patch is pasted.
    angle, region, shift, blur, gain, noise : (T,) float64.
    perturbed : (T,) bool.
    blur_angle : degrees.
    """

    boxes: np.ndarray
    occluder: np.ndarray
    angle: np.ndarray
    region: np.ndarray
    shift: np.ndarray
    blur: np.ndarray
    gain: np.ndarray
    noise: np.ndarray
    perturbed: np.ndarray
    blur_angle: float = 0.0
    flakes: np.ndarray = field(default_factory=lambda: np.zeros((0, 9)))
    shower: np.ndarray | None = None

    @classmethod
    def untouched(cls, boxes: np.ndarray, inside: np.ndarray) -> "_Perturbation":
        """No change on any of the T = len(boxes) frames; ``perturbed`` starts as the window ``inside`` (T,)."""
        T = boxes.shape[0]
        return cls(boxes=boxes, occluder=np.full((T, 4), np.nan), angle=np.zeros(T), region=np.zeros(T),
                   shift=np.zeros(T), blur=np.zeros(T), gain=np.ones(T), noise=np.zeros(T), perturbed=inside.copy())


@dataclass(frozen=True)
class _Window:
    """Where the window lies in the derived frames (T of them).

    w0, w1 : its first derived frame and the one after its last.
    idx : (T,) int, the derived frame numbers.
    u : (T,) float64, 0 at the window's first frame, 1 at its last (outside [0, 1] beyond it).
    inside : (T,) bool, the frames of the window.
    hump : (T,) float64, sin(pi u) inside the window, 0 outside (:func:`_bump`).
    """

    w0: int
    w1: int
    idx: np.ndarray
    u: np.ndarray
    inside: np.ndarray
    hump: np.ndarray

    @classmethod
    def of(cls, T: int, w0: int, w1: int) -> "_Window":
        """The window [w0, w1) of T derived frames."""
        idx = np.arange(T)
        # u: 0 at the window's first frame, 1 at its last
        u = (idx - w0) / max(w1 - 1 - w0, 1)
        inside = (idx >= w0) & (idx < w1)
        hump = np.where(inside, _bump(u), 0.0)
        return cls(w0=w0, w1=w1, idx=idx, u=u, inside=inside, hump=hump)


def _occlude(pt: _Perturbation, win: _Window) -> None:
    """``occlude``: one still rectangle over every place the target takes in the window, with a margin
    of 0.15 box sizes + 2 px each side."""
    wb = pt.boxes[win.w0:win.w1]
    x0, y0 = wb[:, 0].min(), wb[:, 1].min()
    x1, y1 = (wb[:, 0] + wb[:, 2]).max(), (wb[:, 1] + wb[:, 3]).max()
    mx, my = 0.15 * wb[:, 2].mean() + 2, 0.15 * wb[:, 3].mean() + 2
    pt.occluder[win.inside] = (x0 - mx, y0 - my, x1 - x0 + 2 * mx, y1 - y0 + 2 * my)


def _sweep(pt: _Perturbation, win: _Window) -> None:
    """``sweep``: a patch three target widths wide, as tall as the target's path, crossing from left
    of the path to right of it as u goes from 0 to 1."""
    wb = pt.boxes[win.w0:win.w1]
    T = pt.boxes.shape[0]
    ow = 3.0 * wb[:, 2].mean()
    y0, y1 = wb[:, 1].min(), (wb[:, 1] + wb[:, 3]).max()
    my = 0.15 * wb[:, 3].mean() + 2
    xa, xb = wb[:, 0].min() - ow, (wb[:, 0] + wb[:, 2]).max()
    ox = xa + (xb - xa) * np.clip(win.u, 0, 1)
    pt.occluder[win.inside] = np.stack([ox, np.full(T, y0 - my), np.full(T, ow), np.full(T, y1 - y0 + 2 * my)],
                                       1)[win.inside]


def _partial(pt: _Perturbation, win: _Window, f: float, rng: np.random.Generator) -> None:
    """``partial``: a patch covering the fraction ``f`` of the box from a side drawn from ``rng``
    (left, right or bottom), moving with the target."""
    x, y, w, h = pt.boxes.T
    side = ("left", "right", "bottom")[int(rng.integers(3))]
    if side == "left":
        r = np.stack([x - 0.3 * w, y - 0.15 * h, (f + 0.3) * w, 1.3 * h], 1)
    elif side == "right":
        r = np.stack([x + (1 - f) * w, y - 0.15 * h, (f + 0.3) * w, 1.3 * h], 1)
    else:
        r = np.stack([x - 0.15 * w, y + (1 - f) * h, 1.3 * w, (f + 0.3) * h], 1)
    pt.occluder[win.inside] = r[win.inside]


def _slide(pt: _Perturbation, win: _Window) -> None:
    """``slide``: a patch of 1.2 times the target's size whose top edge goes from the box's bottom
    to above its top."""
    x, y, w, h = pt.boxes.T
    oh = 1.2 * h
    top = (y + h) - (h + oh) * np.clip(win.u, 0, 1)
    pt.occluder[win.inside] = np.stack([x - 0.1 * w, top, 1.2 * w, oh], 1)[win.inside]


def _look(pt: _Perturbation, win: _Window, f: float) -> None:
    """``look``: the new top ``f`` of the target, put on from above during the window and kept after it."""
    x, y, w, h = pt.boxes.T
    on = win.idx >= win.w0
    drop = np.where(win.inside, 1.0 - np.clip(win.u, 0, 1), 0.0) * (f + 0.15) * h
    pt.occluder[on] = np.stack([x - 0.1 * w, y - 0.15 * h - drop, 1.2 * w, (f + 0.15) * h], 1)[on]
    pt.perturbed = on


def _leave(pt: _Perturbation, win: _Window, width: int) -> None:
    """``leave``: the image (and the truth with it) shifts out through the nearer side edge of a frame
    ``width`` px wide, far enough to leave a margin, and is out for the middle half of the window."""
    x, w = pt.boxes[:, 0], pt.boxes[:, 2]
    w0, w1, u = win.w0, win.w1, win.u
    c = x[w0] + w[w0] / 2
    left = c < width / 2
    margin = 0.2 * w[w0:w1].max() + 4
    dist = ((x + w)[w0:w1].max() + margin) if left else (width - x[w0:w1].min() + margin)
    ramp = np.clip(np.minimum(u, 1 - u) / 0.25, 0.0, 1.0)
    # the image moves, the target moves with it; smoothstep keeps the start and end gentle
    s = dist * ramp * ramp * (3 - 2 * ramp)
    pt.shift = np.where(win.inside, -s if left else s, 0.0)
    pt.boxes[:, 0] += pt.shift


def _distract(pt: _Perturbation, win: _Window, rng: np.random.Generator) -> None:
    """``distract``: a copy of the target's size at the window's middle frame walks in a straight line at a
    steady pace, level with the target's centre there, from 2.5 box widths on one side of it (drawn from
    ``rng``) to 2.5 on the other as u goes from 0 to 1, and on after the window: it covers the target at
    u = 1/2 and moves on its own, as a passer-by does, whatever the target and the camera do."""
    x, y, w, h = pt.boxes.T
    mid = win.w0 + int(round(0.5 * (win.w1 - 1 - win.w0)))
    cx, cy, wm, hm = x[mid] + 0.5 * w[mid], y[mid] + 0.5 * h[mid], w[mid], h[mid]
    sign = 1.0 if rng.integers(2) else -1.0
    # the copy's centre: (cx + sign (5 u - 2.5) w_mid, cy), u = 1/2 at the middle frame
    ux = cx + sign * (5.0 * (win.idx - mid) / max(win.w1 - 1 - win.w0, 1)) * wm
    on = win.idx >= win.w0
    T = pt.boxes.shape[0]
    pt.occluder[on] = np.stack([ux - 0.5 * wm, np.full(T, cy - 0.5 * hm), np.full(T, wm), np.full(T, hm)], 1)[on]
    pt.perturbed = on


#: ``confetti``: a flake's half length, in units of sqrt(w h) of the target's box at the window's start
FLAKE_SIZE = (0.06, 0.14)
#: a flake's half width at its broadest, in units of its half length
FLAKE_WIDTH = 0.6
#: the most flakes a shower has
MAX_FLAKES = 4000


def _confetti(pt: _Perturbation, win: _Window, cover: float, size: tuple[int, int], rng: np.random.Generator) -> None:
    """``confetti``: flakes of the target's scale, as many as cover the fraction ``cover`` of the frame,
    placed uniformly at the window's start, each falling at its own pace (1-3 % of the frame's height a
    frame), drifting sideways, tumbling (its breadth a |cos(phase + spin t)|) and of a hue of its own; they
    live on the frame widened by a margin m = 2 max(a) each side and wrap round it, so the shower keeps its
    density to the window's end."""
    W, H = size
    x, y, w, h = pt.boxes[win.w0]
    s = math.sqrt(w * h)
    lo, hi = FLAKE_SIZE
    a = np.maximum(rng.uniform(lo * s, hi * s, MAX_FLAKES), 1.5)
    m = 2.0 * float(a.max())
    # a flake's mean area as drawn, its half axes widened by the half pixel the raster adds:
    # pi E[(a + 1/2)(b + 1/2)], b = FLAKE_WIDTH a |cos|, E|cos| = 2 / pi
    e_cos = 2.0 / math.pi
    area = math.pi * float(np.mean((a + 0.5) * (FLAKE_WIDTH * a * e_cos + 0.5)))
    # flakes at uniform places overlap as a Poisson process does: cover = 1 - exp(-K area / domain)
    k = int(min(max(round(-math.log(1.0 - cover) * (W + 2 * m) * (H + 2 * m) / area), 1), MAX_FLAKES))
    a = a[:k]
    m = 2.0 * float(a.max())  # the margin flakes_at wraps on
    pt.flakes = np.column_stack([
        rng.uniform(-m, W + m, k), rng.uniform(-m, H + m, k),  # x0, y0
        rng.normal(0.0, 0.005 * W, k), rng.uniform(0.01, 0.03, k) * H,  # vx, vy
        a, rng.uniform(0.0, 2.0 * math.pi, k), rng.uniform(0.1, 0.4, k),  # a, phase, spin
        rng.uniform(0.0, 180.0, k), rng.uniform(0.0, 180.0, k)])  # tilt, hue
    pt.shower = win.inside.copy()


def flakes_at(plan: StressPlan, i: int) -> np.ndarray:
    """``confetti``'s flakes on derived frame ``i``: (K, 6) float64, each row cx, cy, the ellipse's half axes
    (a, b), its tilt (degrees) and hue; (0, 6) on a frame with none. A flake leaving one edge of the frame
    comes back on the opposite one."""
    if plan.shower is None or not plan.shower[i] or plan.flakes.shape[0] == 0:
        return np.zeros((0, 6))
    W, H = plan.image_size
    f = plan.flakes
    t = float(i - plan.window[0])
    a = f[:, 4]
    m = 2.0 * a.max()
    # c(t) = c_0 + v t, wrapped onto [-m, W + m) x [-m, H + m)
    cx = np.mod(f[:, 0] + f[:, 2] * t + m, W + 2.0 * m) - m
    cy = np.mod(f[:, 1] + f[:, 3] * t + m, H + 2.0 * m) - m
    # the tumble: b = FLAKE_WIDTH a |cos(phase + spin t)|, at least half a pixel
    b = np.maximum(FLAKE_WIDTH * a * np.abs(np.cos(f[:, 5] + f[:, 6] * t)), 0.5)
    return np.column_stack([cx, cy, a, b, f[:, 7], f[:, 8]])


def _draw_flakes(img: np.ndarray, fl: np.ndarray, colour: bool, offset: tuple[float, float] = (0.0, 0.0),
                 value: float | None = None) -> None:
    """Draw the flakes ``fl`` (:func:`flakes_at`) into ``img`` in place, shifted by -``offset``: in their hues
    (saturation 220, value 240) where ``colour``, else in the grey level of that colour; every one in
    ``value`` if given (a mask)."""
    shift = 4  # cv2's sub-pixel bits
    one = float(1 << shift)
    for cx, cy, a, b, tilt, hue in fl:
        if value is not None:
            c: tuple[float, ...] = (value,) * (3 if img.ndim == 3 else 1)
        else:
            bgr = cv2.cvtColor(np.array([[[hue, 220, 240]]], np.uint8), cv2.COLOR_HSV2BGR)[0, 0]
            if colour and img.ndim == 3:
                c = tuple(float(v) for v in bgr)
            else:
                g = 0.114 * bgr[0] + 0.587 * bgr[1] + 0.299 * bgr[2]
                c = (g,) * (3 if img.ndim == 3 else 1)
        centre = (int(round((cx - offset[0]) * one)), int(round((cy - offset[1]) * one)))
        axes = (int(round(a * one)), int(round(b * one)))
        cv2.ellipse(img, centre, axes, float(tilt), 0.0, 360.0, c, -1, cv2.LINE_8, shift)


def _covered(plan: StressPlan, i: int, box: np.ndarray) -> float:
    """The fraction of ``box`` (x, y, w, h) in view on frame ``i`` (in the frame, not under the patch) that no
    flake covers, as a fraction of the box's area (:func:`visible_fraction` with the flakes)."""
    x, y, w, h = (float(v) for v in box)
    W, H = plan.image_size
    x0, y0, x1, y1 = max(int(math.floor(x)), 0), max(int(math.floor(y)), 0), min(int(math.ceil(x + w)), W), \
        min(int(math.ceil(y + h)), H)
    if x1 <= x0 or y1 <= y0 or w * h <= 0:
        return 0.0
    mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
    _draw_flakes(mask, flakes_at(plan, i), False, (float(x0), float(y0)), 255.0)
    free = float((mask == 0).mean())
    return visible_fraction(box, (W, H), plan.occluder[i]) * free


def _perturb(case: StressCase, pt: _Perturbation, win: _Window, size: tuple[int, int],
             rng: np.random.Generator) -> None:
    """Set the parameters of ``case``'s kind in ``pt`` over the window ``win`` (``rng`` draws the
    side of ``partial``, the direction of ``blur``, the side ``distract``'s copy comes from and
    ``confetti``'s flakes); ``size`` is the frame's (W, H)."""
    k = case.kind
    width = size[0]
    if k == "none":
        pt.perturbed = np.zeros(pt.boxes.shape[0], dtype=bool)
    elif k == "occlude":
        _occlude(pt, win)
    elif k == "sweep":
        _sweep(pt, win)
    elif k == "partial":
        _partial(pt, win, case.amount, rng)
    elif k == "slide":
        _slide(pt, win)
    elif k in ("roll-target", "roll-camera"):
        pt.angle = case.amount * win.hump
        if k == "roll-target":
            # a disc of 0.55 times the box's diagonal rolls
            pt.region = np.where(win.inside, 0.55 * np.hypot(pt.boxes[:, 2], pt.boxes[:, 3]), 0.0)
    elif k == "look":
        _look(pt, win, case.amount)
    elif k == "dark":
        pt.gain = 1.0 - (1.0 - case.amount) * win.hump
        pt.noise = 15.0 * win.hump
    elif k == "blur":
        pt.blur = case.amount * win.hump
        pt.blur_angle = float(rng.uniform(0.0, 180.0))
    elif k == "fast":
        pass  # the window's frames were dropped in _source_frames
    elif k == "leave":
        _leave(pt, win, width)
    elif k == "distract":
        _distract(pt, win, rng)
    elif k == "confetti":
        _confetti(pt, win, case.amount, size, rng)


def plan_case(case: StressCase, truth: np.ndarray, image_size: tuple[int, int], rng: np.random.Generator,
              lead: int = 30, tail: int = 60, span: int = SPAN, labelled: np.ndarray | None = None) -> StressPlan:
    """Plan the derived sequence of ``case`` on a sequence with ground truth ``truth``.

    Parameters
    ----------
    case : the perturbation.
    truth : (N, 4) float64, the true box of every original frame 0..N-1.
    image_size : (W, H) of the original frames.
    rng : draws the case's free choices (which side a partial occluder comes from, the blur
        direction).
    lead, tail : derived frames before and after the window.
    span : the run of every case starts where a run with a window this long would be centred.
    labelled : (N,) bool, the frames whose truth is labelled (the others interpolated,
        :func:`fill_truth`); frame 0 must be one. None: every frame.

    Returns
    -------
    StressPlan
    """
    t, (W, H), lab = _check_plan_inputs(truth, image_size, lead, tail, labelled)
    src, (w0, w1) = _source_frames(case, t.shape[0], lead, tail, span, lab)
    T = src.shape[0]
    win = _Window.of(T, w0, w1)
    pt = _Perturbation.untouched(t[src].copy(), win.inside)
    _perturb(case, pt, win, (W, H), rng)
    visible = np.array([visible_fraction(pt.boxes[i], (W, H), pt.occluder[i]) for i in range(T)])
    plan = StressPlan(case=case, source=src, window=(w0, w1), boxes=pt.boxes, occluder=pt.occluder, angle=pt.angle,
                      region=pt.region, shift=pt.shift, blur=pt.blur, gain=pt.gain, noise=pt.noise, visible=visible,
                      perturbed=pt.perturbed, labelled=lab[src], blur_angle=pt.blur_angle, image_size=(W, H),
                      flakes=pt.flakes, shower=pt.shower)
    if pt.shower is not None:
        # the flakes cover part of the box: its fraction in view counts them too
        for i in np.flatnonzero(pt.shower):
            visible[i] = _covered(plan, int(i), pt.boxes[i])
    return plan


def occluder_size(plan: StressPlan) -> tuple[int, int] | None:
    """The largest (width, height) the patch takes, in pixels, or None if the case pastes none."""
    o = plan.occluder[~np.isnan(plan.occluder[:, 0])]
    if o.shape[0] == 0:
        return None
    return int(math.ceil(o[:, 2].max())), int(math.ceil(o[:, 3].max()))


def target_copy(image: np.ndarray, box: np.ndarray) -> np.ndarray:
    """The target's look for ``distract``: the pixels of ``box`` (x, y, w, h) in ``image`` (clipped to it),
    mirrored left to right, so the copy is like the target and not the same picture.

    Returns (h', w', C) or (h', w') uint8, a new array. Raises ``ValueError`` if the box is not in the image."""
    H, W = image.shape[:2]
    x0, y0 = max(int(round(box[0])), 0), max(int(round(box[1])), 0)
    x1, y1 = min(int(round(box[0] + box[2])), W), min(int(round(box[1] + box[3])), H)
    if x1 - x0 < 2 or y1 - y0 < 2:
        raise ValueError(f"the target's box {tuple(float(v) for v in box)} is not in the {W}x{H} image")
    return image[y0:y1, x0:x1][:, ::-1].copy()


def _paste(img: np.ndarray, rect: np.ndarray, patch: np.ndarray) -> None:
    """Paste ``patch`` resized to ``rect`` (x, y, w, h) into ``img`` in place, clipped to the image."""
    H, W = img.shape[:2]
    x, y, w, h = (float(v) for v in rect)
    pw, ph = max(int(round(w)), 1), max(int(round(h)), 1)
    px, py = int(round(x)), int(round(y))
    a0, b0 = max(px, 0), max(py, 0)
    a1, b1 = min(px + pw, W), min(py + ph, H)
    if a1 <= a0 or b1 <= b0:
        return
    resized = cv2.resize(patch, (pw, ph), interpolation=cv2.INTER_AREA if pw * ph < patch.shape[0] * patch.shape[1]
                         else cv2.INTER_LINEAR)
    if resized.ndim == 2 and img.ndim == 3:
        resized = cv2.cvtColor(resized, cv2.COLOR_GRAY2BGR)
    elif resized.ndim == 3 and img.ndim == 2:
        resized = cv2.cvtColor(resized, cv2.COLOR_BGR2GRAY)
    img[b0:b1, a0:a1] = resized[b0 - py:b1 - py, a0 - px:a1 - px]


def motion_kernel(length: float, angle: float) -> np.ndarray:
    """A normalised line kernel of ``length`` pixels at ``angle`` degrees, (K, K) float32."""
    k = int(math.ceil(length)) | 1
    ker = np.zeros((k, k), np.float32)
    c = (k - 1) / 2.0
    dx, dy = math.cos(math.radians(angle)), -math.sin(math.radians(angle))
    half = (length - 1) / 2.0
    p0 = (int(round((c - half * dx) * 16)), int(round((c - half * dy) * 16)))
    p1 = (int(round((c + half * dx) * 16)), int(round((c + half * dy) * 16)))
    cv2.line(ker, p0, p1, 1.0, 1, cv2.LINE_AA, 4)
    return ker / max(float(ker.sum()), 1e-6)


def render_frame(image: np.ndarray, plan: StressPlan, i: int, patch: np.ndarray | None = None,
                 rng: np.random.Generator | None = None) -> np.ndarray:
    """Derived frame ``i`` of ``plan`` made from its original image.

    Parameters
    ----------
    image : (H, W, 3) or (H, W) uint8, the original frame ``plan.source[i]``.
    plan : the plan.
    i : derived frame index.
    patch : (h, w, 3) or (h, w) uint8, the real image patch the case pastes (resized to each
        frame's rectangle); needed by the cases that paste one.
    rng : draws the noise of the frame (needed when ``plan.noise[i] > 0``).

    Returns
    -------
    (H, W, 3) or (H, W) uint8, a new array (``image`` is not changed).
    """
    if image.dtype != np.uint8 or image.ndim not in (2, 3):
        raise ValueError(f"image must be (H, W) or (H, W, 3) uint8, got {image.shape} {image.dtype}")
    if (image.shape[1], image.shape[0]) != tuple(plan.image_size):
        raise ValueError(f"image is {image.shape[1]}x{image.shape[0]}, the plan is for "
                         f"{plan.image_size[0]}x{plan.image_size[1]}")
    if not 0 <= i < len(plan):
        raise ValueError(f"frame {i} is outside the plan's {len(plan)} frames")
    out: np.ndarray = image.copy()
    H, W = out.shape[:2]
    box = plan.boxes[i]
    cx, cy = box[0] + box[2] / 2, box[1] + box[3] / 2
    if plan.shift[i] != 0.0:
        shift = np.array([[1, 0, plan.shift[i]], [0, 1, 0]], dtype=np.float32)
        out = cv2.warpAffine(out, shift, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    if plan.angle[i] != 0.0:
        m = cv2.getRotationMatrix2D((float(cx), float(cy)), float(plan.angle[i]), 1.0)
        rolled = cv2.warpAffine(out, m, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        r = plan.region[i]
        if r > 0:  # only a disc around the target rolls; a soft edge 15 % of its radius wide
            yy, xx = np.mgrid[0:H, 0:W]
            d = np.hypot(xx - cx, yy - cy)
            a = np.clip((r - d) / (0.15 * r), 0.0, 1.0).astype(np.float32)
            if out.ndim == 3:
                a = a[..., None]
            out = (a * rolled + (1 - a) * out + 0.5).astype(np.uint8)
        else:
            out = rolled
    if not np.isnan(plan.occluder[i, 0]):
        if patch is None:
            raise ValueError(f"stress case {plan.case.name!r} pastes an image patch: give one")
        _paste(out, plan.occluder[i], patch)
    if plan.shower is not None and plan.shower[i]:
        # flakes in their colours on a colour frame, in grey levels on a grey one (equal channels)
        colour = out.ndim == 3 and not (np.array_equal(out[..., 0], out[..., 1])
                                        and np.array_equal(out[..., 1], out[..., 2]))
        _draw_flakes(out, flakes_at(plan, i), colour)
    if plan.gain[i] != 1.0 or plan.noise[i] > 0:
        f = out.astype(np.float32) * np.float32(plan.gain[i])
        if plan.noise[i] > 0:
            if rng is None:
                raise ValueError(f"stress case {plan.case.name!r} adds noise: give an rng")
            f += rng.normal(0.0, plan.noise[i], size=f.shape).astype(np.float32)
        out = np.clip(f + 0.5, 0, 255).astype(np.uint8)
    if plan.blur[i] >= 2.0:
        out = cv2.filter2D(out, -1, motion_kernel(float(plan.blur[i]), plan.blur_angle),
                           borderType=cv2.BORDER_REFLECT101)
    return out
