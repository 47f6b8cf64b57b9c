#pragma once
// Graduated non-convexity (Yang, Antonante, Tzoumas, Carlone, RA-L 2020) as a batch Backend:
// a BatchBackend whose factorWeights() carry the GNC weights of the uncertain factors
// (trusted factors always weigh 1). optimize(): the plain least-squares solve, then outer
// steps — update the weights in closed form at the current residuals, re-solve warm from the
// previous solution (solveOnce(), reusing the symbolic factorization), move μ — until the
// notes' stopping rule holds. Each factor's inlier threshold c̄² is χ²_dim(0.99) in our rᵀr
// convention (GTSAM's barcSq is half of that, in its ½-scaled error).
//
//   GM:  w = (μc̄²/(r² + μc̄²))²,  μ₀ = 2·max r²/c̄², μ ← max(1, μ/1.4), stop at μ = 1.
//   TLS: w = 1 | c̄/|r|·√(μ(μ+1)) − μ | 0,  μ₀ = 1/(2·max r²/c̄² − 1) (≥ 1e-6), μ ← 1.4μ,
//        stop when every weight is within 1e-4 of 0 or 1; return at once if all r² ≤ c̄².
//   Both: stop when the weighted cost changes by less than 1e-5 relatively, or after 100
//   outer steps.
#include <vector>

#include "solvers/batch/batch_backend.h"

namespace loopd {

enum class GncLoss { GemanMcClure, TruncatedLeastSquares };

struct GncOptions {
  GncLoss loss = GncLoss::TruncatedLeastSquares;
  double inlierProbability = 0.99;  // c̄² = χ²_dim(p); BackendOptions::robustParameter > 0
                                    // overrides c̄² directly (the same for every dimension)
  double muStep = 1.4;
  double relativeCostTol = 1e-5;
  double weightsTol = 1e-4;
  int maxOuterIterations = 100;
  double rejectBelow = 0.5;
  /// Start from the trusted factors' linear initialization (outliers cannot bend it).
  bool trustedInitialization = true;
  /// Outer steps start from the previous solution (true) or, as GTSAM does, from the values
  /// the GNC started from (false).
  bool warmStart = true;
};

class GncBackend : public BatchBackend {
 public:
  GncBackend(BackendOptions options, GncOptions gnc);

  std::string name() const override;
  void optimize() override;
  std::vector<std::pair<FactorId, double>> decisions() const override;
  std::vector<FactorId> rejected() const override;

  int outerIterations() const { return outer_; }
  double finalMu() const { return mu_; }

 protected:
  const double* factorWeights() const override {
    return weights_.size() == static_cast<size_t>(graph_.size()) ? weights_.data() : nullptr;
  }

 private:
  double barc2(const Factor& f) const;
  void updateWeights(const std::vector<double>& r2, const std::vector<double>& c2);

  GncOptions gnc_;
  std::vector<double> weights_;
  double mu_ = 0.0;
  int outer_ = 0;
  bool firstSolve_ = true;
};

}  // namespace loopd
