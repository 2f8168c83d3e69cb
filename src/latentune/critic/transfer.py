"""Phase 3 that uses everything the source run learned: a model of the target built from the
source's trials and the target's own, a measured agreement that decides how much the source is
trusted, and a search that moves between the latent box and the full θ box.

:class:`Transfer` is a critic on the full normalized θ box ``[0, 1]^d`` (a two-space critic like
:class:`~latentune.critic.handover.Handover`: latent-pool points carry their codes in
:attr:`Transfer.last_z`). It is built from the source run's trials ``(X_s, y_s, fell_s)``
(every θ the source tried, (N, d), with its cost and fall flag), the source's latent space (the
map D) and the target's manual θ.

The model of the target
-----------------------
A GP on the target's cost ranks whose prior mean is a scaling, ``a``, of a source model,
with ``a`` (the *agreement*) measured from the target's own trials at every ask, and the
same construction on the fall flags: :mod:`latentune.critic.transfer_model`.

The search (every ask; every decision is kept in :attr:`Transfer.decisions`)
---------------------------------------------------------------------------
Candidates come from three pools:

* ``elite``: the source's best *diverse* θ (greedy: best first, each at least ``elite_spacing``
  from those chosen, in the unit box) and the target's manual θ, until evaluated;
* ``latent``: Sobol codes in a box around the code of the target's best θ in the latent box,
  decoded (D);
* ``full``: TuRBO-style perturbations of the target's best θ in a box of side ``L`` shaped by the
  source's lengthscales (a coordinate is perturbed with probability ``min(20/d, 1)``); with
  ``full_scales`` = s > 1 the pool is split evenly over the sides ``L, 2L, …, 2^(s-1) L`` (capped
  at ``length_max``), so the model, not the trust region alone, chooses how far to step;
* ``global``: a share ``global_share`` of the candidates drawn over the whole θ box (Sobol).

The first ``n_design`` own points come from the elite pool only (the initial design); while
every trial so far fell, the next one is the target's manual θ (once). After it,
the latent pool's share is ``w_lat = clip(agreement, 0, latent_share_max)``, set to 0 once at
least ``latent_falls`` latent-pool trials fell and they fell more often than not; the full pool
gets the rest. ``L`` follows TuRBO's rule on the full box (doubling after ``succ_tol``
improving batches, halving after ``fail_tol`` batches without one); by default a batch improves
when it beats the best by more than ``1e-3`` times the spread of the target's standing costs
(``success_scale="spread"`` below), not times ``|best|``, so a constant in the cost does not
decide when the region shrinks. A candidate whose predicted
fall probability (its posterior mean plus ``fall_kappa`` standard deviations: an upper
confidence bound, as in safe Bayesian optimization) exceeds ``max_fall_prob`` is skipped (if fewer than the batch remain, the least
likely to fall are kept); among the rest each point of the batch is the argmin of one joint
Thompson sample of the cost model. By default every second ask after the design is an explore
ask (``explore_every`` below): its candidates are decoded codes of the whole latent box or lines
through the best θ, whichever pool has made more records on the target
(``explore_pool="adaptive"``), and ``L`` follows the other asks only.

Options that change the model and the choice (:data:`TRANSFER_DEFAULTS`): ``fit_lengthscale``
lets the target cost model choose, with σ_r², a multiplier of the source's lengthscales
(0.25–2, by marginal likelihood); ``acquisition`` ``"ei"`` takes the candidates of highest
expected improvement over the best told value instead of Thompson samples; ``restart`` sets
``L`` back to ``length_init`` when halving it would go below ``length_min``; ``fit_ard`` = k > 0
fits, once the target has k trials, the residual kernel's ARD lengthscales and σ_r² by marginal
likelihood (GPyTorch, a log-normal prior around the source's lengthscales;
:func:`fit_residual_kernel`) and shapes the full pool's box with them; ``design_screen`` lets
the fall screen end the initial design when it rejects every remaining elite;
``safe_fallback``: when the screen admits fewer candidates than the batch, perturbations of the
centre on shrinking sides (``L/2 … L/2^8``) join the candidates before the least likely to fall
are kept, so the search steps back toward its safe trial rather than asking over the screen
(``"region"``: on the trust-region asks only, braked as the explore asks are after
``explore_falls`` fallen fallback trials); ``fall_budget`` = q in (0, 1) with the constructor's
``budget`` (the target trials the run will hold, told ones included): once ``max(1, ⌊q ·
budget⌋)`` of the target's trials fell and one stands, every ask is the best standing θ
(:attr:`Transfer.fall_budget_spent`; the phase loop stops there), a trade of the rest of the
search for no more falls on a target where each costs a robot (``fall_budget_counts``:
``"after_stand"``, the default, counts only the falls after the first trial that stood, those
taken while a standing θ was in hand; ``"all"`` every fall);
``record_walk`` = k > 0 (default 0: off): once the target has tried θ of the source's record
(the zero-shot θ, the design's elites; the manual θ aside) and every one of them fell, the next
k asks after the design walk down the source's standing trials ranked by cost, one per rank
quantile (i + 1)/(k + 1), i = 0 … k − 1: at each, the best-ranked θ no told trial has and at
least ``elite_spacing`` from every told fall (a rule ask in pool ``elite``, recorded with its
``walk_rank``); the walk ends once one of them stands. A step whose θ is one of the
elite pool's (the source's diverse best, which may lie deep in the ranks) is not counted
among the k, so a walk can take more than k asks (up to 6 for k = 3 in the ladder's runs).
Where a gap moves the fall boundary
through the source's best region, the θ the source tried on the way there, farther from its
optimum, are the ones that stand (``benchmarks.transfer_reach``); ``walk_pick`` (default
``"rank"``, the rule above) chooses each step among the same candidates with the target fall
model instead: ``"fall"``, the least likely to fall over the whole record; ``"band"``, the
least likely to fall among ranks (i + 1)/(k + 1) to (i + 2)/(k + 1) (recorded as
``walk_fall_prob``). On the stored runs where the record fell, a deeper rank and a lower fall
probability both go with standing (``benchmarks.transfer_walk``);
``fall_cost``: the acquisition counts the fall among the outcomes of a candidate, with the fall
model's posterior mean ``p(θ)`` (clipped to [0, 1]) as its probability: a Thompson sample ``s(θ)``
of the cost rank score becomes the expected score ``(1 − p) s + p s_fall`` (``s_fall``: the
mean score of the target's falls, or the last rank's score before any fall), also in the
lowest-bound preselection, and expected improvement becomes ``EI · (1 − p)`` (constrained EI,
Gardner et al. 2014): among the candidates the screen admits, the less likely to fall win ties
in cost; ``stop_converged``: once the trust region has converged (``fail_tol`` batches without
an improving one at side ``length_min``, where TuRBO ends or restarts a region; ``restart``
restarts it instead), every later ask is the centre itself (the best θ that did not fall, tag
pool ``full``): the search stops perturbing an incumbent whose remaining gain it cannot
resolve, where every perturbation risks a fall near a fall boundary; ``success_scale`` (default ``"spread"``): a batch
improves (TuRBO's success) when it beats the best by more than ``1e-3`` times ``|best|``
(``"best"``, TuRBO's rule) or times the spread of the target's standing costs told before it,
median minus best (``"spread"``: the same for any constant added to the cost, so a small gain
near an optimum counts when it is large against what the target's trials vary by).
``source_order`` (default ``"canonical"``): the source's trials are used sorted by
(cost, fell, θ) (:func:`canonical_order`), so the fitted subset, the source models and the elite
pool depend on the set of trials alone, not on the order a parallel phase 1 stored them in
(completion order); ``"stored"`` uses them as given (runs stored before the option existed).

``explore_every`` = k ≥ 2 (0: off; default 2) makes every k-th ask an *explore* ask: generation ``g`` is
one when ``g % k == k − 1`` and the ask is not an initial-design ask of the elite pool, the
manual θ after falls, nor the converged centre (``stop_converged``). Its candidates are
``n_candidates`` Sobol codes over the whole latent box (side 1, not ``2L`` around the centre's
code), decoded as the latent pool's (tag pool ``latent``); without a latent space, Sobol points
over the whole θ box (tag pool ``global``). The fall screen applies as usual (without
``safe_fallback``'s centre perturbations), and the batch is chosen among these candidates alone
as every batch is (Thompson samples of the cost model by default): the model chooses where in
the decoded manifold to look, and perturbations of the centre cannot take the slot. The told
history recognises an explore generation by the same rule (``g % k == k − 1`` and none of its
trials in pool ``elite`` or ``full``). Explore generations leave ``L`` and its counters alone
(and ``handoff_fall_shrink``'s rule; the trust region follows the other batches only) and do
not count in the latent pool's fall record (``latent_falls``); their trials are data for the
models and raise the best value a later batch must beat, and an explore trial that becomes the
best moves the centre, as any trial does. Each decision records ``"explore"``.
``explore_pool`` (default ``"adaptive"``, below) says where an explore ask's candidates come from:
``"latent"``, decoded codes of the whole latent box as above; ``"source"``, ``n_candidates`` θ
drawn from the source's promising distribution (the Gaussian that warm-starts CMA-ES from a
source task, Nomura et al. 2021, fitted to the top 10 % of the source's trials that did not
fall; tag pool ``global``); ``"both"``: half of each, so the model chooses between the decoded
manifold and the source's spread over the full θ box; ``"auto"``: the latent box while every
trial on the target fell (decoded codes are the way out where the source's θ all fall), the
source's distribution once a trial stood, until its draws fell more often than the fall screen
admits (``explore_falls`` counted on the source's draws alone), then the latent box again
under its own brake; ``"box"``: ``n_candidates`` Sobol points over the whole θ box (tag pool
``global``), where neither the source's manifold nor its distribution bound the search: the fall
screen and the brake are what keep it off the falls; ``"lines"``: ``n_candidates`` copies of the
centre with one coordinate (half of them) or two (the other half), chosen uniformly (or, with
``lines_pick="fall"``, in proportion to the source fall model's lengthscales), set
uniformly over [0, 1] (tag pool ``global``): steps as far as the box's faces that keep the rest
of the standing θ, for a gap that moves the best value of a few gains (a payload, friction)
beyond the region the source's trials support. While every trial on the target fell there is
no standing θ to draw lines through, and ``"lines"`` asks decode codes of the whole latent box
as ``"latent"`` does (the whole θ box without a latent space). ``"cma"``: ``n_candidates`` draws
of a CMA-ES that starts from the source's promising distribution (as ``"source"``) and is told
every target trial, a population at a time (:meth:`Transfer._pool_cma`; tag pool ``global``);
the ask runs its first draw the fall screen admits, in CMA-ES's own order rather than the
model's, or where the screen admits none, the draw least likely to fall. ``record_cma``
(default off) hands every ask after the design to that CMA-ES, screened at ``max_fall_prob``,
once the source's record fell on the target (:meth:`Transfer.record_fell`: every θ of the
source's trials the target ran fell; the trigger of ``record_walk``). ``"latent_lines"``: half the
candidates are decoded codes of the whole latent box, half lines through the centre, so the
model chooses at each explore ask between a step along the source's manifold (many gains
together, what a 77-weight robot's explore asks gain by) and one gain or two moved as far as
the box's faces (what a payload on a 21-weight arm needs); while no trial stands, the latent
box alone. ``"adaptive"``: each explore ask takes one pool whole, decoded codes of the whole
latent box or lines through the centre, chosen from the target's own record of the two: every
told explore generation counts as an ask of its pool (tag pool ``latent`` or ``global``) and as
a record when its best standing trial improved on the best before it (TuRBO's success rule, as
``explore_adapt`` counts); the next explore ask takes the pool with the higher
``(records + 1) / (asks + 2)`` (the mean of a uniform prior's posterior on the pool's record
rate), the latent box on a tie. The decoded manifold goes first and keeps the explore asks while
at least half of them make records; lines are tried once it falls below that and keep the asks
while they do better. While no trial stands, the latent box. Each explore decision records the
two pools' ``[asks, records]`` (``explore_record``). Without a latent space, ``"lines"``.
``explore_fall_weight`` = w > 0 (default 0: off) weighs the falls into that record: an explore
generation in which a trial fell counts as ``w`` records less, so a pool scores
``(records − w · falls + 1) / (asks + 2)`` and ``explore_record`` holds
``[asks, records, falls]``; on a target where one pool's steps fall as often as they find
records, the other pool takes the explore asks.
``explore_record`` (default ``"count"``): ``"gain"`` weighs each record in that score by its
size: a record that lowered a standing best counts as its drop in cost over the mean drop of
both pools' such records (a first standing trial as 1), so records of equal size score as their
count, and a pool that keeps making small records (one gain nudged) cannot hold the explore
asks from one whose records were large (many gains moved together along the source's
manifold). ``explore_record`` then holds ``[asks, records, falls, drop, records with a drop]``.
``explore_bandit`` (default ``"mean"``): how ``"adaptive"`` chooses from the two scores: the
higher one (the posterior mean of the record rate), or with ``"thompson"`` the higher of one
draw from each pool's Beta posterior (``a`` = score · (asks + 2), ``b`` = asks + 2 − ``a``;
Thompson sampling, the two-armed bandit's rule), seeded by the run's seed and the generation so
a replay chooses the same pool. The mean gives every ask to the pool ahead on its record, and a
pool that fell behind after one or two asks is never asked again; the draws give it asks in
proportion to the chance that its rate is the higher one.
``explore_void`` (default False): a record an explore ask made holds only once the trust region
around it stands. When more than ``max_fall_prob`` of the first region generation told after it
(the next generation that is neither an explore nor a design ask) fell, the record is void: the
explore trials that beat the best before them stop being the centre (it is the best standing
trial that is not void), the best value the success rule counts from goes back to the best of
the trials that are not void, and with ``"adaptive"`` the ask counts for its pool as one without
a record. A step that lands a standing θ on the edge of a cliff (one gain moved to a face on a
legged robot that only just stands) then moves the search once, not for the rest of the run.
The told history replays the voids (``explore_void`` in each decision: the number so far).
``centre_screen`` (default False): the centre the trust region, the lines and the latent box
around the best θ are drawn about is the best standing trial whose θ the fall screen admits
(the target fall model's bound ≤ ``max_fall_prob``, the same bound the candidates pass), not
the best standing trial when the falls around it put it over the bound; when the screen admits
no standing trial, the best one. On a target whose best trial only just stands (a third of the
trials around it fall), the search moves to the best trial whose neighbourhood stands instead
of asking around a θ the model already expects to fall. Each ask that moved the centre records
``centre_screened``.
``explore_fall_prob`` = q > 0 (default None: ⅔ of ``max_fall_prob``, 0.2 at its default, since
session 39; 0: off) screens an explore ask's candidates at the bound q (at most
``max_fall_prob``) instead of ``max_fall_prob``; when fewer than the batch pass it, at
``max_fall_prob`` as every ask (then the least likely to fall, as every ask): an explore
ask is a step the local search does not need, so it may take less risk. Each explore decision
records the bound it applied (``explore_bound``).
``explore_skip`` (default False): an explore ask whose pool holds fewer candidates the fall
screen admits (at ``max_fall_prob``) than the batch is not made, once a trial on the target
stands: the generation asks the trust region's full pool around the centre instead (tag pool
``full``, so the told history replays it as a region ask: ``L`` and its counters follow it).
Without it such an ask takes the candidates least likely to fall, all of them over the bound.
While every trial fell the explore asks are made (they are the way out). Each skipped ask
records ``explore_skipped``. A skipped pool teaches the fall model nothing, so on a target
where the screen overrates the explore pool's risk every later explore ask is skipped too.
``fall_calibrate`` (default False): the fall screen's probability is calibrated on the
target's own outcomes. The score above (the fall model's upper confidence bound) ranks θ by risk
but is no fall rate: a target may fall at a tenth of it or at twice it. Each told θ is scored
by the fall model fitted on the trials told before it (:meth:`Transfer.prequential_scores`:
out-of-sample), and a Platt map ``P(fall) = σ(a + b · logit s)`` is fitted to those scores and
the outcomes (:func:`fit_calibration`: a prior around the identity map ``(a, b) = (0, 1)``, so
with few outcomes the score stands). Every use of the probability (the screen at
``max_fall_prob``, ``explore_fall_prob``, ``design_screen``, ``centre_screen``,
``safe_fallback``, and ``fall_cost``'s probability of the fall outcome) takes the calibrated
value, so a bound is a fall rate the target's record supports. Each decision records ``(a, b)``
(``fall_calibration``).
``explore_gp`` (default True since session 39): an explore ask of the lines (``"lines"``, or
``"adaptive"`` resolved to them) is chosen by a GP on the target's trials alone (:class:`TargetGP`: no
source prior), not by the transfer model, and over a wider pool: half the lines through the
centre, as many Sobol points over the whole θ box, and the local maxima of that GP's log
expected improvement (L-BFGS-B from the best of those, :func:`log_expected_improvement`), which
end on the box's faces and corners. With ``"latent_lines"`` the lines' half of the pool is
widened so, and the decoded codes of the whole latent box stay in it: the target's own GP
weighs a step along the source's manifold against a line, a Sobol point or a maximum at every
explore ask (a code rarely outscores a local maximum of the same log EI). The fall screen
applies as at every ask; among the candidates it admits, the batch is the highest log expected
improvement. Where the gap moves the best θ to a region the source ranks as bad (the arm's
gravity gain at its face), the source's prior keeps the transfer model's samples away from it;
the target's own model, as Optuna's GPSampler fits it, goes there once the target's trials say
so. The adaptive record counts these asks as the lines'. With ``fall_cost`` the choice is the
highest ``log EI + log(1 − p)`` (constrained EI, ``p`` as ``fall_cost`` takes it). Each such
decision records ``explore_gp``.
``region_gp`` (default False): a trust-region ask (neither an explore ask nor a design ask)
made while the adaptive record's next explore pool is the lines (the target's own GP has led
the explore asks) is chosen as ``explore_gp`` chooses: its pool (elites, the full box around
the centre, the latent box) gains as many Sobol points over the θ box and the local maxima of
the target GP's log EI from the :data:`~latentune.critic.transfer_model._GP_STARTS` best of
all, and the ask is the highest log EI the fall screen admits (at ``max_fall_prob``). ``L``
and its counters follow it as any region ask. Such a decision records ``region_gp``. With ``region_gp="screened"`` such an ask
is screened as an explore ask is: at ``explore_fall_prob`` first, at ``max_fall_prob`` when
fewer than the batch pass (recorded as ``explore_bound``): an ask the target's own GP moves out
of the trust region's choice, toward the box's faces, takes the explore asks' smaller risk.
``fall_shrink`` (default False): the same rule for falls in the early phase. A trust-region
generation (neither an explore ask nor a design ask of the elite pool) in which more than
``max_fall_prob`` of the trials fell halves the side ``L`` (once, at least ``length_min``) and
resets the counters, once a trial on the target stands: a step of side ``L`` around the centre
fell, so the next steps are shorter. The told history replays it as it replays ``L``.
``centre_falls`` = k > 0 (default 0: off): a standing trial at least k of whose neighbours
fell (other told trials within 0.05 of it in every coordinate of the unit box,
:data:`_FRAGILE_STEP`), more often than ``max_fall_prob`` of them, is *fragile*: the
centre of the trust region, the lines and the latent box is the best standing trial that is
neither fragile nor void (``explore_void``), or the best standing trial when every one is.
The fall model cannot tell a θ that only just stands from its neighbours that fall (on such
targets its score hardly separates them: ``fall_calibrate``'s map), but the falls around it
are observed: the search leaves a centre whose own small steps fall. The best value the
success rule counts from is unchanged. Each decision records the number of fragile trials
(``centre_fragile``).
``fall_rank`` (default ``"clipped"``) orders the candidates "least likely to fall" is taken
from when fewer than the batch pass the fall screen: ``"clipped"``, by the screen's probability
(the bound clipped to [0, 1]); ``"bound"``, by the bound before clipping
(:meth:`Transfer._fall_bound`); ``"mean"``, by the fall model's posterior mean before clipping.
Once the target's trials fell, the bound exceeds 1 on most candidates; clipped, they all tie at
1, and the candidates kept are the first generated (the source's best elites during the design,
whose neighbours on the target just fell). Unclipped, the bound is lowest where the model is
surest, next to the trials that fell, so ``"bound"`` asks there; the mean is lowest where the
model expects a trial to stand. Each decision with ``"bound"`` or ``"mean"`` records the largest
value of its order asked (``max_fall_rank_asked``).
``distinct`` (default True; False before session 30, so stored runs resume as they ran): an
ask never picks a θ the target has run, nor one θ twice in a batch (equal to 1e-9): the choice
passes over such candidates to the next best (each ask that did so records
``repeats_avoided``). The candidates themselves are unchanged, so an ask whose choice had no
repeat picks what it picked before. When fewer candidates than the batch are new, the repeats
are dropped and perturbations of the centre in the full pool added (``duplicates_dropped``:
how many were dropped). Without it, a small θ (a 3-weight system: a 2-dim latent space whose
decoder maps a region of codes to one θ) or fewer elites than the batch made a batch ask one θ
several times, and the Optuna sampler, which refuses a θ the study has, stopped.
``explore_when="stalled"`` makes a due generation an explore ask only while the side it is asked
at is ``length_min`` (the trust region has nothing left to resolve near its centre); the other
due generations are ordinary asks, so the local search keeps every ask while it still improves.
``explore_falls`` = k > 0 (default 3; 0: never) stops the explore asks for good once at least k
explore trials fell and they fell more often than ``max_fall_prob`` (the risk the fall screen
admits), once the target holds a trial that did not fall: the fall model underrates the whole
box's risk on this target, and later due generations are ordinary asks. While every trial fell
the explore asks go on (they are the way out of a target where the source's θ all fall). The
replay applies the same rule in generation order.
``explore_adapt`` (default False) lets the explore asks earn their slots: the interval between
due generations starts at ``explore_every`` = k, doubles (to at most ``8k``) after each explore
generation whose best standing trial did not improve on the best before it (TuRBO's success rule
with ``success_scale``), and returns to k after one that did; a due generation that is not an
explore ask (design, manual, converged) keeps the interval. Where the decoded manifold holds
nothing better than the region around the centre, the region asks get the budget; where explore
asks keep finding records they keep coming every k-th ask. The schedule is replayed from the
told history like the side ``L``.
``full_shape`` (default ``"lengthscales"``): the full pool's box has sides ``L · w_i``,
``w_i`` the lengthscales (the source's, or the fitted ones) over their geometric mean, clipped to
[0.25, 4], as TuRBO shapes its region; ``"cube"`` gives every coordinate the side ``L``. A
coordinate the source's cost is most sensitive to has the shortest lengthscale and so the
narrowest side, yet a change of the system (a payload, friction) moves the optimum of such a
gain first: the cube lets the region follow it.
``tilt`` = t > 0 (default 0: off) adds a linear drift to the target cost model:
``z(θ) = a · m_s(θ) + b + cᵀ(θ − ½) + r(θ)`` with ``c ~ N(0, σ_t² I)`` integrated out like
``(a, b)`` (the basis ``h`` gains the columns ``σ_t (θ − ½)``); ``σ_t`` is chosen with ``σ_r²``
by marginal likelihood from ``(0, t/4, t/2, t)`` at every ask and recorded as the decision's
``"tilt"``. The residual ``r`` reverts to the source's prior a lengthscale away from the
target's trials; the drift does not, so where the target's trials show the cost falling along a
coordinate, the model predicts it goes on falling beyond them (a gap that moves a gain's best
value toward a face).
``fall_source_sd`` (default False) adds the source fall model's own posterior variance to the
fall screen's bound (``fall_kappa`` times the root of the target fall model's variance plus the
source's): far from every source trial the source's fall model only knows its prior mean, and
the screen then treats such θ as unknown rather than as safe as the source's average.
``fall_fit`` (default False): the target fall model's hyperparameters are chosen on the target:
a multiplier of the source's fall lengthscales (0.25–2) and the nugget, the variance of the fall
flags' noise (0.01, 0.05 or 0.15; 0.01 without it), by marginal likelihood with σ_r² at every ask.
Where standing and fallen θ lie closer together on the target than the source's lengthscales say
(a θ that only just stands, whose small steps fall), the model chooses a shorter lengthscale or a
larger nugget and no longer predicts "stands" for every small step from a standing trial; each
decision records the choice (``fall_fit``: ``[multiplier, nugget]``).
``face_snap`` = p > 0 (default 0: off): in the full pool every coordinate whose region reaches
a face of the unit box (``[lb, ub]`` clipped at 0 or 1) is set to that face with probability
p (the nearer one when it reaches both), before the perturbation mask: the candidates include
the region's faces and corners, where a gain's best value on the target often lies (its bound)
and where expected improvement maximized over the box by a gradient method ends, while a
uniform draw inside the region reaches them with probability 0. The model chooses among them as
among the others, and the fall screen applies.
``escape_falls`` = k > 0 (default 0: off): once at least k target trials were told and every
one fell, an explore ask takes, among ``n_candidates`` Sobol points over the whole θ box, the θ
farthest from every told trial and from those it chose before (a greedy maximin design;
recorded as ``escape``): a way off the source's manifold for a target that falls wherever the
source stood. Where the target's stable θ lie near the source's (the physical targets measured,
``results/transfer/escape``) the box's far corners fall, so it is not the default.
``target_scores`` (default ``"ranks"``): what the target's cost model fits, the costs'
Gaussian-copula rank scores or (``"values"``) their standardized values, falls one sd above the
worst standing trial (:func:`~latentune.critic.transfer_model.value_scores`): values keep how
much better a trial is, which ranks hide (on a smooth bowl without falls GPSampler, a GP on
values, ends far lower: ``results/transfer/bowl``); screened there, not the default.
``"warped"``: the standing costs' values through a Yeo-Johnson power warp fitted to them
(:func:`~latentune.critic.transfer_model.warped_scores`), which pulls in a tail of bad costs.
``"auto"``: at every ask both models (ranks and warped values) are fitted to the target's
trials and the one whose leave-one-out predictions put fewer pairs of those trials in the wrong
order (RGPE's ranking loss; falls below every standing trial, pairs of two falls not counted)
is used; ranks on a tie and while fewer than :data:`AUTO_MIN_STANDING` trials stood. The
choice and both losses are recorded (``auto_scores``: ``{model: [scores, loss of ranks, loss
of warped]}``). Values are earned on the target, not assumed.
``refine_scores`` (default None: ``target_scores``'s): the scores of the cost model the
refinement asks choose by (the asks that are neither the design, an explore ask nor a rule's);
the agreement, the pools and the explore asks keep ``target_scores``'s model. Ranks are robust
where falls and jumps dominate the record; near the best θ, values say where it is lower.
``explore_scores`` (default None: ``target_scores``'s): the scores of the target's own GP that
the ``explore_gp`` and ``region_gp`` asks choose by (their expected improvement); the rest keeps
``target_scores``'s model.
``stand_first`` (default False): while every trial on the target fell, a batch that falls too
leaves ``L`` and its counters alone: there is no incumbent it could fail to improve on, so the
trust region that starts at the first standing trial starts at side ``length_init``, not at a
side halved by the falls before it (recorded as every decision's ``length``).

The late phase (``handoff`` = k > 0): the asks made once the target has k own (tagged) trials
follow TuRBO-m's rules (:class:`~latentune.critic.turbo.TurboM` with one region and batch 1:
its ``success_tol``, its ``failure_tol`` counted in evaluations, its side bounds), the side
carrying on from the transfer's side at the hand-off, the counters reset
(``handoff_rules="transfer"`` keeps the early phase's rules: only the model changes); and their
cost model is ``handoff_model``: ``"target"``, a GP on the target's trials alone fitted as
TuRBO-m fits a region's GP (:class:`TargetGP`: constant mean, Matérn-5/2 ARD by marginal
likelihood on the standardized rank scores, a cold fit at every ask); ``"prior"``, the transfer
model ``a·m_s + b + r`` with the residual's ARD lengthscales and σ_r² fitted as ``fit_ard`` fits
them; ``"transfer"``, the transfer model as before (only the side rules change). With
``"target"`` and ``"prior"`` the full pool's box takes its shape from the fitted lengthscales.
The agreement, the latent share, the fall model and its screen are those of the early phase.
``handoff_fall_shrink`` adds TuRBO-m's rule for falls as the pipeline's fall-aware TuRBO-m runs
it (``fall_shrink`` = ``max_fall_prob``; "Falls" in :mod:`latentune.critic.turbo`): a late
generation in which more than that share of the trials fell halves the side (once) and resets
the counters, when the target holds a trial that did not fall.

Tags and resume
---------------
``tag = 4 · generation + pool`` (pool 0 elite, 1 full, 2 latent, 3 global). The critic's state (``L``, the
counters, the latent share, the hand-off: the number of own trials told before a generation) is
a function of the told history, so a fresh critic told the stored
rows asks what the original would have asked; the options and the source models' fitted
hyperparameters are :meth:`Transfer.state_dict` (a resume or an ask/tell call does not refit
them, and asks with the options the run was started with).
Untagged points (the zero-shot and manual trials) are data for the models and the centre.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from latentune.checks import is_whole
from latentune.critic.base import TwoSpaceCritic, as_unit_points
from latentune.critic.transfer_model import (LS_SCALES, SourceModel, TargetGP, TargetModel,
                                             agreement_unmeasured, calibrated, fit_calibration, fit_residual_kernel,
                                             gp_maxima, jittered_cholesky, rank_scores,
                                             ranking_loss,
                                             target_fall_model, value_scores,
                                             warped_scores)
from latentune.wording import counted

log = logging.getLogger(__name__)

ELITE, FULL, LATENT, GLOBAL = 0, 1, 2, 3
POOL_NAMES = {ELITE: "elite", FULL: "full", LATENT: "latent", GLOBAL: "global"}

TRANSFER_DEFAULTS: dict[str, Any] = {
    "max_fall_prob": 0.3, "n_design": 3, "n_elite": 16, "elite_spacing": 0.15,
    "n_candidates": 1000, "length_init": 0.5, "length_max": 1.0, "length_min": 1 / 128,
    "succ_tol": 2, "fail_tol": 3, "latent_share_max": 0.5, "latent_falls": 3,
    "max_points": 300, "fall_kappa": 1.0, "fit_lengthscale": False, "acquisition": "thompson",
    "restart": False, "full_scales": 1, "global_share": 0.0, "design_screen": False,
    "fit_ard": 0, "safe_fallback": False, "fall_cost": False, "handoff": 0,
    "handoff_model": "target", "handoff_fall_shrink": False, "handoff_rules": "turbo",
    "stop_converged": False, "success_scale": "spread", "explore_every": 2,
    "explore_when": "always", "source_order": "canonical", "explore_falls": 3,
    "stand_first": False, "explore_pool": "adaptive", "explore_adapt": False,
    "full_shape": "lengthscales", "tilt": 0.0, "lines_pick": "uniform",
    "fall_source_sd": False, "face_snap": 0.0, "explore_void": False,
    "explore_fall_weight": 0.0, "centre_screen": False, "distinct": True,
    "explore_fall_prob": None, "explore_skip": False, "fall_calibrate": False,
    "fall_shrink": False, "centre_falls": 0, "fall_rank": "clipped", "explore_gp": True,
    "explore_record": "count", "explore_bandit": "mean", "region_gp": False,
    "fall_fit": False, "fall_budget": 0.0, "fall_budget_counts": "after_stand",
    "record_walk": 0, "walk_pick": "rank", "record_cma": False, "escape_falls": 0,
    "target_scores": "ranks", "refine_scores": None, "explore_scores": None,
}
"""The options of :class:`Transfer` (see the module docstring); recorded in its state, where
``explore_fall_prob`` is resolved (:func:`resolved_options`)."""


def resolved_options(options: dict[str, Any]) -> dict[str, Any]:
    """Every option of :class:`Transfer` given ``options`` (a subset of :data:`TRANSFER_DEFAULTS`):
    the defaults, with ``explore_fall_prob``'s default (None) resolved to ⅔ of ``max_fall_prob``
    (0.2 at its default 0.3), so a smaller ``max_fall_prob`` keeps the explore asks' bound below
    it. A ``max_fall_prob`` that is not a number leaves None for the constructor to refuse."""
    opts = {**TRANSFER_DEFAULTS, **options}
    p = opts["max_fall_prob"]
    if opts["explore_fall_prob"] is None and isinstance(p, (int, float)) \
            and not isinstance(p, bool):
        opts["explore_fall_prob"] = round(2.0 * float(p) / 3.0, 12)
    return opts

WHOLE_OPTIONS: dict[str, int] = {"n_design": 0, "n_elite": 0, "n_candidates": 1,
                                 "max_points": 2, "succ_tol": 1, "fail_tol": 1,
                                 "latent_falls": 0, "fit_ard": 0, "full_scales": 1,
                                 "handoff": 0}
"""Options that count something, with the least whole number each takes."""


def check_numbers(opts: dict[str, Any]) -> None:
    """ValueError, naming the option, when a counting option (:data:`WHOLE_OPTIONS`) is not a
    whole number at or above its least value, a trust-region side (``length_min``,
    ``length_init``, ``length_max``, in units of the unit box) is not a finite positive number
    or ``length_min`` exceeds ``length_max``, ``elite_spacing`` or ``fall_kappa`` is not a
    finite number ≥ 0, or ``latent_share_max`` is not a share in [0, 1]."""
    def number(v: Any) -> bool:
        return isinstance(v, (int, float, np.integer, np.floating)) and not \
            isinstance(v, (bool, np.bool_)) and math.isfinite(float(v))

    for key, low in WHOLE_OPTIONS.items():
        if not is_whole(opts[key], low):
            raise ValueError(f"{key} must be a whole number ≥ {low}, got {opts[key]!r}")
    for key in ("length_min", "length_init", "length_max"):
        if not (number(opts[key]) and float(opts[key]) > 0):
            raise ValueError(f"{key} must be a positive side of the unit box, got {opts[key]!r}")
    if float(opts["length_min"]) > float(opts["length_max"]):
        raise ValueError(f"length_min ({opts['length_min']!r}) must not exceed length_max "
                         f"({opts['length_max']!r})")
    for key in ("elite_spacing", "fall_kappa"):
        if not (number(opts[key]) and float(opts[key]) >= 0):
            raise ValueError(f"{key} must be a finite number ≥ 0, got {opts[key]!r}")
    if not (number(opts["latent_share_max"]) and 0.0 <= float(opts["latent_share_max"]) <= 1.0):
        raise ValueError(f"latent_share_max must be a share in [0, 1], "
                         f"got {opts['latent_share_max']!r}")


ADDED_OPTIONS: dict[str, Any] = {"design_screen": False, "fit_ard": 0, "safe_fallback": False,
                                 "fall_cost": False, "handoff": 0, "handoff_model": "target",
                                 "handoff_fall_shrink": False, "handoff_rules": "turbo",
                                 "stop_converged": False, "success_scale": "best",
                                 "explore_every": 0, "explore_when": "always",
                                 "source_order": "stored", "explore_falls": 0,
                                 "stand_first": False, "explore_pool": "latent",
                                 "explore_adapt": False, "full_shape": "lengthscales",
                                 "tilt": 0.0, "lines_pick": "uniform",
                                 "fall_source_sd": False, "face_snap": 0.0,
                                 "explore_void": False, "explore_fall_weight": 0.0,
                                 "centre_screen": False, "distinct": False,
                                 "explore_fall_prob": 0.0, "explore_skip": False,
                                 "fall_calibrate": False, "fall_shrink": False,
                                 "centre_falls": 0, "fall_rank": "clipped",
                                 "explore_gp": False, "explore_record": "count",
                                 "explore_bandit": "mean", "region_gp": False,
                                 "fall_fit": False, "fall_budget": 0.0,
                                 "fall_budget_counts": "all", "record_walk": 0,
                                 "walk_pick": "rank", "record_cma": False,
                                 "escape_falls": 0, "target_scores": "ranks",
                                 "refine_scores": None, "explore_scores": None}
"""Options added after :meth:`Transfer.state_dict` recorded the options, with the value their
behaviour had before they existed: a stored run without them resumes with these."""

LEGACY_OPTIONS: dict[str, Any] = {**TRANSFER_DEFAULTS, **ADDED_OPTIONS, "max_fall_prob": 0.3,
                                  "length_init": 0.3,
                                  "fit_lengthscale": False, "acquisition": "thompson",
                                  "restart": False, "full_scales": 1, "global_share": 0.0}
"""The options of runs stored before :meth:`Transfer.state_dict` recorded them."""

NEUTRAL_OPTIONS: dict[str, Any] = {
    k: v for k, v in TRANSFER_DEFAULTS.items()
    if k != "max_fall_prob" and ADDED_OPTIONS.get(k, v) == v and LEGACY_OPTIONS.get(k, v) == v}
"""The options whose default every stored run resumes with too (the same value in
:data:`TRANSFER_DEFAULTS`, :data:`ADDED_OPTIONS` and :data:`LEGACY_OPTIONS`: ``fall_budget`` 0,
``record_walk`` 0, ``target_scores`` ``"ranks"``, …): given at it, such an option is the option
left out (:func:`same_options`). ``max_fall_prob`` is not among them: the phase's own option
sets it."""


def same_options(old: dict[str, Any] | None, new: dict[str, Any] | None) -> bool:
    """Whether two records of a phase 3's ``transfer_options`` (None: none given) run the same
    critic: equal once the options given at their :data:`NEUTRAL_OPTIONS` value are left out
    (``{"fall_budget": 0.0}`` is None; ``{"explore_gp": True}``, the default today but not
    what a run stored before it resumes with, is not)."""
    def given(opts: dict[str, Any] | None) -> dict[str, Any]:
        return {k: v for k, v in (opts or {}).items()
                if not (k in NEUTRAL_OPTIONS and v == NEUTRAL_OPTIONS[k]
                        and isinstance(v, bool) == isinstance(NEUTRAL_OPTIONS[k], bool))}
    return given(old) == given(new)


EXPLORE_RECORDS = ("count", "gain")
"""How ``explore_pool="adaptive"`` weighs an explore record (``explore_record``)."""
EXPLORE_BANDITS = ("mean", "thompson")
"""How ``explore_pool="adaptive"`` chooses a pool from the records (``explore_bandit``): the higher
posterior mean of the record rate, or the higher draw from each pool's posterior."""

ACQUISITIONS = ("thompson", "ei")
HANDOFF_MODELS = ("target", "prior", "transfer")
"""Cost models of the late phase (``handoff``): a GP on the target alone, the transfer model
with fitted residual lengthscales, or the transfer model unchanged (TuRBO's side rules only)."""
HANDOFF_RULES = ("turbo", "transfer")
"""Side rules of the late phase (``handoff_rules``): TuRBO-m's, or the early phase's options."""
SUCCESS_SCALES = ("best", "spread")
"""What TuRBO's ``1e-3`` success margin multiplies (``success_scale``): ``|best|`` or the spread
of the target's standing costs."""
SOURCE_ORDERS = ("canonical", "stored")
"""The order the source's trials are used in (``source_order``): sorted by (cost, fell, θ), or as
given."""
EXPLORE_POOLS = ("latent", "source", "both", "auto", "box", "lines", "latent_lines", "adaptive",
                 "cma")
"""Where an explore ask's candidates come from (``explore_pool``): decoded codes of the whole
latent box, the source's promising distribution over θ, half of each, or the latent box while
every target trial fell and the source's distribution after, the whole θ box, or lines through
the centre along one or two coordinates, half decoded codes and half lines, or decoded codes or
lines by the target's record of each, or the draws of a CMA-ES that starts from the source's
promising distribution and is told every target trial (:meth:`Transfer._pool_cma`)."""
LINES_PICKS = ("uniform", "fall")
"""How ``explore_pool="lines"`` picks the coordinates it sets (``lines_pick``): uniformly, or with
probability in proportion to the source fall model's lengthscale (the gains its falls depend on
least are moved most often)."""
FALL_RANKS = ("clipped", "bound", "mean")
"""The order the least likely to fall are taken by when too few candidates pass the fall screen
(``fall_rank``): the screen's clipped probability, its unclipped bound, or the fall model's
unclipped posterior mean."""
WALK_PICKS = ("rank", "fall", "band")
"""How ``record_walk`` picks each step (``walk_pick``): the best rank past the step's quantile,
the least likely to fall over the whole record, or the least likely to fall in the step's band
of ranks."""
TARGET_SCORES = ("ranks", "values", "warped", "auto")
"""What the target's cost model fits (options ``target_scores``, ``refine_scores`` and
``explore_scores``): the costs' Gaussian-copula rank scores, their standardized values
(:func:`~latentune.critic.transfer_model.value_scores`), their warped values
(:func:`~latentune.critic.transfer_model.warped_scores`), or (``"auto"``) ranks or warped
values, whichever model orders the target's own trials better when each is left out
(:meth:`Transfer._chosen_scores`)."""
AUTO_MIN_STANDING = 6
"""``"auto"`` scores: the standing target trials needed before warped values may be chosen
(with fewer a leave-one-out order says little): ranks until then."""
FULL_SHAPES = ("lengthscales", "cube")
"""The full pool's box (``full_shape``): sides in proportion to the lengthscales, or a cube."""
FALL_BUDGET_COUNTS = ("all", "after_stand")
"""The falls a fall budget counts (``fall_budget_counts``, :func:`counted_falls`)."""
EXPLORE_WHEN = ("always", "stalled")
"""When a due generation is an explore ask (``explore_when``): always, or only while the trust
region's side is at its minimum."""
_EXPLORE_WAIT_MAX = 8
"""With ``explore_adapt`` the interval between explore asks grows to at most this many times
``explore_every``."""
_FRAGILE_STEP = 0.05
"""``centre_falls``: the largest coordinate difference (unit box) of a trial's neighbours."""
_JOINT = 256
"""Candidates (lowest confidence bounds) that share one joint Thompson sample."""


# --------------------------------------------------------------------------- the critic
def elite_points(X: np.ndarray, z: np.ndarray, fell: np.ndarray, k: int,
                 spacing: float) -> np.ndarray:
    """Indices (≤ k,) of the source's best diverse trials: by rank score ``z``, trials that did not
    fail, each at least ``spacing`` (Euclidean, unit box, divided by sqrt(d)) from those taken."""
    ok = np.flatnonzero(~fell)
    if ok.size == 0:
        ok = np.arange(len(z))
    order = ok[np.argsort(z[ok], kind="stable")]
    taken: list[int] = []
    d = X.shape[1]
    for i in order:
        if len(taken) >= k:
            break
        if all(np.linalg.norm(X[i] - X[j]) / math.sqrt(d) >= spacing for j in taken):
            taken.append(int(i))
    return np.asarray(taken, dtype=np.int64)


@dataclass
class ExploreRecord:
    """One explore pool's record over the told history (``explore_pool="adaptive"``): its explore
    asks, the asks that made a record (their best standing trial improved on the best before it),
    the asks in which a trial fell, the summed drop in cost of the records made from a standing
    best (cost units), and how many records those are."""

    asks: int = 0
    records: int = 0
    falls: int = 0
    drop: float = 0.0
    n_drop: int = 0

    def as_list(self, n: int = 5) -> list[float]:
        """The first ``n`` fields, in the order above (what a decision stores)."""
        return [self.asks, self.records, self.falls, self.drop, self.n_drop][:n]


@dataclass
class _AskContext:
    """What one ask decided before it chose its points (recorded with the choice)."""

    generation: int
    state: dict[str, Any]
    design: bool
    agree: np.ndarray
    agree_sd: np.ndarray
    w_lat: float
    latent_off: bool
    cost_m: TargetModel | None
    fall_m: TargetModel | None = None
    design_screened: bool = False
    safe_fallback: bool = False
    explore: bool = False
    centre_screened: bool = False
    duplicates: int = 0
    repeats: int = 0
    explore_bound: float | None = None
    explore_skipped: bool = False
    fragile: int = 0
    explore_gp: TargetGP | None = None
    region_gp: bool = False
    explore_cma: bool = False
    record_cma: bool = False
    escape: bool = False
    refine_scores: str | None = None


@dataclass
class _Candidates:
    """One ask's candidates: θ (m, d), latent codes (m, k; NaN outside the latent pool), pool
    (m,), the fall screen's probability (m,), its verdict (m,) and, with ``fall_rank`` other
    than ``"clipped"``, the unclipped order the least likely to fall are taken by (m,)."""

    X: np.ndarray
    Z: np.ndarray
    pool: np.ndarray
    pf: np.ndarray
    ok: np.ndarray | None = None
    rank: np.ndarray | None = None

    @property
    def risk(self) -> np.ndarray:
        """(m,) what "least likely to fall" orders by: ``rank`` when given (``fall_rank``), else
        the screen's probability."""
        return self.pf if self.rank is None else self.rank


class Transfer(TwoSpaceCritic):
    """Phase 3 from everything the source learned (see the module docstring).

    Args:
        source: ``(X (N, d), y (N,), fell (N,))``, the source run's trials in the θ unit box.
        latent: the source's latent space (``d_low``, ``encode``, ``decode``, ``to_unit``) or None
            (then the latent pool is empty).
        manual: the target's manual θ (d,) in the unit box, an elite candidate, or None.
        batch_size, seed: as for every critic.
        **options: any of :data:`TRANSFER_DEFAULTS`.
    """

    method = "transfer"

    def __init__(self, source: tuple[np.ndarray, np.ndarray, np.ndarray], latent: Any = None,
                 manual: np.ndarray | None = None, *, batch_size: int = 1, seed: int = 0,
                 budget: int | None = None, **options: Any) -> None:
        Xs = np.asarray(source[0], dtype=float)
        if Xs.ndim != 2:
            raise ValueError(f"source X must be (N, d), got shape {Xs.shape}")
        unknown = set(options) - set(TRANSFER_DEFAULTS)
        if unknown:
            raise TypeError(f"Transfer: unknown option(s) {sorted(unknown)}")
        super().__init__(Xs.shape[1], batch_size=batch_size, seed=seed)
        self.opts = resolved_options(options)
        self._explicit = frozenset(options)
        p = self.opts["max_fall_prob"]
        if not (isinstance(p, (int, float)) and 0 < float(p) <= 1):
            raise ValueError(f"max_fall_prob must be in (0, 1], got {p!r}")
        if not 0.0 <= float(self.opts["global_share"]) < 1.0:
            raise ValueError(f"global_share must be in [0, 1), got {self.opts['global_share']!r}")
        check_numbers(self.opts)
        if self.opts["handoff_model"] not in HANDOFF_MODELS:
            raise ValueError(f"handoff_model must be one of {HANDOFF_MODELS}, "
                             f"got {self.opts['handoff_model']!r}")
        if self.opts["handoff_rules"] not in HANDOFF_RULES:
            raise ValueError(f"handoff_rules must be one of {HANDOFF_RULES}, "
                             f"got {self.opts['handoff_rules']!r}")
        k_ex = self.opts["explore_every"]
        if not is_whole(k_ex, 0) \
                or k_ex == 1:
            raise ValueError(f"explore_every must be 0 (off) or an integer ≥ 2, got {k_ex!r}")
        for flag in ("stand_first", "explore_adapt", "fall_source_sd", "explore_void",
                     "centre_screen", "distinct", "explore_skip", "fall_calibrate",
                     "fall_shrink", "explore_gp", "fall_fit", "record_cma", "fit_lengthscale",
                     "restart", "design_screen", "fall_cost", "stop_converged",
                     "handoff_fall_shrink"):
            if not isinstance(self.opts[flag], (bool, np.bool_)):
                raise ValueError(f"{flag} must be true or false, got {self.opts[flag]!r}")
        q_fb = self.opts["fall_budget"]
        if isinstance(q_fb, bool) or not isinstance(q_fb, (int, float)) or \
                not 0.0 <= float(q_fb) < 1.0:
            raise ValueError(f"fall_budget must be a share of the trials in [0, 1) (0: none), "
                             f"got {q_fb!r}")
        if budget is not None and not is_whole(budget, 1):
            raise ValueError(f"budget must be a whole number of trials ≥ 1, got {budget!r}")
        self.budget = None if budget is None else int(budget)
        if self.opts["fall_budget_counts"] not in FALL_BUDGET_COUNTS:
            raise ValueError(f"fall_budget_counts must be one of {FALL_BUDGET_COUNTS}, "
                             f"got {self.opts['fall_budget_counts']!r}")
        for flag, word in (("safe_fallback", "region"), ("region_gp", "screened")):
            v = self.opts[flag]
            if not (isinstance(v, (bool, np.bool_)) or (isinstance(v, str) and v == word)):
                raise ValueError(f"{flag} must be true, false or \"{word}\", got {v!r}")
        k_ef = self.opts["explore_falls"]
        if not is_whole(k_ef, 0):
            raise ValueError(f"explore_falls must be an integer ≥ 0 (0: never stop exploring), "
                             f"got {k_ef!r}")
        k_rw = self.opts["record_walk"]
        if not is_whole(k_rw, 0):
            raise ValueError(f"record_walk must be an integer ≥ 0 (0: off), got {k_rw!r}")
        if self.opts["target_scores"] not in TARGET_SCORES:
            raise ValueError(f"target_scores must be one of {TARGET_SCORES}, "
                             f"got {self.opts['target_scores']!r}")
        for key in ("refine_scores", "explore_scores"):
            if self.opts[key] is not None and self.opts[key] not in TARGET_SCORES:
                raise ValueError(f"{key} must be None or one of {TARGET_SCORES}, "
                                 f"got {self.opts[key]!r}")
        if self.opts["walk_pick"] not in WALK_PICKS:
            raise ValueError(f"walk_pick must be one of {WALK_PICKS}, "
                             f"got {self.opts['walk_pick']!r}")
        if self.opts["walk_pick"] != TRANSFER_DEFAULTS["walk_pick"] and not int(k_rw) > 0:
            # another pick without a walk would be ignored (the default, restored with a
            # stored run's options, is no choice)
            raise ValueError(f"walk_pick chooses the steps of a record walk: give record_walk "
                             f"> 0 with it (got walk_pick = {self.opts['walk_pick']!r}, "
                             f"record_walk = {k_rw!r})")
        k_es = self.opts["escape_falls"]
        if not is_whole(k_es, 0):
            raise ValueError(f"escape_falls must be an integer ≥ 0 (0: off), got {k_es!r}")
        k_cf = self.opts["centre_falls"]
        if not is_whole(k_cf, 0):
            raise ValueError(f"centre_falls must be an integer ≥ 0 (0: off), got {k_cf!r}")
        if self.opts["fall_rank"] not in FALL_RANKS:
            raise ValueError(f"fall_rank must be one of {FALL_RANKS}, "
                             f"got {self.opts['fall_rank']!r}")
        if self.opts["explore_record"] not in EXPLORE_RECORDS:
            raise ValueError(f"explore_record must be one of {EXPLORE_RECORDS}, "
                             f"got {self.opts['explore_record']!r}")
        if self.opts["explore_bandit"] not in EXPLORE_BANDITS:
            raise ValueError(f"explore_bandit must be one of {EXPLORE_BANDITS}, "
                             f"got {self.opts['explore_bandit']!r}")
        if self.opts["explore_pool"] not in EXPLORE_POOLS:
            raise ValueError(f"explore_pool must be one of {EXPLORE_POOLS}, "
                             f"got {self.opts['explore_pool']!r}")
        t = self.opts["tilt"]
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not 0.0 <= float(t) < 10.0:
            raise ValueError(f"tilt must be a number in [0, 10) (0: no tilt), got {t!r}")
        w_f = self.opts["explore_fall_weight"]
        if isinstance(w_f, bool) or not isinstance(w_f, (int, float)) or not 0.0 <= w_f <= 10.0:
            raise ValueError(f"explore_fall_weight must be a number in [0, 10] (0: off), "
                             f"got {w_f!r}")
        q = self.opts["explore_fall_prob"]
        if isinstance(q, bool) or not isinstance(q, (int, float)) or \
                not 0.0 <= float(q) <= float(p):
            raise ValueError(f"explore_fall_prob must be a number in [0, max_fall_prob = {p}] "
                             f"(0: the same bound as every ask), got {q!r}")
        f = self.opts["face_snap"]
        if isinstance(f, bool) or not isinstance(f, (int, float)) or not 0.0 <= float(f) <= 1.0:
            raise ValueError(f"face_snap must be a probability in [0, 1] (0: off), got {f!r}")
        if self.opts["lines_pick"] not in LINES_PICKS:
            raise ValueError(f"lines_pick must be one of {LINES_PICKS}, "
                             f"got {self.opts['lines_pick']!r}")
        if self.opts["full_shape"] not in FULL_SHAPES:
            raise ValueError(f"full_shape must be one of {FULL_SHAPES}, "
                             f"got {self.opts['full_shape']!r}")
        if self.opts["explore_when"] not in EXPLORE_WHEN:
            raise ValueError(f"explore_when must be one of {EXPLORE_WHEN}, "
                             f"got {self.opts['explore_when']!r}")
        if self.opts["source_order"] not in SOURCE_ORDERS:
            raise ValueError(f"source_order must be one of {SOURCE_ORDERS}, "
                             f"got {self.opts['source_order']!r}")
        if self.opts["success_scale"] not in SUCCESS_SCALES:
            raise ValueError(f"success_scale must be one of {SUCCESS_SCALES}, "
                             f"got {self.opts['success_scale']!r}")
        if self.opts["acquisition"] not in ACQUISITIONS:
            raise ValueError(f"acquisition must be one of {ACQUISITIONS}, "
                             f"got {self.opts['acquisition']!r}")
        self.source = (as_unit_points(Xs, self.dim, "source X"),
                       np.asarray(source[1], dtype=float).reshape(-1),
                       np.asarray(source[2], dtype=bool).reshape(-1))
        if not (self.source[1].shape[0] == self.source[2].shape[0] == Xs.shape[0]):
            raise ValueError("source X, y and fell must have the same length")
        self.latent = latent
        if latent is not None and int(latent.d) != self.dim:
            raise ValueError(f"the latent space maps to {latent.d}-dim θ, not {self.dim}")
        self.manual = None if manual is None else as_unit_points(manual, self.dim, "manual")[0]
        self._model: SourceModel | None = None
        self._canonical: np.ndarray | None = None      # (N,) canonical_order of the source
        self._hypers: dict[str, Any] | None = None
        self._added: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._incoming: tuple[np.ndarray, np.ndarray] | None = None
        self._Z = np.empty((0, self.k))
        self.last_z = np.empty((0, self.k))
        self.decisions: list[dict[str, Any]] = []
        self._not_target: tuple[int, int] | None = None    # told rows that are not the target's
        self._elite: np.ndarray | None = None
        self._source_mgd: tuple[np.ndarray, float, np.ndarray] | None = None   # _pool_source
        self._turbo: Any = None
        self._auto: dict[str, list] = {}    # this ask's "auto" choices (its decision's)
        self._preq = np.empty(0)        # (t,) prequential screen scores (fall_calibrate)
        self._calib: tuple[int, np.ndarray] | None = None     # (n_told, (a, b))
        self._fit_failed: dict[str, str] = {}   # model fits that raised since the last decision

    # ------------------------------------------------------------------ properties
    @property
    def k(self) -> int:
        """Dimension of the latent box (0 without a latent space)."""
        return 0 if self.latent is None else int(self.latent.d_low)

    def source_rows(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The source's (X (N, d) unit box, y (N,), fell (N,)) in the order the models and the
        elites use (``source_order``)."""
        X, y, f = self.source
        if self.opts["source_order"] == "stored":
            return X, y, f
        if self._canonical is None:
            self._canonical = canonical_order(X, y, f)
        o = self._canonical
        return X[o], y[o], f[o]

    def source_model(self) -> SourceModel:
        """The fitted source models (fitted at the first need, or restored from the state)."""
        if self._model is None:
            X, y, f = self.source_rows()
            fitted = self._hypers is None
            self._model = SourceModel(X, y, f, seed=self.seed, max_points=self.opts["max_points"],
                                      hypers=self._hypers)
            self._hypers = self._model.hypers
            if fitted:              # a fit that raised is said in the next ask's decision
                self._fit_failed.update(self._model.fit_failures())
        return self._model

    def add_source(self, X: np.ndarray, y: np.ndarray, fell: np.ndarray) -> None:
        """Source trials made while phase 3 runs (θ (n, d) in the unit box, costs (n,), fall
        flags (n,)): the source models are conditioned again on the source run's trials and
        every trial added so far, with the hyperparameters they have (the fall model is fitted
        when the added falls first make one possible). The elites, the design and the explore
        pools keep the source run's own trials. Experimental: ``benchmarks.transfer``'s
        ``sim_check`` runs the critic's proposals on the model system this way; nothing in
        the phase loop calls it yet, and added trials are not part of :meth:`state_dict`."""
        Xa = as_unit_points(X, self.dim, "X")
        ya = np.asarray(y, dtype=float).reshape(-1)
        fa = np.asarray(fell, dtype=bool).reshape(-1)
        if not ya.shape[0] == fa.shape[0] == Xa.shape[0]:
            raise ValueError(f"X, y and fell must have {Xa.shape[0]} rows")
        self.source_model()                     # the hyperparameters, fitted once
        X0, y0, f0 = self._added if self._added is not None else self.source_rows()
        self._added = (np.vstack([X0, Xa]), np.concatenate([y0, ya]), np.concatenate([f0, fa]))
        Xu, yu, fu = self._added
        self._model = SourceModel(Xu, yu, fu, seed=self.seed, max_points=len(yu),
                                  hypers=self._hypers)
        self._hypers = {**self._hypers, "fall": self._hypers.get("fall")
                        or self._model.hypers.get("fall")}
        self._proposer = None

    def elites(self) -> np.ndarray:
        """(m, d) the elite pool before removing evaluated points: the source's best diverse θ,
        then the manual θ."""
        if self._elite is None:
            X, y, f = self.source_rows()
            z = rank_scores(y, f)
            idx = elite_points(X, z, f, int(self.opts["n_elite"]), float(self.opts["elite_spacing"]))
            E = X[idx]
            if self.manual is not None:
                E = np.vstack([E, self.manual[None, :]])
            self._elite = E
        return self._elite

    # ------------------------------------------------------------------ tell
    def _tell(self, idx: np.ndarray, tags: np.ndarray) -> None:
        _, za = self._incoming_told()
        self._Z = np.vstack([self._Z, za]) if self.k else self._Z

    # ------------------------------------------------------------------ state from history
    def _replay_state(self) -> dict[str, Any]:
        """Trust-region side, counters and the latent pool's record, from the told history."""
        tags = self._tags
        own = tags >= 0
        ext = ~own
        y = np.where(np.isfinite(self._y) & ~self._fell, self._y, np.inf)
        best = float(y[ext].min()) if ext.any() else math.inf
        L = float(self.opts["length_init"])
        succ = fail = restarts = n_seen = 0
        k_h = int(self.opts["handoff"])
        rules = self._side_rules(False)
        late = turbo = False
        converged = False
        gens = np.unique(tags[own] // 4) if own.any() else np.empty(0, dtype=np.int64)
        explore = np.zeros(len(tags), dtype=bool)
        # a trial stands before generation g when an untagged one stood or an own one of an
        # earlier generation did: g > the first own generation with a standing trial
        ok = ~self._fell
        first_ok = -1 if (ok & ext).any() else \
            int((tags[ok & own] // 4).min()) if (ok & own).any() else math.inf
        k_ex = int(self.opts["explore_every"])
        interval, next_due = k_ex, k_ex - 1         # the explore schedule (``explore_adapt``)
        record = {LATENT: ExploreRecord(), GLOBAL: ExploreRecord()}     # per pool
        void = np.zeros(len(tags), dtype=bool)      # explore records the region fell around
        pending: tuple[int, np.ndarray, float] | None = None   # (pool, trials, drop) of the last
        for g in gens:
            m = own & (tags // 4 == g)
            standing = g > first_ok
            due = self._explore_generation(int(g), L, next_due)
            if due and self._explore_pool(explore, standing, record, int(g)) is not None and \
                    not np.isin(tags[m] % 4, (ELITE, FULL)).any():
                explore |= m            # data and best value only: L follows the other batches
                gb = float(y[m].min())
                improved = self._improves(gb, best, g, y, ext, own, tags)
                counts = record.get(int(tags[m][0] % 4))     # the pool this ask drew from
                drop = best - gb if improved and math.isfinite(best) else 0.0
                if counts is not None:
                    counts.asks += 1
                    counts.records += int(improved)
                    counts.falls += int(self._fell[m].any())
                    counts.drop += drop
                    counts.n_drop += int(drop > 0.0)
                if improved and self.opts["explore_void"]:
                    pending = (int(tags[m][0] % 4), m & (y < best), drop)
                if improved:
                    interval = k_ex
                else:                   # an explore ask that found nothing: wait twice as long
                    interval = min(2 * interval, _EXPLORE_WAIT_MAX * k_ex)
                next_due = int(g) + interval
                best = min(best, gb)
                n_seen += int(m.sum())
                continue
            if due:                     # due but not an explore ask: the interval stays
                next_due = int(g) + interval
            if pending is not None and not (tags[m] % 4 == ELITE).all():
                if self._fell[m].mean() > float(self.opts["max_fall_prob"]):
                    void |= pending[1]          # the region around the record fell: void
                    counts = record.get(pending[0])
                    if counts is not None:
                        counts.records -= 1
                        counts.drop -= pending[2]
                        counts.n_drop -= int(pending[2] > 0.0)
                    kept = (ext | (own & (tags // 4 < g))) & ~void & np.isfinite(y)
                    best = float(y[kept].min()) if kept.any() else math.inf
                pending = None
            if self.opts["stand_first"] and not standing and not (ok & m).any():
                n_seen += int(m.sum())  # every trial so far fell: no incumbent, L waits
                continue
            if k_h > 0 and not late and n_seen >= k_h:     # the hand-off
                late, turbo = True, self.opts["handoff_rules"] == "turbo"
                if turbo:
                    succ, fail, rules = 0, 0, self._side_rules(True)
            succ_tol, fail_tol, l_min, l_max = rules
            gb = float(y[m].min())
            if self._improves(gb, best, g, y, ext, own, tags):
                succ, fail = succ + 1, 0
            else:           # TuRBO counts failures in evaluations, the early phase in batches
                succ, fail = 0, fail + (int(m.sum()) if turbo else 1)
            best = min(best, gb)
            n_seen += int(m.sum())
            side = L
            if succ >= succ_tol:
                L, succ = min(2.0 * L, l_max), 0
            elif fail >= fail_tol:
                if self.opts["restart"] and L / 2.0 < l_min:
                    L, restarts = float(self.opts["length_init"]), restarts + 1
                else:
                    converged = converged or L / 2.0 < float(self.opts["length_min"])
                    L = max(L / 2.0, l_min)
                fail = 0
            fall_rule = self.opts["handoff_fall_shrink"] if late else \
                self.opts["fall_shrink"] and not (tags[m] % 4 == ELITE).all()
            if fall_rule and self._fall_shrink_due(m, tags // 4 <= g):
                L, succ, fail = max(min(L, side / 2.0), l_min), 0, 0
        lat = own & (tags % 4 == LATENT) & ~explore
        g_next = int(gens.max()) + 1 if gens.size else 0
        pool = self._explore_pool(explore, bool(ok.any()), record, g_next)
        n_rec = 5 if self.opts["explore_record"] == "gain" else \
            3 if float(self.opts["explore_fall_weight"]) > 0 else 2
        return {"L": L, "succ": succ, "fail": fail, "n_own": int(own.sum()), "restarts": restarts,
                "explore_next": next_due, "void": np.flatnonzero(void).tolist(),
                "explore_record": {"latent": record[LATENT].as_list(n_rec),
                                   "lines": record[GLOBAL].as_list(n_rec)},
                "converged": converged, "explore_braked": pool is None, "explore_pool": pool,
                "explore_told": int(explore.sum()), "explore_fell": int(self._fell[explore].sum()),
                "generation": g_next,
                "latent_told": int(lat.sum()), "latent_fell": int(self._fell[lat].sum())}

    def _braked(self, asked: np.ndarray, standing: bool) -> bool:
        """``explore_falls`` = k > 0: True once at least k of the told trials of a kind of ask
        (``asked`` (n,) bool over the told history: the explore asks', a pool's, or
        ``safe_fallback="region"``'s fallback asks') fell and they fell more often than
        ``max_fall_prob`` allows, while the target holds a trial that did not fall
        (``standing``): those asks are riskier on this target than the fall model predicts, and
        the local search has a standing centre to work from. While every trial so far fell, the
        explore asks go on: they are the way out."""
        k = int(self.opts["explore_falls"])
        if k <= 0 or not standing:
            return False
        fell = int(self._fell[asked].sum())
        return fell >= k and fell > float(self.opts["max_fall_prob"]) * int(asked.sum())

    def _escape_due(self) -> bool:
        """``escape_falls`` = k > 0: True while every told trial fell and there are at least k
        of them (the zero-shot θ, the design's elites, the manual θ and the asks after them):
        the explore asks then leave the source's manifold (:meth:`_farthest`)."""
        k, n = int(self.opts["escape_falls"]), self.n_told
        return k > 0 and n >= k and bool(self._fell[:n].all())

    def _farthest(self, C: np.ndarray, n: int) -> np.ndarray:
        """Indices of ``n`` of the candidates ``C`` (m, d) chosen one by one as the farthest
        (Euclidean, in the unit box) from every told θ and from those chosen before it (a
        greedy maximin design): ``escape_falls``'s ask, where the models, trained on falls
        alone, cannot tell where the target stands."""
        X = self._X[:self.n_told]
        d2 = (C * C).sum(1)[:, None] + (X * X).sum(1)[None, :] - 2.0 * C @ X.T
        d = np.sqrt(np.maximum(d2, 0.0)).min(1)
        out: list[int] = []
        for _ in range(min(n, len(C))):
            i = int(np.argmax(d))
            out.append(i)
            d = np.minimum(d, np.sqrt(((C - C[i]) ** 2).sum(-1)))
        return np.asarray(out, dtype=np.int64)

    def _explore_pool(self, explore: np.ndarray, standing: bool,
                      record: dict[int, ExploreRecord] | None = None, g: int = 0
                      ) -> str | None:
        """The pool of the next explore ask (``explore_pool`` resolved: ``"auto"`` to
        ``"latent"`` or ``"source"``, ``"adaptive"`` to ``"latent"`` or ``"lines"``, ``"lines"``
        to ``"latent"`` while no trial stands), or None once the explore asks are braked, from
        the told explore trials ``explore`` (n,) bool, whether a trial stands (``standing``) and,
        for ``"adaptive"``, the explore generations' record per tag pool (``record``,
        ``LATENT`` and ``GLOBAL``; none told: both empty) and the generation
        ``g`` the pool is for (``explore_bandit="thompson"`` draws with a seed of it).

        With ``"auto"`` each pool has its own brake (``_braked`` on its own explore
        trials: the source's draws carry tag pool ``global``, the decoded codes ``latent``): the
        source's distribution once a trial stands, until its draws fell beyond the admitted
        risk; then the latent box, until its codes did; then none. Without a latent space
        ``"auto"`` is ``"source"``."""
        where = self.opts["explore_pool"]
        if where == "adaptive" and self.latent is None:
            where = "lines"             # no manifold to weigh the lines against
        elif where == "adaptive":
            rec = record or {}
            lat, lin = rec.get(LATENT, ExploreRecord()), rec.get(GLOBAL, ExploreRecord())
            s_lin, s_lat = self._record_score(lin, lat), self._record_score(lat, lin)
            if self.opts["explore_bandit"] == "thompson":
                rng = np.random.default_rng([self.seed, g, 13])
                s_lat, s_lin = (rng.beta(*self._record_beta(sc, own))
                                for sc, own in ((s_lat, lat), (s_lin, lin)))
            where = "lines" if s_lin > s_lat else "latent"
        if where in ("lines", "latent_lines") and not standing:
            where = "latent"            # no standing centre to draw lines through yet
        if where != "auto" or self.latent is None:
            where = "source" if where == "auto" else where
            return None if self._braked(explore, standing) else where
        pool = self._tags % 4
        if standing and not self._braked(explore & (pool == GLOBAL), standing):
            return "source"
        if not self._braked(explore & (pool == LATENT), standing):
            return "latent"
        return None

    def _record_score(self, own: ExploreRecord, other: ExploreRecord) -> float:
        """``explore_pool="adaptive"``'s score of a pool from its explore record ``own`` and the
        other pool's ``other``:
        ``(records − w · falls + 1) / (asks + 2)`` (``w``: ``explore_fall_weight``). With
        ``explore_record="gain"`` a record from a standing best counts as its drop in cost over
        the mean drop of both pools' such records (a record from no standing best as 1), so
        records of equal size score as their count and a pool whose records are small does
        not keep the asks from one whose records are large."""
        w = float(self.opts["explore_fall_weight"])
        records = float(own.records)
        n_drop = own.n_drop + other.n_drop
        if self.opts["explore_record"] == "gain" and n_drop > 0:
            mean = (own.drop + other.drop) / n_drop
            if mean > 0.0:
                records = own.records - own.n_drop + own.drop / mean
        return (records - w * own.falls + 1) / (own.asks + 2)

    @staticmethod
    def _record_beta(score: float, own: ExploreRecord) -> tuple[float, float]:
        """The Beta posterior ``(a, b)`` of a pool's record rate whose mean is its ``score``
        (:meth:`_record_score`) over ``asks + 2`` pseudo-trials: ``a = score · (asks + 2)``,
        ``b = asks + 2 − a``, each at least 0.01 (a fall weight or a gain weighting may push
        the weighted records outside [0, asks])."""
        n = float(own.asks) + 2.0
        a = min(max(score * n, 0.01), n - 0.01)
        return a, n - a

    def _improves(self, gb: float, best: float, g: int, y: np.ndarray, ext: np.ndarray,
                  own: np.ndarray, tags: np.ndarray) -> bool:
        """TuRBO's success: the best standing cost ``gb`` of generation ``g`` beats ``best`` by
        more than ``1e-3`` times the ``success_scale`` (``y`` (n,): told costs, inf for falls;
        ``ext``/``own`` (n,) bool: untagged / tagged trials; ``tags`` (n,))."""
        if not math.isfinite(best):
            return gb < best
        if self.opts["success_scale"] == "spread":
            before = y[(ext | (own & (tags // 4 < g))) & np.isfinite(y)]
            scale = float(np.median(before)) - best if before.size else 0.0
        else:
            scale = abs(best)
        return gb < best - 1e-3 * scale

    def _explore_generation(self, g: int, L: float, next_due: int) -> bool:
        """True when generation ``g`` is due for an explore ask (``explore_every`` = k ≥ 2 and
        ``g % k == k − 1``, or with ``explore_adapt`` ``g ≥ next_due``, the replay's schedule;
        with ``explore_when="stalled"`` only while the side ``L`` it is asked at is
        ``length_min``); the ask itself is one unless it is a design, manual or converged ask:
        module docstring."""
        k = int(self.opts["explore_every"])
        if k < 2 or not (g >= next_due if self.opts["explore_adapt"] else g % k == k - 1):
            return False
        return self.opts["explore_when"] == "always" or \
            L <= float(self.opts["length_min"]) * (1.0 + 1e-9)

    def _fall_shrink_due(self, group: np.ndarray, upto: np.ndarray) -> bool:
        """The rule for falls of ``fall_shrink`` and ``handoff_fall_shrink`` for the generation
        ``group`` (n,) bool: more than ``max_fall_prob`` of its trials fell and one of the trials
        ``upto`` (n,) bool (those told with it or before, the untagged ones included) did not."""
        if self._fell[group].mean() <= float(self.opts["max_fall_prob"]):
            return False
        return bool((~self._fell[upto]).any())

    def _side_rules(self, late: bool) -> tuple[int, int, float, float]:
        """(succ_tol, fail_tol, length_min, length_max) of the early phase (the options) or, after
        the hand-off, of TuRBO-m (its defaults for this dimension; with ``handoff_rules``
        ``"turbo"``)."""
        if not late or self.opts["handoff_rules"] != "turbo":
            o = self.opts
            return (int(o["succ_tol"]), int(o["fail_tol"]), float(o["length_min"]),
                    float(o["length_max"]))
        tm = self._turbo_helper()
        return tm.success_tol, tm.failure_tol, tm.length_min, tm.length_max

    def _turbo_helper(self) -> Any:
        """A one-region :class:`~latentune.critic.turbo.TurboM` of this dimension, whose rules
        and GP fit the late phase uses (made at the first need)."""
        if self._turbo is None:
            from latentune.critic.turbo import TurboM

            self._turbo = TurboM(self.dim, batch_size=1, seed=self.seed, n_regions=1)
            self._turbo.fit_report.what = "phase 3's target GP"     # its failures' log line
        return self._turbo

    def _target_gp(self, base: TargetModel) -> TargetGP:
        """A GP on the target's trials alone (:class:`TargetGP`, TuRBO-m's model) over
        ``base``'s rank scores: the late phase's cost model and the explore and region asks'."""
        report = self._turbo_helper().fit_report
        before = report.n_failed
        gp = TargetGP(self._X, base.v, self._turbo_helper(), base)
        if report.n_failed > before:
            self._fit_failed["target GP"] = report.last_failure
        return gp

    def _explore_target_gp(self, base: TargetModel) -> TargetGP:
        """The target's own GP of the explore and region asks: over ``base``'s scores, or over
        ``explore_scores``'s where that option names others (recorded in the decision)."""
        scores = self.opts["explore_scores"]
        if scores == "auto":
            own = self.opts["target_scores"]      # base's scores: not fitted again
            return self._chosen_scores(
                lambda s: self._target_gp(base if s == own else self._cost_model(s)), "explore")
        if scores is None or scores == self.opts["target_scores"]:
            return self._target_gp(base)
        return self._target_gp(self._cost_model(scores))

    def _chosen_scores(self, make: Any, key: str) -> Any:
        """``"auto"`` scores: ``make("ranks")``, or ``make("warped")`` when at least
        :data:`AUTO_MIN_STANDING` target trials stood and its leave-one-out means (``loo_mean``)
        have the lower :func:`~latentune.critic.transfer_model.ranking_loss` on the told trials;
        the choice and both losses are kept under ``key`` for the ask's decision."""
        ranks = make("ranks")
        if int((~self._fell & np.isfinite(self._y)).sum()) < AUTO_MIN_STANDING:
            self._auto[key] = ["ranks", None, None]
            return ranks
        warped = make("warped")
        loss = [ranking_loss(m.loo_mean(), self._y, self._fell) for m in (ranks, warped)]
        pick = "warped" if loss[1] < loss[0] else "ranks"
        self._auto[key] = [pick, round(loss[0], 4), round(loss[1], 4)]
        return warped if pick == "warped" else ranks

    def falls_allowed(self) -> int | None:
        """The fall budget among the target's told trials (the zero-shot and manual ones
        included): :func:`falls_allowed` of ``fall_budget`` and ``budget``."""
        return falls_allowed(self.opts["fall_budget"], self.budget)

    @property
    def fall_budget_spent(self) -> bool:
        """True once one of the target's told trials stands and the falls
        ``fall_budget_counts`` counts reach :meth:`falls_allowed` (:func:`fall_budget_spent`):
        every later ask is the best θ that did not fall (tag pool ``full``), as
        ``stop_converged`` asks the centre, and a loop that runs the trials itself stops there.
        While every trial fell the search goes on: it has nothing to stop at."""
        return self.fall_budget_spent_after(np.zeros(0, dtype=bool))

    def fall_budget_spent_after(self, fell: np.ndarray) -> bool:
        """:attr:`fall_budget_spent` once outcomes ``fell`` (n,) bool (trials of an asked batch
        that finished, not told yet) are told after the told ones: what a loop running the
        batch checks before it starts each further trial."""
        told = self._fell
        n = self._not_target
        if n is not None:
            told = np.delete(told, np.arange(n[0], min(n[1], len(told))))
        return fall_budget_spent(np.concatenate([told, np.asarray(fell, dtype=bool)]),
                                 self.opts["fall_budget"], self.budget,
                                 self.opts["fall_budget_counts"])

    def tell_not_target(self, X: np.ndarray, y: np.ndarray, fell: np.ndarray) -> None:
        """:meth:`tell` trials that are data but not the target's trials (the source run's own
        phase-1 trials when the target is its system): the fall budget does not count them."""
        start = len(self._fell)
        self.tell(X, y, fell=fell)
        self._not_target = (start, len(self._fell))

    def _handoff_active(self) -> bool:
        """True once the target has ``handoff`` own (tagged) trials (``handoff`` > 0)."""
        k = int(self.opts["handoff"])
        return k > 0 and int((self._tags >= 0).sum()) >= k

    def _centre(self, void: np.ndarray | None = None) -> np.ndarray:
        """The target's best θ: lowest cost among trials that did not fail (and are not ``void``
        (n,) bool: ``explore_void``), else the fall with the lowest cost (falling later), else
        the first elite."""
        if self.n_told == 0:
            return self.elites()[0]
        y = np.where(np.isfinite(self._y), self._y, np.inf)
        ok = ~self._fell
        if void is not None and (ok & ~void).any():
            ok = ok & ~void
        if ok.any():
            return self._X[np.flatnonzero(ok)[np.argmin(y[ok])]]
        return self._X[int(np.argmin(y))]

    def _fragile(self) -> np.ndarray:
        """(n_told,) bool: ``centre_falls`` = k > 0: the standing trials at least k of whose
        neighbours fell, more often than ``max_fall_prob`` of them (a neighbour: another told
        trial within :data:`_FRAGILE_STEP` of it in every coordinate of the unit box); all False
        when the option is off."""
        k, n = int(self.opts["centre_falls"]), self.n_told
        out = np.zeros(n, dtype=bool)
        if k <= 0:
            return out
        X, fell = self._X[:n], self._fell[:n]
        for i in np.flatnonzero(~fell):
            near = np.abs(X - X[i]).max(1) <= _FRAGILE_STEP
            near[i] = False
            f = int(fell[near].sum())
            out[i] = f >= k and f > float(self.opts["max_fall_prob"]) * int(near.sum())
        return out

    def _screened_centre(self, centre: np.ndarray, void: np.ndarray, fall_m: TargetModel
                         ) -> tuple[np.ndarray, bool]:
        """``centre_screen``: the best standing trial (not ``void`` (n,) bool) whose θ the fall
        screen admits (:meth:`_fall_prob` ≤ ``max_fall_prob`` under the target fall model
        ``fall_m``), and whether it differs from ``centre`` (d,), the best standing trial; when
        the screen admits none, ``centre`` itself."""
        y = np.where(np.isfinite(self._y), self._y, np.inf)
        idx = np.flatnonzero(~self._fell & ~void)
        if idx.size == 0:
            return centre, False
        idx = idx[np.argsort(y[idx], kind="stable")]
        ok = self._fall_prob(self._X[idx], fall_m) <= float(self.opts["max_fall_prob"])
        if not ok.any():
            return centre, False
        c = self._X[idx[int(np.argmax(ok))]]
        return c, not np.array_equal(c, centre)

    # ------------------------------------------------------------------ pools
    def _pool_full(self, m: int, L: float, centre: np.ndarray, rng: np.random.Generator,
                   ls: np.ndarray | None = None) -> np.ndarray:
        """``m`` TuRBO perturbations (m, d) of ``centre`` in a box of side ``L`` shaped by the
        lengthscales ``ls`` (d,) (default: the source's), or a cube of side ``L`` with
        ``full_shape="cube"``."""
        import torch
        from torch.quasirandom import SobolEngine

        if m <= 0:
            return np.empty((0, self.dim))
        if self.opts["full_shape"] == "cube":
            w = np.ones(self.dim)
        else:
            ls = self.source_model().lengthscales if ls is None else ls
            w = np.clip(ls / np.exp(np.mean(np.log(ls))), 0.25, 4.0)
        lb, ub = np.clip(centre - L * w / 2, 0, 1), np.clip(centre + L * w / 2, 0, 1)
        sob = SobolEngine(self.dim, scramble=True, seed=int(rng.integers(2 ** 31))).draw(
            m, dtype=torch.float64).numpy()
        pert = lb + (ub - lb) * sob
        if self.opts["face_snap"] > 0:
            pert = self._snap_faces(pert, lb, ub, rng)
        mask = rng.random((m, self.dim)) <= min(20.0 / self.dim, 1.0)
        none = ~mask.any(1)
        mask[np.flatnonzero(none), rng.integers(0, self.dim, size=int(none.sum()))] = True
        return np.where(mask, pert, centre[None, :])

    def _snap_faces(self, pert: np.ndarray, lb: np.ndarray, ub: np.ndarray,
                    rng: np.random.Generator) -> np.ndarray:
        """``pert`` (m, d) with each coordinate whose region ``[lb, ub]`` (d,) reaches a face of
        the unit box set to that face with probability ``face_snap`` (the nearer face when the
        region reaches both): a gain's best value on the target often lies at its bound, where
        a continuous optimizer of the acquisition ends and a uniform draw in the region does
        not (``face_snap``)."""
        lo, hi = lb <= 0.0, ub >= 1.0
        face = np.where(hi[None, :] & (~lo[None, :] | (pert >= 0.5)), 1.0, 0.0)
        snap = (rng.random(pert.shape) < float(self.opts["face_snap"])) & (lo | hi)[None, :]
        return np.where(snap, face, pert)

    def _pool_global(self, m: int, rng: np.random.Generator) -> np.ndarray:
        """``m`` scrambled Sobol points (m, d) over the whole θ box."""
        import torch
        from torch.quasirandom import SobolEngine

        if m <= 0:
            return np.empty((0, self.dim))
        return SobolEngine(self.dim, scramble=True, seed=int(rng.integers(2 ** 31))).draw(
            m, dtype=torch.float64).numpy()

    def _pool_explore_gp(self, XI: np.ndarray, gp: TargetGP, rng: np.random.Generator
                         ) -> np.ndarray:
        """``explore_gp``'s candidates (m', d) from the lines ``XI`` (m, d): half of the lines,
        as many Sobol points over the whole θ box, and the local maxima of ``gp``'s log expected
        improvement (:func:`~latentune.critic.transfer_model._local_max`) from the
        :data:`~latentune.critic.transfer_model._GP_STARTS` best of those, which end
        on the box's faces and corners where the target's own model puts its best values (as
        a gradient optimizer of GPSampler's or BoTorch's acquisition does)."""
        m = len(XI)
        XB = np.vstack([XI[:m - m // 2], self._pool_global(m // 2, rng)])
        return np.vstack([XB, gp_maxima(gp, XB)])

    def _pool_lines(self, m: int, centre: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """``m`` θ (m, d) on axis lines and planes through ``centre`` (d,): each is the centre
        with one coordinate (half of them) or two (the other half) set uniformly over its whole
        range [0, 1] (``explore_pool="lines"``): steps as far as the box's faces that change as
        little of a standing θ as possible. The coordinates are chosen uniformly, or with
        ``lines_pick="fall"`` with probability ∝ the source fall model's lengthscales (uniformly
        when the source has no fall model)."""
        if m <= 0:
            return np.empty((0, self.dim))
        p = None
        sm = self.source_model()
        if self.opts["lines_pick"] == "fall" and sm.fall_gp is not None:
            p = np.asarray(sm.fall_lengthscales, dtype=float)
            p = p / p.sum()
        X = np.tile(centre, (m, 1))
        rows = np.arange(m)
        X[rows, rng.choice(self.dim, size=m, p=p)] = rng.random(m)
        two = rows[rng.random(m) < 0.5]
        X[two, rng.choice(self.dim, size=two.size, p=p)] = rng.random(two.size)
        return X

    def _pool_cma(self, m: int) -> np.ndarray:
        """``m`` draws (m, d) of a CMA-ES (``cmaes.CMA``, population 4 + ⌊3 ln d⌋, bounded to the
        box, seeded with the run's seed) that starts from the source's promising distribution
        (:meth:`_pool_source`'s Gaussian, as Optuna's ``CmaEsSampler(source_trials=...)``) and
        is told every target trial in the order told, a population at a time (the last,
        incomplete one not yet): a fall, or a cost that is not finite, as the worst
        (``explore_pool="cma"``). A function of the told history."""
        from cmaes import CMA

        mu, sigma, cov = self._source_mgd_of()
        d = self.dim
        lam = 4 + int(math.floor(3 * math.log(d)))
        opt = CMA(mean=np.clip(mu, 0.0, 1.0), sigma=sigma, cov=cov,
                  bounds=np.tile([0.0, 1.0], (d, 1)), seed=int(self.seed),
                  population_size=lam)
        y = np.where(self._fell | ~np.isfinite(self._y), np.inf, self._y)
        n = self.n_told - self.n_told % lam
        for i in range(0, n, lam):
            opt.tell([(np.clip(self._X[j], 0.0, 1.0), float(y[j])) for j in range(i, i + lam)])
        return np.array([opt.ask() for _ in range(m)]).reshape(m, d)

    def _source_mgd_of(self) -> tuple[np.ndarray, float, np.ndarray]:
        """The source's promising distribution ``(μ, σ, Σ)`` (:meth:`_pool_source`), fitted
        once."""
        if self._source_mgd is None:
            from cmaes import get_warm_start_mgd

            X, y, f = self.source_rows()
            keep = ~f & np.isfinite(y)
            if keep.sum() < 2:          # nothing to fit: the whole box
                self._source_mgd = (np.full(self.dim, 0.5), 0.5, np.eye(self.dim))
            else:
                mu, sigma, cov = get_warm_start_mgd(
                    [(x, float(v)) for x, v in zip(X[keep], y[keep])], gamma=0.1, alpha=0.1)
                self._source_mgd = (np.asarray(mu), float(sigma), np.asarray(cov))
        return self._source_mgd

    def _pool_source(self, m: int, rng: np.random.Generator) -> np.ndarray:
        """``m`` θ (m, d) drawn from the source's promising distribution, clipped to the box:
        the Gaussian ``N(μ, σ² Σ)`` that warm-starts CMA-ES from a source task (Nomura et al.
        2021, ``cmaes.get_warm_start_mgd``: the top 10 % of the source's trials that did not
        fall, α = 0.1), the distribution Optuna's ``CmaEsSampler(source_trials=...)`` starts
        from (``explore_pool``)."""
        if m <= 0:
            return np.empty((0, self.dim))
        mu, sigma, cov = self._source_mgd_of()
        Xs = rng.multivariate_normal(mu, sigma ** 2 * cov, size=m, method="cholesky")
        return np.clip(Xs, 0.0, 1.0)

    def _pool_latent(self, m: int, L: float, centre: np.ndarray, rng: np.random.Generator,
                     whole: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """``m`` decoded Sobol codes: θ (m, d) and their unit codes (m, k), in a box of side
        ``min(1, 2L)`` around the code of ``centre`` (d,), or with ``whole`` in the whole latent
        box (``explore_every``)."""
        import torch
        from torch.quasirandom import SobolEngine

        if m <= 0 or self.latent is None:
            return np.empty((0, self.dim)), np.empty((0, self.k))
        if whole:
            lb, ub = np.zeros(self.k), np.ones(self.k)
        else:
            u0 = np.asarray(self.latent.to_unit(self.latent.encode(centre)), dtype=float)
            side = min(1.0, 2.0 * L)
            lb, ub = np.clip(u0 - side / 2, 0, 1), np.clip(u0 + side / 2, 0, 1)
        sob = SobolEngine(self.k, scramble=True, seed=int(rng.integers(2 ** 31))).draw(
            m, dtype=torch.float64).numpy()
        U = lb + (ub - lb) * sob
        return np.clip(np.atleast_2d(self.latent.decode(U)), 0, 1), U

    def _record_rows(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The source's record against the told trials: its standing trials ``S`` (m, d) ranked
        by cost, which told trials are record θ (n_told,) bool (the manual θ is not, though
        phase 1 started from it) and which record θ are free (m,) bool: no told trial has it
        and it lies at least ``elite_spacing`` from every told fall."""
        X, y, f = self.source_rows()
        ok = np.flatnonzero(~f)
        S = X[ok[np.argsort(y[ok], kind="stable")]]
        told = np.zeros(self.n_told, dtype=bool)      # told trials that are source trials
        free = np.ones(len(S), dtype=bool)            # no told trial has it, far from falls
        spacing = float(self.opts["elite_spacing"])
        for j, x in enumerate(self._X if len(S) else ()):   # row by row: no (n, m, d) array
            gap = np.abs(S - x).max(1)
            told[j] = bool((gap <= 1e-9).any())
            free &= gap > 1e-9
            if self._fell[j]:
                free &= gap >= spacing
        if self.manual is not None:     # the manual θ (phase 1's start) is not the record's
            told &= np.abs(self._X - self.manual).max(1) > 1e-9
        return S, told, free

    def record_fell(self) -> bool:
        """True once the target has run θ of the source's record and every one of them fell
        (the trigger of ``record_walk`` and ``record_cma``)."""
        if self.n_told == 0:
            return False
        _, told, _ = self._record_rows()
        return bool(told.any() and not (told & ~self._fell).any())

    def _walk_theta(self, fall_m: TargetModel | None
                    ) -> tuple[np.ndarray, int, float | None] | None:
        """``record_walk`` = k > 0: once the target has tried θ of the source's record and every
        one of them fell, the next of k asks walks down the source's standing trials ranked by
        cost. Its candidates are those no told trial has and that lie at least
        ``elite_spacing`` from every told fall; the i-th step (i = the told record θ outside the
        elite pool) takes, by ``walk_pick``, the best-ranked candidate past the rank quantile
        (i + 1)/(k + 1) (``"rank"``), the candidate the target fall model finds least likely
        to fall (``"fall"``; its mean to 3 decimals, ties to the better rank), or that within the
        step's band of ranks, quantiles (i + 1)/(k + 1) to (i + 2)/(k + 1) (``"band"``).
        A step whose θ is in the elite pool is not counted (so the walk may take more than k
        asks). ``fall_m``: the target fall model of this ask (:meth:`models`).
        ``(θ (d,), its rank, its fall probability or None)``, or None (off, a record θ stood,
        the walk is done, or nothing is left)."""
        k = int(self.opts["record_walk"])
        if k <= 0 or self.n_told == 0:
            return None
        S, told, free = self._record_rows()
        if not len(S) or not told.any() or (told & ~self._fell).any():
            return None
        E = self.elites()
        in_elite = np.array([np.min(np.abs(E - x).max(1)) <= 1e-9 for x in self._X[told]])
        i = int((~in_elite).sum())
        if i >= k:
            return None
        pick = self.opts["walk_pick"]
        lo = 0 if pick == "fall" else int(len(S) * (i + 1) / (k + 1))
        hi = int(len(S) * (i + 2) / (k + 1)) if pick == "band" else len(S)
        idx = np.flatnonzero(free[lo:hi]) + lo
        if not len(idx):
            return None
        if pick == "rank":
            return S[idx[0]].copy(), int(idx[0]), None
        p = np.asarray(fall_m.mean_cov(S[idx], with_cov=False)[0])
        r = idx[np.lexsort((idx, np.round(p, 3)))[0]]
        return S[r].copy(), int(r), float(p[idx == r][0])

    def _pool_elite(self) -> np.ndarray:
        E = self.elites()
        if self.n_told == 0:
            return E
        seen = np.array([np.min(np.abs(self._X - e).max(1)) > 1e-9 for e in E], dtype=bool)
        return E[seen]

    def _manual_next(self) -> bool:
        """True when every told trial fell and the target's manual θ was not tried yet."""
        if self.manual is None or self.n_told == 0 or not self._fell.all():
            return False
        return bool(np.min(np.abs(self._X - self.manual).max(1)) > 1e-9)

    # ------------------------------------------------------------------ models
    def models(self) -> tuple[TargetModel | None, TargetModel | None]:
        """(cost model, fall model) of the target from the told points (None before any)."""
        if self.n_told == 0:
            return None, None
        return self._cost_model(self.opts["target_scores"]), self._fall_model(self.n_told)

    def _cost_model(self, scores: str) -> TargetModel:
        """The target's cost model on the told trials' ``scores`` (one of
        :data:`TARGET_SCORES`): the transfer model over the source's, or the late phase's or
        ``fit_ard``'s variant of it."""
        if scores == "auto":
            return self._chosen_scores(self._cost_model, "cost")
        sm = self.source_model()
        v = {"values": value_scores, "warped": warped_scores,
             "ranks": rank_scores}[scores](self._y, self._fell)
        scales = LS_SCALES if self.opts["fit_lengthscale"] else (1.0,)
        t = float(self.opts["tilt"])
        tilts = (0.0, t / 4, t / 2, t) if t > 0 else (0.0,)
        cost = TargetModel(self._X, v, sm.cost, sm.lengthscales, ls_scales=scales, tilts=tilts)
        if self._handoff_active() and self.opts["handoff_model"] == "target":
            cost = self._target_gp(cost)
        elif self._ard_active():
            ls, s2 = fit_residual_kernel(self._X, v, cost.hX[:, 0], (1.0, 0.0), cost.ls,
                                         cost.sigma_r2)
            cost = TargetModel(self._X, v, sm.cost, ls, sigma_r2=s2, tilts=tilts)
        return cost

    def _fall_model(self, t: int) -> TargetModel:
        """The target fall model on the first ``t`` ≥ 1 told trials (:func:`target_fall_model`,
        fitted with ``fall_fit``)."""
        return target_fall_model(self._X[:t], self._fell[:t], self.source_model(),
                                 bool(self.opts["fall_fit"]))

    def _ard_active(self) -> bool:
        """True when the transfer model's residual lengthscales are fitted on the target
        (``fit_ard``, or the late phase's ``"prior"`` model)."""
        k = int(self.opts["fit_ard"])
        return (k > 0 and self.n_told >= k) or (
            self._handoff_active() and self.opts["handoff_model"] == "prior")

    def _fitted_ls(self) -> bool:
        """True when the cost model's lengthscales are fitted on the target (and shape the full
        pool's box)."""
        return self._ard_active() or (self._handoff_active()
                                      and self.opts["handoff_model"] == "target")

    # ------------------------------------------------------------------ ask
    def _ask(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        from latentune.threads import one_thread

        with one_thread():          # many small matrix operations: one BLAS thread is fastest
            return self._ask_one_thread(n)

    def _rule_ask(self, n: int, g: int, theta: np.ndarray, pool: int, design: bool, rule: str,
                  **record: Any) -> tuple[np.ndarray, np.ndarray]:
        """An ask a rule decides without the models: ``theta`` (d,) ``n`` times, tagged
        ``pool`` in generation ``g``, recorded as a decision with the ``rule`` and ``record``."""
        self.last_z = np.full((n, self.k), np.nan)
        self.decisions.append({"generation": g, "n_told": self.n_told, "design": design,
                               "rule": rule, **record, "pools": [POOL_NAMES[pool]] * n,
                               "explore": False, **self._fits_said()})
        return np.tile(theta, (n, 1)), np.full(n, 4 * g + pool, dtype=np.int64)

    def _fits_said(self) -> dict[str, Any]:
        """``{"fit_failed": {model: why}}`` for the model fits that raised since the last
        decision (each kept its starting hyperparameters: the ask differs from a fitted one's),
        then forgotten; ``{}`` when none did."""
        said, self._fit_failed = self._fit_failed, {}
        return {"fit_failed": said} if said else {}

    def _manual_ask(self, n: int, g: int) -> tuple[np.ndarray, np.ndarray]:
        """Every told trial fell: the target's manual θ once, first; the rest of a batch (n > 1)
        is what the ask would be otherwise (never the manual θ again), and the generation's
        decision is that ask's with the rule and the manual θ's pool put first."""
        rule = "every trial so far fell: the target's manual θ"
        if n == 1:
            return self._rule_ask(1, g, self.manual, ELITE, True, rule)
        X, T = self._ask_one_thread(n, manual=False)   # n: room for the manual θ among them
        keep = np.flatnonzero(np.abs(X - self.manual).max(1) > 1e-9)[:n - 1]
        z = np.vstack([np.full((1, self.k), np.nan), self.last_z[keep]])
        dec = self.decisions[-1]
        dec.update(rule=f"{rule}, then the ask's own",
                   pools=["elite"] + [dec["pools"][i] for i in keep])
        self.last_z = z
        return (np.vstack([self.manual[None, :], X[keep]]),
                np.concatenate([[4 * g + ELITE], T[keep]]).astype(np.int64))

    def _ask_one_thread(self, n: int, manual: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """The ask of ``n`` points (``manual``: the manual-θ rule may decide it, as it does
        unless :meth:`_manual_ask` asks the rest of its batch)."""
        st = self._replay_state()
        g = st["generation"]
        self._auto = {}
        if self.fall_budget_spent:
            k_fb = self.falls_allowed()
            return self._rule_ask(n, g, self._centre(), FULL, False,
                                  f"the fall budget is spent ({counted(k_fb, 'fall')} of "
                                  f"{counted(self.budget, 'trial')}): the best θ",
                                  fall_budget=k_fb)
        rng = np.random.default_rng([self.seed, g, 11])
        sm = self.source_model()
        cost_m, fall_m = self.models()
        void = np.isin(np.arange(self.n_told), st["void"])
        fragile = self._fragile()
        centre = self._centre(void | fragile)
        centre_screened = False
        if self.opts["centre_screen"] and fall_m is not None:
            centre, centre_screened = self._screened_centre(centre, void, fall_m)
        agree, agree_sd = (np.array([1.0, 0.0]), np.array([1.0, 1.0])) if cost_m is None \
            else cost_m.coefficients()
        w_lat = float(np.clip(agree[0], 0.0, self.opts["latent_share_max"]))
        latent_off = st["latent_told"] >= self.opts["latent_falls"] and \
            st["latent_fell"] * 2 > st["latent_told"]
        if latent_off or self.latent is None:
            w_lat = 0.0
        E = self._pool_elite()
        design = st["n_own"] < int(self.opts["n_design"]) and len(E) >= 1   # elites left to ask
        M = int(self.opts["n_candidates"])
        if manual and self._manual_next():
            return self._manual_ask(n, g)
        if st["converged"] and self.opts["stop_converged"]:
            return self._rule_ask(n, g, centre, FULL, False,
                                  "the trust region converged: the centre",
                                  length=st["L"], restarts=st["restarts"])
        walk = None if design else self._walk_theta(fall_m)
        if walk is not None:
            return self._rule_ask(n, g, walk[0], ELITE, True,
                                  "the source's top fell: a θ deeper in its record",
                                  walk_rank=walk[1],
                                  **({} if walk[2] is None else {"walk_fall_prob": walk[2]}))
        ctx = _AskContext(generation=g, state=st, design=design, agree=agree,
                          agree_sd=agree_sd, w_lat=w_lat, latent_off=latent_off, cost_m=cost_m,
                          fall_m=fall_m,
                          centre_screened=centre_screened,
                          fragile=int(fragile.sum()))
        if design and len(E) >= 1 and self.opts["design_screen"]:
            ok_e = self._fall_prob(E, fall_m) <= float(self.opts["max_fall_prob"])
            if ok_e.sum() < n:          # the screen rejects the elites: search instead
                design = ctx.design = False
                ctx.design_screened = True
        if design and len(E) >= 1:
            parts = [(E, np.full((len(E), self.k), np.nan), ELITE)]
        elif self.opts["record_cma"] and self.record_fell():
            # the source's record fell on the target: CMA-ES behind the fall screen from here
            XC = self._pool_cma(M)
            ctx.explore_cma = ctx.record_cma = True
            parts = [(XC, np.full((len(XC), self.k), np.nan), GLOBAL)]
        elif self._explore_generation(g, st["L"], st["explore_next"]) and \
                st["explore_pool"] is not None:
            # explore: the whole latent box (or θ box), or the source's distribution, only
            ctx.explore = True
            where = st["explore_pool"]
            if self.opts["explore_gp"] and cost_m is not None and \
                    where in ("lines", "latent_lines"):
                ctx.explore_gp = self._explore_target_gp(cost_m)
            if self._escape_due():      # everything the source suggested fell: go far from it
                ctx.escape = True
                parts = [(self._pool_global(M, rng), np.full((M, self.k), np.nan), GLOBAL)]
            elif where == "lines":
                XI = self._pool_lines(M, centre, rng)
                if ctx.explore_gp is not None:
                    XI = self._pool_explore_gp(XI, ctx.explore_gp, rng)
                parts = [(XI, np.full((len(XI), self.k), np.nan), GLOBAL)]
            elif where == "latent_lines":
                XL, UL = self._pool_latent(M // 2, st["L"], centre, rng, whole=True)
                XI = self._pool_lines(M - len(XL), centre, rng)
                if ctx.explore_gp is not None:      # the decoded codes stay candidates
                    XI = self._pool_explore_gp(XI, ctx.explore_gp, rng)
                parts = [(XL, UL, LATENT), (XI, np.full((len(XI), self.k), np.nan), GLOBAL)]
            elif where == "cma":
                XC = self._pool_cma(M)
                ctx.explore_cma = True
                parts = [(XC, np.full((len(XC), self.k), np.nan), GLOBAL)]
            elif where == "box" or (self.latent is None and where == "latent"):
                parts = [(self._pool_global(M, rng), np.full((M, self.k), np.nan), GLOBAL)]
            else:                       # "latent", "source" or "both"
                m_src = {"latent": 0, "source": M, "both": M // 2}[where] \
                    if self.latent is not None else M
                XL, UL = self._pool_latent(M - m_src, st["L"], centre, rng, whole=True)
                XS = self._pool_source(m_src, rng)
                parts = [(XL, UL, LATENT), (XS, np.full((len(XS), self.k), np.nan), GLOBAL)]
            if self.opts["explore_skip"] and bool((~self._fell).any()) and \
                    (self._fall_prob(np.vstack([p[0] for p in parts]), fall_m)
                     <= float(self.opts["max_fall_prob"])).sum() < n:
                # the screen admits too few of the explore pool: the trust region asks instead
                ctx.explore, ctx.explore_skipped, ctx.explore_gp = False, True, None
                XF = self._pool_full(M, st["L"], centre, rng, cost_m.ls if cost_m is not None
                                     and self._fitted_ls() else None)
                parts = [(XF, np.full((len(XF), self.k), np.nan), FULL)]
        else:
            m_lat = int(round(M * w_lat))
            XL, UL = self._pool_latent(m_lat, st["L"], centre, rng)
            m_glob = int(round(M * float(self.opts["global_share"])))
            XG = self._pool_global(m_glob, rng)
            m_full, k_sc = M - len(XL) - len(XG), max(1, int(self.opts["full_scales"]))
            l_max = self._side_rules(self._handoff_active())[3]
            XF = np.vstack([self._pool_full(
                m_full // k_sc + (1 if i < m_full % k_sc else 0),
                min(st["L"] * 2.0 ** i, l_max), centre, rng,
                cost_m.ls if cost_m is not None and self._fitted_ls() else None)
                for i in range(k_sc)])
            parts = [(E, np.full((len(E), self.k), np.nan), ELITE),
                     (XF, np.full((len(XF), self.k), np.nan), FULL), (XL, UL, LATENT),
                     (XG, np.full((len(XG), self.k), np.nan), GLOBAL)]
            if self.opts["region_gp"] and cost_m is not None and st["explore_pool"] == "lines":
                # the lines lead the explore record: the target's own GP chooses this ask too
                ctx.explore_gp, ctx.region_gp = self._explore_target_gp(cost_m), True
                XS = self._pool_global(M // 2, rng)
                XM = np.vstack([XS, gp_maxima(ctx.explore_gp,
                                               np.vstack([p[0] for p in parts] + [XS]))])
                parts.append((XM, np.full((len(XM), self.k), np.nan), GLOBAL))
            refine = self.opts["refine_scores"]
            if refine is not None and refine != self.opts["target_scores"] and \
                    cost_m is not None and not ctx.region_gp:
                # the refinement chooses by a model of other scores (the pools stay the same)
                cost_m = ctx.cost_m = self._cost_model(refine)
                ctx.refine_scores = refine
        keys = None
        if self.opts["distinct"]:
            taken = self._told_keys()
            keys, fresh = self._fresh(np.vstack([p[0] for p in parts]), taken)
            if fresh.sum() < n:         # too few θ not run yet: drop repeats, add perturbations
                parts = self._distinct(parts, fresh, taken, st["L"], centre, rng)
                ctx.duplicates, keys = int((~fresh).sum()), None
        C = np.vstack([p[0] for p in parts])
        bound, rank = self._fall_bound(C, fall_m)
        cands = _Candidates(
            X=C, Z=np.vstack([p[1] for p in parts]) if self.k else np.empty((len(C), 0)),
            pool=np.concatenate([np.full(len(p[0]), p[2], dtype=np.int64) for p in parts]),
            pf=self._fall_prob(C, fall_m, bound), rank=rank)
        # the fall screen (an explore ask, and a screened ``region_gp`` ask, first at the
        # explore asks' own, stricter bound)
        ok = cands.pf <= float(self.opts["max_fall_prob"])
        q_ex = float(self.opts["explore_fall_prob"])
        if (ctx.explore or (ctx.region_gp and self.opts["region_gp"] == "screened")) \
                and q_ex > 0.0:
            strict = cands.pf <= q_ex
            ctx.explore_bound = q_ex if strict.sum() >= n else float(self.opts["max_fall_prob"])
            ok = strict if strict.sum() >= n else ok
        if ok.sum() < n and self._fallback_due(ctx):
            cands = self._safe_fallback(cands, st["L"], centre, fall_m, rng)
            C, ctx.safe_fallback = cands.X, True
            if keys is not None:
                keys = self._fresh(C)[0]
            ok = cands.pf <= float(self.opts["max_fall_prob"])
        forced = ok.sum() < n
        if forced:
            ok = np.zeros(len(C), dtype=bool)
            ok[np.argsort(cands.risk, kind="stable")[:max(n, min(len(C), 3 * n))]] = True
        cands.ok = ok
        cand = np.flatnonzero(ok)
        if ctx.escape:          # the candidates farthest from every told trial (all fell)
            return self._chosen(cands, self._farthest(C, n), ctx)
        if ctx.explore_cma:     # CMA-ES's own order: its first draws the screen admits, or
            # where it admits too few, the least likely to fall
            sel = cand[np.argsort(cands.risk[cand], kind="stable")] if forced else cand
            return self._chosen(cands, sel[:n], ctx)
        if ctx.explore_gp is not None:      # the target's own GP chooses: highest log EI
            acq = ctx.explore_gp.log_ei(C[cand])
            if fall_m is not None and self.opts["fall_cost"]:     # EI · (1 − p), as below
                p = self._fall_outcome(C[cand], fall_m, ctx.explore_gp.v, cands.pf[cand])[0]
                acq = acq + np.log(np.maximum(1.0 - p, 1e-300))
            order = cand[np.argsort(-acq, kind="stable")]
            sel = order[:n] if keys is None else self._distinct_picks(order, keys, n, ctx)
            if len(sel) < n:                # every admissible θ is told: the best of them
                sel = np.concatenate([sel, order[:n - len(sel)]])
            return self._chosen(cands, sel, ctx)
        ei = self.opts["acquisition"] == "ei" and cost_m is not None
        mu = var = None
        if cost_m is not None and (ei or len(cand) > _JOINT):
            mu, _ = cost_m.mean_cov(C[cand], False)
            var = cost_m.variance(C[cand])
        p_fall = s_fall = None
        if cost_m is not None and fall_m is not None and self.opts["fall_cost"]:
            p_fall, s_fall = self._fall_outcome(C[cand], fall_m, cost_m.v, cands.pf[cand])
        if cost_m is not None and len(cand) > _JOINT:
            # joint samples on the candidates a sample could pick: the lowest confidence bounds
            lcb = mu - 2.0 * np.sqrt(var)
            if p_fall is not None:
                lcb = (1.0 - p_fall) * lcb + p_fall * s_fall
            keep = np.sort(np.argsort(lcb, kind="stable")[:_JOINT])
            cand, mu, var = cand[keep], mu[keep], var[keep]
            p_fall = None if p_fall is None else p_fall[keep]
        if ei:                  # expected improvement over the best told value, top n
            from scipy.stats import norm

            sd = np.sqrt(np.maximum(var, 1e-12))
            u = (float(cost_m.v.min()) - mu) / sd
            acq = sd * (u * norm.cdf(u) + norm.pdf(u))
            if p_fall is not None:
                acq = acq * (1.0 - p_fall)
            order = cand[np.argsort(-acq, kind="stable")]
            sel = order[:n] if keys is None else self._distinct_picks(order, keys, n, ctx)
            if len(sel) < n:
                sel = np.resize(sel, n)
            return self._chosen(cands, sel, ctx)
        # joint Thompson samples of the cost model on the admissible candidates
        if cost_m is None:
            mu, cov = sm.cost(C[cand]), None
        else:
            mu, cov = cost_m.mean_cov(C[cand])
        if cov is None:
            S = np.tile(mu, (n, 1)) + 0.1 * rng.standard_normal((n, len(cand)))
        else:
            Lc = jittered_cholesky(0.5 * (cov + cov.T))
            S = mu[None, :] + rng.standard_normal((n, len(cand))) @ Lc.T
        if p_fall is not None:
            S = (1.0 - p_fall)[None, :] * S + (p_fall * s_fall)[None, :]
        picked: list[int] = []                   # indices into ``cand``
        chosen: list[int] = []                   # indices into ``C``
        if keys is not None:                     # ``distinct``: a repeat is never picked
            taken = self._told_keys()
            ck = [keys[i] for i in cand]
            banned = np.array([k in taken for k in ck], dtype=bool)
        for j in range(n):
            s = S[j % len(S)].copy()
            s[picked] = np.inf
            if keys is not None:
                first = int(np.argmin(s))
                s[banned] = np.inf
                i = None
                if np.all(~np.isfinite(s)):      # every admissible candidate is a repeat:
                    i = self._least_falling_new(cands.risk, keys, taken)  # the screen's rule
                if i is None and np.any(np.isfinite(s)):
                    picked.append(int(np.argmin(s)))
                    i = int(cand[picked[-1]])
                if i is not None:
                    ctx.repeats += int(i != cand[first])
                    chosen.append(i)
                    taken.add(keys[i])           # its θ, wherever else it is a candidate
                    banned |= np.array([k == keys[i] for k in ck], dtype=bool)
                    continue
            if np.all(~np.isfinite(s)):          # fewer candidates than points: reuse the best
                s = S[j % len(S)].copy()
            picked.append(int(np.argmin(s)))
            chosen.append(int(cand[picked[-1]]))
        return self._chosen(cands, np.asarray(chosen, dtype=np.int64), ctx)

    @staticmethod
    def _least_falling_new(pf: np.ndarray, keys: list[tuple[float, ...]],
                           taken: set[tuple[float, ...]]) -> int | None:
        """The candidate (index) least likely to fall (``pf`` (m,)) whose θ is not in ``taken``
        (``distinct``), or None."""
        for i in np.argsort(pf, kind="stable"):
            if keys[i] not in taken:
                return int(i)
        return None

    def _told_keys(self) -> set[tuple[float, ...]]:
        """The told θ, rounded to 1e-9 (``distinct``)."""
        return {tuple(r) for r in np.round(self._X, 9).tolist()} if self.n_told else set()

    def _fresh(self, C: np.ndarray, taken: set[tuple[float, ...]] | None = None
               ) -> tuple[list[tuple[float, ...]], np.ndarray]:
        """Keys (θ rounded to 1e-9) of the candidates ``C`` (m, d) and which of them (m,) are
        neither in ``taken`` (default: the told θ) nor a repeat of an earlier candidate
        (``distinct``); ``taken`` gains every key."""
        taken = self._told_keys() if taken is None else taken
        keys = list(map(tuple, np.round(C, 9).tolist()))
        fresh = np.zeros(len(C), dtype=bool)
        for i, k in enumerate(keys):
            fresh[i] = k not in taken
            taken.add(k)
        return keys, fresh

    def _distinct_picks(self, order: np.ndarray, keys: list[tuple[float, ...]], n: int,
                        ctx: _AskContext) -> np.ndarray:
        """The first ``n`` candidates of ``order`` (indices, best first) whose θ is neither told
        nor picked already (``distinct``)."""
        told, out, taken = self._told_keys(), [], set()
        for i in order:
            if keys[i] in told or keys[i] in taken:
                continue
            out.append(int(i))
            taken.add(keys[i])
            if len(out) == n:
                break
        ctx.repeats += int(list(order[:len(out)]) != out)
        return np.asarray(out, dtype=np.int64)

    def _distinct(self, parts: list[tuple[np.ndarray, np.ndarray, int]], fresh: np.ndarray,
                  taken: set[tuple[float, ...]], L: float, centre: np.ndarray,
                  rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray, int]]:
        """The candidate pools ``parts`` ((θ (m_i, d), codes (m_i, k), pool) each) cut to their
        ``fresh`` candidates ((Σ m_i,) bool, :meth:`_fresh` over the pools stacked), with
        perturbations of ``centre`` in the full pool (side ``L``) added whose θ are not in
        ``taken`` (the told θ and every candidate's) nor repeated (option ``distinct``). A
        decoder that maps a region of codes to one θ, or fewer elites than the batch, would
        otherwise make the batch ask one θ several times, or a θ the target has run."""
        cuts = np.cumsum([len(X) for X, _, _ in parts])[:-1]
        out = [(X[f], Z[f], pool) for (X, Z, pool), f in zip(parts, np.split(fresh, cuts))]
        XF = self._pool_full(int(self.opts["n_candidates"]), L, centre, rng)
        new = self._fresh(XF, taken)[1]
        out.append((XF[new], np.full((int(new.sum()), self.k), np.nan), FULL))
        return out

    def _fallback_due(self, ctx: _AskContext) -> bool:
        """Whether this ask, whose screen admitted fewer candidates than the batch, takes
        :meth:`_safe_fallback`'s steps (never an explore ask): ``safe_fallback=True`` on every
        other ask; ``"region"`` on the trust-region asks only (not while the source's elites are
        the initial design) until the explore asks' brake (:meth:`_braked`) stops the told trials
        of fallback asks (the generations whose decision recorded ``safe_fallback``): where
        small steps from the standing θ fall, the fallback is no safer than the least risky
        candidate the screen ranked."""
        mode = self.opts["safe_fallback"]
        if not mode or ctx.explore:
            return False
        if mode != "region":
            return True
        if ctx.design:
            return False
        gens = [int(d["generation"]) for d in self.decisions if d.get("safe_fallback")]
        return not self._braked((self._tags >= 0) & np.isin(self._tags // 4, gens), True)

    def _safe_fallback(self, cands: _Candidates, L: float, centre: np.ndarray,
                       fall_m: TargetModel | None, rng: np.random.Generator) -> _Candidates:
        """``cands`` with full-pool perturbations of ``centre`` (the best θ that did not fall)
        added on shrinking sides ``L/2, L/4, …, L/2^8`` (``n_candidates/8`` each): where the fall
        screen rejects the candidates, the search steps back toward the safe trial, as safe
        Bayesian optimization expands from its safe set, instead of asking the candidate least
        likely to fall (``safe_fallback``)."""
        M, J = int(self.opts["n_candidates"]), 8
        XS = np.vstack([self._pool_full(max(1, M // J), L / 2.0 ** j, centre, rng)
                        for j in range(1, J + 1)])
        bound, rank = self._fall_bound(XS, fall_m)
        return _Candidates(
            X=np.vstack([cands.X, XS]),
            Z=np.vstack([cands.Z, np.full((len(XS), self.k), np.nan)]),
            pool=np.concatenate([cands.pool, np.full(len(XS), FULL, dtype=np.int64)]),
            pf=np.concatenate([cands.pf, self._fall_prob(XS, fall_m, bound)]),
            rank=None if cands.rank is None else np.concatenate([cands.rank, rank]))

    def _fall_outcome(self, C: np.ndarray, fall_m: TargetModel, v: np.ndarray, pf: np.ndarray
                      ) -> tuple[np.ndarray, float]:
        """The fall model's posterior mean probability (m,) at θ ``C`` (m, d), clipped to [0, 1]
        (with ``fall_calibrate``, ``pf`` (m,): the calibrated screen's probability
        :meth:`_fall_prob` at ``C``, as the screen computed it), and
        the cost rank score of a fall (``fall_cost``): the mean of the told falls' scores in
        ``v`` (n_told,) (the cost model's rank scores of the told trials), or, before any fall,
        the score of the last of ``n_told + 1`` ranks."""
        from scipy.special import ndtri

        p = pf if self.opts["fall_calibrate"] else \
            np.clip(fall_m.mean_cov(C, False)[0], 0.0, 1.0)
        if self._fell.any():
            s = float(v[self._fell].mean())
        else:
            s = float(ndtri(1.0 - 0.5 / (self.n_told + 1)))
        return p, s

    def _fall_prob(self, C: np.ndarray, fall_m: TargetModel | None,
                   bound: np.ndarray | None = None) -> np.ndarray:
        """The fall screen's probability (m,) at θ ``C`` (m, d): :meth:`_fall_score`, mapped by
        the target's calibration (:meth:`calibration`) with ``fall_calibrate``. ``bound``: the
        candidates' bound (:meth:`_fall_bound`) when already computed."""
        p = self._fall_score(C, fall_m) if bound is None else np.clip(bound, 0, 1)
        if not self.opts["fall_calibrate"]:
            return p
        ab = self.calibration()
        return p if ab is None else calibrated(p, ab)

    def _fall_score(self, C: np.ndarray, fall_m: TargetModel | None) -> np.ndarray:
        """The fall screen's score (m,) at θ ``C`` (m, d): the bound of :meth:`_fall_bound`
        clipped to [0, 1]."""
        return np.clip(self._fall_bound(C, fall_m)[0], 0, 1)

    def _fall_bound(self, C: np.ndarray, fall_m: TargetModel | None
                    ) -> tuple[np.ndarray, np.ndarray | None]:
        """``(bound, order)`` at θ ``C`` (m, d), from one evaluation of the models. ``bound``
        (m,) is the fall screen's bound, not clipped: the source's fall model
        before the target has data, else the target fall model's upper confidence bound (where
        the model is unsure, it screens). With ``fall_source_sd`` the source fall model's own
        standard deviation joins the bound (``fall_kappa`` times the root of the two variances
        summed; before the target has data, the source mean plus ``fall_kappa`` of its sd), so
        θ far from every source trial, where the source's fall model only knows its prior, are
        screened as unknown rather than as the source's average. ``order`` (m,) is what
        ``fall_rank`` takes the least likely to fall by: None with ``"clipped"``, else the bound
        or the posterior mean, unclipped."""
        sm = self.source_model()
        kappa = float(self.opts["fall_kappa"])
        v_src = sm.fall_sd(C) ** 2 if self.opts["fall_source_sd"] else 0.0
        if fall_m is None:
            mean, var = sm.fall_prob(C), v_src
        else:
            mean, var = fall_m.mean_cov(C, False)[0], fall_m.variance(C) + v_src
        bound = mean + kappa * np.sqrt(var)
        how = self.opts["fall_rank"]
        return bound, (None if how == "clipped" else bound if how == "bound" else mean)

    def prequential_scores(self) -> np.ndarray:
        """(n_told,) the fall screen's score (:meth:`_fall_score`) of each told θ from the trials
        told before it: the fall model fitted on rows ``0 … t−1`` (the source's fall model for
        row 0) scores row ``t``. Out-of-sample by construction; a function of the told history
        (kept as the history grows, which tells only append to)."""
        for t in range(len(self._preq), self.n_told):
            fall_m = None if t == 0 else self._fall_model(t)
            self._preq = np.append(self._preq, self._fall_score(self._X[t:t + 1], fall_m))
        return self._preq[:self.n_told]

    def calibration(self) -> np.ndarray | None:
        """(2,) ``(a, b)`` of the target's calibration of the fall screen, ``P(fall) =
        σ(a + b · logit s)`` for a screen score ``s`` (Platt scaling), fitted by maximum a
        posteriori on the told trials' :meth:`prequential_scores` and fall flags with the prior
        ``a ~ N(0, 1)``, ``b ~ N(1, ½²)`` (the identity map: before the target's outcomes say
        otherwise, a score is its probability); None before any told trial."""
        if self.n_told == 0:
            return None
        if self._calib is None or self._calib[0] != self.n_told:
            self._calib = (self.n_told, fit_calibration(self.prequential_scores(),
                                                        self._fell[:self.n_told]))
        return self._calib[1]

    def _chosen(self, cands: _Candidates, sel: np.ndarray, ctx: _AskContext
                ) -> tuple[np.ndarray, np.ndarray]:
        """The chosen candidates ``cands.X[sel]`` with their tags; records the decision."""
        n = len(sel)
        X = cands.X[sel]
        self.last_z = cands.Z[sel] if self.k else np.empty((n, 0))
        tags = 4 * ctx.generation + cands.pool[sel]
        cm = ctx.cost_m
        self.decisions.append({
            "generation": ctx.generation, "n_told": self.n_told, "design": bool(ctx.design),
            "agreement": float(ctx.agree[0]), "agreement_sd": float(ctx.agree_sd[0]),
            **({"agreement_unmeasured": why} if (why := agreement_unmeasured(cm)) else {}),
            "sigma_r2": None if cm is None else cm.sigma_r2,
            "ls_scale": None if cm is None else cm.ls_scale,
            **({"tilt": getattr(cm, "tilt", None)} if self.opts["tilt"] else {}),
            "latent_share": ctx.w_lat, "latent_off": bool(ctx.latent_off),
            "length": ctx.state["L"], "restarts": ctx.state["restarts"],
            "n_candidates": int(len(cands.X)), "n_admissible": int(cands.ok.sum()),
            "max_fall_prob_asked": float(cands.pf[sel].max()),
            **({"max_fall_rank_asked": float(cands.rank[sel].max())}
               if cands.rank is not None else {}),
            "pools": [POOL_NAMES[int(p)] for p in cands.pool[sel]],
            "explore": bool(ctx.explore),
            **({"explore_pool": ctx.state["explore_pool"]} if ctx.explore else {}),
            **({"explore_record": ctx.state["explore_record"]}
               if ctx.explore and self.opts["explore_pool"] == "adaptive" else {}),
            **({"explore_braked": True} if ctx.state.get("explore_braked") else {}),
            **({"explore_bound": ctx.explore_bound} if ctx.explore_bound is not None else {}),
            **({"explore_skipped": True} if ctx.explore_skipped else {}),
            **({"region_gp" if ctx.region_gp else "explore_gp": True}
               if ctx.explore_gp is not None else {}),
            **({"fall_calibration": [float(v) for v in self.calibration()]}
               if self.opts["fall_calibrate"] and self.n_told else {}),
            **({"explore_void": len(ctx.state["void"])}
               if self.opts["explore_void"] else {}),
            **({"explore_next": int(ctx.state["explore_next"])}
               if self.opts["explore_adapt"] else {}),
            **({"design_screened": True} if ctx.design_screened else {}),
            **({"centre_screened": True} if ctx.centre_screened else {}),
            **({"centre_fragile": ctx.fragile} if self.opts["centre_falls"] else {}),
            **({"duplicates_dropped": ctx.duplicates} if ctx.duplicates else {}),
            **({"escape": True} if ctx.escape else {}),
            **({"repeats_avoided": ctx.repeats} if ctx.repeats else {}),
            **({"safe_fallback": True} if ctx.safe_fallback else {}),
            **({"fall_fit": [ctx.fall_m.ls_scale, ctx.fall_m.noise]}
               if self.opts["fall_fit"] and ctx.fall_m is not None else {}),
            **({"ls_ratio": float(np.exp(np.mean(np.log(
                cm.ls / self.source_model().lengthscales))))}
               if cm is not None and self._fitted_ls() else {}),
            **({"handoff": True} if self._handoff_active() else {}),
            **({"record_cma": True} if ctx.record_cma else {}),
            **({"refine_scores": ctx.refine_scores} if ctx.refine_scores else {}),
            **({"auto_scores": dict(self._auto)} if self._auto else {}),
            **({"explore_scores": self.opts["explore_scores"]}
               if ctx.explore_gp is not None and self.opts["explore_scores"] is not None
               else {}),
            **self._fits_said()})
        log.debug("transfer ask %s", self.decisions[-1])
        return X, tags

    # ------------------------------------------------------------------ state
    def state_dict(self) -> dict[str, Any]:
        """The options, the source models' fitted hyperparameters, every decision of the run
        (one per ask, by generation; a generation asked again keeps its last decision) and the
        last one (JSON-ready)."""
        by_gen = {int(d["generation"]): d for d in self.decisions}
        return {"options": dict(self.opts), "source_hypers": self._hypers,
                "decisions": [by_gen[g] for g in sorted(by_gen)],
                "last_decision": self.decisions[-1] if self.decisions else None}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore :meth:`state_dict`: the decisions so far, the source hyperparameters, and the
        options the stored run was asked with (a state stored before options were recorded
        resumes with :data:`LEGACY_OPTIONS`), so a resumed run asks what the original would
        have and its record of decisions carries on."""
        if not state:
            return
        if state.get("decisions") and not self.decisions:     # the run's record carries on
            self.decisions = [dict(d) for d in state["decisions"]]
        if state.get("source_hypers") and self._model is None:
            self._hypers = state["source_hypers"]
        if "options" in state:
            self.opts.update(stored_options(state))
        elif "last_decision" in state:      # options given to the constructor stand
            self.opts.update({k: v for k, v in LEGACY_OPTIONS.items() if k not in self._explicit})

    def __repr__(self) -> str:
        return (f"Transfer(dim={self.dim}, k={self.k}, n_source={len(self.source[1])}, "
                f"n_told={self.n_told}, best_y={self.best_y:.6g})")


def falls_allowed(share: float, budget: int | None) -> int | None:
    """The falls a target of ``budget`` trials may take under ``fall_budget`` = ``share``:
    ``max(1, ⌊share · budget⌋)``, or None without a budget (``share`` 0 or ``budget`` None)."""
    if float(share) <= 0.0 or budget is None:
        return None
    return max(1, int(np.floor(float(share) * int(budget) + 1e-9)))


def fall_budget_spent(fell: np.ndarray, share: float, budget: int | None,
                      counts: str = "all") -> bool:
    """Whether told outcomes ``fell`` (n,) bool, in told order, spent the fall budget
    :func:`falls_allowed` of ``share`` and ``budget``: one of them stands and the falls it
    counts reach it, every fall (``counts="all"``) or those told after the first trial that
    stood (``"after_stand"``)."""
    k = falls_allowed(share, budget)
    fell = np.asarray(fell, dtype=bool)
    return k is not None and not fell.all() and counted_falls(fell, counts) >= k


def fall_budget_status(fell: np.ndarray, share: float, budget: int | None,
                       counts: str = "all") -> dict[str, Any] | None:
    """The fall budget over told outcomes ``fell`` (n,) bool, in told order, as ``status``
    reports it: ``{falls_allowed, falls, counts, spent}`` (:func:`falls_allowed`,
    :func:`counted_falls`, :func:`fall_budget_spent`), or None without a budget."""
    k = falls_allowed(share, budget)
    if k is None:
        return None
    f = np.asarray(fell, dtype=bool)
    return {"falls_allowed": k, "falls": counted_falls(f, counts), "counts": counts,
            "spent": fall_budget_spent(f, share, budget, counts)}


def counted_falls(fell: np.ndarray, counts: str = "all") -> int:
    """The falls a fall budget counts among told outcomes ``fell`` (n,) bool, in told order:
    all of them (``counts="all"``) or those after the first trial that stood
    (``"after_stand"``; none while every trial fell)."""
    fell = np.asarray(fell, dtype=bool)
    if counts == "all":
        return int(fell.sum())
    return 0 if fell.all() else int(fell[int(np.argmax(~fell)) + 1:].sum())


def stored_options(state: dict[str, Any]) -> dict[str, Any] | None:
    """The options a stored :meth:`Transfer.state_dict` resumes with: the recorded ones, and
    :data:`ADDED_OPTIONS` for options added after it was stored; :data:`LEGACY_OPTIONS` for a
    state stored before options were recorded (options its constructor was given then stand
    instead, which the state does not record); None for a state that is not a transfer
    critic's."""
    if "options" in state:
        return {**TRANSFER_DEFAULTS, **ADDED_OPTIONS, **state["options"]}
    if "last_decision" in state:
        return dict(LEGACY_OPTIONS)
    return None


def canonical_order(X: np.ndarray, y: np.ndarray, fell: np.ndarray) -> np.ndarray:
    """(N,) the permutation that sorts trials by cost, then fell, then θ's coordinates: the same
    set of trials in any order gives the same sorted rows (a source is a set; the order a
    parallel run stored a batch in carries no information)."""
    X = np.asarray(X, dtype=float)
    keys = [X[:, j] for j in range(X.shape[1] - 1, -1, -1)]
    return np.lexsort([*keys, np.asarray(fell, dtype=bool), np.asarray(y, dtype=float)])
