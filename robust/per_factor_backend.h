#pragma once
// PerFactorRobustBackend: applies what a sender asked for each factor (Factor::robustRequest,
// the wire's `robust` and `robust_param`) around the server's solver, whatever that is:
//
//   ""  or the solver's own name   the solver's handling (passed through unchanged)
//   "none"                         never down-weighted: the solver sees it as trusted
//   huber, cauchy, gm, dcs         that kernel (IRLS) on this factor
//   sc, mm                         a switchable constraint (own switch variable and prior) or
//                                  a max-mixture on this factor
//   anything else (gnc-gm, gnc-tls, risam, …)  the solver's handling: those schemes act on all
//                                  uncertain factors together; the server refuses such a
//                                  request unless it names its --solver
//
// Only uncertain factors (loop closures, landmark sightings) are looked at. A factor handled
// here reaches the solver wrapped and marked trusted (role Odometry, as switch priors are), so
// the solver's own robust scheme leaves it alone. graph() gives the factors as sent, so chi2()
// stays Σ rᵀr of the input; decisions()/rejected() merge the solver's with this layer's.
//
// Under a batch solver (lm, gn, dogleg, gnc-*: each solve judges its steps by the cost it
// evaluates), a kernel request is given as a HeldKernelFactor: its weight is held through
// each solve and refreshed at the solution until the weights settle (IRLS; see
// held_kernel_factor.h). With the weight re-evaluated at every trial point instead, the
// closures of a redescending kernel that start far from agreement (a batch of poses placed
// by odometry) are never pulled in.
#include <memory>
#include <optional>
#include <string>
#include <unordered_map>

#include "robust/decorator_backend.h"
#include "robust/held_kernel_factor.h"
#include "robust/robust_wrapping.h"

namespace loopd {

class PerFactorRobustBackend : public DecoratorBackend {
 public:
  explicit PerFactorRobustBackend(std::unique_ptr<Backend> solver);

  std::string name() const override { return inner_->name(); }
  UpdateResult update(const BackendUpdate& update) override;
  /// The solver's optimize(), then held kernel weights settled (batch solvers).
  void optimize() override;
  const FactorGraph& graph() const override;
  std::vector<std::pair<FactorId, double>> decisions() const override;
  std::vector<FactorId> rejected() const override;
  bool handlesAmbiguous() const override { return inner_->handlesAmbiguous(); }
  std::optional<int> chosenAlternative(FactorId id) const override {
    return inner_->chosenAlternative(id);
  }

  /// The solver underneath (for what only it reports, e.g. mh's hypotheses).
  Backend& solver() { return *inner_; }
  const Backend& solver() const { return *inner_; }

  /// True if this layer handles f itself (a kernel, sc, mm or "none" request).
  bool handlesHere(const Factor& f) const;
  bool judgesUncertain() const override { return inner_->judgesUncertain(); }
  /// True if f may be down-weighted or rejected: an uncertain factor under a kernel, sc or mm
  /// request, or under the solver's handling when the solver judgesUncertain().
  bool mayDownWeight(const Factor& f) const;

  /// Switch variables of this layer: index ≥ 2³⁹, so they never meet the solver's own; their
  /// priors' ids have bit 62 set (the solver's own internal factors use bit 63).
  static constexpr std::uint64_t kSwitchIndexBase = std::uint64_t{1} << 39;
  static constexpr FactorId kPriorIdBit = FactorId{1} << 62;
  static constexpr double kRejectBelow = 0.5;
  /// Held kernel weights are settled when no refresh changes one by more than this, or after
  /// this many re-solves (each a warm-started batch solve).
  static constexpr double kWeightTolerance = 1e-4;
  static constexpr int kMaxWeightRounds = 50;

 private:
  struct Handled {
    FactorPtr sent;   // as the sender sent it
    FactorPtr given;  // what the solver got: a wrapper, or for "none" a clone, marked trusted
    std::shared_ptr<HeldKernelFactor> held;  // given, when its weight is held (batch solvers)
  };
  /// The weight of a handled factor at x (a held kernel's at x, not the one it holds).
  static double weightOf(const Handled& h, const Values& x);
  /// Refreshes every held weight at the estimate and re-solves until none changes by more
  /// than kWeightTolerance (or kMaxWeightRounds re-solves ran).
  void settleHeldWeights();

  const bool holdKernels_;  // the solver re-solves the whole graph with step acceptance
  std::unordered_map<FactorId, Handled> handled_;
  std::unordered_map<FactorId, Key> switches_;  // id → switch key (sc requests)
  std::uint64_t nextSwitch_ = 0;
  mutable FactorGraph asSent_;  // the solver's graph with every wrapper replaced by the original
  mutable bool asSentStale_ = true;
};

}  // namespace loopd
