#pragma once
// iSAM2 (Kaess et al., IJRR 2012): the incremental Bayes tree. Each update re-eliminates
// only the "top" of the tree (cliques holding affected variables and their ancestors),
// reusing the cached separator factor of every untouched subtree; fluid relinearization
// (threshold β) and wildfire back-substitution (threshold α) keep the cost proportional to
// what an update touches. Elimination is in information (Hessian) form: each clique gathers
// its dense Hessian block from its factors and its children's separator factors, then a
// partial Cholesky gives the conditional (L_FF, L_SF, d) and the separator factor it passes
// up. See ../shared/ISAM2_NOTES.md.
#include <Eigen/Core>
#include <algorithm>
#include <array>
#include <memory>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include "solvers/backend/backend.h"
#include "solvers/incremental/shared_buffer.h"

namespace loopd {

struct Isam2Options {
  double relinearizeThreshold = 0.1;  // β: max |Δ| component (rad or m) before relinearizing
  int relinearizeSkip = 10;  // check for relinearization every k-th update (GTSAM's default)
  // A variable whose Δ reaches this (any component) makes the next update check for
  // relinearization whatever relinearizeSkip says (0: off). A factor whose weight follows the
  // estimate (riSAM's SIG kernel) linearized at a θ that far behind feeds each update's Δ back
  // into the next one's weights: an iteration that can run away to NaN.
  double urgentRelinearizeThreshold = 0.0;
  double wildfireThreshold = 0.001;  // α: descend into a subtree if a separator Δ moved more
  // Ordering of the top: variables that no new factor touched for this many updates are
  // eliminated first (0: off), if that costs at most recencyFillTolerance × the fill of the
  // plain order (new factors' variables last). Keeps old variables off the root path.
  long recencyGrouping = 300;
  double recencyFillTolerance = 1.2;
  double gaugeInformation = 1e8;  // internal prior on the first pose when no prior exists
  // Each update's step is judged by the objective (Factor::objective) of the factors on the
  // variables it moved: a step that raises it is cut back along its path to the best of
  // 1/2, 1/4, …, 1/1024 of it, and those variables are relinearized there (the rest of the
  // step waits for later updates). A max-mixture's undamped step toward a wrong closure it
  // takes as an inlier can push every closure between two robots past its switch point at
  // once; with nothing left to pull them back, the robots' frames stay apart.
  bool guardSteps = false;
  int maxFinalIterations = 30;            // optimize(): full relinearizations at most
  double finalRelativeTolerance = 1e-10;  // optimize(): stop when the cost improves less
};

/// Counters of the last update (for benches and tests).
struct Isam2UpdateStats {
  int topCliques = 0;  // cliques re-eliminated
  int topVariables = 0;
  int orphans = 0;
  int solvedCliques = 0;  // back-substitution visits
  int relinearized = 0;
  double stepKept = 1.0;  // guardSteps: the fraction of the step kept
};

class Isam2Backend : public Backend {
 public:
  explicit Isam2Backend(BackendOptions options = {}, Isam2Options isam = {});

  std::string name() const override { return "isam2"; }
  UpdateResult update(const BackendUpdate& update) override;
  /// Full Gauss–Newton steps from the whole tree relinearized at the estimate, judged by the
  /// objective (Factor::objective: rᵀr for least squares, a kernel's ρ, a max-mixture's
  /// better component); where one goes uphill, heldDescent, or plain Levenberg–Marquardt if
  /// every factor is least squares. Judged by rᵀr of the re-weighted residuals instead, a
  /// step that pushes closures out looks downhill (a max-mixture's rᵀr falls to ~0 past its
  /// switch point, DCS's w(χ²)·χ² as χ² grows past Φ): that fallback had ended with the
  /// closures between two robots all rejected (mm), with 423 of sphere2500's first 450
  /// closures rejected (dcs at once).
  void optimize() override;
  /// The next update checks for relinearization whatever relinearizeSkip says (a caller
  /// about to change factors' weights in steps: riSAM's graduation).
  void relinearizeNextUpdate() { relinearizeNext_ = true; }
  /// Moves the variables x holds to its values and relinearizes the whole tree there, without
  /// taking a step (a caller undoing a runaway: riSAM). Variables x lacks keep theirs.
  void resetEstimate(const Values& x);
  /// optimize()'s full Gauss–Newton steps, without its batch fallback, until one lowers the
  /// cost by less than relativeGain of it (kept), one raises it (taken back), or maxSteps
  /// ran: cheap, and enough to settle a map one update left mid-way (riSAM's optimize()).
  void settle(int maxSteps, double relativeGain);
  const Values& estimate() const override { return estimate_; }
  const FactorGraph& graph() const override { return graph_; }
  Eigen::MatrixXd marginalCovariance(const std::vector<Key>& keys) override;
  std::vector<Eigen::MatrixXd> marginals(const std::vector<Key>& keys) override;
  SolveSummary summary() const override { return summary_; }

  /// Joint marginal by sparse solves along the root paths of the keys' cliques (the general
  /// path; marginalCovariance uses clique marginals when the keys share a clique).
  Eigen::MatrixXd marginalCovarianceByPathSolve(const std::vector<Key>& keys);
  /// False when a damped clique lies on k's path to the root (a part of the graph nothing
  /// ties to the first pose): its marginal is then the damping's, arbitrary. The robust
  /// layers read such a marginal as the huge uncertainty it stands for; loopd-solve refuses
  /// to write it, as the batch marginals refuse a singular information matrix.
  bool marginalDetermined(Key k) const;

  const Values& linearizationPoint() const { return theta_; }
  const Isam2UpdateStats& lastUpdateStats() const { return stats_; }
  const Isam2Options& isamOptions() const { return isam_; }
  bool hasGaugePrior() const { return gaugeFactor_ >= 0; }
  int cliqueCount() const { return static_cast<int>(cliques_.size() - freeCliques_.size()); }
  /// Bytes of clique numerics (conditionals with separator factors, cached marginals) in the
  /// live tree. With `seen`: only buffers not in it yet, which it then records — summed over
  /// copies of one backend, what they hold together with their shared cliques counted once.
  size_t cliqueStorageBytes(std::unordered_set<const double*>* seen = nullptr) const;
  /// True if key is a frontal variable of a root clique (where the newest pose should be).
  bool isInRootClique(Key key) const;

 private:
  // Aligned to a cache line, the fields the wildfire reads of every clique it visits first
  // (numFrontals, createdStamp, vars, m's pointer): a clique it only checks costs one line.
  struct alignas(64) Clique {
    int numFrontals = 0;
    int nf = 0;  // frontal scalar dimension
    int n = 0;   // total scalar dimension
    int parent = -1;
    long createdStamp = -1;
    std::vector<int> vars;  // frontal variables (elimination order), then separator
    // n×n column-major, then n entries: top-left L_FF (lower Cholesky factor of the frontal
    // block), bottom-left L_SF = H_SF·L_FF⁻ᵀ, bottom-right the separator factor's Hessian
    // (symmetric); vector: d = L_FF⁻¹·b_F, then the separator factor's b.
    // Copies of the backend share both buffers until one of them re-eliminates the clique.
    SharedBuffer m;  // only the lower triangle of the symmetric parts is kept
    std::vector<int> children;
    std::vector<int> offsets;  // local scalar offset of vars[i]; size vars.size() + 1
    SharedBuffer marginal;     // n×n joint covariance of vars (cached per epoch)
    long marginalEpoch = -1;
    // Its frontal block was singular and damped to factor (a part of the graph nothing ties
    // to the rest): the Bayes tree's covariances on and below it are arbitrary.
    bool damped = false;
    long topStamp = -1;
    long pathStamp = -1;
    bool alive = false;
  };

  // The top of one recompute(), handed from step to step. Positions are elimination
  // positions (scratchPos_ of a top variable while recompute() runs).
  struct Top {
    Top() = default;
    // Scratch, not state: a copy of the backend (a new hypothesis) starts with an empty one.
    Top(const Top&) {}
    Top& operator=(const Top&) { return *this; }
    /// Empties the lists for the next update; their capacity stays.
    void clear();

    std::vector<int> vars;     // the variables to re-eliminate
    std::vector<int> orphans;  // untouched children of detached cliques
    std::vector<int> factors;  // factors entirely inside the top (the orphans' rows follow)
    // Each row's columns (indices into vars): the factors' variables, then each orphan's
    // separator; read by the ordering and by the symbolic elimination.
    std::vector<int> rowPtr, rowCol;
    std::vector<int> ov;                      // variable at each position
    std::vector<int> homeStart, homeRows;     // rows by home (first-eliminated) position
    std::vector<std::vector<int>> structure;  // later positions in each position's column
    std::vector<int> etParent;                // elimination-tree parent position, −1 at a root
    std::vector<int> created;                 // new cliques, each parent before its children
  };

  // --- bookkeeping (isam2.cpp)
  int addVariable(const Values& from, int slot);
  int addFactor(const FactorPtr& f);
  void removeFactor(int index);
  void markAffected(int v);
  void manageGauge();
  void relinearize(bool all);
  /// θ of v ← its estimate, Δ ← 0 (counted in stats_.relinearized).
  void relinearizeAtEstimate(int v);
  /// Marks v and every variable of its factors affected (v's linearization changed).
  void markWithItsFactors(int v);
  double deltaMax(int v) const;
  /// Every variable relinearized at the current estimate (Δ = 0) and the tree recomputed.
  void relinearizeAllAtEstimate();
  /// The objective (Factor::objective) of the graph and the internal gauge prior at the
  /// estimate: their χ² where every factor is least squares.
  double costWithGauge() const;
  /// optimize()'s full steps from cost `previous` (updated): true when one gains less than
  /// relativeTolerance of the cost; false when one goes uphill (reverted to θ; `uphill` set,
  /// if given) or maxSteps ran out.
  bool fullSteps(int maxSteps, double relativeTolerance, double& previous, int& iterations,
                 bool* uphill = nullptr);

  // --- the step guard (isam2_step_guard.cpp)
  /// Keeps v's estimate before this update's step first changes it (guardSteps).
  void recordBeforeStep(int v);
  /// Cuts back a step that raised the objective (guardSteps); see Isam2Options.
  void guardStep();
  /// optimize()'s fallback where Gauss–Newton went uphill and some factor re-weights its
  /// residual (Factor::heldAt): each such factor is held as at the estimate,
  /// Levenberg–Marquardt minimises that least-squares majorizer, and the objective is read
  /// again, until it gains less than finalRelativeTolerance, fails to fall (the estimate
  /// stays) or `budget` iterations are used. `previous` is the objective at the estimate
  /// (updated). Returns false, doing nothing, if no factor is held (least squares: plain LM).
  bool heldDescent(int budget, double& previous, int& iterations);
  /// Variables the batch fallbacks hold fixed: those no factor touches.
  std::vector<char> fixedForBatch() const;
  /// Σ objective of guardFactors_, the stepped variables read from `stepped` (null: the
  /// estimate, where the step left them), the others from the estimate.
  double guardedObjective(const std::vector<double>* stepped) const;

  // --- re-elimination of the top (isam2_recompute.cpp)
  /// Re-eliminates the top formed by affected_ (constrained_ ordered last).
  void recompute();
  /// Lists the top (affected cliques and their ancestors) and frees its cliques.
  void detachTop(Top& top);
  void collectTopFactors(Top& top);
  /// Fills top.ov and the variables' positions (scratchPos_).
  void orderTop(Top& top);
  void symbolicEliminate(Top& top);
  /// New cliques from the elimination tree, orphans re-attached, new roots recorded.
  void buildCliques(Top& top);
  void eliminateCliques(const Top& top);

  // --- clique storage, numerics and back-substitution (isam2_cliques.cpp)
  int newClique();
  void freeClique(int c);
  bool factorizeClique(Clique& C);
  void linearizeInto(int factor, Clique& C);
  void accumulateChild(const Clique& child, Clique& C);
  void backSubstitute(std::vector<Key>* moved);
  /// Solves C's frontal Δ; true if one moved by more than α.
  bool solveClique(const Clique& C, std::vector<Key>* moved);

  // --- marginals (isam2_marginals.cpp)
  const double* cliqueMarginal(int c);
  void computeCliqueMarginal(int c);
  int varIndex(Key k) const;

  BackendOptions options_;
  Isam2Options isam_;
  FactorGraph graph_;
  Values theta_;     // linearization point
  Values estimate_;  // θ ⊕ Δ, kept up to date in place
  SolveSummary summary_;
  Isam2UpdateStats stats_;

  // Variables, indexed densely (= slot in theta_ and estimate_).
  std::vector<int> dims_;
  std::vector<int> cliqueOf_;  // clique holding the variable as frontal, −1 if not in the tree
  std::vector<double> delta_;  // kMaxVarDim per variable
  std::vector<std::vector<int>> varFactors_;
  std::vector<long> affectedStamp_;
  std::vector<long> changedStamp_;  // Δ moved by more than α in this epoch
  std::vector<char> relinCandidate_;
  std::vector<int> relinCandidates_;
  std::vector<int> scratchPos_;  // per-variable scratch (elimination position), −1 when free
  std::vector<int> localIdx_;    // per-variable scratch (index in one clique), −1 when free
  std::vector<long> constrainedStamp_;
  std::vector<long> movedStamp_;
  std::vector<long> touched_;  // update count when a new factor last involved the variable
  // Step guard: the variables this update's step changed (guardIndex_: position in it, valid
  // when guardStamp_ is this epoch), their values before it, and the factors on them.
  std::vector<long> guardStamp_;
  std::vector<int> guardIndex_;
  std::vector<int> guardVars_;
  std::vector<double> guardBefore_;  // kValueStride per guarded variable
  std::vector<long> guardFactorStamp_;
  std::vector<int> guardFactors_;
  bool guarding_ = false;  // update()'s back-substitution, with guardSteps
  int firstPose_ = -1;
  int newestVar_ = -1;

  // Factors, indexed densely; removed ones are null.
  std::vector<FactorPtr> factors_;
  std::vector<std::array<int, kMaxFactorKeys>> factorVars_;
  std::vector<long> factorStamp_;
  std::unordered_map<FactorId, int> idIndex_;
  int priorCount_ = 0;
  int gaugeFactor_ = -1;

  // The tree.
  std::vector<Clique> cliques_;
  std::vector<int> freeCliques_;
  std::vector<int> roots_;

  // Per-update state.
  long epoch_ = 0;
  long updateCount_ = 0;
  bool relinearizeNext_ = false;
  long pathCounter_ = 0;
  std::vector<int> affected_;
  std::vector<int> constrained_;
  std::vector<int> newRoots_;
  std::vector<int> createdIndex_;  // recompute(): clique → index among the new cliques, −1
  Top top_;                        // recompute()'s lists, kept so each update reuses them
  std::vector<double> scratch_;
};

}  // namespace loopd
