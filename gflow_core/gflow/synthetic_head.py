"""Synthetic frames of a textured ellipsoid head for tests and benchmarks.

The head (:class:`.head_model.EllipsoidHead`) is rendered exactly under weak
perspective (orthographic projection scaled by ``c``, eq. 1) by casting one ray per
pixel (optionally several per pixel, averaged) against the ellipsoid with semi-axes
``a * (stretch @ c)`` (pixels), rotation ``r`` and translation ``l``; the nearest
intersection is the visible surface. By default only the patch of the surface that
the model's vertex grid covers (plus a 5 degree margin) is drawn -- a textured
"face mask" -- so that the object is what the model describes (the paper's
generative model has no object pixels outside its vertices); the whole ellipsoid
can be drawn instead. Its texture is a smooth function of the
unit-sphere direction ``q`` of the surface point (so it moves with the surface), and
it may drift over time (texture change, the ``Psi_v`` of eq. 4). Everything else is
the background image. Gaussian pixel noise (``W_t`` of eq. 4) comes from an explicit
generator, and the result is clipped to ``[0, 1]``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .geometry import COEF, TRANS, make_pose, project, rotation_matrices
from .head_model import EllipsoidHead, MorphableModel, bounding_box, fit_head_to_box

__all__ = ["SphereTexture", "smooth_background", "render_head", "SyntheticSequence", "synthetic_sequence"]


@dataclass(frozen=True)
class SphereTexture:
    """Smooth texture on the unit sphere: ``0.5 + sum_j a_j sin(f_j . q + phi_j + omega_j t)``.

    Attributes
    ----------
    freqs : (J, 3) float64
    amps, phases, drift : (J,) float64
        ``drift`` = ``omega_j``, phase change per frame (radians).
    """

    freqs: np.ndarray
    amps: np.ndarray
    phases: np.ndarray
    drift: np.ndarray

    @classmethod
    def random(
        cls,
        rng: np.random.Generator,
        n_waves: int = 12,
        min_freq: float = 2.0,
        max_freq: float = 7.0,
        contrast: float = 0.4,
        drift: float = 0.0,
    ) -> "SphereTexture":
        """Random texture; values stay in ``[0.5 - contrast, 0.5 + contrast]``."""
        d = rng.standard_normal((n_waves, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        freqs = d * rng.uniform(min_freq, max_freq, (n_waves, 1))
        amps = rng.uniform(0.5, 1.0, n_waves)
        amps *= contrast / amps.sum()
        phases = rng.uniform(0.0, 2 * np.pi, n_waves)
        drifts = drift * rng.choice([-1.0, 1.0], n_waves) * rng.uniform(0.5, 1.0, n_waves)
        return cls(freqs, amps, phases, drifts)

    def __call__(self, q: np.ndarray, t: float = 0.0) -> np.ndarray:
        """Texture at unit-sphere points ``q`` ``(..., 3)`` at time ``t`` -> ``(...)``."""
        arg = q @ self.freqs.T + self.phases + self.drift * t
        return 0.5 + np.sin(arg) @ self.amps


def smooth_background(
    shape: tuple[int, int], rng: np.random.Generator, sigma_px: float = 6.0, contrast: float = 0.2
) -> np.ndarray:
    """Smooth random background ``(H, W)`` float64: blurred white noise, mean 0.5."""
    noise = rng.standard_normal(shape)
    img = cv2.GaussianBlur(noise, (0, 0), sigma_px, borderType=cv2.BORDER_REFLECT)
    img = img / (img.std() + 1e-12) * (contrast / 2.0)
    return np.clip(0.5 + img, 0.0, 1.0)


def render_head(
    head: EllipsoidHead,
    pose: np.ndarray,
    texture: SphereTexture,
    background: np.ndarray,
    *,
    t: float = 0.0,
    rng: np.random.Generator | None = None,
    noise_std: float = 0.0,
    supersample: int = 2,
    patch_only: bool = True,
    patch_margin_deg: float = 5.0,
) -> np.ndarray:
    """Render the head at ``pose`` over ``background``.

    Parameters
    ----------
    head : EllipsoidHead
    pose : (P,) float64
        Pose vector (layout in :mod:`.geometry`).
    texture : SphereTexture
    background : (H, W) float64
    t : float
        Time for the texture drift.
    rng : numpy.random.Generator, optional
        Needed when ``noise_std > 0``.
    noise_std : float
        Std of additive Gaussian pixel noise.
    supersample : int
        Rays per pixel along each axis (anti-aliasing of the silhouette).
    patch_only : bool
        Render only the part of the surface the model's vertex grid covers
        (``|lon| <= lon_max``, ``|lat| <= lat_max``), a textured "face mask", so that
        every object pixel lies inside the mesh (the paper's model: the object is its
        vertices). False renders the whole ellipsoid.
    patch_margin_deg : float
        The rendered patch extends this far (degrees of longitude / latitude) beyond
        the vertex grid, so the outermost vertices lie inside the object.

    Returns
    -------
    (H, W) float64 in [0, 1]
    """
    H, W = background.shape
    u = np.asarray(pose, dtype=np.float64)
    semi = head.effective_semi_axes(u[COEF])
    if (semi <= 0).any():
        raise ValueError(f"pose gives non-positive ellipsoid semi-axes {semi}")
    R = rotation_matrices(u)
    # points X (camera frame, relative to l) on the surface satisfy X^T M X = 1
    M = R @ np.diag(1.0 / semi**2) @ R.T
    lx, ly = u[TRANS]
    acc = np.zeros((H, W))
    offs = (np.arange(supersample) + 0.5) / supersample - 0.5
    cols = np.arange(W, dtype=np.float64)[None, :]
    rows = np.arange(H, dtype=np.float64)[:, None]
    for oy in offs:
        for ox in offs:
            a = cols + ox - lx + 0.0 * rows
            b = rows + oy - ly + 0.0 * cols
            # M33 z^2 + 2 z (M13 a + M23 b) + (M11 a^2 + 2 M12 a b + M22 b^2 - 1) = 0
            A = M[2, 2]
            B = M[0, 2] * a + M[1, 2] * b
            C = M[0, 0] * a * a + 2 * M[0, 1] * a * b + M[1, 1] * b * b - 1.0
            disc = B * B - A * C
            hit = disc >= 0
            z = (-B - np.sqrt(np.where(hit, disc, 0.0))) / A  # nearest (smallest z) intersection
            X = np.stack([a, b, z], axis=-1)
            p = X @ R  # r^T X, object frame
            q = p / semi
            if patch_only:
                # q = (sin(lon) cos(lat), sin(lat), -cos(lon) cos(lat))
                lon = np.degrees(np.arctan2(q[..., 0], -q[..., 2]))
                lat = np.degrees(np.arcsin(np.clip(q[..., 1], -1.0, 1.0)))
                hit &= (np.abs(lon) <= head.lon_max_deg + patch_margin_deg) & (
                    np.abs(lat) <= head.lat_max_deg + patch_margin_deg
                )
            acc += np.where(hit, texture(q, t), background)
    img = acc / supersample**2
    if noise_std > 0:
        if rng is None:
            raise ValueError("noise_std > 0 needs an rng")
        img = img + rng.normal(0.0, noise_std, img.shape)
    return np.clip(img, 0.0, 1.0)


@dataclass(frozen=True)
class SyntheticSequence:
    """A rendered sequence with its ground truth.

    Attributes
    ----------
    frames : (T, H, W) float64
    poses : (T, P) float64
        True pose of each frame.
    head : EllipsoidHead
    model : MorphableModel
        ``head.model()``; equal to :func:`.head_model.fit_head_model_to_box` of ``box``.
    box : (4,) float64
        Bounding box of the projected vertices in frame 0.
    texture : SphereTexture
    background : (H, W) float64
    """

    frames: np.ndarray
    poses: np.ndarray
    head: EllipsoidHead
    model: MorphableModel
    box: np.ndarray
    texture: SphereTexture
    background: np.ndarray


def synthetic_sequence(
    rng: np.random.Generator,
    n_frames: int = 30,
    image_shape: tuple[int, int] = (120, 160),
    *,
    box: tuple[float, float, float, float] | None = None,
    rot_amp_deg: tuple[float, float, float] = (10.0, 20.0, 8.0),
    trans_amp_px: tuple[float, float] = (15.0, 8.0),
    scale_amp: float = 0.05,
    texture_drift: float = 0.02,
    noise_std: float = 0.01,
    n_lon: int = 15,
    n_lat: int = 15,
    patch_only: bool = True,
    morph_stretch: np.ndarray | None = None,
    morph_amp: tuple[float, ...] = (),
) -> SyntheticSequence:
    """Render a head moving along a known smooth 3-D trajectory, optionally changing its shape.

    The rotation vector is ``deg2rad(rot_amp_deg) * sin(2 pi f tau)`` with
    ``f = (1, 0.75, 0.5)`` cycles over the sequence (``tau`` from 0 to 1), so frame 0
    has the identity rotation; translation moves ``trans_amp_px * sin(pi tau), sin(2 pi tau)``
    and the scale ``1 + scale_amp sin(pi tau)``. The texture drifts
    (``texture_drift`` radians of phase per frame per wave) and every frame gets noise
    of std ``noise_std``. ``patch_only``: see :func:`render_head`.

    Morphs (an "expression", eq. 1 with ``k > 1``): ``morph_stretch`` ``(3, k - 1)`` adds morph bases
    to the rigid head (:class:`.head_model.EllipsoidHead`'s ``stretch``: basis ``j`` stretches the
    semi-axes by ``morph_stretch[:, j]``), and their coefficients follow
    ``c_{j+1} = c_1 morph_amp_j sin(2 pi (j + 1) tau)`` (zero at frame 0), so the model of the
    sequence (``SyntheticSequence.model``) has ``k`` bases and ``poses[:, 5:]`` the true ``c``.
    """
    H, W = image_shape
    if box is None:
        h = 0.5 * H
        w = 0.8 * h
        box = (W / 2 - w / 2, H / 2 - h / 2, w, h)
    head, pose0 = fit_head_to_box(np.asarray(box), image_shape, n_lon=n_lon, n_lat=n_lat)
    amps = np.asarray(morph_amp, dtype=np.float64).reshape(-1)
    if morph_stretch is not None:
        ms = np.asarray(morph_stretch, dtype=np.float64)
        if ms.ndim != 2 or ms.shape[0] != 3 or ms.shape[1] != amps.size:
            raise ValueError(f"morph_stretch must be (3, {amps.size}) for {amps.size} morph amplitudes, got {ms.shape}")
        head = EllipsoidHead(head.semi_axes, n_lon, n_lat, head.lon_max_deg, head.lat_max_deg,
                             np.concatenate([head.stretch, ms], axis=1))
        pose0 = np.concatenate([pose0, np.zeros(amps.size)])
    elif amps.size:
        raise ValueError("morph_amp needs morph_stretch")
    texture = SphereTexture.random(rng, drift=texture_drift)
    background = smooth_background(image_shape, rng)
    tau = np.linspace(0.0, 1.0, n_frames) if n_frames > 1 else np.zeros(1)
    f = np.array([1.0, 0.75, 0.5])
    amp = np.radians(np.asarray(rot_amp_deg, dtype=np.float64))
    poses = np.empty((n_frames, pose0.size))
    frames = np.empty((n_frames, H, W))
    for t, ta in enumerate(tau):
        w = amp * np.sin(2 * np.pi * f * ta)
        l = pose0[TRANS] + np.asarray(trans_amp_px) * np.array([np.sin(np.pi * ta), np.sin(2 * np.pi * ta)])
        c = pose0[COEF] * (1.0 + scale_amp * np.sin(np.pi * ta))
        if amps.size:
            c[1:] = c[0] * amps * np.sin(2 * np.pi * np.arange(1, amps.size + 1) * ta)
        poses[t] = make_pose(w, l, c)
        frames[t] = render_head(
            head, poses[t], texture, background, t=t, rng=rng, noise_std=noise_std, patch_only=patch_only
        )
    model = head.model()
    return SyntheticSequence(
        frames=frames,
        poses=poses,
        head=head,
        model=model,
        box=bounding_box(project(model.bases, poses[0])),
        texture=texture,
        background=background,
    )
