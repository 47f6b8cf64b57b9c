#pragma once
// Multi-hypothesis incremental smoothing in the manner of MH-iSAM2 (Hsiao & Kaess, ICRA 2019):
// every ambiguous measurement (k alternatives, optionally none) is a layer of a hypothesis
// tree; each live hypothesis is one leaf, with the choice it made at every layer, its view of
// the Bayes tree and a score. See ../../shared/ROBUST_NOTES.md §6 and robust/README.md.
//
// Sharing: hypotheses share every factor object, the id bookkeeping and the validation. A
// branch copies the parent's Isam2Backend, whose clique numerics are copy-on-write: the child
// shares every clique with its parent until one of them re-eliminates it, so a clique whose
// conditional does not depend on the choices is stored once and one that does carries one
// conditional per hypothesis (MH-iSAM2's multi-hypothesis Bayes tree). The last surviving
// child of a parent takes the parent's backend itself.
//
// Scoring: a hypothesis's score is its accumulated χ² increase — the innovation test
// Δχ² = rᵀ(I + JΣJᵀ)⁻¹r of each uncertain factor against the hypothesis's own marginal Σ of
// the factor's keys, which is the exact increase of the minimum for a linear problem — plus
// max(χ²_d(nullProbability), the tailQuantile of the χ² of the loop closures sent as certain,
// at the best estimate) − 2 ln(null weight) for every layer it answered "none": "none" wins
// only over alternatives that fit worse than nearly every closure the front-end was sure of,
// so over-confident data do not turn true alternatives into nulls. A layer's children are scored
// before they are built, so only plausible ones ever are: an alternative above
// χ²_d(gateProbability) is not branched on. While several hypotheses live, every later loop
// closure is scored in each before it is added (a second inner update adds it), and
// hypotheses are pruned: those more than
// −2 ln(pruneRatio) worse than the best (a tenth as likely), and all beyond K. optimize() ranks
// them by χ² at their optimum (plus null penalties).
#include <array>
#include <cmath>
#include <memory>
#include <optional>
#include <unordered_map>
#include <vector>

#include "solvers/backend/backend.h"
#include "solvers/incremental/isam2.h"

namespace loopd {

struct MhOptions {
  int maxHypotheses = 10;            // K: live hypotheses at most
  double gateProbability = 0.99999;  // no branch for an alternative with Δχ² > χ²_d(p)
  double nullProbability = 0.9999;   // "none" costs χ²_d(p): an alternative must pass χ² at p
  double tailQuantile = 0.999;       // … and fit no worse than this quantile of the certain
  int minTailSamples = 20;           //     loop closures' χ² (once there are this many)
  double pruneRatio = 0.1;           // drop a hypothesis less likely than this × the best's
                                     // (score more than −2 ln(ratio) = 4.6 above the best)
  Isam2Options isam;                 // each hypothesis's Bayes tree
};

/// One live hypothesis as reported (best first).
struct HypothesisSummary {
  double score = 0.0;
  std::vector<int> choices;  // per ambiguous measurement, in arrival order: position or −1
  const Values* estimate = nullptr;  // valid until the next update
};

class MhBackend : public Backend {
 public:
  MhBackend(BackendOptions options, MhOptions mh);

  std::string name() const override { return "mh"; }
  UpdateResult update(const BackendUpdate& update) override;
  void optimize() override;
  const Values& estimate() const override { return best().tree->estimate(); }
  const FactorGraph& graph() const override { return best().tree->graph(); }
  Eigen::MatrixXd marginalCovariance(const std::vector<Key>& keys) override;
  std::vector<Eigen::MatrixXd> marginals(const std::vector<Key>& keys) override;
  std::vector<std::pair<FactorId, double>> decisions() const override;
  std::vector<FactorId> rejected() const override;
  SolveSummary summary() const override { return best().tree->summary(); }
  /// The best hypothesis's tree: the estimate, graph and marginals above are its.
  const Isam2Backend& bestTree() const { return *best().tree; }
  bool handlesAmbiguous() const override { return true; }
  std::optional<int> chosenAlternative(FactorId id) const override;

  /// Live hypotheses, best first (at most `count`).
  std::vector<HypothesisSummary> hypotheses(int count) const;
  int liveHypotheses() const { return static_cast<int>(live_.size()); }
  /// Live hypotheses averaged over the updates so far (what the cost scales with).
  double meanLiveHypotheses() const { return updates_ ? double(liveSum_) / updates_ : 1.0; }
  /// Clique numerics of the live hypotheses: `shared` counts a clique two hypotheses share
  /// once (what they hold), `unshared` once per hypothesis (what separate trees would hold).
  struct Storage {
    size_t sharedBytes = 0;
    size_t unsharedBytes = 0;
  };
  Storage cliqueStorage() const;
  /// The largest cliqueStorage() seen while several hypotheses lived (sampled every 16th
  /// update).
  Storage peakCliqueStorage() const { return peakStorage_; }
  /// Hypotheses built (branched) so far, and children never built because the prediction
  /// pruned them.
  long branchesBuilt() const { return branchesBuilt_; }
  long branchesPredictedAway() const { return predictedAway_; }

 private:
  struct Hypothesis {
    std::unique_ptr<Isam2Backend> tree;
    std::vector<int> choices;  // per layer
    double score = 0.0;
    std::vector<Key> moved;  // by this update (for UpdateResult::moved)
  };
  struct Layer {
    FactorId id = 0;
    std::vector<FactorPtr> alternatives;
    bool null = false;
    double nullWeight = 1.0;
    int dim = 0;
  };
  struct Child {
    int parent = 0;
    int choice = -1;
    double score = 0.0;
  };

  const Hypothesis& best() const { return live_.front(); }
  void validate(const BackendUpdate& u, const Values& initial) const;
  /// Branches every live hypothesis on layer `l` (keys must all exist).
  void branch(int l);
  /// Splits an update's factors into those added first and the uncertain ones scored after.
  void splitScored(const std::vector<FactorPtr>& factors, std::vector<FactorPtr>& first,
                   std::vector<FactorPtr>& scored) const;
  /// Linearised χ² increase of adding f to h (the innovation test); f's keys must be in h.
  double predictedIncrease(Hypothesis& h, const Factor& f);
  /// Score = χ² at the estimate + null penalties (after optimize(), where that is the optimum).
  void rescore();
  void prune();
  double pruneGap() const { return -2.0 * std::log(mh_.pruneRatio); }
  /// What answering "none" to a layer costs: χ²_d(nullProbability) − 2 ln(nullWeight).
  double nullPenalty(const Layer& layer) const;
  /// Recomputes certainTail_ from the best hypothesis (O(factors); per null layer and at the end).
  void refreshCertainTail();

  BackendOptions options_;
  MhOptions mh_;
  std::vector<Hypothesis> live_;  // best first after every update
  std::vector<Layer> layers_;
  std::unordered_map<FactorId, int> layerIndex_;  // measurement id → layer
  std::unordered_map<int, double> certainTail_;   // residual dim → χ² tail of certain closures
  std::unordered_map<FactorId, int> ids_;  // factor id → −1 (plain) or its alternative's layer
  Storage peakStorage_;
  long branchesBuilt_ = 0;
  long predictedAway_ = 0;
  long updates_ = 0;
  long liveSum_ = 0;
};

}  // namespace loopd
