"""Is the target visible? The distance to the exemplars as a sigma^2 chi^2_d variable.

Toyama & Blake (IJCV 2002, sec. 3.3.3 and the appendix) show that, with the likelihood
exp(-rho / 2 sigma^2) / Z of eq. 7, the distance rho between an exemplar and the image of
the object it explains is a sigma^2 chi^2_d random variable, and they learn sigma and d from
the sample moments of rho (eq. 10):

    d = 2 mean(rho)^2 / (mean(rho^2) - mean(rho)^2),    sigma^2 = mean(rho) / d.

A tracker can use that distribution at run time to ask whether the region it chose is the
target at all. This module keeps two such distributions, each by running moments:

* **target** -- rho at the estimate on frames judged visible (the target as it looks while
  the tracker is sure of it);
* **clutter** -- the best rho the search window offers away from the estimate, on the frames
  the target is present (what the best look-alike in the background scores; while the target
  is hidden the best match away from a held box may be the target itself).

and weighs three hypotheses for the rho of the estimate:

    visible : rho ~ sigma_t^2 chi^2_{d_t}              (the target, looking as usual; a
                                                       distance below the mode counts as the
                                                       mode: a closer match is the target too)
    partial : rho ~ U(0, mean of the clutter's rho)    (the target, part hidden or a new look:
                                                       no model, an outlier process between a
                                                       perfect match and what clutter scores)
    hidden  : rho ~ sigma_c^2 chi^2_{d_c}              (what the region holds is clutter; a
                                                       distance beyond the clutter's mode
                                                       counts as the mode: worse than the
                                                       best clutter is clutter too)

with equal priors, so P(visible | rho) is the confidence a user reads, and the target is
present (seen in the box) while P(visible) + P(partial) >= P(hidden). Nothing here is tuned
to a sequence: both distributions are learned on the video being tracked, and the only
constants are the priors, the rate at which the moments forget, and a floor on the spread.

Departures from the paper: the moments are exponentially weighted running moments (the look
of the target and of its background drift over a video), not moments of a training set; the
"partial" outlier hypothesis and the clutter distribution are not in the paper (a tail test
alone calls every change of look an occlusion). The caller may add the log of the estimate's
place under each hypothesis's motion prior (``log_place``, ``log_place_partial``); that too is
ours.

The distances here are rho = 1 - r with r a normalised correlation, so rho lies in [0, 2].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["ChiSquare", "Cue", "Visibility", "visibility", "RHO_MAX", "load_gamma"]

#: rho = 1 - r lies in [0, RHO_MAX]
RHO_MAX = 2.0


def load_gamma() -> None:
    """Import SciPy's gamma functions (:meth:`ChiSquare.cdf`, :meth:`ChiSquare.log_pdf_min`) now.

    They are imported where they are called, so a process that reads this module and never judges
    visibility does not import SciPy; a filter stage that will judge it calls this when a runner
    takes it, so the import (about 0.2-0.3 s of CPU) is not made on the frame the first judgement
    falls on."""
    from scipy.special import gammainc, gammaln  # noqa: F401


@dataclass(frozen=True)
class ChiSquare:
    """rho ~ sigma^2 chi^2_d, with sigma^2 and d from running moments of rho (eq. 10).

    m1, m2 : running means of rho and rho^2.
    n : samples seen (the first ``1 / rate`` samples are averaged with equal weight, so the
        first frames do not dominate; later ones forget at ``rate``).
    """

    m1: float = 0.0
    m2: float = 0.0
    n: int = 0

    def update(self, rho: float, rate: float) -> "ChiSquare":
        """The moments after one more sample ``rho``, forgetting at ``rate`` (in (0, 1])."""
        if not 0 < rate <= 1:
            raise ValueError(f"rate must be in (0, 1], got {rate}")
        rho = float(min(max(rho, 0.0), RHO_MAX))
        a = max(rate, 1.0 / (self.n + 1))
        # m <- (1 - a) m + a rho;   m2 <- (1 - a) m2 + a rho^2
        return ChiSquare(m1=(1.0 - a) * self.m1 + a * rho, m2=(1.0 - a) * self.m2 + a * rho * rho, n=self.n + 1)

    def params(self, min_std: float) -> tuple[float, float]:
        """(d, sigma^2) by eq. 10, with the spread of rho at least ``min_std`` and its mean at
        least ``min_std`` (a few samples of a steady target would give d -> infinity)."""
        mean = max(self.m1, min_std)
        var = max(self.m2 - self.m1 * self.m1, min_std * min_std)
        # d = 2 mean^2 / var,  sigma^2 = mean / d                                  (eq. 10)
        d = 2.0 * mean * mean / var
        return d, mean / d

    def log_pdf(self, rho: float, min_std: float) -> float:
        """log p(rho) of sigma^2 chi^2_d (a Gamma(d / 2, 2 sigma^2) density):

            log p = (d/2 - 1) log(rho / sigma^2) - rho / (2 sigma^2) - (d/2) log 2 - log Gamma(d/2) - log sigma^2
        """
        d, s2 = self.params(min_std)
        x = max(float(rho), 1e-6) / s2
        return (0.5 * d - 1.0) * math.log(x) - 0.5 * x - 0.5 * d * math.log(2.0) - math.lgamma(0.5 * d) - math.log(s2)

    def mean(self) -> float:
        return self.m1

    def cdf(self, rho: np.ndarray, min_std: float) -> np.ndarray:
        """P(rho' <= rho) = P(d / 2, rho / (2 sigma^2)), the regularised lower incomplete gamma."""
        from scipy.special import gammainc  # imported where used: most processes that read this module never call it

        d, s2 = self.params(min_std)
        return gammainc(0.5 * d, np.maximum(np.asarray(rho, dtype=np.float64), 0.0) / (2.0 * s2))

    def log_pdf_min(self, rho: float, n: float, min_std: float) -> float:
        """log density of the smallest of ``n`` independent draws (n >= 1, not necessarily whole):

            p_min(rho) = n (1 - F(rho))^(n - 1) p(rho),

        made one-sided like the clutter hypothesis: beyond its mode the density is the mode's
        (found on a grid of 2001 points over [0, RHO_MAX])."""
        if n <= 1.0:
            return self.log_pdf(min(rho, self.mode(min_std)), min_std)
        from scipy.special import gammaln

        grid = np.linspace(0.0, RHO_MAX, 2001)[1:]
        d, s2 = self.params(min_std)
        x = grid / s2
        # log p on the grid (the formula of log_pdf)
        lp = (0.5 * d - 1.0) * np.log(x) - 0.5 * x - 0.5 * d * math.log(2.0) - gammaln(0.5 * d) - math.log(s2)
        # log p_min = log n + (n - 1) log(1 - F) + log p
        lpm = math.log(n) + (n - 1.0) * np.log(np.maximum(1.0 - self.cdf(grid, min_std), 1e-300)) + lp
        mode = float(grid[int(np.argmax(lpm))])
        x = min(max(float(rho), float(grid[0])), mode)
        return float(math.log(n) + (n - 1.0) * math.log(max(1.0 - float(self.cdf(np.array([x]), min_std)[0]), 1e-300))
                     + self.log_pdf(x, min_std))

    def mode(self, min_std: float) -> float:
        """The mode of sigma^2 chi^2_d, (d - 2) sigma^2 (0 for d <= 2)."""
        d, s2 = self.params(min_std)
        return max(d - 2.0, 0.0) * s2


@dataclass(frozen=True)
class Cue:
    """A further distance of the same estimate, from another cue, with its own learnt target and
    clutter distributions; given the hypothesis it is independent of the first (the cues'
    likelihoods multiply, as in multi-cue particle filters: Perez, Vermaak & Blake, Proc. IEEE 2004).

    rho : its distance; trials : as :func:`visibility`'s, for this cue (the estimate was picked by
    the best of this many clutter draws of it).
    """

    rho: float
    target: ChiSquare
    clutter: ChiSquare
    trials: float = 1.0


@dataclass(frozen=True)
class Visibility:
    """Posterior of the three hypotheses for one distance; they sum to 1."""

    visible: float
    partial: float
    hidden: float

    @property
    def present(self) -> bool:
        """The target is judged in the box (fully or partly): P(visible) + P(partial) >= P(hidden)."""
        return self.visible + self.partial >= self.hidden


def visibility(rho: float, target: ChiSquare, clutter: ChiSquare, min_std: float,
               prior: tuple[float, float, float] = (1.0, 1.0, 1.0), trials: float = 1.0,
               log_place: float = 0.0, log_place_partial: float | None = None, cues: tuple[Cue, ...] = ()
               ) -> Visibility:
    """P(visible), P(partial), P(hidden) of a distance ``rho`` (module docstring).

    Parameters
    ----------
    rho : distance 1 - r of the estimate.
    target, clutter : the learned distributions; a model with no samples yet is left out
        (its hypothesis gets probability 0, or all of it if it is the only one).
    min_std : floor on the spread of rho in both models.
    prior : unnormalised prior weights of (visible, partial, hidden).
    trials : ``rho`` is the best of this many times the positions the clutter distribution was
        learnt over (a search over a wider region): under "hidden" it is then the smallest of
        ``trials`` clutter draws (:meth:`ChiSquare.log_pdf_min`), so a wider search needs a
        closer match to count as the target.
    log_place : log of how much likelier the estimate's place is under the target's motion
        prior than under clutter's (uniform over the searched window); added to the visible
        and partial hypotheses, so a far jump needs a better match.
    log_place_partial : the same under the partial hypothesis when it differs (a target partly
        hidden is placed by its motion rather than by a match that says little; default:
        ``log_place``).
    cues : further cues of the same estimate (:class:`Cue`); each adds its log-density under each
        hypothesis, by the same rules (one-sided target and clutter densities, the partial
        hypothesis uniform up to its clutter's mean). A cue whose distributions have no samples
        yet is left out.
    """
    place = (log_place, log_place if log_place_partial is None else log_place_partial, 0.0)
    logs = []
    # the partial hypothesis: uniform between a perfect match and the clutter's mean distance
    top_partial = max(clutter.mean(), min_std) if clutter.n else RHO_MAX
    # log pi_h + log p(rho | h) for h = visible, partial, hidden
    for w, m, lpl in ((prior[0], target, place[0]), (prior[1], None, place[1]), (prior[2], clutter, place[2])):
        if w <= 0 or (m is not None and m.n == 0) or (m is None and rho > top_partial):
            logs.append(-math.inf)
            continue
        if m is None:
            lp = -math.log(top_partial)
        elif m is clutter:
            # one-sided: p(rho | hidden) = p_c(min(rho, mode_c)), of the best of `trials` draws
            lp = m.log_pdf_min(rho, trials, min_std)
        else:
            # one-sided: p(rho | visible) = p_t(max(rho, mode_t)), a closer match than usual is the target
            lp = m.log_pdf(max(rho, m.mode(min_std)), min_std)
        logs.append(math.log(w) + lp + lpl)
    for cue in cues:
        if cue.target.n == 0 or cue.clutter.n == 0:
            continue
        # p(rho, rho' | h) = p(rho | h) p(rho' | h): the cue's log-density under each hypothesis
        logs[0] += cue.target.log_pdf(max(cue.rho, cue.target.mode(min_std)), min_std)
        top_c = max(cue.clutter.mean(), min_std)
        logs[1] += -math.log(top_c) if cue.rho <= top_c else -math.inf
        logs[2] += cue.clutter.log_pdf_min(cue.rho, max(cue.trials, 1.0), min_std)
    top = max(logs)
    if top == -math.inf:
        return Visibility(visible=0.0, partial=1.0, hidden=0.0)
    # P(h | rho) = pi_h p(rho | h) / sum_h' pi_h' p(rho | h')
    e = [math.exp(v - top) for v in logs]
    z = sum(e)
    return Visibility(visible=e[0] / z, partial=e[1] / z, hidden=e[2] / z)
