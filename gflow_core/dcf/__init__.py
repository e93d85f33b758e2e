"""A particle filter whose likelihood is a discriminative correlation filter learnt online (``--tracker dcf``).

The appearance tracker (:mod:`gflow_core.appearance.filter`) scores the target against exemplars of its own
look; nothing in that score says what the surroundings look like, so a background that resembles
the target, or a target that changes, is judged by rules tuned on the videos at hand. This tracker
keeps the particle filter of the papers (particles over (x, y, log s), importance weights from a
likelihood, systematic resampling: Toyama & Blake, IJCV 2002; Isard & Blake) and makes its
likelihood a model of the target *against its surroundings*, learnt online as KCF, DSST, Staple,
BACF and CSRT learn theirs:

* **Features** (:mod:`.features`): fHOG on cells of 4 pixels (Felzenszwalb et al. 2010; 31 channels)
  and the cells' mean grey level, over a window of the target plus ``padding`` times its mean side,
  resampled to ``template``^2 template pixels; a cosine window tapers it (Bolme et al. 2010). With
  ``colour_names`` (off) the cells of a colour frame also hold the 11 colour names (the CN tracker's
  feature, Danelljan et al. CVPR 2014, and CSRT's), by prototypes in CIELab rather than van de Weijer
  et al.'s learnt table.
* **The filter** (:mod:`.filter`, :mod:`.constrained`): ridge regression of a Gaussian label (sigma
  ``label_sigma`` sqrt(w h)) on every shift of the window, solved per frequency in the Fourier
  domain (Henriques et al. PAMI 2015, eq. 12; Danelljan et al. BMVC 2014, eq. 3; Bolme et al. CVPR
  2010, MOSSE). The window is wide (the target plus 3 mean sides), so that fast motion stays inside
  it and every real shift of the background is a negative example; the filter itself is held to
  a box of the target's size (``mask``), by the ADMM of Galoogahi et al. (BACF, ICCV 2017; the
  spatial constraint of Lukezic et al.'s CSR-DCF, CVPR 2017), so that the background does not
  become part of the target. Learnt online from the running average of the windowed samples at rate
  ``rate`` (BACF sec. 3.3), only on frames the tracker is confident of; the first frame's filter
  is kept as an anchor and detection uses (1 - ``anchor_weight``) the running filter + that anchor.
  Two options, off by default: with ``augment`` the first sample averages in warped copies of the
  first window -- rolled, resized, blurred about the target (:mod:`.augment`; MOSSE, Bolme et al.
  2010; UPDT, Bhat et al. ECCV 2018) -- and with ``young`` the running filter's rate is
  max(``rate``, 1 / (``young`` + n + 1)) after n frames the target was seen on, the mean of the
  frames seen while that is faster (:mod:`.rates`); with ``rate_adapt`` (off) the rate is raised while the
  target's distance runs above its mean, max(rate, 1 - (1 - rate) rho_bar / S_t), S_t its short-run
  mean (the gain of a local-level Kalman filter whose innovation variance is matched to the one
  observed, Mehra 1970; :mod:`.rates`).
* **Roll** (:mod:`.rotation`, ``roll_step``): the target's in-plane angle is kept in
  the state and every window of the target is sampled rolled by it, so the filter learns and detects
  the target upright; the angle is searched as DSST searches scale (the filter applied to windows
  rolled a step either way, the best refined by a parabola), only on frames whose distance at the
  estimate is unusual (``roll_gate``), and held unless another angle beats it by ``roll_margin``;
  a new angle is taken only when it explains the unusual look (its distance back within
  ``roll_explain`` standard deviations of the target's), and with none explaining the frame the
  held one relaxes towards upright (``roll_relax``).
  Departures: the scale filter and the search for a hidden target keep upright windows; the box
  reported stays axis-aligned.
* **Colour** (:mod:`.histogram`): Staple's model (Bertinetto et al., CVPR 2016): histograms of the
  box and of its surroundings, the per-pixel probability that a colour is the target's, averaged
  over the box; merged with the filter's response as (1 - alpha) y_cf + alpha y_hist (Staple eq. 2).
  Grey video -- one channel, or three equal ones (:func:`.features.is_grey`) -- is detected and
  the model uses 32 grey levels instead of 32^3 colours.
* **Likelihood** (:mod:`.model`, :mod:`.tracker`): the merged response over the window at the
  constant-velocity prediction, upsampled by zero-padding its spectrum to template pixels, read
  at each particle: p(z | X) ~ exp(``kappa`` y(X)). A fraction ``detect_fraction`` of the particles
  is drawn at the response's peak (a mixture proposal, as the appearance tracker and Okuma et al.,
  ECCV 2004), so the particle filter and the filter's peak agree.
* **Motion** (:mod:`.dynamics`): constant velocity; the centre's noise is a random walk of
  ``std_xy_rel`` sqrt(w0 h0) sqrt(dt) px (the proposal stage) plus ``speed_noise`` |v| dt (the
  filter, which holds v), and every particle is weighed by a motion prior N(pred, (``motion_prior``
  box + ``speed_noise`` |v| dt)^2), so the spread follows the target's observed speed and the time
  since the last frame seen (dt periods).
  With ``detect_peaks`` > 1 (off) the particles drawn at the response are shared among its best
  separate peaks (:mod:`.proposal`; Okuma et al.'s boosted proposal), not given to the best alone.
  With ``motion_switch`` > 0 (off) the motion switches between constant velocity and a manoeuvre (no
  mean velocity, the target's speed as the noise) by a Markov chain, each particle drawing its mode and
  the likelihood picking it (:mod:`.modes`; Isard & Blake's mixed-state Condensation, ICCV 1998, with
  the modes collapsed to one probability a frame as in Blom & Bar-Shalom's IMM).
  With ``flow_mix`` > 0 (off) the second mode is the last box's own displacement to this frame, matched
  by NCC under Lowe's ratio test (:mod:`.flowpred`): the frames say where the target went when it moved
  faster than the velocity predicts.
  With ``motion_tail`` = nu > 0 (off) the motion prior is the bivariate Student-t of the same scale, or with
  ``motion_tail_weight`` < 1 its mixture with the Gaussian, the weight learnt from the track's innovations
  with ``motion_tail_rate`` (:mod:`.heavytail`; heavy-tailed process noise, Roth et al. 2013): a target
  that turned is not priced quadratically in its distance from the prediction.
* **Scale** (:mod:`.scale`): DSST's 1-D scale filter (17 scales 2 % apart, as fDSST samples) at the
  estimate, on confident frames; the particles carry the scale it finds.
* **Is it the target?** Two cues, each a distance rho = 1 - y at the estimate: the filter's
  response and the colour score. Each has its own learnt target and clutter distributions, rho ~
  sigma^2 chi^2_d by running moments (Toyama & Blake eq. 10; :mod:`gflow_core.visibility`): the
  clutter's from the best score away from the estimate in the window (half a box for the filter,
  a box for colour, whose boxes overlap), the target's from the estimate on frames it is present.
  The two cues multiply (Perez, Vermaak & Blake 2004), the colour's as a cue that may fail (its
  densities mixed with a uniform one of weight ``colour_outlier``, :mod:`.cues`, so it alone cannot
  outvote the filter), with the estimate's place under the motion
  prior against clutter's, anywhere in the window, and give P(visible), P(partial), P(hidden);
  ``confidence`` is P(visible). The model learns only when P(visible) >= 1/2, so an occluder is
  not learnt.
* **Hidden, lost, found again.** After ``hidden_after`` frames that clutter explains, the target
  is ``occluded``: the box holds the prediction, the velocity decays, nothing is learnt, and the
  target's place spreads by ``search_growth`` mean sides a frame; the filter (times its cosine
  window, so each placement is scored as a window centred there) is slid over three standard
  deviations of that place (:func:`.model.search`), up to the whole frame (``lost``). The best
  placement is taken back only on strong evidence: its filter score against the clutter's as the
  best of as many draws as the search covered, its colour score, its place under the spread prior
  against the searched area, and a prior ``reappear`` that a hidden target is back. With
  ``search_clutter`` the search also keeps the distribution of its own best placement's distance
  over the frames the target stayed hidden (TLD's negatives, Kalal et al. 2012, as a distribution
  of the detector's score) and, from ``search_min`` such frames on (as many as the priors'
  pseudo-samples: a few placements give too narrow a distribution), takes the lower of its density
  and the window clutter's under
  "hidden": a placement far better than any the search gave while the target was away is the
  target come back.
  The target's log size, unseen, spreads too (``search_size_growth`` a frame): the search tries the
  sizes ``search_size_step`` apart within three standard deviations of it (at most
  ``search_sizes``), each candidate's size under that prior against a size uniform over those
  tried added to its place term; a target back after a long occlusion is seldom the size it had.
  With ``search_size_volume`` clutter's place and size are uniform over the volume searched (the
  areas summed over the sizes times the step); off, the number of sizes is counted a second time,
  favouring every candidate of the wider search by that factor in odds (the option is off so that
  recordings re-run; docs/dcf-development.md gives what it changes).
  With ``search_size_track`` a placement at another size than the held one is never taken on one
  frame's P(visible): only as the candidate track below, judged over its frames (off: measured on
  the cases the sizes change, it got no more back than the default).
  A frame alone may not outweigh ``reappear`` where the target comes back looking unlike what the
  filter learnt; with ``search_track`` (:mod:`.trackscore`) the search's best placements are a
  candidate track, scored as radar trackers confirm a new track (Blackman & Popoli 1999: the
  kinematic log likelihood ratios summed, against clutter uniform or standing still, and the
  signal's mean, as the look is one object's), and taken when its probability reaches
  ``search_track`` (0.95); with ``search_track_wald`` (on) it is dropped only at Wald's lower
  threshold for equal error rates, the upper one mirrored, so a track whose look scores like
  clutter is kept while its motion may still outweigh it.
* **A long-term filter** (:mod:`.longterm`, ``longterm``; LCT, Ma et al. CVPR 2015): a second
  filter learnt at ``longterm_rate`` only on confident frames whose long-term score at the estimate
  is within ``longterm_level`` standard deviations of its mean; with ``longterm_witness`` its
  distance at the estimate is a third cue, and while the target is hidden the search slides it
  after the adaptive filter, its candidates judged by its own distributions.

Departures from the papers, each measured on the nine shared sequences and their stress cases
together (docs/trackers.md):

* KCF, DSST and Staple keep a filter as large as their window; BACF and CSR-DCF constrain it. Here
  the constraint is a box of the target's size (not BACF's exact target size in cells, nor
  CSR-DCF's colour segmentation, which ``segment``, off, adds within the box: :mod:`.reliability`), solved by two ADMM iterations a frame from zero, with mu starting
  at ``mu`` times the sample's mean energy per frequency (scale-free) and growing threefold an
  iteration; the detection uses the constrained filter h rather than BACF's g. Without the mask
  (``mask`` 0) the filter is DSST's closed form with numerator and denominator averaged.
* Every feature channel's response counts alike at detection; CSR-DCF weights each by its channel
  reliability, which ``channel_weights``, off, adds (:mod:`.channels`: the weights at a mean of 1, the
  learning reliability of the running filter, the detection reliability read at the estimate, the anchor
  keeping the first frame's weights).
* Staple's colour histograms are learnt over the whole window's ring, and its score is computed on
  the filter's cells (so the two responses add cell for cell and are upsampled together).
* fHOG here bins each pixel to its own cell (no bilinear spatial vote) and takes the grey level's
  gradient (fHOG takes the colour channel of largest gradient).
* The scale filter takes the argmax over 17 scales (no interpolation to 33, no sub-step: a
  parabola's sub-step, ``scale_refine``, off, drifted the box on fixed-size ground truth).
* Nothing in the papers says whether the target is there; the visibility model, the search and
  the place prior are this project's (as the appearance tracker's), here with the filter's and the
  colour's scores as cues. TLD learns its negatives as patches for a classifier; here only
  the search's best distance a frame is kept, as a distribution, and it may only lower the
  clutter's density (a target in view but not yet taken back is among those placements too).
  The colour cue's outlier density is the robust likelihood of multi-cue fusion; its weight
  (0.01) is a modelling choice, not fitted: it costs david_indoor's ``occlude-60`` on the stress
  benchmark, where the face came back under other light and only the colour knew it. Ten
  searches before the search's clutter counts cost tiger1's undisturbed stress control, whose
  blurred toy was taken back against three.
* MOSSE and UPDT solve the initial regression over all the warped copies (their energies summed in the
  denominator); with the mask the filter here is solved from the copies' averaged sample, as BACF's
  from the running average of frames, and the copies are a fixed set (no random affine draws, no
  shifted copies: the label stays at the window's centre). The young filter's rate counts the frames
  the target was judged present on, not only the confident ones it learnt from (:mod:`.rates`).
* LCT re-detects with a random-fern classifier and decides by fixed thresholds on the long-term
  filter's peak (T_r, T_a); here the re-detector is the long-term filter slid over the searched
  region beside the adaptive one, and its decisions are likelihood ratios and levels learnt from
  the run (:mod:`.longterm`). Searching several sizes is TLD's and LCT's scanning over scales; the
  spreading size prior that limits it is this project's.
* Off by default, measured on the stress cases (docs/dcf-development.md): the search may judge several
  separate peaks and condition its place prior on the region searched (:mod:`.reacquire`; TLD's and
  LCT's several candidates), a frame may teach the model only when its distance is within
  ``learn_level`` deviations of the target's (:mod:`.gate`; MOSSE's and LMCF's gated updates, here a
  level of the learnt distribution rather than a fraction of a mean peak).
  A new track may be tentative for its first ``confirm`` frames (:mod:`.confirm`): a frame in doubt is
  then the target's and it cannot be judged hidden (the track confirmation of multi-target trackers,
  SORT's ``min_hits`` and DeepSORT's ``n_init``, which delete a tentative track that misses; here the
  user's box says the target exists, and only the judgement of "hidden" waits).
  The motion may switch between constant velocity and a manoeuvre (``motion_switch``, :mod:`.modes`:
  the modes collapsed to one probability a frame, one velocity shared), and the filter's rate may
  follow the distance's rise (``rate_adapt``, :mod:`.rates`: the innovation's variance from running
  means, not a window's sample covariance); both lose more fast-motion cases than they get back.
  The target's displacement matched frame to frame may be the motion's second mode (``flow_mix``,
  :mod:`.flowpred`; Median Flow, Kalal et al. 2010, moves its box by such a displacement, here it only
  proposes and the likelihood weighs): more AUC at every 3rd frame, less on the sequences as they are
  and on noisy frames.
  With ``scale_anchor`` the scale filter detects, as the translation filter does, with its first
  frame's filter mixed in at ``anchor_weight`` (:mod:`.scale`; DSST has no anchor): more AUC on
  blurred and half-size footage, less at every 3rd frame and fewer stress cases back.
  With ``scale_prior``
  the scale filter's pick is the mode of its response read as a likelihood, exp(``kappa`` y), times a
  Gaussian prior on the log size about the first box's (:mod:`.sizeprior`; DSST has no prior on the
  size; chamfer's ``scale_prior``).
  A re-detection the options add -- the search's placement at another size (``search_sizes``), a rolled
  window taken at detection (``roll_detect``) -- may be checked by the first frame's filter before it
  is taken (``verify``, :mod:`.verify`): TLD's
  conservative similarity (Kalal et al. 2012, sec. 5), the similarity to the early exemplars only,
  here the anchor's distance judged by its own learnt target and clutter distributions rather than a
  fixed threshold on a patch's correlation.
* On by default (measured on the stress cases of seeds 1-3, docs/dcf-development.md): the colour cue fails
  more often on a search candidate (``search_colour_outlier`` 0.1: the colour model is learnt against
  the target's own surroundings, not the places the search looks), and after a re-detection of a
  target judged hidden the unknown velocity widens the next frame's prior by the typical speed
  learnt on tracked frames (``redetect_speed``). Recordings made before them re-run with both off.

Modules: :mod:`.params` (``DCFParams``), :mod:`.features`, :mod:`.filter`, :mod:`.constrained`,
:mod:`.histogram`, :mod:`.scale`, :mod:`.model` (the window, the target model, responses, search),
:mod:`.dynamics` (the proposal's walk), :mod:`.modes` (the motion's two modes), :mod:`.flowpred` (the target's
own displacement as the second mode), :mod:`.cues` (a cue that may fail), :mod:`.longterm` (the long-term filter),
:mod:`.reacquire` (the search's candidates and place prior), :mod:`.gate` (which frames teach the model),
:mod:`.verify` (a re-detection checked by the first filter), :mod:`.augment` (the first filter's warped copies), :mod:`.sizeprior` (a prior on the size), :mod:`.rates` (the young filter's rate), :mod:`.confirm` (a tentative
track), :mod:`.rotation` (the target's roll), :mod:`.camera` (the camera's own motion, ``camera_motion``), :mod:`.reliability` (CSR-DCF's spatial reliability map, ``segment``), :mod:`.channels` (CSR-DCF's channel reliability, ``channel_weights``), :mod:`.state` (frozen states, snapshots), :mod:`.tracker`
(the :class:`~gflow_core.tracker.TrackingFilter`).
"""
