#pragma once
// The one seam between the estimation core and everything that drives it (server,
// loopd-solve, comparison scripts): every solver variant is a Backend, picked by name.
#include <Eigen/Core>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "solvers/batch/nonlinear_optimizer.h"
#include "solvers/graph/factor_graph.h"

namespace loopd {

/// One measurement the front-end could not decide: k alternative factors (ids unique like any
/// factor's), at most one of them true; with nullHypothesis, possibly none. Multi-measurement
/// (same keys, k measurements) and multi-association (one measurement, k candidate keys)
/// are both just alternatives here.
struct AmbiguousFactor {
  FactorId id = 0;  // the measurement's own id (a namespace of its own)
  std::vector<FactorPtr> alternatives;
  bool nullHypothesis = false;
  /// Prior weight of "none" relative to one alternative (> 0; 1 = as likely as each).
  double nullWeight = 1.0;
};

/// What one update brings: new factors (ids unique within the backend), initial values for
/// the new variables they introduce, ambiguous measurements over existing or new variables,
/// and ids of factors to remove. Applied atomically.
struct BackendUpdate {
  std::vector<FactorPtr> factors;
  Values initial;
  std::vector<FactorId> removals;
  std::vector<AmbiguousFactor> ambiguous;
};

/// For variants without hypotheses: every alternative becomes an ordinary factor (a decoy is
/// then just another loop closure for the robust kernels to judge).
void flattenAmbiguous(BackendUpdate& update);

struct UpdateResult {
  double seconds = 0.0;
  std::vector<Key> moved;  // variables whose estimate changed by more than the threshold
  int relinearized = 0;    // variables relinearized (incremental solvers)
};

/// How the last optimisation went (for stats and progress).
struct SolveSummary {
  int iterations = 0;
  double initialChi2 = 0.0;
  double finalChi2 = 0.0;
  bool converged = false;
  /// Stopped because the iteration budget ran out, still descending: another optimize() goes
  /// on from here (the server's idle optimize resumes it, EngineOptions::idleRounds).
  bool budgetSpent = false;
  std::string stopReason;
};

struct BackendOptions {
  OptimizerMethod method = OptimizerMethod::LevenbergMarquardt;
  int maxIterations = 100;
  /// Batch: replace the first estimate by the chordal (3D) / orientation-first (2D) one.
  bool linearInitialization = true;
  /// A variable "moved" when its tangent-space change exceeds this.
  double moveThreshold = 1e-4;
  /// Variant parameter (kernel width, switch prior, …); 0 = the variant's default.
  double robustParameter = 0.0;
  /// mh: live hypotheses kept at most (K).
  int maxHypotheses = 10;
  std::function<void(const IterationReport&)> progress;
  /// Asked during long optimize() work that can be given up without losing anything (today
  /// only `risam`'s GNC look, RisamOptions::interrupt); true gives it up, and the answer stays
  /// as it was before that work. The server: input is waiting, or it is stopping.
  std::function<bool()> interrupt;
  /// Asked instead of `interrupt` by such work once it has given way too often to give way
  /// to input again (RisamOptions::looksGivenUpAtMost): true only for a stop. The server: it
  /// is stopping.
  std::function<bool()> stopping;
};

class Backend {
 public:
  virtual ~Backend() = default;
  virtual std::string name() const = 0;

  /// Applies the update and re-solves (incrementally where the variant can). Variants that
  /// do not handlesAmbiguous() refuse a non-empty update.ambiguous: callers flatten it first.
  /// Throws std::invalid_argument, leaving the backend unchanged, if the update refers to
  /// unknown keys or ids, or lacks an initial value for a new variable.
  virtual UpdateResult update(const BackendUpdate& update) = 0;

  /// Iterates to convergence on everything it has (end of a run, or an idle server).
  virtual void optimize() = 0;

  virtual const Values& estimate() const = 0;
  virtual const FactorGraph& graph() const = 0;

  /// Joint marginal covariance of keys, in their tangent spaces (SE2: x y θ; SE3: ρ then φ,
  /// both in the body frame), keys in the order given.
  virtual Eigen::MatrixXd marginalCovariance(const std::vector<Key>& keys) = 0;

  /// Each key's own marginal (no cross terms); variants override with a faster path.
  virtual std::vector<Eigen::MatrixXd> marginals(const std::vector<Key>& keys) {
    std::vector<Eigen::MatrixXd> out;
    out.reserve(keys.size());
    for (Key k : keys) out.push_back(marginalCovariance({k}));
    return out;
  }

  /// Per uncertain factor: weight in [0, 1] (1 trusted). Plain solvers trust everything.
  virtual std::vector<std::pair<FactorId, double>> decisions() const { return {}; }
  /// Ids of factors judged outliers.
  virtual std::vector<FactorId> rejected() const { return {}; }
  /// True for variants that may down-weight or reject uncertain factors (the robust ones).
  virtual bool judgesUncertain() const { return false; }

  /// True for variants that keep alternatives apart (mh); others flatten them.
  virtual bool handlesAmbiguous() const { return false; }
  /// Position of the alternative of ambiguous measurement `id` that the best hypothesis took,
  /// −1 for none (null); nullopt if this variant does not choose (see chooseAlternative).
  virtual std::optional<int> chosenAlternative(FactorId /*id*/) const { return std::nullopt; }

  virtual SolveSummary summary() const = 0;
  /// Σ rᵀr over all factors at the current estimate (robust weights not applied).
  double chi2() const { return graph().chi2(estimate()); }
};

using BackendFactory = std::function<std::unique_ptr<Backend>(const BackendOptions&)>;

}  // namespace loopd
