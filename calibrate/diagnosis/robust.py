"""What an unexplained residual costs: a covariance that covers it, in the units a user reads.

Two covariances: per-cluster (:func:`cluster_covariance`, CR2) and a process in time over the whole
recording (:func:`time_correlated_covariance`); the four-flip's widening (:func:`structure_in_time`)
takes one channel's offset step, or structure locked to the turn, instead of the process where that
explains the whole structure.

When structure remains that no effect explains (SPEC section 4, ``unexplained: true``), the fit's
covariance ``(J^T J)^-1 chi2/dof`` assumes residuals independent from sample to sample: a smooth
structure, correlated over many samples, moves the parameters far more than that says.

Derivation.  Write the weighted residual as ``r = e + s``: white noise ``e`` at the floor and a
structure ``s`` the model lacks.  To first order the fitted parameters move by
``dx = (J^T J)^-1 J^T (e + s)``; the part of ``s`` in the span of ``J`` is absorbed (it moved the
parameters and left the residual), the rest is what the residual shows.  Take ``s`` as a
realisation of a process correlated within clusters ``g`` of the recording (the four-flip: within
one flip, where one mounting and one stretch of time make an unmodelled effect of the field or of
time nearly the same from sample to sample) and independent between them.  The covariance of
``dx`` is then the sandwich

.. math:: V = H^{-1} \\Big( \\sum_g \\tilde s_g \\tilde s_g^T \\Big) H^{-1}, \\qquad
          \\tilde s_g = J_g^T (I - P_{gg})^{-1/2} r_g, \\qquad H = J^T J, \\quad P_{gg} = J_g H^{-1} J_g^T,

the cluster-robust estimate with Bell and McCaffrey's (2002) bias reduction ("CR2").

Why the plain sandwich (``s_g = J_g^T r_g``) under-covers correlated residuals.  Its meat
estimates ``var(J^T s)`` from the residual at the solution, and that residual is what the fit left:
``r = (I - P) s``.  For a cluster that carries much of the information on some parameters (one
flip of four holds a quarter of every direction's information and most of what tells a direction
from the dip), the fit absorbs much of that cluster's structure: ``E[r_g r_g^T] = (I - P_{gg})``
times the structure's covariance there, not the covariance itself, and the cluster sums shrink by
the cluster's leverage.  A random walk of the offsets or a turntable axis whose tilt turns during
the session is smooth across a whole flip: the part a flip's mounting can absorb is large, the
residual shows little of it, and half-turn clusters without the correction gave directions 2.0
and 2.1 times their stated sigma.  The factor ``(I - P_{gg})^{-1/2}`` restores it, and it makes the
meat unbiased when the residual is white noise at the floor (``E[r_g r_g^T] = I - P_{gg}``, so
``E[sum_g s~_g s~_g^T] = H``): no widening without structure.  A HAC (Newey-West) meat with a
bandwidth from the residual's autocorrelation, or a Toeplitz covariance of the residual put
between ``J^T`` and ``J``, measures the same shrunken residual and did worse (1.5-2.3; the lag-one
autocorrelation of a residual dominated by white noise picks bandwidths of 4-7 samples).  The
jackknife over clusters ("CR3", ``(I - P_{gg})^{-1}``) over-corrects with four clusters.

Why per-flip clusters are not enough (the four-flip uses the process below; the clusters stay for
callers that want them).  CR2 takes the clusters as independent, and with four of them its meat is
a variance estimated from about three degrees of freedom.  A random walk of the offsets or a room's
temperature cycle carries over from one flip to the next: the cross-cluster terms
``J_g^T s_g s_h^T J_h`` it drops are positive (the level of flip 2 is correlated with flip 1's), and
what tells a direction's y and z from the dip is exactly the level differences between flips,
which the mountings absorb; these were left at 1.3-1.6 times the widened sigma.  The few degrees of
freedom inflate the RMS of error over sigma on their own (``E[1/s^2]`` of a three-dof variance is
three times ``1/sigma^2``).  Rate memory (an offset of +-h by the sign of each channel's field
change) goes the other way: its fundamental is a phase shift the same in every channel, the field
azimuth absorbs it and the directions barely move, while each flip's residual, taken as
independent, says they could (0.37).

A process in time.  Take ``s`` instead as a stationary process in time over the whole recording,
each channel's own and processes common to each pair of channels (alike or opposed), with a
spectrum piecewise flat in octave bands ``B_k`` (autocovariance of a band-limited flat spectrum,
:func:`_band_kernel`): ``cov(s) = sum_k S_k (x) B_k``, ``S_k`` the band's channel-by-channel
spectral matrix.  Sum the weighted residual over time blocks (``A``, ``BLOCK_S``; structure within
a block counts as white) and take ``s`` constant within a block.  Then with ``G = A J`` and
``keep = A (I - P) A^T = diag(n_b) - G H^-1 G^T``,

.. math:: E[z z^T] = (1 + f)\\, keep + keep\\, K\\, keep, \\qquad z = A r,
          \\qquad V = (1 + f) H^{-1} + H^{-1} G^T K G H^{-1},

``f`` the noise floor's own error.  What the fit absorbed is in ``keep`` on both sides: a band the
mountings absorb shows little in ``z`` and is estimated from what shows, then propagated whole into
``V``.  The spectrum is fitted to the block sums' second moments (MINQUE at ``K = 0``: normal
equations in traces ``tr(K_k keep K_l keep)``, right-hand sides ``z^T K_k z - tr(K_k keep)``),
in two stages: a score test per band (the floor's factor profiled out; under white noise the
right-hand sides are centred with covariance twice the normal matrix, and the statistic is the score
in that metric) keeps the bands that carry structure at ``BAND_P_VALUE``, then a non-negative least
squares on those bands alone gives the spectrum (non-negative: a covariance), ``f`` bounded below
by -1.  The score is a quadratic form in ``z``, not Gaussian: in the low bands, where the fit
absorbs most of the band, it has few effective degrees of freedom and a heavy right tail, and a
chi-square threshold passed white noise several times too often (14 of 400 band tests at 1 %).
Each band's statistic is therefore compared with its own null distribution, simulated: under white
noise ``z ~ N(0, keep)`` exactly (a linear fit), so ``NULL_DRAWS`` block sums drawn through
``keep``'s eigendecomposition, with a fixed seed (the fit is deterministic), give it.

One step, not a process. An offset stepping once, ``s(t) = h 1[t >= tau]`` in one channel (a connector
reseated, a part magnetised by a passing current), is not a stationary wander: with ``tau`` uniform over
the session its covariance ``h^2 min(t, t') / T`` is a random walk's, so the process model's second
moments cannot tell the two apart and state for every step the cost of a step at a random time. The
recording shows where the step is, and that decides what it costs (a step between flips is a level
difference the directions are read from; one within a turn leaks into that turn's ``cos phi`` and ``sin
phi``). On tools/bench_loop.py's ``offset step`` the process model widened the channels without the step
1.6-6 times (pairs' common processes and each band's non-negative power, estimated from one realisation)
where their errors are the noise's, and gave 0.60. The alternative: block levels ``u = h s_{a,j}`` (``s``
one on channel ``a``'s blocks from ``j`` on), so ``z = h keep s + A (I - P) e`` and, ``z`` lying in
``keep``'s range, the generalised least squares size ``h^ = s^T z / s^T keep s`` with chi-square drop
``(s^T z)^2 / s^T keep s``, best over channels and blocks (reversed cumulative sums). It is taken for the
structure when it is decisive against no step as the loop adds an effect (delta-BIC ``rank ln(Q / (Q -
drop)) - 3 ln(rank)`` over ``DECISIVE_BIC``, ``Q = z^T keep^+ z``, the floor's factor free, a size, a
time and a channel chosen) and the remainder ``z - h^ keep s`` passes stage 1's band test in every band
(the test that found structure finds none left; its null ignores the one degree of freedom the step took,
slightly conservative). Both are needed: a weak structure of another shape can leave a remainder that
passes after its best step took a little of it (an odd cubic the loop did not name, bench_loop seed 22:
excess chi-square 83 of which the step took 18, delta-BIC -2.6; with the remainder test alone the step
was taken and the channel it missed was left at twice its sigma), while true steps take nearly all of it
(0.95-1.04 of the excess on seeds 0-4). Its move of the parameters is a structure of block levels
propagated as the tumble's walk levels are (calibrate/diagnosis/blocks.py): ``dx = H^-1 G^T s h``, and
the covariance ``H^-1 + (h^2 - 1 / s^T keep s) d d^T``, ``d = H^-1 G^T s`` (``h^2`` less its noise's
variance, unbiased for the step's square). Its limits: at 1 % a band, the remainder of a true step fails
the test by chance about once in ten (0 and 2 of 12 on two seeds of the test's line fit) and the process
model stands, over-covering as before; the choice among ``c nb`` candidates inflates ``h^2`` by a few
times ``1 / s^T keep s``, small against a step the test sees; a step within a block leaves a partial
level there, counted as white; two steps, or a step on a wander, leave structure and the process model
stands.

Locked to the turn.  A structure that follows the turntable's angle, not time (rate memory's +-h by the sign of
each channel's field change, a knee of the response, a gain that differs from turn to turn), moves the
parameters by ``dx = H^-1 J^T s`` (weighted units) as any structure does, and only through its part in the
span of ``J``.  Per turn and channel, the base model's columns (a channel's offset and gain, its direction,
the field's dip and azimuth) are all made of a constant, ``cos phi`` and ``sin phi``: over whole, evenly
sampled turns, a turn's harmonics ``h >= 2`` are orthogonal to every column and move nothing.  The first
harmonic and the constant do move them, and the residual shows only what the fit did not absorb. So the
structure is written in nuisance columns ``N`` of known shape, each turn's own in each channel: the turn
angle's harmonics 2 .. 12, and (the four-flip) the channel's signal less its mean over the turn (a gain of the
turn's turning part) and the signal's rate in the turn angle (a lag of the turn).  What the fit leaves of
them, ``(I - P) N``, is seen in the residual, and where ``M = N^T (I - P) N`` is not singular their size
``beta`` is estimated from the residual alone; its move of the parameters ``H^-1 J^T N beta`` is then known,
not extrapolated (:func:`_without_locked`).  What cannot be seen are the combinations the fit absorbs whole
(``M``'s null space, cut at ``LOCKED_RCOND``; 5 of 288 on tools/bench_loop.py's recordings): with these shapes
the lag common to every channel and turn (the field's azimuth), a channel's gain, and a direction turned about
the flip axis (it changes no turn's level, only each turn's gain and lag).  Their size is taken as zero, so a
structure of exactly that shape would move a direction unseen here, as it would be by any bound from the
residual.
What the residual sees too little of to weigh is dropped as well.  Unbiased is not enough: a combination the
fit absorbs nearly whole is seen with little information, and its estimated move's noise can be far above the
fit's own (``M``'s eigenvalues above the cut ran down to 1.4e-5 of the largest, and on bench_loop's rate
memory seeds 40-43 the move's noise was 140-3700 times the naive variance of the log gains, the dip and the
azimuth).  The move's square less that noise was then unbiased but mostly noise (-700 to 6e5 times the naive
variance), indefinite, and :func:`widened` kept its positive half: the gains over-covered 10-100 times, a level
heading's sigma 1.2-26 times the naive one, where the directions (the one thing bench_loop scores) looked
fine.  So the combinations ``w_j`` are taken with unit information and turned so that their moves
``D_j = H^-1 J^T N w_j`` are orthogonal in ``H``; then ``rho_j = |P N w_j|^2 / |(I - P) N w_j|^2`` (what the fit
absorbs of it over what it leaves) is its estimated move's noise over the fit's own noise along ``D_j``.  The
choice per combination, for a true size ``b`` (in units of its noise): propagating states the move's square
along ``D_j`` as ``rho (gamma^2 - 1)`` naive variances, an error of standard deviation ``rho sqrt(2 + 4 b^2)``;
dropping it errs by ``rho b^2``; propagating pays where ``b^2 > 2 + sqrt 6 ~ 4.4``, and ``rho`` scales both.
``b`` is not known; but a structure of energy ``S`` along a combination's shape ``N w_j / |N w_j|`` is seen
with ``b^2 = S / (1 + rho)``: the combinations the fit absorbs most are those any structure is least seen
in.  So the cut is on ``rho``: ``LOCKED_ABSORBED = 1`` propagates the combinations the residual sees at least
half of (worth it for a structure seen there at ``S > 9``), and their noise is then at most ``H^-1`` as a
matrix (``D D^T`` has ``rho_j <= 1`` times ``H^-1`` along each ``H``-orthogonal ``D_j``): the stated move errs
by at most about the naive covariance.  The rest count, for the move, as absorbed whole, as ``M``'s null space
does; all of them still take their structure out of the residual for the band test.  Clipping each
combination's ``gamma^2 - 1`` at zero instead leaves ``E[(chi2_1 - 1)+] = 0.48`` times ``rho`` of over-cover per
combination of white noise, thousands of naive variances on the same seeds.
The covariance is ``H^-1 + d d^T - D D^T``, ``d = D gamma`` over the combinations propagated: the move's square
less its noise's variance, unbiased for the square of their move.  It is taken, as the step is, only where
it explains the whole structure: the residual with it taken out passes stage 1's band test in every band.
Otherwise the process model stands, as before: the locked columns also take part of a wander's or a cycle's
power (their harmonics near
the turn's), and the process model, estimated from what they leave, then over-covers air-con cycle, pink
offsets and an offset step (0.70-0.78 where it was 0.97-1.10, tools/bench_loop.py seeds 0-19, a version
that always took it).  The gain's level over a turn is left out of its shape for the same reason: it is an
offset level of the turn, which the mountings absorb as they absorb a wander's (with it, the process model
estimated from what the locked columns left widened a gain walk's directions 10-100 times).  Measured: the
harmonics 2 and up alone, as nuisance columns before the process model, changed nothing that matters
(rate memory 0.41 -> 0.38, gain walk 0.48 -> 0.47): the process model's over-cover of rate memory is not,
as was thought, the harmonics' power spread into ``cos phi`` and ``sin phi``, but the first harmonic's:
each turn's own lag (``4h / (pi A_c)``, largest where the channel's turning amplitude ``A_c`` is small), a
structure the residual shows almost whole, whose absorbed part the stationary model assumes as large.

A gain process times the signal (tried, not adopted; the carrier's reading below replaced it).  A gain that
wanders, ``K_c (1 + g_c(t))``, adds ``K_c x_c(t) g_c(t)`` to channel ``c``'s reading: a product, the gain's slow
process times the signal ``x_c``, not a stationary residual.  Modelling the residual as ``o_c(t) + g_c(t) \\hat x_c(t) +
e_c(t)`` (block sums of ``r`` and of ``r \\hat x``, each kind propagated through its own Jacobian
columns) was built and measured (docs/benchmarks.md): within a 10 s block the signal
barely changes, so an offset and a gain give the two sums in the same ratio and the fit shares the
power between them; the offsets' share propagates with an offset's larger leverage on the directions.
On tools/bench_loop.py seeds 0-19 a gain walk went 0.48 -> 0.58 but a gain swinging at a 500 s period
(``gain sine``, made to judge it) 0.85 -> 0.68, out of the band; the four-flip then kept the offsets alone.

Why the offsets' process over-covers a gain walk (measured; the carrier's reading below takes it where decisive). On
tools/bench_loop.py's ``gain walk`` every recording the process model takes is over-covered about twice (err/sig
0.42, 0.58, 0.57 over its 6, 8 and 5 recordings on seeds 0-19, 20-39 and 40-59; stated sigmas 4.1-4.3 times the
naive ones where the errors are 1.8-2.0 times); the locked path, taken on 3 of the 22, does not over-cover the
directions (0.99 over 2 recordings, 1.60 over 1: inside one recording's spread) but under-covers the gains (3.3 and
4.5 sigmas off on seeds 4 and 7), and the case's err/sig over unexplained recordings is whichever mix a seed set
draws (0.58 on 20-39, 0.83 on 40-59, where one locked recording lifts five at 0.57). What the structure is: ``K_c
g_c(t) x_c(t)``, the signal times the gain's wander. Per turn ``x_c = m_ck + A_ck cos(phi + a_ck)``, the level
``m_ck`` the field's component along the turn axis, which changes size and sign from flip to flip (zero for a
channel along the flip axis; for the others the vertical field in two flips, opposite in sign, and about zero in the
other two). The walk's slow part in the residual is ``m_ck g_c(t)``: the offsets' model takes it as a stationary
wander of every flip alike and moves each flip's level by as much; but the levels a gain walk moves go with the
level's own sign, and the gain absorbs their common part, so the level differences the directions are read from move
much less (the widening came from the lowest bands, periods of 640 s and more, the longest beyond the record: 6-300
times the naive variance in one direction coordinate on seeds 22, 32, 38). A gain process alone (``cov s = X K X``,
``X`` the fitted signal: the same moment equations with ``L = A (I - P) X A^T`` for ``keep``'s lift, the block sums
``L^T keep^+ z``) covers it (0.58 -> 1.10 on seeds 20-39) but under-covers every structure that is not a gain
(random walk 2.36, pink offsets 1.64, four stacked 2-4 a channel); choosing between the two by the moment equations'
fitted objective (same data, same metric, same parameters) picked the gain for 8/8 gain walks and 1/14 random walks,
but for 7/19 of a precessing axis (1.10 -> 1.54): a field turning is neither, and the objective has no test of its
difference's size. Not adopted.

A gain's wander: its carrier.  A gain wandering, ``K_c (1 + g_c(t))``, leaves ``w_ic g_c(t_i)`` in the weighted
residual, ``w`` the channel's fitted signal less its offset (weighted; ``carrier``): it turns with the turntable
(its sign changes within a turn) and its level over a turn changes size and sign from flip to flip.  With ``g``
constant within a block, ``s = C v`` (``C`` the carrier's rows of each block, ``v`` the block levels), and the move
is ``H^-1 J^T C v = H^-1 G_w^T v``, ``G_w = C^T J``: through the gain's column (``J^T C 1`` is its own, a constant
``v`` moves the channel's gain alone, by ``v``; so ``about_mean`` takes ``v`` about its mean over the rows as it
takes an offset's levels, the gain the file states being the session's mean) and the directions'.  The block sums
demodulated by the carrier, ``z_w = C^T r``, obey the offsets' moment equations with ``keep_w = C^T (I - P) C``:
the same band tests and spectrum estimate ``v``'s process (:func:`_block_moments` with a carrier).  The offsets'
reading takes the same structure as block levels ``u_b ~ w_b v_b`` of a stationary process: the modulated process
it fits, and what it extrapolates into what the fit absorbed (the gain takes the common part of the flips' level
changes), are the wrong shape.  Are the two separable from one recording?  Not within a block: a block is 10 deg
of the turn, the carrier nearly constant in it, so ``z_w ~ w_b z`` block by block and the demodulated sums repeat
the plain ones (why fitting both carriers' processes together shared the power between them: below).  Only across
blocks, by the shape of the block levels over the recording: an offset's wander is stationary, a gain's is the
known ``w_b`` (changing sign within each turn and from flip to flip) times a stationary one.  So the two are
readings of the same block sums ``z``, each spectrum fitted by its own moment equations, compared by the Gaussian
likelihood of ``z`` in ``keep``'s range, ``(1 + f) keep + L K_v L^T`` (``L = A (I - P) C``) against ``(1 + f) keep
+ keep K keep``; the gain's is taken where it is decisively likelier (``2 d ln L > DECISIVE_BIC``), then
propagated with its own floor as the offsets' is.  The comparison fixes the floor's factor at its nominal
``f = 0`` and fits each spectrum without it: free, the moment fit trades the floor against the white block levels
of band 0 and lands on ``f = -1`` in most recordings, which leaves ``keep``'s least-seen combinations nearly
variance-free, and the likelihoods then differed by 1e2-1e11 either way (with the floor clipped at ``f >= 0``
instead, the offsets' reading, at ``f = -1``, counted the white twice and lost a random walk and two precessing
axes to the gain: err/sig 0.6 -> 2.5, 1.1 -> 2.3, 1.8 -> 5.8 on tools/bench_loop.py seeds 60-79).  Degenerate: a
channel whose signal barely turns in a flip (along the turn axis) has a carrier nearly constant over that flip,
where a gain's wander is an offset's times the flip's level, told apart only by the level's change between flips;
a channel along the flip axis as well (its level near zero) carries almost none of its gain's wander, and moves
by almost none.  A structure that is neither (a field turning with the table) goes to whichever reading is
likelier; on tools/bench_loop.py's precessing axis the offsets' (docs/benchmarks.md).

A wander under an explained fit.  A random walk of an offset, ``w(t)`` with ``E[w(t) w(t')] = q^2 min(t, t')``,
under a fit that named a smooth drift (a polynomial in time, a warm-up): the polynomial takes the walk's
lowest part, and what it leaves, ``w~ = (I - P_d) w``, is at most a few tenths of the floor in any one sample
(tools/bench_loop.py's walk, 0.004 uT a sample over 1440 samples: about 0.05 uT RMS after a cubic, against
0.15 uT of noise), so neither the per-flip harmonic test nor the rms margin sees it and the loop calls the fit
explained.  But ``w~`` is not white: it is nearly constant over a flip, and each flip's level is what tells a
direction's two components across the flip axis from the offset and the dip.  The parameters move by ``dx =
H^-1 J^T w~``, a sum over a whole flip that grows as the flip's count (``n``) where white noise grows as
``sqrt(n)``: block-level error the white-noise covariance does not carry (directions RMS 2.65 times their
stated sigma on that walk's 9 explained recordings of seeds 60-79).  The block sums see it: a 10 s block sums
ten samples of ``w~`` coherently, so its share of the block sums' variance is ten times its share per sample.  The
four-flip therefore asks the band test of every fit it called explained, as one family (:func:`family_p_value`:
Bonferroni over the ten tests) beside the walk's likelihood-ratio test
(:func:`calibrate.diagnosis.walk.walk_p_value`, most powerful against a walk, whose power sits in the lowest
bands), the two by Bonferroni at half ``BAND_P_VALUE`` each, the rate under white noise ``BAND_P_VALUE``, so about
one clean recording in a hundred is widened by chance, and, where it passes, widens it: one channel's offset step
where that leaves white block sums (:func:`offset_step`), else a random walk of each channel's offset, one size per
channel from the block sums, its move propagated whole (:mod:`calibrate.diagnosis.walk`).  The earlier widening
reused :func:`structure_in_time` here (measured, docs/benchmarks.md): on a weak walk the locked-to-the-turn
columns took enough of it for the remainder to pass the band test (absence of evidence, not evidence of a locked
structure), and their move, which leaves each turn's level out, under-covered; the process model alone instead
widened two of nine walks' offsets 25 times through the lowest band, which the named cubic absorbs almost whole.
The walk's one size per channel has a known shape, so its extrapolation into what the drift absorbs is fixed.

About the session's mean. A structure's mean over the recording in one channel is a constant, and the channel's
offset column is the constant: the fit absorbs it whole, it moves that offset by exactly its size and nothing else
(``H^-1 G^T 1_c`` is the offset's unit move), and the block sums show none of it (``keep 1_c = 0``). Taken about
zero, the process model states that move as the process's own mean over the session, extrapolated from what the fit
leaves by the lowest band's flat spectrum (periods beyond the record). But under an offset wander the offset a
calibration can state is the session's mean level (what tools/bench_loop.py's truth is, and the only level the
recording holds; the offset at runtime, at another time, no calibration knows): the wander's own mean is no error of
it. So the unexplained four-flip takes the move about each channel's mean (``about_mean``): block levels ``u`` enter
as ``Q u = u - 1 (n^T u) / (n^T 1)`` per channel (``n`` the blocks' row counts), the move ``H^-1 G^T Q u``, for the
process (``Q^T G`` in place of ``G``) and for a step alike. Nothing estimated changes (``keep`` annihilates the
constants, so the moment equations, the band tests and the step's choice are the same), and nothing but the offsets
moves: the directions' and gains' covariance is the same (exactly where a channel's rows weigh alike, as in the line
fit of the tests; the four-flip's bins of unequal counts make the offset's column nearly the constant, and the
directions' and gains' err/sig on tools/bench_loop.py moved by at most 0.02); the offsets keep the floor's factor
and the structure's move less its mean. Why it matters: a level housing's heading reads the x and y channels'
offsets, and taken about zero the offsets' part of its sigma was a median 29 times (5-175) the heading error their
error from the session's level makes, on tools/bench_loop.py's random walk (its 11 unexplained recordings of seeds
60-79: the heading's err/sig 0.65 where the directions' read 0.98; 1.01 about the mean). Its limit: a structure that
is not in the sensor's offset (a field turning with the bench, ``precessing axis``) has a session mean too, which
the offsets absorb as an error that is not a wander's level; the residual cannot tell the two apart (the mean is
invisible either way), and here it is taken as zero, as the constant tilt below is (measured on precessing axis, its
16 recordings of seeds 60-79 the process model took: the heading error the offsets make is 4.7 times its sigma about
the mean, 0.76 times about zero; the heading as a whole, whose sigma its directions dominate, 1.00 about the mean,
0.67 about zero; docs/benchmarks.md). The explained fit's wander widening (``wander_cost``) takes it about the mean
too: its offset walk by construction (:mod:`calibrate.diagnosis.walk`), its one offset step like this one.  Not
the cause of the heading's over-cover (measured on the same recordings, 28 unexplained ones of four cases):
correlations across channels the file cannot carry (the heading's sigma from the full covariance and from each
channel's block with the offsets' cross terms agree within 0.98-1.07), or :func:`widened`'s clipping of the
difference's negative eigenvalues (its heading sigma is the process covariance's own within 1.5 %).

Checks on paper.  White noise: every right-hand side is centred, no band passes but by chance, the
floor's factor is unbiased: ``V = H^-1`` (the naive covariance) on average without the
non-negativity, and in most recordings with it.  A structure the fit absorbs whole (a constant tilt
of the turntable axis, or the fundamental of rate memory, a common phase) leaves nothing in ``z``:
no residual-based bound sees it.  A single channel has no pairs; a parameter the data cannot
determine keeps NaN.

Its limits (measured: tools/bench_loop.py, tests/calibrate/diagnosis/test_robust.py).  A band that
passes the score test by chance where the fit absorbs nearly all of it (periods beyond the record)
widens by far too much: at the test's level that is about 1 % of white-noise recordings (none of
120 replicates of the test's two-channel line widened beyond 1.33 times; with the chi-square
threshold 2 of 40 widened 39 times).  A flat spectrum within the lowest band over-covers a random walk where per-segment levels
absorb most of it (0.53 in the test).  Rate memory (an offset of ``+-h`` by the sign of the channel's field
change: a square wave locked to the turn, ``-(4h/pi) (sin u + sin 3u / 3 + ...)``, ``u = phi + alpha_c``)
was over-covered 2.5 times by the process model alone; "Locked to the turn" above says why and what takes
it now (err/sig 0.72 on tools/bench_loop.py seeds 0-19, where it was 0.41).  A bound from the residual
cannot see what the fit absorbs whole: the mean lag over every channel (the field's azimuth, which turns
no direction) is taken as zero, as a constant tilt of the turntable axis is by every bound here.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.optimize import lsq_linear

from compass.iron_uncertainty import ChannelUncertainty, joint_weights

from .evidence import DECISIVE_BIC

__all__ = ["BLOCK_S", "BlockLayout", "LEVERAGE_ONE", "LOCKED_HARMONICS", "N_BANDS", "OffsetStep", "TimeStructure",
           "TurnPhase", "band_edges_hz", "band_p_values", "block_layout", "cluster_covariance", "extra_sigma",
           "family_p_value", "heading_sigma_deg", "offset_step", "structure_in_time", "time_correlated_covariance",
           "widened"]

BLOCK_S = 10.0
"""Time blocks of :func:`time_correlated_covariance`, s: structure faster than this counts as white."""
N_BANDS = 9
"""Octave bands of the structure's spectrum below the blocks' Nyquist (0.05 Hz down to 0.05 / 256 ~ 2e-4 Hz, then to 0)."""
GRAM_RIDGE = 1e-12
"""Relative ridge on the normalised normal equations of the non-negative fit (loadings too alike share power)."""
GRAM_RCOND = 1e-10
"""Relative cut-off of the normal equations' pseudo-inverse (bands too alike to tell apart share their power)."""
BAND_P_VALUE = 0.01
"""A band's spectral matrix counts when white noise would leave one as large this rarely (simulated null)."""
NULL_DRAWS = 1000
"""Draws of white noise's block sums giving each band's null distribution (fixed seed: the fit is deterministic)."""
KERNEL_RCOND = 1e-12
"""A band kernel's eigenvalues below this fraction of its largest count as zero (its factor for the quadratics)."""
NULL_CHUNK = 250
"""Draws simulated at once (memory: draws x bands x channels x blocks)."""

LOCKED_HARMONICS = tuple(range(2, 13))
"""Harmonics of the turn's angle whose structure locked to the turn is taken as nuisance columns (module docstring)."""

LOCKED_RCOND = 1e-8
"""Combinations of the locked nuisance columns with less than this fraction of the largest information the fit
leaves them count as absorbed whole (their size taken as zero)."""

LOCKED_ABSORBED = 1.0
"""A locked combination's move is propagated only where the fit absorbs at most this much of it for what it
leaves (``|P N v|^2 / |(I - P) N v|^2``: its estimated move's noise over the fit's own noise in the direction it
moves); the rest count, for the move, as absorbed whole (module docstring, "Locked to the turn")."""

LEVERAGE_ONE = 1e-6
"""Leverage eigenvalues within this of one count as one (a cluster alone determines the direction)."""


def bread_root(bread: np.ndarray) -> np.ndarray:
    """``B^{1/2}`` of a bread ``B = (J^T J)^-1`` (symmetrised, negative eigenvalues taken as zero), shape (k, k)."""
    w, v = np.linalg.eigh(0.5 * (bread + bread.T))
    return (v * np.sqrt(np.maximum(w, 0.0))) @ v.T


def cr2_factor(root: np.ndarray, info: np.ndarray) -> np.ndarray:
    """CR2's bias reduction of one cluster in parameter space, ``F_g = B^{1/2} (I - M_g)^{-1/2} B^{1/2}``.

    Parameters
    ----------
    root : ndarray, shape (k, k)
        ``B^{1/2}`` (:func:`bread_root`).
    info : ndarray, shape (k, k)
        The cluster's information ``J_g^T J_g``.

    Returns
    -------
    ndarray, shape (k, k)
        ``F_g`` with ``M_g = B^{1/2} J_g^T J_g B^{1/2}``; eigenvalues of ``M_g`` within ``LEVERAGE_ONE`` of
        one get no weight (:func:`cluster_covariance`'s notes).
    """
    lam, u = np.linalg.eigh(root @ info @ root)
    lam = np.clip(lam, 0.0, None)
    factor = np.where(lam < 1.0 - LEVERAGE_ONE, 1.0 / np.sqrt(np.maximum(1.0 - lam, LEVERAGE_ONE)), 0.0)
    return root @ (u * factor) @ u.T @ root


def cluster_covariance(jac: np.ndarray, weighted: np.ndarray, clusters: np.ndarray,
                       bread: np.ndarray) -> np.ndarray:
    """Bias-reduced cluster-robust (CR2 sandwich) covariance of a least-squares fit's parameters.

    Parameters
    ----------
    jac : ndarray, shape (m, k)
        Jacobian of the weighted residual at the solution.
    weighted : ndarray, shape (m,)
        The weighted residual (over the noise floor, so white noise has unit variance).
    clusters : ndarray of int, shape (m,)
        The cluster of each residual row.
    bread : ndarray, shape (k, k)
        ``(J^T J)^-1`` (NaN rows and columns for what the data cannot determine).

    Returns
    -------
    ndarray, shape (k, k)
        ``bread meat bread`` with the meat of the module docstring; NaN where ``bread`` is.

    Notes
    -----
    ``(I - P_gg)^{-1/2}`` is applied in parameter space: with ``Y = J_g B^{1/2}`` (``B`` the bread),
    ``J_g^T (I - Y Y^T)^{-1/2} r_g = B^{-1/2} (I - M_g)^{-1/2} B^{1/2} J_g^T r_g``, ``M_g = Y^T Y``,
    so only ``k x k`` matrices are decomposed.  Eigenvalues of ``M_g`` within ``LEVERAGE_ONE`` of one
    get no weight.

    Raises
    ------
    ValueError
        Fewer than two clusters, or mismatched shapes.
    """
    jac = np.asarray(jac, dtype=float)
    if jac.shape[0] != weighted.size or clusters.size != weighted.size:
        raise ValueError(f"expected {jac.shape[0]} residuals and clusters, got {weighted.size} and {clusters.size}")
    _, index = np.unique(clusters, return_inverse=True)
    index = index.ravel()
    if index.max(initial=0) < 1:
        raise ValueError("a cluster-robust covariance needs at least two clusters")
    good = np.isfinite(np.diag(bread))
    j = np.nan_to_num(jac[:, good])
    root = bread_root(bread[np.ix_(good, good)])
    moved = np.zeros((index.max() + 1, good.sum()))  # B s~_g: each cluster's share of the parameters' error
    for g in range(index.max() + 1):
        rows = index == g
        jg = j[rows]
        moved[g] = cr2_factor(root, jg.T @ jg) @ (jg.T @ weighted[rows])
    out = np.full(bread.shape, np.nan)
    out[np.ix_(good, good)] = moved.T @ moved
    return out


def widened(naive: np.ndarray, robust: np.ndarray) -> np.ndarray:
    """The naive covariance grown to the robust one where that is larger: ``naive + max(robust - naive, 0)``.

    The difference's negative eigenvalues are dropped, so the result is positive semi-definite and
    at least ``naive`` in every direction.  NaN rows and columns of ``naive`` stay NaN.
    """
    bad = ~np.isfinite(np.diag(naive))
    good = ~bad
    out = np.array(naive, dtype=float, copy=True)
    diff = robust[np.ix_(good, good)] - naive[np.ix_(good, good)]
    w, v = np.linalg.eigh(0.5 * (diff + diff.T))
    out[np.ix_(good, good)] += (v * np.maximum(w, 0.0)) @ v.T
    return out


def extra_sigma(wide: np.ndarray, naive: np.ndarray) -> np.ndarray:
    """``sqrt(wide^2 - naive^2)`` elementwise (the part of a widened sigma the structure adds), NaN kept."""
    return np.sqrt(np.maximum(np.asarray(wide) ** 2 - np.asarray(naive) ** 2, 0.0))


def heading_sigma_deg(directions: np.ndarray, direction_covariance: np.ndarray, response_var: np.ndarray,
                      gains: np.ndarray, dip_deg: float, field_norm: float, n_headings: int = 72,
                      offset_covariance: np.ndarray | None = None,
                      channel_covariance: np.ndarray | None = None, curves: np.ndarray | None = None) -> float:
    """RMS heading sigma of a level housing over every heading, from the calibration's uncertainty alone.

    The runtime solves the field ``m = P x`` from each channel's component ``x_c = B_H . a_c``
    (``P`` the pseudo-inverse of the directions); an error ``dx_c`` of a component turns the
    heading by ``(e_perp . P_c) dx_c / |B_h|``, ``e_perp`` the horizontal unit vector across the
    horizontal field.  Per channel ``var(dx_c) = B^T Sigma_a B + (var V0 + x^2 var K) / K^2``
    (the terms of :meth:`compass.model.SensorModel.component_variance`); the noise of one sample
    is left out (it averages down at runtime, the calibration's error does not).

    The offsets' errors need not be independent across channels: a shared parameter (a warm-up's
    time constant, whose error moves each settled offset by its own amplitude times one number) makes
    them correlated, and the heading's variance from them is ``l^T (C_V / K K^T) l`` with the signed
    levers ``l_c = (e_perp . P_c) / |B_h|``, not the sum of ``l_c^2 var V0_c / K_c^2``.  Within a channel
    the direction, offset and gain errors need not be independent either (a warm-up during the first flip
    ties a channel's offset to its direction): with their joint covariance ``S_c`` the component's
    variance is ``w^T S_c w``, ``w = (B, 1 / K, x / K)`` (each error moves the solved component the same
    way: ``-B . da - (dV0 + x dK) / K``).  Measured on four-flip recordings with a warm-up
    (tools/bench_loop.py): the joint terms raise the heading sigma ~1.18x, the cross-channel offsets'
    ~1.00x on a near-orthogonal triad (the cross terms average out over headings).

    A response curve ``g(x) = x + sum_k c_k x^k`` (``curves``) adds its coefficients' errors to the joint
    covariance, ``w = (B, 1 / (K g'), g / (K g'), x^k / g')`` (:func:`compass.iron_uncertainty.joint_weights`):
    a curve and a gain trade against each other over the field range a channel sees (correlation near -1),
    so together they move the heading less than the gain's variance alone says.  The per-channel variance is the
    runtime's own (:meth:`compass.iron_uncertainty.ChannelUncertainty.component_variance`, one formula); the
    offsets' cross terms move the components by ``dV0 / (K g')`` at each heading's ``x``, the offset's lever.

    Parameters
    ----------
    directions : ndarray, shape (c, 3)
        Unit sensing directions in H.
    direction_covariance : ndarray, shape (c, 3, 3)
        rad^2.
    response_var : ndarray, shape (c, 2)
        Variances of each channel's offset and gain (output units^2, (output units per field unit)^2).
    gains : ndarray, shape (c,)
        Output units per field unit.
    dip_deg : float
        The field's dip.
    field_norm : float
        |B| in the gains' field unit.
    n_headings : int
        Headings averaged over.
    offset_covariance : ndarray, shape (c, c), optional
        The offsets' covariance across channels (output units^2); its off-diagonal terms are used (the
        diagonal is ``response_var[:, 0]``'s).  None: the offsets are taken as independent.
    channel_covariance : ndarray, shape (c, 5, 5), optional
        Each channel's joint covariance of its direction (3, rad), offset and gain (the units of
        ``response_var``); it replaces ``direction_covariance`` and ``response_var``.  None: the three
        taken as independent.  Shape (c, 8, 8) with ``curves``: the curve's coefficients after the gain
        (:meth:`calibrate.fourflip._mlfit.MLFit.curve_covariance`).
    curves : ndarray, shape (c, 3), optional
        Each channel's curve coefficients (quadratic, cubic, quintic; 1 / field unit^(k - 1)).  None: linear.

    Returns
    -------
    float
        Degrees.
    """
    psi = np.linspace(0.0, 2 * np.pi, n_headings, endpoint=False)
    dip = np.radians(dip_deg)
    b = field_norm * np.column_stack([np.cos(dip) * np.cos(psi), -np.cos(dip) * np.sin(psi),
                                           np.full_like(psi, -np.sin(dip))])
    across = np.column_stack([np.sin(psi), np.cos(psi), np.zeros_like(psi)])  # horizontal, perpendicular to b's
    solver = np.linalg.pinv(directions)  # (3, c): m = solver @ x
    c = len(gains)
    if channel_covariance is None:
        if curves is not None:
            raise ValueError("a curve's coefficients need the joint covariance that carries their errors")
        channel_covariance = np.zeros((c, 5, 5))
        channel_covariance[:, :3, :3] = direction_covariance
        channel_covariance[:, 3, 3], channel_covariance[:, 4, 4] = response_var[:, 0], response_var[:, 1]
    own = ChannelUncertainty(directions, solver, gains, curves=curves,
                             joint_covariance=np.nan_to_num(np.asarray(channel_covariance, dtype=float)))
    var = own.component_variance(b)  # (h, c)
    cross = np.zeros((c, c)) if offset_covariance is None else np.nan_to_num(np.asarray(offset_covariance, dtype=float))
    cross = cross - np.diag(np.diag(cross))
    lever = across @ solver  # (h, c), signed
    moved = lever * joint_weights(b, directions, gains, curves)[..., 3]  # times the offset's lever 1 / (K g')
    total = np.sum(lever**2 * var, axis=1) + np.einsum("hc,cd,hd->h", moved, cross, moved)
    return float(np.degrees(np.sqrt(np.mean(total)) / (field_norm * np.cos(dip))))



def _half_system(gram: np.ndarray, rhs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(U, t)`` with ``U^T U = gram + ridge`` and ``U^T t = rhs``: least squares in ``U`` then minimises
    ``x^T (gram + ridge) x - 2 rhs^T x``, the normal equations' quadratic form, under bounds.

    From the eigen-decomposition, not a Cholesky factor: with few time blocks several bands are alike
    to rounding, and the (positive semi-definite) gram can then have eigenvalues a rounding below zero;
    they are taken as zero before the ridge (:data:`GRAM_RIDGE`, relative to the normalised gram).
    """
    w, v = np.linalg.eigh(gram)
    root = np.sqrt(np.maximum(w, 0.0) + GRAM_RIDGE)
    return root[:, None] * v.T, (v.T @ rhs) / root


def _band_kernel(lag_s: np.ndarray, low_hz: float, high_hz: float) -> np.ndarray:
    """Autocovariance at ``lag_s`` of a unit-variance process whose spectrum is flat on [low, high] Hz.

    ``(sin(2 pi f2 d) - sin(2 pi f1 d)) / (2 pi d (f2 - f1))``, with numpy's normalised sinc.
    """
    return (high_hz * np.sinc(2 * high_hz * lag_s) - low_hz * np.sinc(2 * low_hz * lag_s)) / (high_hz - low_hz)


def band_edges_hz(block_s: float, n_bands: int) -> np.ndarray:
    """Edges of the spectrum's bands: 0, then octaves up to the blocks' Nyquist ``1 / (2 block_s)``, Hz."""
    return np.concatenate([[0.0], 0.5 / block_s / 2.0 ** np.arange(n_bands - 1, -1, -1)])


def _loadings(n_groups: int) -> np.ndarray:
    """How a structure process enters the groups: each alone, then each pair alike and opposed, shape (l, groups)."""
    out = list(np.eye(n_groups))
    for a in range(n_groups):
        for b in range(a + 1, n_groups):
            for sign in (1.0, -1.0):
                v = np.zeros(n_groups)
                v[a], v[b] = np.sqrt(0.5), sign * np.sqrt(0.5)
                out.append(v)
    return np.array(out)


class _BlockMoments(NamedTuple):
    """What :func:`time_correlated_covariance` fits the structure's spectrum to (see its comments)."""

    b: np.ndarray  # the bread on the determined parameters, (k', k')
    good: np.ndarray  # which parameters are determined, (k,)
    summed_jac: np.ndarray  # G = A J, rows channel-major, (c nb, k')
    y: np.ndarray  # the block sums z = A r, (c, nb)
    bands: np.ndarray  # white beyond the floor, then each band's kernel B_k, (bands, nb, nb)
    blocks: np.ndarray  # keep = A (I - P) A^T as (c, nb, c, nb)
    root: np.ndarray  # keep = root root^T, (c nb, rank)
    factors: np.ndarray  # each band's kernel B_k = F_k F_k^T (its range), side by side: (nb, sum of ranks)
    splits: np.ndarray  # where each band's columns of ``factors`` end, (bands,)
    floor_rhs: float  # z^T keep^+ z - rank(keep)
    traces: np.ndarray  # tr(B_k keep_bc B_l keep_da), (bands, c, c, bands, c, c)
    t_start: np.ndarray  # each block's first time, s, (nb,)
    size: np.ndarray  # each block's count of rows, (nb,)
    block: np.ndarray  # each row's block, (n,)


class _Locked(NamedTuple):
    """A fit with structures locked to the turn as nuisance columns beside its own (:func:`_without_locked`)."""

    jac: np.ndarray  # (n c, k + r): the fit's Jacobian, then the nuisance columns' part the fit leaves
    weighted: np.ndarray  # (n, c), the residual with the nuisance structure taken out
    bread: np.ndarray  # (k + r, k + r), block-diagonal (the added columns orthogonal to the fit's)
    k: int  # the fit's own parameters, first
    shift: np.ndarray  # (k,) what the nuisance structure moved the fit's parameters by, D gamma (measurable part)
    noise: np.ndarray  # (k, k) the shift's covariance under white noise, D D^T

    def own(self, covariance: np.ndarray) -> np.ndarray:
        """The fit's error covariance from the larger fit's (module docstring, "Locked to the turn"): its own block
        plus the shift's square less the noise's share of it (unbiased for the shift's square)."""
        return covariance[:self.k, :self.k] + np.outer(self.shift, self.shift) - self.noise


def _without_locked(jac, weighted, bread, locked: TurnPhase | None) -> _Locked:
    """The fit with each turn's structures locked to the turn as nuisance columns beside its own (module
    docstring, "Locked to the turn").

    With the nuisance columns ``N`` (per turn and channel: the harmonics ``locked.harmonics`` and
    ``locked.shapes``), what the fit leaves of them is ``(I - P) N``; ``M = N^T (I - P) N``'s eigenvectors with an
    eigenvalue above ``LOCKED_RCOND`` of the largest, scaled to unit information and turned so that what the fit
    absorbs of them, ``P N W``, is orthogonal too (``W^T N^T P N W = diag(rho)``), are the combinations ``W``
    (those the fit absorbs whole get no weight: the structure's size there is taken as zero).  ``Q = (I - P) N W``
    is orthonormal: the structure's size ``gamma = Q^T r`` (unit variance under white noise), the residual without
    it ``r - Q gamma`` (its covariance under white noise ``I - P - Q Q^T``, the larger fit's).  What it moved the
    fit's parameters by is ``D gamma``, ``D = H^-1 J^T N W`` over the combinations with ``rho <= LOCKED_ABSORBED``
    alone, with covariance ``D D^T`` under white noise (``rho_j H^-1`` along ``D_j``, the ``D_j`` orthogonal in
    ``H``: at most ``LOCKED_ABSORBED H^-1``).
    """
    jac = np.asarray(jac, dtype=float)
    k = bread.shape[0]
    if locked is None:
        return _Locked(jac, weighted, bread, k, np.zeros(k), np.zeros((k, k)))
    weighted = np.atleast_2d(np.asarray(weighted, dtype=float).T).T
    n, c = weighted.shape
    phase = np.asarray(locked.phase_rad, dtype=float)
    turns = np.unique(locked.turn, return_inverse=True)[1].ravel()
    if phase.size != n or turns.size != n:
        raise ValueError(f"expected a phase and a turn for each of the {n} rows, got {phase.size} and {turns.size}")
    waves = np.column_stack([f(h * phase) for h in locked.harmonics for f in (np.cos, np.sin)])
    shapes = np.zeros((n, c, 0)) if locked.shapes is None else np.asarray(locked.shapes, dtype=float)
    if shapes.shape[:2] != (n, c):
        raise ValueError(f"expected shapes of {n} rows and {c} channels, got {shapes.shape}")
    on_turn = (turns[:, None] == np.arange(turns.max() + 1)).astype(float)  # (n, turns)
    columns = []  # each channel its own columns, rows as weighted.ravel()
    for ch in range(c):
        own_waves = np.hstack([waves, shapes[:, ch, :]])
        block = np.zeros((n, c, own_waves.shape[1] * on_turn.shape[1]))
        block[:, ch, :] = (own_waves[:, :, None] * on_turn[:, None, :]).reshape(n, -1)
        columns.append(block.reshape(n * c, -1))
    nuisance = np.hstack(columns)
    good = np.isfinite(np.diag(bread))
    b = bread[np.ix_(good, good)]
    fit_jac = np.nan_to_num(jac[:, good])
    cross = fit_jac.T @ nuisance  # J^T N
    left = nuisance - fit_jac @ (b @ cross)  # (I - P) N
    lam, vec = np.linalg.eigh(nuisance.T @ left)
    kept = lam > lam.max(initial=0.0) * LOCKED_RCOND
    whitened = vec[:, kept] / np.sqrt(lam[kept])  # combinations the fit leaves with unit information: W^T M W = I
    # turned so that what the fit absorbs of them is orthogonal too: W^T N^T P N W = diag(rho), rho each one's
    # absorbed over left (|P N w|^2 / |(I - P) N w|^2); their moves d_j are then orthogonal in H
    absorbed = (nuisance - left) @ whitened  # P N W
    rho, turn = np.linalg.eigh(absorbed.T @ absorbed)
    combos = whitened @ turn
    q = left @ combos  # orthonormal: the residual's size in each is q^T r, white noise's unit variance
    rows = weighted.ravel()
    gamma = q.T @ rows
    # the move of the combinations the fit leaves at least 1 / (1 + LOCKED_ABSORBED) of (module docstring):
    # d_j gamma_j, its noise d_j d_j^T, rho_j times the fit's own noise in the direction it moves
    seen = rho <= LOCKED_ABSORBED
    d = b @ (cross @ combos[:, seen])
    shift, noise = np.zeros(k), np.zeros((k, k))
    shift[good] = d @ gamma[seen]
    noise[np.ix_(good, good)] = d @ d.T
    r = q.shape[1]
    aug_bread = np.full((k + r, k + r), np.nan)
    aug_bread[:k, :k] = bread
    aug_bread[:k, k:] = np.where(good[:, None], 0.0, np.nan)
    aug_bread[k:, :k] = aug_bread[:k, k:].T
    aug_bread[k:, k:] = np.eye(r)
    return _Locked(np.hstack([jac, q]), (rows - q @ gamma).reshape(n, c), aug_bread, k, shift, noise)


class BlockLayout(NamedTuple):
    """A fit's residual checked and cut into blocks of time (:func:`block_layout`)."""

    jac: np.ndarray
    """Jacobian of the weighted residual, (n c, k), rows time-major."""
    weighted: np.ndarray
    """Weighted residual, (n, c)."""
    t_s: np.ndarray
    """Sample times, s, (n,)."""
    good: np.ndarray
    """The parameters with a finite ``bread`` diagonal, (k,) bool."""
    bread: np.ndarray
    """``bread`` over the good parameters."""
    block: np.ndarray
    """Each sample's block, (n,) int, 0 .. nb - 1."""
    nb: int
    """Number of blocks."""


def block_layout(jac, weighted, t_s, bread, block_s: float) -> BlockLayout:
    """A fit's residual checked and cut into blocks of ``block_s`` seconds from its first sample.

    Raises
    ------
    ValueError
        Mismatched shapes or a non-positive block length.
    """
    jac = np.asarray(jac, dtype=float)
    weighted = np.atleast_2d(np.asarray(weighted, dtype=float).T).T
    t_s = np.asarray(t_s, dtype=float)
    n, c = weighted.shape
    if jac.shape[0] != n * c or t_s.size != n:
        raise ValueError(f"expected {jac.shape[0]} residuals as ({t_s.size} times) x channels, got {weighted.shape}")
    if not block_s > 0:
        raise ValueError(f"block_s must be positive, got {block_s}")
    good = np.isfinite(np.diag(bread))
    block = np.unique(np.floor((t_s - t_s.min()) / block_s), return_inverse=True)[1].ravel()
    return BlockLayout(jac, weighted, t_s, good, bread[np.ix_(good, good)], block, int(block.max()) + 1)


def _block_moments(jac, weighted, t_s, bread, block_s, n_bands, carrier=None) -> _BlockMoments:
    """Block sums, what the fit keeps of them and the band kernels (raises as :func:`time_correlated_covariance`).

    ``carrier`` (n, c), optional: each row's carrier ``w`` (module docstring, "A gain's wander: its carrier"), the
    block sums then ``C^T r`` and ``keep = C^T (I - P) C`` with ``C`` the carrier's rows summed into blocks; none:
    one on every row (an offset's).
    """
    jac, weighted, t_s, good, b, block, nb = block_layout(jac, weighted, t_s, bread, block_s)
    n, c = weighted.shape
    size = np.bincount(block, minlength=nb).astype(float)
    t_block = np.bincount(block, weights=t_s, minlength=nb) / size
    t_start = np.full(nb, np.inf)
    np.minimum.at(t_start, block, t_s)
    carried = np.ones((n, c)) if carrier is None else np.asarray(carrier, dtype=float)
    if carried.shape != (n, c):
        raise ValueError(f"expected a carrier of {n} rows and {c} channels, got {carried.shape}")
    summed_jac = np.zeros((nb, c, b.shape[0]))  # G = C^T J, C the carrier summed into blocks; channel-major below
    np.add.at(summed_jac, block, np.nan_to_num(jac[:, good]).reshape(n, c, -1) * carried[:, :, None])
    summed_jac = summed_jac.transpose(1, 0, 2).reshape(c * nb, -1)
    info = np.concatenate([np.bincount(block, weights=w**2, minlength=nb) for w in carried.T])  # diag(C^T C)
    keep = np.diag(info) - summed_jac @ b @ summed_jac.T  # C^T (I - P) C
    y = np.concatenate([np.bincount(block, weights=w, minlength=nb) for w in (weighted * carried).T]).reshape(c, nb)
    edges = band_edges_hz(block_s, n_bands)
    lag = t_block[:, None] - t_block[None, :]
    bands = np.stack([np.eye(nb)] + [_band_kernel(lag, lo, hi) for lo, hi in zip(edges[:-1], edges[1:])])
    # keep's range (numpy's matrix_rank tolerance): its pseudo-inverse, its rank and a root to draw z from
    w, u = np.linalg.eigh(keep)
    positive = w > w.max(initial=0.0) * keep.shape[0] * np.finfo(float).eps
    root = u[:, positive] * np.sqrt(w[positive])
    floor_rhs = float(np.sum((u[:, positive].T @ y.ravel()) ** 2 / w[positive]) - positive.sum())
    blocks = keep.reshape(c, nb, c, nb)
    moved = np.einsum("kij,bjcl->kbcil", bands, blocks, optimize=True)  # B_k keep_bc
    traces = np.tensordot(moved, moved, axes=([3, 4], [4, 3]))  # (k, b, c, l, d, a)
    factors = []
    for kernel in bands:  # the low bands' kernels have few effective dimensions over the record
        w, u = np.linalg.eigh(kernel)
        kept = w > w.max() * KERNEL_RCOND
        factors.append(u[:, kept] * np.sqrt(w[kept]))
    splits = np.cumsum([f.shape[1] for f in factors])
    return _BlockMoments(b, good, summed_jac, y, bands, blocks, root, np.hstack(factors), splits,
                         floor_rhs, traces, t_start, size, block)


def _with_floor(m: _BlockMoments, outer: np.ndarray, quadratic: np.ndarray, floor_quadratic: np.ndarray):
    """Normal equations of the floor's factor and the bands' spectra in ``outer`` (v, c, c), for block sums
    whose ``z_a^T B_k z_d`` are ``quadratic`` (draws, bands, c, c) and ``z^T keep^+ z`` ``floor_quadratic``.

    Returns the normal matrix (1 + bands v, 1 + bands v) and right-hand sides (draws, 1 + bands v).
    """
    # E[z z^T] = (1 + f) keep + keep K keep, K = sum over bands k of (S_k kron B_k), S_k the band's c x c
    # spectral matrix.  Normal equations of the (MINQUE) fit at K = 0, in traces: <k, v; l, u> =
    # tr(K_kv keep K_lu keep) = sum V_ab U_cd tr(B_k keep_bc B_l keep_da), rhs_kv = z^T K_kv z - tr(K_kv keep);
    # the floor's beside them: <floor, floor> = rank(keep), <floor, K> = tr(K keep), rhs = z^T keep^+ z - rank
    gram = np.einsum("vab,ucd,kbclda->kvlu", outer, outer, m.traces, optimize=True)
    gram = gram.reshape(gram.shape[0] * gram.shape[1], -1)
    cross = np.einsum("kij,diaj,vad->kv", m.bands, m.blocks, outer, optimize=True).ravel()
    rhs = np.einsum("mkad,vad->mkv", quadratic, outer, optimize=True).reshape(len(quadratic), -1) - cross
    rank = m.root.shape[1]
    normal = np.block([[np.array([[rank]]), cross[None]], [cross[:, None], gram]])
    return normal, np.column_stack([floor_quadratic - rank, rhs])


def _quadratic(m: _BlockMoments, z: np.ndarray) -> np.ndarray:
    """``z_a^T B_k z_d`` of block sums ``z`` (draws, c, nb): shape (draws, bands, c, c).

    Through each kernel's factor (``B_k = F_k F_k^T``): ``(z F_k)(z F_k)^T``, batched products (BLAS).
    """
    projected = z @ m.factors  # (draws, c, sum of ranks)
    return np.stack([p @ p.transpose(0, 2, 1) for p in np.split(projected, m.splits[:-1], axis=2)], axis=1)


def _band_p_values(m: _BlockMoments, draws: int = NULL_DRAWS) -> np.ndarray:
    """Each band's score-test p-value for structure, against its null distribution under white noise by simulation
    (``draws`` of it)."""
    c = m.y.shape[0]
    entries = [(i, j) for i in range(c) for j in range(i, c)]
    basis = np.zeros((len(entries), c, c))
    for e, (i, j) in enumerate(entries):
        basis[e, i, j] = basis[e, j, i] = 1.0
    own = np.ones((len(m.bands), len(entries)), dtype=bool)
    own[0] = [i == j for i, j in entries]  # white beyond the floor: each channel's own
    index = 1 + np.arange(own.size).reshape(own.shape)
    normal, _ = _with_floor(m, basis, _quadratic(m, m.y[None]), np.array([m.floor_rhs + m.root.shape[1]]))
    # the floor's factor profiled out: score = rhs_i - <i, floor> rhs_floor / <floor, floor>, under white noise
    # centred with covariance `spread` (twice the profiled normal matrix, were z Gaussian in K's coordinates)
    tests = []
    for k in range(len(m.bands)):
        i = index[k][own[k]]
        lever = normal[i, 0] / normal[0, 0]
        spread = 2.0 * (normal[np.ix_(i, i)] - np.outer(normal[i, 0], normal[0, i]) / normal[0, 0])
        tests.append((i, lever, np.linalg.pinv(spread, rcond=GRAM_RCOND, hermitian=True)))

    def statistics(quadratic, floor_quadratic):
        _, rhs = _with_floor(m, basis, quadratic, floor_quadratic)
        score = [rhs[:, i] - np.outer(rhs[:, 0], lever) for i, lever, _ in tests]
        return np.column_stack([np.einsum("mi,ij,mj->m", s, w, s) for s, (_, _, w) in zip(score, tests)])

    observed = statistics(_quadratic(m, m.y[None]), np.array([m.floor_rhs + m.root.shape[1]]))[0]
    # the statistic is a quadratic form of few effective degrees of freedom in the low bands (heavy-tailed, far
    # from chi-square): its null by simulation, z = A r ~ N(0, keep) under white noise, with a fixed seed
    rng = np.random.default_rng(0)
    exceed = np.zeros(len(m.bands))
    for start in range(0, draws, NULL_CHUNK):
        g = rng.standard_normal((min(NULL_CHUNK, draws - start), m.root.shape[1]))
        z = (g @ m.root.T).reshape(len(g), c, -1)
        exceed += np.sum(statistics(_quadratic(m, z), np.sum(g**2, axis=1)) >= observed, axis=0)
    return (1.0 + exceed) / (1.0 + draws)


def band_p_values(jac: np.ndarray, weighted: np.ndarray, t_s: np.ndarray, bread: np.ndarray,
                  block_s: float = BLOCK_S, n_bands: int = N_BANDS, draws: int = NULL_DRAWS) -> np.ndarray:
    """Stage 1 of :func:`time_correlated_covariance` alone: each band's p-value for structure (white first).

    Parameters as :func:`time_correlated_covariance`; ``draws`` of the null (the first ``NULL_DRAWS`` are
    stage 1's).  Under white noise each is uniform on ``[1 / (draws + 1), 1]`` up to the simulation's error; a
    band counts at ``BAND_P_VALUE``.

    Returns
    -------
    ndarray, shape (n_bands + 1,)
        White beyond the floor, then the bands from 0 Hz upward.
    """
    return _band_p_values(_block_moments(jac, weighted, t_s, bread, block_s, n_bands), draws)


def family_p_value(p_values: np.ndarray) -> float:
    """One p-value for "some band carries structure" from :func:`band_p_values`' per-band ones (Bonferroni).

    The four-flip asks it of a fit the loop called explained (module docstring, "A wander under an explained
    fit"): a band passing at ``BAND_P_VALUE`` by chance happens in about one white-noise recording of ten
    (ten tests), so the family's rate is held at ``BAND_P_VALUE`` instead.  With ``NULL_DRAWS`` draws the
    smallest band p-value is ``1 / (NULL_DRAWS + 1)``, so the family can pass only where
    ``(N_BANDS + 1) / (NULL_DRAWS + 1) <= BAND_P_VALUE`` (1000 draws, ten tests: it passes where one band's
    statistic is beyond every draw of its null).

    Parameters
    ----------
    p_values : ndarray, shape (n_tests,)

    Returns
    -------
    float
        ``min(1, n_tests min(p))``.

    Raises
    ------
    ValueError
        No p-values, or one not finite.
    """
    p_values = np.asarray(p_values, dtype=float)
    if p_values.size == 0:
        raise ValueError("a family p-value needs at least one test's p-value")
    if not np.isfinite(p_values).all():
        raise ValueError(f"a family p-value needs finite p-values, got {p_values.tolist()}")
    return float(min(1.0, p_values.size * p_values.min()))


def time_correlated_covariance(jac: np.ndarray, weighted: np.ndarray, t_s: np.ndarray, bread: np.ndarray,
                               block_s: float = BLOCK_S, n_bands: int = N_BANDS) -> np.ndarray:
    """Covariance of a least-squares fit's parameters with its residual's structure a stationary process in time.

    The module docstring's "A process in time": the residual summed over time blocks, the
    structure's spectra (each channel's own, and processes common to each pair of channels, alike
    or opposed) estimated in octave bands from the block sums' second moments against what the fit
    leaves of each band (bands kept where a score test finds structure, then non-negative least
    squares on those, the noise floor's own factor beside them), and the parameters' covariance
    ``(1 + f) H^-1 + H^-1 G^T K G H^-1``.

    Parameters
    ----------
    jac : ndarray, shape (n * c, k)
        Jacobian of the weighted residual at the solution, rows as ``weighted.ravel()``.
    weighted : ndarray, shape (n, c)
        The weighted residual of ``n`` samples (or bins) of ``c`` channels, over the noise floor
        (white noise has unit variance).
    t_s : ndarray, shape (n,)
        Time of each sample, s.
    bread : ndarray, shape (k, k)
        ``(J^T J)^-1`` (NaN rows and columns for what the data cannot determine).
    block_s : float
        Length of the time blocks, s: structure faster than this counts as white beyond the floor.
    n_bands : int
        Octave bands of the spectrum below the blocks' Nyquist (the lowest reaches 0 Hz).

    Returns
    -------
    ndarray, shape (k, k)
        NaN where ``bread`` is.

    Raises
    ------
    ValueError
        Mismatched shapes, or a non-positive block length.
    """
    m = _block_moments(jac, weighted, t_s, bread, block_s, n_bands)
    return _stationary_covariance(m, _band_p_values(m), bread)


class TurnPhase(NamedTuple):
    """Where each row is in a turn, for structures locked to the turn's phase (module docstring)."""

    phase_rad: np.ndarray
    """(n,) the turn's angle at each time, rad."""
    turn: np.ndarray
    """(n,) which turn each time belongs to (labels; each turn has its own amplitudes)."""
    harmonics: tuple = LOCKED_HARMONICS
    """Harmonics of the turn's angle, each turn's own cosine and sine nuisance columns in each channel."""
    shapes: np.ndarray | None = None
    """(n, c, s) or None: shapes of each channel's own structure, each turn's own nuisance column (the four-flip:
    its signal less the turn's mean and the signal's rate in the turn angle, a gain and a lag of each turn), in
    the weighted residual's units."""


class TimeStructure(NamedTuple):
    """What :func:`structure_in_time` found: the parameters' covariance, the offset step if it is one, and whether
    structure locked to the turn is it."""

    covariance: np.ndarray
    """(k, k), NaN where the bread is."""
    step: OffsetStep | None
    """The step that explains the whole structure, or None."""
    locked: bool = False
    """Whether structure locked to the turn explains the whole structure (its move propagated); with no step
    either, a stationary process in time."""
    gain: bool = False
    """Whether the stationary process is a gain's wander, its block levels times the carrier (module docstring,
    "A gain's wander: its carrier"), rather than the offsets'."""


class OffsetStep(NamedTuple):
    """One channel's offset stepping once (module docstring, "One step, not a process")."""

    channel: int
    """Index of the channel (column of ``weighted``)."""
    t_s: float
    """Start of the first time block at the new level, s (the step lies within the block before it or at its start)."""
    size: float
    """The new level less the old, in the weighted residual's units (noise sigmas of one row)."""
    delta_chi2: float
    """What the step explains of the block sums (chi-square drop)."""


def structure_in_time(jac: np.ndarray, weighted: np.ndarray, t_s: np.ndarray, bread: np.ndarray,
                      block_s: float = BLOCK_S, n_bands: int = N_BANDS,
                      locked: TurnPhase | None = None, about_mean: bool = False,
                      carrier: np.ndarray | None = None) -> TimeStructure:
    """Covariance of a fit's parameters under the structure its residual shows: one offset step, structure locked
    to the turn, or a process in time.

    Where the score test finds structure, the single step in one channel's offset that explains the
    most of the block sums is taken out; if it is decisive against none (delta-BIC over
    ``DECISIVE_BIC``) and what remains passes the same test in every band (white noise at the floor),
    the structure is that step and its move of the parameters is propagated (module docstring, "One
    step, not a process").  Otherwise, given ``locked``, the structure locked to the turn is taken out;
    if what remains passes the test in every band, its move of the parameters is propagated (module
    docstring, "Locked to the turn").  Otherwise the stationary process of :func:`time_correlated_covariance`,
    or, given ``carrier``, a gain's wander where that is decisively likelier.

    Parameters
    ----------
    jac, weighted, t_s, bread, block_s, n_bands
        As :func:`time_correlated_covariance`.
    locked : TurnPhase, optional
        Each row's turn and angle in it (and the shapes of each channel's own turn structure).
    about_mean : bool
        Take the step's and the process's move of the parameters about each channel's mean level over the
        recording (module docstring, "About the session's mean"): the offsets a fit states are then the
        session's mean levels, which a structure's own mean moves with the fit.  False: about zero.
    carrier : ndarray, shape (n, c), optional
        Each channel's fitted signal less its offset, in the weighted residual's units: where it is given and the
        process in time stands, a gain's wander (the process times it) is taken instead of the offsets' where it is
        decisively the likelier reading of the block sums (module docstring, "A gain's wander: its carrier").

    Returns
    -------
    TimeStructure
        The covariance, shape (k, k), NaN where ``bread`` is; the step, or None; whether the locked
        structure was taken; whether the process is read as a gain's wander through ``carrier``.

    Raises
    ------
    ValueError
        Mismatched shapes (``locked``'s too), or a non-positive block length.
    """
    m = _block_moments(jac, weighted, t_s, bread, block_s, n_bands)
    p_values = _band_p_values(m)
    if np.any(p_values <= BAND_P_VALUE):
        found = _offset_step(m, bread, about_mean)
        if found is not None:
            return found
        if locked is not None:
            aug = _without_locked(jac, weighted, bread, locked)
            rest = _block_moments(aug.jac, aug.weighted, t_s, aug.bread, block_s, n_bands)
            if np.all(_band_p_values(rest) > BAND_P_VALUE):  # the locked structure is the whole structure
                return TimeStructure(aug.own(aug.bread), None, True)
    if carrier is not None:
        gain = _gain_process(m, p_values, jac, weighted, t_s, bread, block_s, n_bands, carrier)
        if gain is not None:
            return TimeStructure(_process_covariance(*gain, bread, about_mean), None, gain=True)
    return TimeStructure(_stationary_covariance(m, p_values, bread, about_mean), None)


def _moved_by_levels(m: _BlockMoments, about_mean: bool) -> np.ndarray:
    """``G`` (rows channel-major, (c nb, k')), or with ``about_mean`` ``Q^T G``: each channel's block levels ``u``
    taken about their mean over the recording's rows, ``Q u = u - 1 (n^T u) / n^T 1`` (``n`` the blocks' row
    counts), so that ``H^-1 G^T Q u`` is the parameters' move less that of the levels' mean (module docstring,
    "About the session's mean")."""
    g = m.summed_jac
    if not about_mean:
        return g
    c, nb = m.y.shape
    per = g.reshape(c, nb, -1)
    weight = m.size / np.sum(m.size)
    return (per - weight[None, :, None] * np.sum(per, axis=1, keepdims=True)).reshape(c * nb, -1)


def offset_step(jac: np.ndarray, weighted: np.ndarray, t_s: np.ndarray, bread: np.ndarray,
                block_s: float = BLOCK_S, n_bands: int = N_BANDS, about_mean: bool = False) -> TimeStructure | None:
    """:func:`structure_in_time`'s first alternative alone: the one offset step that is decisive and leaves white
    block sums (module docstring, "One step, not a process"), with its covariance (the step's move taken about each
    channel's mean level with ``about_mean``: "About the session's mean"), or None.

    Parameters and raises as :func:`time_correlated_covariance`.
    """
    return _offset_step(_block_moments(jac, weighted, t_s, bread, block_s, n_bands), bread, about_mean)


def _offset_step(m: _BlockMoments, bread: np.ndarray, about_mean: bool = False) -> TimeStructure | None:
    """The best single offset step and its covariance if it is decisive and leaves white block sums, else None."""
    c, nb = m.y.shape
    if nb < 2:
        return None
    # a step in channel a from block j on: levels s = 1 on a's blocks j.. (0 elsewhere); s^T z from the sums'
    # reversed cumulative sums, its information s^T keep s from the reversed 2-D cumulative sums of keep_aa
    own = m.blocks[np.arange(c), :, np.arange(c), :]  # (c, nb, nb): keep_aa
    info = np.cumsum(np.cumsum(own[:, ::-1, ::-1], axis=1), axis=2)[:, ::-1, ::-1]
    info = np.diagonal(info, axis1=1, axis2=2)[:, 1:]  # from block 1: a step at the first block is a constant
    usable = info > np.max(np.abs(own), initial=0.0) * 1e-9
    safe = np.where(usable, info, 1.0)
    tail = np.cumsum(m.y[:, ::-1], axis=1)[:, ::-1][:, 1:]  # s^T z for j = 1 ..
    drop = np.where(usable, tail**2 / safe, 0.0)  # each candidate's chi-square drop
    channel, j = np.unravel_index(np.argmax(drop), drop.shape)
    best = float(drop[channel, j])
    j += 1
    # decisive against no step, as the loop adds an effect: delta-BIC with the floor's factor free (its own
    # error is not the step's), a size, a time and a channel chosen: rank ln(Q / (Q - drop)) - 3 ln(rank)
    rank = m.root.shape[1]
    total = m.floor_rhs + rank  # z^T keep^+ z
    if not 0.0 < best < total or rank * np.log(total / (total - best)) - 3.0 * np.log(rank) <= DECISIVE_BIC:
        return None
    s = np.zeros(c * nb)
    s[channel * nb + j:(channel + 1) * nb] = 1.0
    keep_s = m.blocks.reshape(c * nb, c * nb) @ s
    info_s = float(s @ keep_s)
    size = float(np.sum(m.y[channel, j:]) / info_s)
    # what remains: z - size keep s (E[z] = keep u for block levels u); z'^T keep^+ z' = z^T keep^+ z - drop
    rest = m._replace(y=m.y - size * keep_s.reshape(c, nb), floor_rhs=m.floor_rhs - size**2 * info_s)
    if np.any(_band_p_values(rest) <= BAND_P_VALUE):
        return None
    move = m.b @ (_moved_by_levels(m, about_mean).T @ s)  # H^-1 G^T s (Q s): the parameters' move per unit of step
    out = np.full(bread.shape, np.nan)
    # size^2 less its noise's variance (1 / info) is unbiased for the step's square
    out[np.ix_(m.good, m.good)] = m.b + max(size**2 - 1.0 / info_s, 0.0) * np.outer(move, move)
    return TimeStructure(out, OffsetStep(int(channel), float(m.t_start[j]), size, size**2 * info_s))


def _stationary_covariance(m: _BlockMoments, p_values: np.ndarray, bread: np.ndarray,
                           about_mean: bool = False) -> np.ndarray:
    """Stage 2 of :func:`time_correlated_covariance` on stage 1's ``p_values`` (``about_mean``: as
    :func:`structure_in_time`'s; the spectrum is fitted as before, only its move is taken about the mean)."""
    return _process_covariance(m, *_process(m, p_values), bread, about_mean)


def _process(m: _BlockMoments, p_values: np.ndarray, free_floor: bool = True) -> tuple[float, np.ndarray]:
    """The floor's factor (at least -1; zero unless ``free_floor``) and the non-negative spectrum, (bands,
    loadings), of the block sums ``m`` on the bands stage 1's ``p_values`` keep."""
    c = m.y.shape[0]
    loads = _loadings(c)
    outer = np.einsum("vi,vj->vij", loads, loads)
    gram, rhs = _with_floor(m, outer, _quadratic(m, m.y[None]), np.array([m.floor_rhs + m.root.shape[1]]))
    rhs = rhs[0]
    # stage 1: which bands carry structure at all (a score test per band, its null by simulation)
    used = np.tile(p_values[:, None] <= BAND_P_VALUE, (1, len(loads)))
    used[0, c:] = False  # white beyond the floor: each channel's own
    # stage 2: the floor's factor (at least -1) and the spectrum on the bands that carry structure,
    # non-negative: each channel's own process and processes common to each pair of channels, alike or opposed
    return _spectrum(m, gram, rhs, used, free_floor)


def _block_process(m: _BlockMoments, power: np.ndarray) -> np.ndarray:
    """``K``, the block levels' covariance (c nb, c nb), of the spectrum ``power`` (:func:`_process`)."""
    loads = _loadings(m.y.shape[0])
    return _structure(m, power, np.einsum("vi,vj->vij", loads, loads))


def _process_covariance(m: _BlockMoments, floor: float, power: np.ndarray, bread: np.ndarray,
                        about_mean: bool) -> np.ndarray:
    """``(1 + f) H^-1 + H^-1 G^T K G H^-1`` (``Q^T G`` for ``G`` with ``about_mean``), NaN where ``bread`` is."""
    out = np.full(bread.shape, np.nan)
    b, g = m.b, _moved_by_levels(m, about_mean)
    out[np.ix_(m.good, m.good)] = (1.0 + floor) * b + b @ g.T @ _block_process(m, power) @ g @ b
    return out


def _log_likelihood(m: _BlockMoments, covariance: np.ndarray) -> float:
    """Gaussian log-likelihood (less its constant) of the block sums ``m.y`` in ``keep``'s range, their covariance
    ``covariance`` (c nb, c nb); ``-inf`` where that is singular there."""
    basis = m.root / np.linalg.norm(m.root, axis=0)  # keep's eigenvectors over its range
    z = basis.T @ m.y.ravel()
    try:
        lower = np.linalg.cholesky(basis.T @ covariance @ basis)
    except np.linalg.LinAlgError:
        return -np.inf
    return float(-np.sum(np.log(np.diag(lower))) - 0.5 * np.sum(np.linalg.solve(lower, z) ** 2))


def _gain_process(m: _BlockMoments, p_values: np.ndarray, jac, weighted, t_s, bread, block_s, n_bands,
                  carrier) -> tuple[_BlockMoments, float, np.ndarray] | None:
    """The gain carrier's block moments, floor and spectrum where a gain's wander is decisively the likelier reading
    of the block sums ``m`` (stage 1's ``p_values``) than an offset's (module docstring, "A gain's wander: its
    carrier"), else None.  Decisive: twice the log-likelihood ratio over ``DECISIVE_BIC``, with no charge for a
    reading that fits more bands' spectra than the other (each reading's bands are those its own tests found)."""
    g = _block_moments(jac, weighted, t_s, bread, block_s, n_bands, carrier)
    g_values = _band_p_values(g)
    if not np.any(g_values <= BAND_P_VALUE):
        return None
    c, nb = m.y.shape
    sums = np.concatenate([np.bincount(m.block, weights=w, minlength=nb) for w in np.asarray(carrier, dtype=float).T])
    lift = np.diag(sums) - m.summed_jac @ m.b @ g.summed_jac.T  # A (I - P) C: the gain's levels in the block sums
    keep = m.blocks.reshape(c * nb, c * nb)
    # the two readings compared at the floor's nominal factor (f = 0): see the module docstring
    as_gain = keep + lift @ _block_process(g, _process(g, g_values, free_floor=False)[1]) @ lift.T
    as_offsets = keep + keep @ _block_process(m, _process(m, p_values, free_floor=False)[1]) @ keep
    if 2.0 * (_log_likelihood(m, as_gain) - _log_likelihood(m, as_offsets)) <= DECISIVE_BIC:
        return None
    return (g, *_process(g, g_values))


def _spectrum(m: _BlockMoments, gram: np.ndarray, rhs: np.ndarray, used: np.ndarray,
              free_floor: bool = True) -> tuple[float, np.ndarray]:
    """The floor's factor (at least -1; zero unless ``free_floor``) and the non-negative spectrum on the ``used``
    (band, loading) pairs."""
    on = np.concatenate([[free_floor], used.ravel()])
    scale = np.sqrt(np.maximum(np.diag(gram)[on], np.finfo(float).tiny))
    half, target = _half_system(gram[np.ix_(on, on)] / np.outer(scale, scale), rhs[on] / scale)
    lower = np.r_[np.full(int(free_floor), -1.0), np.zeros(int(used.sum()))] * scale
    solution = np.zeros(on.size)
    solution[on] = lsq_linear(half, target, bounds=(lower, np.inf)).x / scale
    return float(solution[0]), solution[1:].reshape(used.shape)


def _structure(m: _BlockMoments, power: np.ndarray, outer: np.ndarray) -> np.ndarray:
    """``K = sum_kv power_kv (outer_v kron B_k)``, the block processes' covariance, (c nb, c nb)."""
    c, nb = m.y.shape
    return np.einsum("kv,vad,kij->aidj", power, outer, m.bands, optimize=True).reshape(c * nb, c * nb)

