#pragma once
// riSAM-style incremental GNC (McGann, Rogers, Kaess, ICRA 2023) as a Backend decorator over
// an incremental inner backend ("isam2"; "lm" works too, at batch cost).
//
// Trusted factors (priors, odometry) pass through and stay quadratic. Each uncertain factor
// enters as a GraduatedFactor: riSAM's SIG kernel w = c²(c² + (χ²)^μ(1−μ))/(c² + (χ²)^μ)² at a
// fixed μ, evaluated (IRLS) whenever the inner backend linearizes it. An update that brings
// uncertain factors resets μ to μ_init for them and for the existing uncertain factors that
// share a variable with them, then walks μ along the schedule
//   μ ← min(1, μ + 1.2·(μ − μ_init + 0.1))       (0 → 0.12 → 0.384 → 0.965 → 1)
// with one extra inner update per step. A step changes μ by removing each graduated factor
// and re-adding it under a fresh internal id in the same inner update: that is what makes an
// incremental inner backend relinearize it (a mutable weight would be ignored by cached
// linearizations). Internal ids have the top bit set; original ids must stay below 2⁶³.
// decisions(): SIG weight at the current estimate; rejected(): riSAM's benchmark rule, the
// χ² test χ² > χ²_dim(0.95) at the current estimate (a weight threshold would depend on c).
// Shape c: √χ²_dim(0.95) per factor dimension by default (2.80 for SE2, 3.55 for SE3; the
// paper's c = 3 was for 2D), or BackendOptions::robustParameter for every factor.
#include <functional>
#include <memory>
#include <unordered_map>
#include <unordered_set>

#include "robust/decorator_backend.h"
#include "robust/risam_sig_factor.h"

namespace loopd {

class GncBackend;
class Isam2Backend;
struct TailGate;

struct RisamOptions {
  double shape = 0.0;  // c; ≤ 0: √χ²_dim(0.95) (BackendOptions::robustParameter overrides)
  double muInit = 0.0;
  int extraIterations = 1;         // inner updates at μ = 1 after the schedule
  bool graduateNeighbours = true;  // also reset uncertain factors sharing a variable
  int neighbourWindow = 0;         // … or touching a variable within this many indices of one
  double rejectChi2Probability = 0.95;  // rejected when χ² > χ²_dim(p)
  /// The truncated cost that judges one answer against another at optimize() (the GNC look,
  /// the final candidates, the drop check, the fresh start) caps an uncertain factor at
  /// max(rejection test, χ²_dim(costCapProbability)) unless the gate is tight; online (a
  /// contested arrival) the cap is the rejection test. Capped at χ²_dim(0.95), a true closure
  /// whose removal lowers the least squares by more than that, one in twenty, is cheaper
  /// rejected: kitti_00's 945-pose loop 3370 → 2425 (χ² 1.84 at the optimum, removal gain
  /// 13.7 against 12.59) was, +35%. 0.99 is `gnc-tls`'s truncation, and what the final
  /// candidates' marginal test already allows. ≤ 0: the rejection test.
  double costCapProbability = 0.99;
  /// Noise-aware shape and test (off when BackendOptions::robustParameter > 0 or
  /// tailExponent < 0): the gate g of GncOptions (min(medianFactor·q50, q99·(q99/q90)^e) of
  /// the accepted closures' χ²/χ²_dim(0.5)) is re-estimated whenever the number of uncertain
  /// factors has grown by gateRefreshGrowth (and at optimize()); once it exceeds
  /// widenFactor·c² the shape becomes c² = g·χ²_dim(0.5) and the rejection test χ² > that.
  double tailExponent = 3.0;
  double medianFactor = 100.0;
  double widenFactor = 2.0;
  double gateRefreshGrowth = 0.1;
  /// Also widen the SIG shape c² to the gate. Off: on manhattan + 100 random outliers it let
  /// one outlier in (ATE 4.8 m); with the default shape every outlier is rejected.
  bool widenShape = false;
  /// Under-confident information (parking-garage: true closures at 10⁻⁵ of χ²_dim, so a wrong
  /// closure bends the flexible map until it fits the χ²_dim defaults): once the gate
  /// g·χ²_dim(0.5) is below χ²_dim(0.95)/widenFactor for every dimension, the SIG shape c² (at
  /// μ = 1; see sigShape) and the online rejection and retry tests become g·χ²_dim(0.5) (at
  /// most χ²_dim(0.95)/widenFactor), and stay tight. The accepted closures' uncapped tail
  /// q99·(q99/q90)^e·χ²_dim(0.5), with the same bound, is what an arrival must fit to count as
  /// absorbed and what optimize() decides against: parking-garage's true closures reach 208×
  /// their median (GncOptions::tighten and readmit).
  bool tighten = true;
  /// With tighten: every uncertain factor is graduated again at the tightened shape (the inner
  /// backend optimized at each μ) when the gate first tightens and whenever it has fallen by
  /// more than this factor since.
  double regraduateFactor = 10.0;
  /// An update whose new uncertain factors all have χ² ≤ consistentFraction·(rejection
  /// threshold) at the current estimate (new variables at their initial values) adds them at
  /// μ = 1 with no graduation and no neighbour reset: one inner update instead of six.
  /// Off: on manhattan few true closures fit at arrival (odometry drift), so it saved no
  /// time (3.31 s vs 3.36 s) and, with 100 random outliers, let 1 in (ATE 4.8 m).
  bool skipConsistent = false;
  /// After the first (convex, μ = μ_init) inner update, if every active factor has
  /// χ² ≤ absorbedFraction·(rejection threshold) at the new estimate, re-add them once at
  /// μ = 1 instead of walking the schedule (2 inner updates instead of 6).
  bool acceptAbsorbed = true;
  double absorbedFraction = 0.5;
  /// At optimize() (the end of a run, the server's idle solve) each rejected factor is tested
  /// against the map's own uncertainty: rᵀ(I + JΣJᵀ)⁻¹r ≤ χ²_dim(retryProbability) with Σ the
  /// joint marginal covariance of its variables. Those that pass (true closures dropped while
  /// the map was drifted) are graduated again from μ_init. At most retryMaxTests marginals per
  /// call; nothing is retested until the number of uncertain factors changes.
  bool retryRejected = true;
  double retryProbability = 0.99;
  int retryMaxTests = 2000;
  int retryRounds = 3;
  double consistentFraction = 1.0;
  int gateMinSamples = 200;  // q99 needs a few hundred samples to mean anything
  /// The SIG weight of a graduated factor is taken at the inner backend's current estimate
  /// instead of the point it is linearized at (iSAM2's θ lags the estimate by up to its
  /// relinearization threshold, which for a stiff closure is a χ² of 10⁴ and more).
  bool weightAtEstimate = true;
  /// optimize()'s drop check (dropBending): accepted clusters (ends within dropWindow poses,
  /// at most maxCluster closures) whose predicted removal gain exceeds their rejection
  /// thresholds are rejected, kept if the truncated cost dropped. Tightened, it judges at the
  /// gate, then the decisions against the tail are made again.
  bool dropBending = true;
  int dropWindow = 10;
  int maxCluster = 20;
  /// optimize() ends with the least-squares solve over its decisions (accepted closures at
  /// weight 1, rejected at 0), decided again at that optimum, at most this many rounds.
  int finalRounds = 5;
  /// Rounds of the final marginal-test candidates (rejected closures put back at weight 1).
  int finalCandidateRounds = 3;
  /// optimize(), when it rejects anything, then also starts afresh: the linear initialization
  /// (initializeLinear) of the trusted factors and the accepted closures, solved, decided
  /// again as above; kept if its truncated cost is lower, else the answer before is restored
  /// exactly. Wrong closures that were in for a while can fold the map into a local minimum
  /// the least squares cannot leave once they are out (intel + 1000 local, seed 2: every
  /// decision right, χ² over the true edges 170 against 45 at the optimum, ATE 10.7 m).
  bool freshStart = true;
  /// Neighbours (uncertain factors sharing a variable with an arrival) are reset to μ_init
  /// only when the arrival is not absorbed at its convex step or that step pushed one of them
  /// over its rejection threshold; otherwise they keep their state (no re-add, no
  /// relinearization of their far ends).
  bool lazyNeighbours = true;
  /// An absorbed arrival goes from μ_init to μ = 1 in place (no inner update) when that
  /// changes its SIG weight at the estimate by at most this fraction. With a tightened gate,
  /// always: an absorbed arrival fits the tail test, but the tight shape weighs it differently
  /// at μ_init and μ = 1, and re-adding cost an inner update per closure (parking-garage:
  /// 2.0× plain isam2 instead of 1.5×).
  double promoteTolerance = 0.5;
  /// The steps of a graduation schedule (an arrival the convex step did not absorb) always
  /// relinearize an inner iSAM2; other updates follow its relinearizeSkip (the registry's
  /// default: 10, as plain isam2). Relinearizing at every update cost riSAM 2.3–3× plain
  /// isam2 on manhattan and parking-garage, where most arrivals are absorbed.
  bool relinearizeGraduation = true;
  /// A factor whose χ² at the end of its graduation is above parkFactor × its tail test
  /// (tailChi2; SIG weight at μ = 1 below 10⁻⁴) and whose χ² predicted with the map's own
  /// uncertainty, rᵀ(I + JΣJᵀ)⁻¹r, is above parkPredictedFactor × that test, is taken out of
  /// the inner backend at the next update: there it only added fill to the Bayes tree
  /// (sphere2500 + 1000 random outliers: plain isam2 235 s against 7.6 s without them).
  /// Parked factors are checked against the estimate before every update and come back at
  /// μ = 1 once one fits the tail test; they join an arrival's graduation as any neighbour
  /// does, and the retry at optimize() tests them too. parkFactor 0: off.
  double parkFactor = 100.0;
  double parkPredictedFactor = 10.0;
  /// An arrival after which the map's extent (largest coordinate) is more than runawayFactor
  /// × what it was before is undone: the inner iSAM2 goes back to the estimate before it (new
  /// variables at their initial values) and the arrival's uncertain factors are parked, to
  /// come back once they fit. New poses move the extent by a step; a hundredfold is a runaway
  /// (parking-garage + 1000 local outliers: 254 m → 2·10⁵ m in one arrival's graduation, the
  /// schedule's steps ×2–×20 each, then 10¹⁸⁷ m). Not 10: grouped wrong closures bend
  /// manhattan ×16–×21 for one arrival, and it recovers by itself (undone, two stayed in).
  /// 0: off.
  double runawayFactor = 100.0;
  /// A contested arrival: one with several uncertain factors whose graduation ran (not
  /// absorbed), after which more than max(collateralMin, collateralFactor × its uncertain
  /// factors) closures that passed the rejection test before it fail it, and for which the
  /// estimate before it with its uncertain factors rejected has the lower truncated cost
  /// (Σ trusted χ² + Σ uncertain min(χ², rejection test)). It is undone (the inner iSAM2 back
  /// to the estimate before it, relinearized there; its uncertain factors parked) and they
  /// are fed again one at a time, largest χ² first, each undone and parked if it alone is
  /// contested the same way. manhattan + 1000 local, seed 2: two true closures back to poses
  /// 99 and 114 arriving at pose 2848 with a wrong one from pose 2822 pushed 55 accepted true
  /// closures out, and they stayed out. The cost test keeps a true closure that pushes out
  /// wrong ones a group had bent the map to (manhattan + 1000 in groups, seed 1: P 0.986
  /// with the count alone). collateralFactor 0: off.
  double collateralFactor = 2.0;
  int collateralMin = 3;
  /// At optimize(), rounds of the gate re-estimated from the decided map (not tightened
  /// only): the online gate only ever widens, and a drifted map widens it far beyond what the
  /// settled closures' own χ² say (manhattan + 1000 random, seed 3: 121 medians online, so
  /// two wrong closures whose removal gains 180 and 230 stayed in). Taken, as GncBackend's
  /// regateAtEnd, when it shrinks the rejection test by more than widenFactor for every
  /// dimension of uncertain factor; the decisions are then made again against it. The
  /// online gate comes back with the next update. Tightened, the same rounds run after the
  /// second looks, from the map they leave, and each shrink is followed by the second looks
  /// again: the tight gate follows the online estimate, and a map bent online sets it far
  /// above what the settled closures say (parking-garage + 1000 in groups, seed 5: 0.25
  /// against 0.0015 for `gnc-tls`, so a group of 10 whose removal gains 10.3 stayed in
  /// against summed tests of 13.5). 0: off.
  int endGateRounds = 3;
  /// The first noise-aware gate that does not tighten (it would widen, or stay at the
  /// defaults) is checked against a batch GNC (`gnc-tls`, GncBackend with its defaults) over
  /// the graph so far, from the online estimate. If the accepted closures' gate at the GNC's
  /// solution tightens, the online map was bent: until the gate exists the default tests
  /// apply, and under-confident information lets wrong closures bend a flexible map until they
  /// pass them, after which a gate read off it looks like a heavy tail and widens, and a
  /// widened gate is never narrowed online (parking-garage's first 500 poses + 1000 local
  /// wrong closures, seed 1: every one of the 320 accepted, ×2·10⁵ the optimum). Then the
  /// inner iSAM2 takes the GNC's solution, the gate and tail its accepted closures give, and
  /// every uncertain factor its SIG kernel at μ = 1 there. Online once per run; and at
  /// optimize() while there are fewer than gateMinSamples uncertain factors (no gate yet) and
  /// their number changed since the last check (parking-garage:500 + 1000 in groups, seed 1:
  /// 40 wrong closures among fewer than 200, all accepted, ×3.9·10³). There, a gate that
  /// widens is taken too, with the GNC's solution, for that optimize()'s answer only (the
  /// online gate is back at the next update): too few closures for a gate of its own, it
  /// judged at the defaults, and smallGrid3D's heavy-tailed true closures (χ² up to 14.8 at
  /// the optimum, 173 of them) bent the map until four were cheaper out (+8.6%); the GNC's
  /// gate, 10.5 medians, keeps them.
  bool batchGateCheck = true;
  /// With several robots' frames joined by uncertain factors (anchor keys), a gate reading
  /// that would widen the gate beyond widenFactor times the last one a batch GNC confirmed is
  /// checked the same way: a wrong closure joining two frames, or wrong ones fighting over
  /// the join, bend both robots' maps in a way one robot's odometry never allows, and a
  /// gate read there widens and keeps widening (manhattan + 300 wrong closures in groups of
  /// 10, seed 1, fed as two interleaved robots: 16.7 → 87.5 → … → 1.5·10⁴ medians, every
  /// closure accepted, 76 m off the optimum). If the GNC's solution reads a gate at least
  /// widenFactor narrower, the inner iSAM2 takes that solution and the gate stays; otherwise
  /// the reading stands and is the confirmed one. One robot: never.
  bool frameWideningCheck = true;
  /// optimize() first takes at most this many full Gauss–Newton steps of the inner iSAM2 at
  /// the current weights (Isam2Backend::settle: each kept only if the cost falls; the first
  /// that gains less than 10% is the last, so a settled map takes one) before it
  /// reads the gate or makes a decision: an update can end mid-graduation with the map bent
  /// for one step (the next update would bring it back), and decisions read off that map
  /// stick (parking-garage + 1000 local wrong closures, seed 3: the file ends in such a bend,
  /// χ² over the true edges ×10⁹ at poses 1659–1660; read off it, the gate fell below its
  /// online value and 15 true closures were rejected, +3.8%). Not a full optimize(): under
  /// SIG weights Gauss–Newton goes uphill on a settled map and its batch fallback cost
  /// manhattan without outliers 2.9 s. 0: off.
  int convergeFirstSteps = 5;
  /// optimize(), when its answer rejects anything, last looks at a batch GNC's (`gnc-tls`,
  /// GncBackend with its defaults, over the whole graph from the answer): the inner iSAM2 is
  /// reset to the GNC's solution and the closures decided there by risam's own tests; kept if
  /// the truncated cost at the gate is lower (by more than 10⁻⁹ relative, so a tie leaves
  /// the answer as it was, bit for bit), else the answer before is restored exactly. The
  /// online run and the looks above only move the map within the basin it reached (intel +
  /// 1000 random wrong closures, seed 2: four wrong ones kept, ×4 the optimum; the GNC's
  /// basin is 4.6% cheaper at the gate, and the optimum). Costs one batch GNC per such
  /// optimize(); without outliers the answer rejects nothing and it does not run.
  bool gncLook = true;
  /// After a GNC look, optimize() looks again only once there are at least gncLookGrowth
  /// times as many uncertain factors as that look saw. The server optimizes at every input
  /// pause, and one look costs a batch `gnc-tls` over the whole graph (parking-garage + 100
  /// random wrong closures: 22–28 s against 0.5 s for the rest of optimize()); growing
  /// geometrically, the looks of a whole stream cost about 1/(1 − 1/gncLookGrowth) times the
  /// last one. A run with one optimize() (loopd-solve) always looks. ≤ 1: at every
  /// optimize() whose answer rejects anything.
  double gncLookGrowth = 1.5;
  /// A tightened gate stays tight online whatever the map reads later (tighten), and a young
  /// map can read tight where the whole data is not under-confident: Victoria Park fed as two
  /// robots, interleaved, gave 1.1 × χ²₂(0.5) from its first 200 sightings over two 230-pose
  /// stretches (one robot reads 5.8 at 782 poses), and at the tight test, χ²₂(0.95)/2 = 3.0,
  /// 49 true sightings ended rejected (χ² 6611.69, against 13 and 6368.34 fed as one robot).
  /// With this, the GNC look reads the gate from its answer (as batchGateCheck does); if that
  /// is not tighter, the tight gate is released (the gate becomes the GNC answer's) before
  /// both answers are judged; if the GNC's answer is kept, decided at that gate, the release
  /// stands for good, else the tight gate and the answer before are back as they were.
  bool releaseTightGate = true;
  /// The GNC look's GncOptions::interrupt (asked throughout the look: see there); true gives
  /// the look up: the answer stays as it was before it, and the next optimize() looks again.
  /// The server sets it (BackendOptions::interrupt) to "input is waiting, or the server
  /// stops", so a pause's look never holds new data back. Unset: never.
  std::function<bool()> interrupt;
  /// After this many looks in a row given up, the next one is asked `stopping` instead of
  /// `interrupt`, and so runs to its end while input waits (nothing is lost: the server
  /// queues it): under input that pauses often but never for as long as a look takes, no
  /// look would finish, and the answer would stay the online run's and the second looks'
  /// (where the look alone finds the basin, as for intel + 1000 grouped, seed 3, solved with
  /// one optimize(): 3.3 m off without it). 0: always `interrupt`.
  int looksGivenUpAtMost = 3;
  /// The server sets it (BackendOptions::stopping) to "the server stops". Unset: never.
  std::function<bool()> stopping;
};

class RisamBackend : public DecoratorBackend {
 public:
  RisamBackend(std::unique_ptr<Backend> inner, RisamOptions options);

  std::string name() const override { return "risam"; }
  UpdateResult update(const BackendUpdate& update) override;
  void optimize() override;
  std::vector<std::pair<FactorId, double>> decisions() const override;
  std::vector<FactorId> rejected() const override;
  bool judgesUncertain() const override { return true; }

  /// Inner updates run by the last update() (1 + schedule steps when it graduated factors).
  int lastInnerUpdates() const { return lastInnerUpdates_; }
  /// Updates whose graduation was cut short because the convex step absorbed every factor.
  int absorbedUpdates() const { return absorbedUpdates_; }
  /// Rejected factors graduated again by optimize() (they passed the marginal test).
  int retriedFactors() const { return retried_; }
  /// Factors currently out of the inner backend (RisamOptions::parkFactor).
  size_t parkedFactors() const { return parked_.size(); }
  /// Arrivals undone as runaways (RisamOptions::runawayFactor).
  int runawaysUndone() const { return runawaysUndone_; }
  /// Arrivals (and single closures fed again) undone for pushing accepted closures out
  /// (RisamOptions::collateralFactor).
  int contestedUndone() const { return contestedUndone_; }
  /// optimize() calls that took the second looks (drop check, fresh start): only those whose
  /// answer rejects something.
  int secondLooks() const { return secondLooks_; }
  /// optimize() calls whose fresh start was kept (RisamOptions::freshStart).
  int freshStartsKept() const { return freshStartsKept_; }
  /// Closures rejected by optimize()'s drop check (RisamOptions::dropBending).
  int droppedBending() const { return droppedBending_; }
  /// Rounds in which optimize() shrank the gate (RisamOptions::endGateRounds).
  int endGateShrinks() const { return endGateShrinks_; }
  /// Batch GNC checks of the first gate run, and those whose tight gate was taken
  /// (RisamOptions::batchGateCheck).
  int batchGateChecks() const { return batchGateChecks_; }
  int batchGatesAdopted() const { return batchGatesAdopted_; }
  /// RisamOptions::frameWideningCheck: batch checks run, and those whose solution was taken.
  int frameWideningChecks() const { return frameWideningChecks_; }
  int frameWideningsRebased() const { return frameWideningsRebased_; }
  /// optimize() calls that looked at a batch GNC's answer, and those that kept it
  /// (RisamOptions::gncLook, gncLookGrowth); looks given up (RisamOptions::interrupt) are
  /// counted apart.
  int gncLooks() const { return gncLooks_; }
  int gncLooksKept() const { return gncLooksKept_; }
  int gncLooksInterrupted() const { return gncLooksInterrupted_; }
  /// Looks given up since the last one that ran to its end (RisamOptions::looksGivenUpAtMost).
  int looksGivenUpInARow() const { return looksGivenUpInARow_; }
  /// Tight gates released by a kept GNC look (RisamOptions::releaseTightGate).
  int tightGatesReleased() const { return tightGatesReleased_; }
  static constexpr FactorId kInternalIdBit = FactorId{1} << 63;

 private:
  struct Graduated {
    FactorPtr original;
    FactorPtr wrapper;  // the SIG wrapper the inner backend holds
    FactorId internalId = 0;
    double mu = 0.0;       // SIG μ, or the fixed weight (0/1) once decided
    bool decided = false;  // optimize() put it in at a fixed weight
    bool parked = false;   // out of the inner backend (parkFactor); internalId unused
  };
  /// update() without the runaway and collateral checks.
  UpdateResult updateArrival(const BackendUpdate& update);
  /// Undoes an arrival (RisamOptions::runawayFactor, collateralFactor): the inner iSAM2 back
  /// at runawayStart_ (its first beforeSize variables; new ones at u.initial), u's uncertain
  /// factors parked; with `settle`, optimized there.
  void undoArrival(const BackendUpdate& u, int beforeSize, bool settle);
  /// Uncertain factors other than the arriving ones, in the inner backend and undecided, that
  /// pass the rejection test at runawayStart_ and fail it at the estimate.
  int pushedOut(const std::vector<FactorId>& arriving, int beforeSize) const;
  /// The truncated cost (truncatedCost(), over every factor) of undoing an arrival minus that
  /// of keeping it: the estimate at runawayStart_ with the arriving uncertain factors
  /// rejected, against the estimate now. Negative: undoing is cheaper.
  double undoCostChange(const std::vector<FactorId>& arriving, int beforeSize) const;
  /// The parked ids fed again, each as an arrival of its own, largest χ² first.
  void refeedSingly(std::vector<FactorId> ids);
  /// Drops a factor's state (graduated_, parked_, toPark_, byKey_) so that it can arrive
  /// again as new. A parked factor merely unparked for that kept the internal id of the
  /// wrapper it had before parking, which the inner backend no longer holds: a regraduation
  /// of every closure before the arrival committed (the gate tightening) asked the inner
  /// backend to remove it (intel + 1000 local, seed 5: "removal of unknown factor id").
  void forget(FactorId id);
  /// Still in the inner backend, undecided, and χ² above parkFactor × its tail test.
  bool farOut(const Graduated& g, const Values& x) const;
  /// The far-out ones of ids, after their graduation: toPark_ (parked at the next update).
  void markFarOut(const std::vector<FactorId>& ids);
  /// farOut, and the predicted χ² rᵀ(I + JΣJᵀ)⁻¹r above parkPredictedFactor × the tail test.
  bool shouldPark(FactorId id);
  void park(FactorId id);    // parked flag on, undecided, into parked_ (the caller removes it)
  void unpark(FactorId id);  // parked flag off and out of parked_ (the caller re-adds it)
  double nextMu(double mu) const;
  /// The inner update that re-adds each of ids at μ under a fresh internal id.
  BackendUpdate regraduate(const std::vector<FactorId>& ids, double mu);
  double shapeSquared(int dim) const;
  /// The kernel graduated factors use: c² = shapeSquared, or once tightened the default c²
  /// on χ² scaled so that μ = 1 weighs as c² = shapeSquared does.
  SigShape sigShape(int dim) const;
  double rejectChi2(int dim) const;
  /// The rejection test, raised to χ²_dim(p) unless the gate is tight (or p ≤ 0).
  double rejectChi2AtLeast(int dim, double p) const;
  /// The cap of an uncertain factor in truncatedCost (RisamOptions::costCapProbability).
  double costCapChi2(int dim) const;
  /// With tight_: the tail test (optimize()'s rejection test, and what an arrival must fit to
  /// count as absorbed); otherwise rejectChi2.
  double tailChi2(int dim) const;
  /// A tightened gate as χ²: g·χ²_dim(0.5), at most χ²_dim(0.95)/widenFactor.
  double tightChi2(double gate, int dim) const;
  /// Whether a gate (normalized) is wider than the defaults by widenFactor for some dimension,
  /// and (with `tighten`) tighter by it for every one.
  void gateDirection(double gate, bool& wider, bool& tighter) const;
  void refreshGate();
  /// A batch `gnc-tls` (GncBackend, its defaults) over the graph so far, started from the
  /// estimate; null if it threw or its solution is not finite. With `interrupt`, throws
  /// GncInterrupted when that returns true.
  std::unique_ptr<GncBackend> solveBatchGnc(const std::function<bool()>& interrupt = {}) const;
  /// RisamOptions::batchGateCheck: true if the GNC's tight gate and solution were taken (or,
  /// with widenThisAnswer, a wider gate for this optimize() only).
  bool adoptBatchGate(bool widenThisAnswer = false);
  /// RisamOptions::frameWideningCheck for a gate reading `reading` about to widen the gate:
  /// true if the batch GNC's solution was taken instead (the gate kept).
  bool rebaseFrameWidening(double reading);
  /// The inner iSAM2 reset to a batch solution `x`, every uncertain factor re-wrapped at μ = 1
  /// there (at the current gate), optimized, and the far-out ones marked.
  void takeBatchSolution(const Values& x);
  /// RisamOptions::gncLook (needs an inner iSAM2).
  void tryGncLook();
  /// The tail gate of the closures a batch GNC's answer accepts, at its estimate.
  TailGate batchTailGate(const GncBackend& gnc) const;
  /// RisamOptions::releaseTightGate: true if the tight gate was released (gate_ from `gnc`).
  bool releaseTightGate(const GncBackend& gnc);
  /// The gate's members a release changes, to undo it.
  struct GateState {
    double gate, onlineGate, tail, regraduatedAtGate;
    bool tight, atTail;
  };
  GateState gateState() const;
  void setGateState(const GateState& s);
  /// The closures that pass the rejection test, as χ²/χ²_dim(0.5) at the estimate.
  std::vector<double> acceptedNormalized() const;
  /// Every graduated uncertain factor's id, parked ones too.
  std::vector<FactorId> graduatedIds() const;
  /// Gate and tail re-estimated from the closures the estimate accepts (into `out`); false when
  /// the gate is fixed (shape, no tailExponent) or fewer than gateMinSamples are accepted.
  bool settledTailGate(TailGate& out) const;
  /// RisamOptions::endGateRounds, one round: true if the gate was shrunk.
  bool shrinkGateAtEnd();
  /// The same for a tightened gate: re-estimated (gate and tail) from the estimate, taken if
  /// the gate shrank by more than widenFactor.
  bool shrinkTightGateAtEnd();
  /// optimize()'s second looks (drop check, fresh start) when the answer rejects anything.
  void takeSecondLooks();
  double predictedChi2(const Factor& f);
  /// Rejected closures (at most retryMaxTests tested) whose predicted χ² increase passes the
  /// retry test: what retryRejected() and optimize()'s candidate rounds put back.
  std::vector<FactorId> retryCandidates();
  int retryRejected();
  /// Graduates ids again from μ_init along the schedule, as new arrivals; with `converge`,
  /// the inner backend relinearizes and optimizes to convergence at each μ (tightened: the
  /// retry's single steps ran parking-garage:800 + 30 random away, χ² 4e15).
  void graduateAgain(const std::vector<FactorId>& ids, bool converge);
  /// Every uncertain factor graduated again, when the gate first tightens or has fallen by
  /// more than regraduateFactor since the last time: closures accepted under the wider shape
  /// (before the noise scale was known) bent the map before it could reject them.
  void regraduateIfTightened();
  /// After optimize(): every decided closure back to its SIG kernel at μ = 1.
  void restoreGraduated();
  /// Installs 0/1 decisions (χ² test at the estimate; the ids in include forced to 1 in the
  /// first round) and solves, until no decision changes (at most finalRounds).
  void decideAndSolve(const std::vector<FactorId>* include);
  /// The final marginal-test candidate rounds (finalCandidateRounds) after decideAndSolve.
  void admitFinalCandidates();
  /// RisamOptions::freshStart (needs an inner iSAM2).
  void tryFreshStart();
  /// The inner iSAM2 reset to the linear initialization of the trusted factors and the
  /// closures decided in, and optimized there; false (nothing done) without a pose.
  bool startAfresh();
  /// RisamOptions::dropBending (needs an inner iSAM2); true if it rejected closures.
  bool dropBending();
  /// optimize()'s answer (estimate, 0/1 weights, truncated cost), to go back to.
  struct Answer {
    Values estimate;
    std::unordered_map<FactorId, double> weights;
    double cost = 0.0;
  };
  Answer answer() const;
  void restore(const Answer& a);  // needs an inner iSAM2
  void setDecided(FactorId id, double w, BackendUpdate& step);
  void forceDecisions(const std::unordered_set<FactorId>& ids, double w);  // no solve
  /// Σ_trusted χ² + Σ_uncertain min(χ², costCapChi2) at the estimate: what optimize() judges
  /// answers by.
  double truncatedCost() const { return truncatedCost(&RisamBackend::costCapChi2); }
  /// The same with each uncertain factor capped at (this->*cap)(dim).
  double truncatedCost(double (RisamBackend::*cap)(int) const) const;
  FactorPtr wrap(const FactorPtr& f, double mu, FactorId internal) const;

  RisamOptions options_;
  std::unordered_map<FactorId, Graduated> graduated_;     // original id → state
  std::unordered_map<Key, std::vector<FactorId>> byKey_;  // key → uncertain ids (lazy)
  std::vector<FactorId> parked_;                          // graduated_ entries with parked set
  std::vector<FactorId> toPark_;  // far out after their graduation: parked at the next update
  FactorId nextInternal_ = 0;
  int lastInnerUpdates_ = 0;
  int absorbedUpdates_ = 0;
  int runawaysUndone_ = 0;
  int contestedUndone_ = 0;
  int secondLooks_ = 0;
  int freshStartsKept_ = 0;
  int droppedBending_ = 0;
  int endGateShrinks_ = 0;
  int batchGateChecks_ = 0;
  int batchGatesAdopted_ = 0;
  int gncLooks_ = 0;
  int gncLooksKept_ = 0;
  int gncLooksInterrupted_ = 0;
  int looksGivenUpInARow_ = 0;  // since the last look that ran to its end
  int tightGatesReleased_ = 0;
  size_t gncLookAtCount_ = 0;       // uncertain factors at the last GNC look (0: none yet)
  bool onlineGateChecked_ = false;  // the first gate with gateMinSamples was checked
  bool framesJoined_ = false;       // an uncertain factor touches a robot's anchor
  double confirmedGate_ = 0.0;      // the last gate a batch GNC confirmed (frameWideningCheck)
  int frameWideningChecks_ = 0;
  int frameWideningsRebased_ = 0;
  size_t smallGateCheckAtCount_ = 0;  // uncertain factors at the last check below them
  bool refeeding_ = false;            // refeedSingly: the factors are in originals_ already
  std::vector<double> runawayStart_;  // the estimate's storage before the current arrival
  int retried_ = 0;
  size_t retriedAtCount_ = 0;
  double gate_ = 0.0;                   // noise-aware gate (normalized), 0 = defaults
  double onlineGate_ = -1.0;            // gate_ before the end-gate rounds (< 0: not shrunk)
  double onlineTail_ = 0.0;             // tail_ before them
  bool tight_ = false;                  // gate_ is below the defaults (tighten)
  double tail_ = 0.0;                   // with tight_: the uncapped tail gate (normalized)
  bool atTail_ = false;                 // optimize(): tight_ decisions against tail_
  double regraduatedAtGate_ = 0.0;      // gate_ of the last regraduateIfTightened (0: none)
  size_t gateAtCount_ = 0;              // number of uncertain factors at the last refresh
  bool finalized_ = false;              // optimize() left decided (fixed-weight) closures in
  Isam2Backend* innerIsam2_ = nullptr;  // the inner backend, if it is an iSAM2
 public:
  /// The noise-aware gate in use (χ²/χ²_dim(0.5) units; 0 = the χ²_dim defaults).
  double noiseGate() const { return gate_; }
};

}  // namespace loopd
