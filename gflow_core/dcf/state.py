"""What the correlation-filter tracker reads of a frame, proposes, and carries from frame to frame.

All frozen: the tracker's functions return new values and never change their arguments.
:func:`to_arrays` and :func:`from_arrays` turn a state into plain arrays and values and back, bit for
bit (a stage's snapshot).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from ..visibility import ChiSquare
from . import filter as cf
from .histogram import ColourModel
from .longterm import LongTerm
from .negatives import Place, from_array, to_array
from .model import Geometry, TargetModel, geometry
from .params import DCFParams
from .scale import ScaleFilter
from .trackscore import Track

__all__ = ["DCFObservation", "DCFProposal", "DCFState", "model_arrays", "model_of_arrays", "to_arrays", "from_arrays"]


@dataclass(frozen=True)
class DCFObservation:
    """A frame as the tracker reads it.

    image : (H, W, 3) BGR uint8 of a colour frame, or (H, W) uint8 of a grey one (single channel, or
    three equal channels: :func:`gflow_core.dcf.features.is_grey`); grey : (H, W) float32 grey levels;
    is_grey : whether the frame holds grey levels only.
    """

    image: np.ndarray
    grey: np.ndarray
    is_grey: bool


@dataclass(frozen=True)
class DCFProposal:
    """The proposal for frame t: particles (N, 3) (x, y, log s) from the proposal's random walk about
    the posterior of the frame before, and ``dt``, the frame periods since that posterior."""

    particles: np.ndarray
    dt: float = 1.0


@dataclass(frozen=True)
class DCFState:
    """The posterior after a frame.

    geom : the filter's window (:class:`.model.Geometry`, a function of the first box's size and the
        parameters); model : the filters, the colour model and the scale filter.
    particles : (N, 3) float64 resampled posterior over (x, y, log s).
    centre : (2,) float64 and log_s : the last estimate (the box is exp(log_s) times the first size).
    velocity : (2,) float64 px / frame.
    target : distribution of the estimate's distance rho = 1 - y (y the filter's response) on frames the
        target was present; clutter : of the best distance away from the estimate (:mod:`gflow_core.visibility`);
        ctarget, cclutter : the same of the colour score (unused without a colour model).
    hidden_run : frames in a row that clutter explained the estimate (0: present).
    back : while the target is judged hidden, the filtered probability it was present on the last frame.
    target_state : how the target was judged on the last frame with evidence (what a coasted frame
        reports).
    spread : px, how far the target's place has spread since it was last seen (0 while it is).
    sclutter : distribution of the filter's distance at the search's best placement on the frames since the
        target was last seen (empty while it is; ``search_clutter``).
    longterm : the long-term filter and its distributions (``longterm``; :mod:`.longterm`), or None.
    speed2 : px^2 / frame^2, running mean of |v|^2 on the frames the target was tracked
        (``redetect_speed``; 0 without), from 0 at rate ``target_rate`` (so low over the first
        1 / target_rate tracked frames).
    negatives : the places the search's best placement kept falling at on the frames since the target was
        last seen (empty while it is; ``search_negatives``; :mod:`.negatives`).
    last_grey : (H, W) uint8 grey levels of the last frame while the track is tentative and
        ``confirm_flow`` asks for its flow (:mod:`.confirm`), and on every frame with ``camera_motion``
        (:mod:`.camera`), else None.
    angle : radians, the target's roll: the windows of the target are sampled rolled by it (``roll_step``;
        :mod:`.rotation`; 0 without).
    manoeuvre : the posterior probability that the target is manoeuvring, not moving at constant velocity
        (``motion_switch``; :mod:`.modes`; 0 without).
    recent : the short-run mean of the target's distance on the frames it was present (``rate_adapt``;
        :mod:`.rates`; 0 without).
    vtarget, vclutter : distributions of the first frame's filter's distance at the estimate and of its best
        half a box away on confident frames (``verify``; :mod:`.verify`; empty without).
    track : while the target is hidden, the search's best placements as a candidate track (``search_track``;
        :mod:`.trackscore`; None without).
    motion_fit : the sums (A, B) of the motion model's learnt gain (``motion_fit``; :mod:`.motion_fit`; (0, 0)
        without).
    tail : the learnt weight of the motion prior's heavy tail (``motion_tail_rate``; :mod:`.heavytail`; 0 before
        the first tracked frame and without).
    """

    geom: Geometry
    model: TargetModel
    particles: np.ndarray
    centre: np.ndarray
    log_s: float
    velocity: np.ndarray
    target: ChiSquare
    clutter: ChiSquare
    ctarget: ChiSquare = ChiSquare()
    cclutter: ChiSquare = ChiSquare()
    hidden_run: int = 0
    back: float = 0.0
    target_state: str = "tracked"
    spread: float = 0.0
    sclutter: ChiSquare = ChiSquare()
    longterm: LongTerm | None = None
    speed2: float = 0.0
    negatives: tuple[Place, ...] = ()
    last_grey: np.ndarray | None = None
    angle: float = 0.0
    manoeuvre: float = 0.0
    recent: float = 0.0
    vtarget: ChiSquare = ChiSquare()
    vclutter: ChiSquare = ChiSquare()
    track: Track | None = None
    motion_fit: tuple[float, float] = (0.0, 0.0)
    tail: float = 0.0


def _pair(v: Sequence[float]) -> tuple[float, float]:
    """Two numbers of a snapshot's values, as a pair of floats."""
    a, b = v
    return float(a), float(b)


def _chi_values(d: ChiSquare) -> list[float]:
    return [d.m1, d.m2, d.n]


def _real(a: np.ndarray) -> np.ndarray:
    """A complex array as float64 (..., 2 n) (real and imaginary parts interleaved); a real one as float64."""
    if np.iscomplexobj(a):
        return np.ascontiguousarray(a, dtype=np.complex128).view(np.float64)
    return np.ascontiguousarray(a, dtype=np.float64)


def _complex(a: np.ndarray) -> np.ndarray:
    """The inverse of :func:`_real` for a complex array."""
    return np.ascontiguousarray(a, dtype=np.float64).view(np.complex128)


def model_arrays(m: TargetModel) -> dict[str, np.ndarray]:
    """The target model's arrays by name, as float64 (complex ones with real and imaginary parts interleaved
    on their last axis): the filters, the colour histograms, the scale filter. :func:`model_of_arrays`
    inverts it bit for bit."""
    arrays = {"det": _real(m.det), "anchor": _real(m.anchor)}
    if isinstance(m.train, cf.Spectrum):
        arrays.update(train_num=_real(m.train.num), train_den=_real(m.train.den))
    else:
        arrays["train_x"] = _real(m.train)
    if m.colour is not None:
        arrays.update(colour_fg=_real(m.colour.fg), colour_bg=_real(m.colour.bg))
    if m.scale is not None:
        arrays.update(scale_num=_real(m.scale.num), scale_den=_real(m.scale.den), scale_label=_real(m.scale.label_hat))
        if m.scale.anchor_num is not None and m.scale.anchor_den is not None:
            arrays.update(scale_anchor_num=_real(m.scale.anchor_num), scale_anchor_den=_real(m.scale.anchor_den))
    if m.support is not None:
        arrays["support"] = np.ascontiguousarray(m.support, dtype=np.float64)
    if m.channels is not None:
        arrays["channels"] = np.ascontiguousarray(m.channels, dtype=np.float64)
    return arrays


def model_of_arrays(arrays: Mapping[str, np.ndarray], colour_mode: str, scale_model: Any, geom: Geometry) -> TargetModel:
    """The target model of :func:`model_arrays`' ``arrays`` (``KeyError`` for a part missing, ``ValueError``
    for a filter that does not fit ``geom``'s window); ``scale_model`` the scale filter's (h, w) model size."""
    wc, hc = geom.cells
    det, anchor = _complex(arrays["det"]), _complex(arrays["anchor"])
    if det.shape[:2] != (hc, wc // 2 + 1) or anchor.shape != det.shape:
        raise ValueError(f"filter of shape {det.shape} does not fit the window of {wc}x{hc} cells")
    train: cf.Spectrum | np.ndarray
    if "train_num" in arrays:
        train = cf.Spectrum(_complex(arrays["train_num"]), np.array(arrays["train_den"]))
    else:
        train = _complex(arrays["train_x"])
    colour = ColourModel(np.array(arrays["colour_fg"]), np.array(arrays["colour_bg"])) if "colour_fg" in arrays else None
    scale = None
    if "scale_num" in arrays:
        has_anchor = "scale_anchor_num" in arrays
        scale = ScaleFilter(_complex(arrays["scale_num"]), np.array(arrays["scale_den"]),
                            _complex(arrays["scale_label"]), (int(scale_model[0]), int(scale_model[1])),
                            _complex(arrays["scale_anchor_num"]) if has_anchor else None,
                            np.array(arrays["scale_anchor_den"]) if has_anchor else None)
    support = np.array(arrays["support"]) if "support" in arrays else None
    channels = np.array(arrays["channels"]) if "channels" in arrays else None
    if channels is not None and channels.shape != (det.shape[2],):
        raise ValueError(f"channel weights of shape {channels.shape} do not fit a filter of {det.shape[2]} channels")
    return TargetModel(train, det, anchor, colour, colour_mode, scale, support, channels)


def to_arrays(st: DCFState) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """The state as named float64 arrays (complex ones with real and imaginary parts interleaved on their
    last axis) and plain values, for a snapshot; :func:`from_arrays` inverts it bit for bit."""
    m = st.model
    arrays = {"particles": st.particles, "centre": st.centre, "velocity": st.velocity, **model_arrays(m)}
    values = {"size0": [float(v) for v in st.geom.size0], "log_s": float(st.log_s), "hidden_run": int(st.hidden_run),
              "back": float(st.back), "target_state": st.target_state, "spread": float(st.spread), "colour_mode": m.colour_mode,
              "target": [st.target.m1, st.target.m2, st.target.n], "clutter": [st.clutter.m1, st.clutter.m2, st.clutter.n],
              "ctarget": [st.ctarget.m1, st.ctarget.m2, st.ctarget.n],
              "cclutter": [st.cclutter.m1, st.cclutter.m2, st.cclutter.n],
              "sclutter": [st.sclutter.m1, st.sclutter.m2, st.sclutter.n],
              "scale_model": None if m.scale is None else [int(v) for v in m.scale.model]}
    if st.speed2:
        values["speed2"] = float(st.speed2)
    if st.angle:
        values["angle"] = float(st.angle)
    if st.manoeuvre:
        values["manoeuvre"] = float(st.manoeuvre)
    if st.recent:
        values["recent"] = float(st.recent)
    if any(st.motion_fit):
        values["motion_fit"] = [float(v) for v in st.motion_fit]
    if st.tail:
        values["tail"] = float(st.tail)
    if st.vtarget.n:
        values["vtarget"] = _chi_values(st.vtarget)
        values["vclutter"] = _chi_values(st.vclutter)
    if st.negatives:
        arrays["negatives"] = to_array(st.negatives)
    if st.last_grey is not None:
        arrays["last_grey"] = st.last_grey
    if st.track is not None:
        arrays["track"] = st.track.to_array()
    lt = st.longterm
    if lt is not None:
        arrays["lt_det"] = _real(lt.det)
        if isinstance(lt.train, cf.Spectrum):
            arrays.update(lt_train_num=_real(lt.train.num), lt_train_den=lt.train.den)
        else:
            arrays["lt_train_x"] = _real(lt.train)
        values.update(lt_target=_chi_values(lt.target), lt_clutter=_chi_values(lt.clutter),
                      lt_sclutter=_chi_values(lt.sclutter), lt_updates=int(lt.updates))
    return {k: np.asarray(v, dtype=np.float64) for k, v in arrays.items()}, values


def from_arrays(arrays: Mapping[str, np.ndarray], values: Mapping[str, Any], p: DCFParams) -> DCFState:
    """The state of :func:`to_arrays` (``KeyError`` / ``ValueError`` for a part missing or of the wrong
    shape); the window's geometry is made again from the first size and the parameters."""
    size0 = values["size0"]
    geom = geometry((float(size0[0]), float(size0[1])), p)
    wc, hc = geom.cells
    model = model_of_arrays(arrays, values["colour_mode"], values.get("scale_model"), geom)
    det = model.det
    def chi(key: str) -> ChiSquare:
        # a snapshot made before the search's clutter existed has none: an empty distribution
        v = values[key] if key not in ("sclutter", "vtarget", "vclutter") else values.get(key, [0.0, 0.0, 0])
        return ChiSquare(float(v[0]), float(v[1]), int(v[2]))


    longterm = None
    if "lt_det" in arrays:
        lt_det = _complex(arrays["lt_det"])
        if lt_det.shape != det.shape:
            raise ValueError(f"long-term filter of shape {lt_det.shape} does not fit the window of {wc}x{hc} cells")
        lt_train: cf.Spectrum | np.ndarray = (cf.Spectrum(_complex(arrays["lt_train_num"]), np.array(arrays["lt_train_den"]))
                                              if "lt_train_num" in arrays else _complex(arrays["lt_train_x"]))
        longterm = LongTerm(lt_train, lt_det, chi("lt_target"), chi("lt_clutter"), chi("lt_sclutter"),
                            int(values["lt_updates"]))
    return DCFState(geom=geom, model=model, particles=np.array(arrays["particles"]), centre=np.array(arrays["centre"]),
                    log_s=float(values["log_s"]), velocity=np.array(arrays["velocity"]),
                    target=chi("target"), clutter=chi("clutter"), ctarget=chi("ctarget"), cclutter=chi("cclutter"),
                    sclutter=chi("sclutter"),
                    hidden_run=int(values["hidden_run"]),
                    back=float(values["back"]), target_state=str(values["target_state"]),
                    spread=float(values["spread"]), longterm=longterm, speed2=float(values.get("speed2", 0.0)),
                    angle=float(values.get("angle", 0.0)), manoeuvre=float(values.get("manoeuvre", 0.0)),
                    recent=float(values.get("recent", 0.0)),
                    motion_fit=_pair(values.get("motion_fit", (0.0, 0.0))), tail=float(values.get("tail", 0.0)),
                    vtarget=chi("vtarget"), vclutter=chi("vclutter"),
                    negatives=from_array(arrays["negatives"]) if "negatives" in arrays else (),
                    last_grey=np.asarray(arrays["last_grey"]).astype(np.uint8) if "last_grey" in arrays else None,
                    track=Track.of_array(arrays["track"]) if "track" in arrays else None)
