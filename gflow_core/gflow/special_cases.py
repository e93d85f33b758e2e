"""Constrained optic flow and template matching: the special cases of G-flow (sec. 4).

Direct, independent implementations used to check that G-flow reduces to them:

* **Constrained optic flow** (eq. 3, 21): one pose, Gauss-Newton on
  ``1/2 sum_i [y_t(x_i(u)) - y_{t-1}(x_i(u_{t-1}))]^2``. G-flow reduces to it with one
  expert, ``alpha -> 0``, an uninformative pose prior and background, equal initial
  texel variances and ``Psi_v -> inf`` (:func:`optic_flow_config`; ``Psi_v`` is a large
  finite number, ``1e6`` by default, so the object template is
  ``y_{t-1}(x_i(u_{t-1}))`` to about ``1e-9``, eq. 20).
* **Template matching** (eq. 22): Gauss-Newton on ``sum_i [y_t(x_i(u)) - mu_1(i)]^2`` with
  a fixed template. G-flow reduces to it with ``Var(V_1) = 0`` and ``Psi_v = 0``
  (:func:`template_matching_config`): the texture never changes.

The direct solvers are written separately from G-flow (least squares on the stacked
residual Jacobian of eq. 21 / 22, the template read straight from the previous frame)
but use the same step rule as G-flow's Gauss-Newton (:mod:`.pose_opinion`): a step
is kept only if it lowers the sum of squares, otherwise the step length is halved.
Plain Gauss-Newton with the central-difference image gradient does not stop at the
minimum of the sampled objective, so without the same rule the two would stop at
different points of the flat rotation/translation valley.
"""

from __future__ import annotations

import numpy as np

from .filter import GFlowConfig
from .geometry import box_plus, project, projection_jacobian
from .image import bilinear_stencil, prepare_frame
from .params import paper_config

__all__ = ["constrained_optic_flow", "template_matching", "optic_flow_config", "template_matching_config"]


def _sample(frame: np.ndarray, points: np.ndarray) -> np.ndarray:
    st = bilinear_stencil(points, frame.shape)
    return st.sample(np.ascontiguousarray(frame, dtype=np.float64).reshape(-1))


def template_matching(
    bases: np.ndarray, pose_init: np.ndarray, template: np.ndarray, frame: np.ndarray, n_iter: int = 10
) -> np.ndarray:
    """Gauss-Newton on ``sum_i [y_t(x_i(u)) - template_i]^2`` (eq. 22) from ``pose_init``.

    Parameters
    ----------
    bases : (n, 3, k) float64
    pose_init : (P,) float64
    template : (n,) float64
    frame : (H, W) float64 in [0, 1]
    n_iter : int

    Returns
    -------
    (P,) float64
    """
    fd = prepare_frame(frame)
    template = np.asarray(template, dtype=np.float64)

    def residuals(u: np.ndarray) -> np.ndarray:
        # y_t(x_i(u)) - mu_1(i)
        return _sample(fd.image, project(bases, u[None]))[0] - template

    u = np.asarray(pose_init, dtype=np.float64).copy()
    r = residuals(u)
    step = 1.0
    for _ in range(int(n_iter)):
        st = bilinear_stencil(project(bases, u[None]), fd.shape)
        gx, gy = st.sample_gradient_images(fd)
        J = projection_jacobian(bases, u[None])[0]  # (n, 2, P)
        Jr = gx[0, :, None] * J[:, 0, :] + gy[0, :, None] * J[:, 1, :]
        # Gauss-Newton: delta = argmin_d |r + J d|^2
        delta = np.linalg.lstsq(Jr, -r, rcond=None)[0]
        cand = box_plus(u, step * delta)
        rc = residuals(cand)
        if rc @ rc <= r @ r:
            u, r, step = cand, rc, min(1.0, 2.0 * step)
        else:
            step *= 0.5
    return u


def constrained_optic_flow(
    bases: np.ndarray, pose_prev: np.ndarray, frame_prev: np.ndarray, frame: np.ndarray, n_iter: int = 10
) -> np.ndarray:
    """Constrained optic flow (eq. 3, 21): ``argmin_u 1/2 sum_i [y_t(x_i(u)) - y_{t-1}(x_i(u_{t-1}))]^2``.

    Parameters
    ----------
    bases : (n, 3, k) float64
    pose_prev : (P,) float64
        ``u_{t-1}``, also the starting point.
    frame_prev, frame : (H, W) float64 in [0, 1]
        ``y_{t-1}``, ``y_t``.
    n_iter : int

    Returns
    -------
    (P,) float64
    """
    u0 = np.asarray(pose_prev, dtype=np.float64)
    # mu_t^v(i) = y_{t-1}(x_i(u_{t-1}))                                         (eq. 20)
    template = _sample(prepare_frame(frame_prev).image, project(bases, u0[None]))[0]
    return template_matching(bases, u0, template, frame, n_iter)


def optic_flow_config(**overrides) -> GFlowConfig:
    """G-flow settings under which it is constrained optic flow (sec. 4): the paper's filter
    (:data:`.params.PAPER`) with one expert at the peak, ``Psi_v -> infinity`` and no pose prior."""
    return paper_config(**{**dict(n_experts=1, n_samples=1, alpha=0.0, psi_v=1e6, v_init_var=1e-3, background=False,
                                  prior_std_rotation=np.inf, prior_std_translation=np.inf,
                                  prior_std_coefficients=np.inf), **overrides})


def template_matching_config(**overrides) -> GFlowConfig:
    """G-flow settings under which it is template matching (sec. 4): ``Var(V_1) = 0``, ``Psi_v = 0``."""
    return paper_config(**{**dict(n_experts=1, n_samples=1, alpha=0.0, psi_v=0.0, v_init_var=0.0, background=False,
                                  prior_std_rotation=np.inf, prior_std_translation=np.inf,
                                  prior_std_coefficients=np.inf), **overrides})
