#pragma once
// Batch nonlinear least squares over a factor graph: Gauss–Newton, Levenberg–Marquardt
// (Marquardt scaling, Nielsen's gain-ratio update) and Powell's Dogleg, all on one CHOLMOD
// symbolic factorization computed once and reused by every iteration (and by every call of
// optimize(), so robust outer loops only pay for numeric factorizations).
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "solvers/linear/hessian_factorization.h"
#include "solvers/linear/normal_equations.h"

namespace loopd {

enum class OptimizerMethod { GaussNewton, LevenbergMarquardt, Dogleg };

/// "gn", "lm", "dogleg" → method; throws std::invalid_argument for other names.
OptimizerMethod optimizerMethodFromName(const std::string& name);
const char* optimizerMethodName(OptimizerMethod m);

struct IterationReport {
  int iteration = 0;
  double chi2 = 0.0;  // after the step (or unchanged if rejected)
  double weightedCost = 0.0;
  double trustParameter = 0.0;  // λ (LM) or radius (Dogleg)
  bool accepted = true;
  double seconds = 0.0;  // wall time of this iteration
};

struct OptimizerOptions {
  OptimizerMethod method = OptimizerMethod::LevenbergMarquardt;
  int maxIterations = 100;
  double relativeTolerance = 1e-7;   // stop when an accepted step lowers the cost by less
  double absoluteTolerance = 1e-12;  // or by less than this
  double stepTolerance = 1e-12;      // or moves every variable by less (relative to |x|+tol)
  double initialLambda = 1e-10;      // LM: damping relative to diag(H); pose graphs are
                                     // badly conditioned, so start near Gauss–Newton
  double initialRadius = 1e4;        // Dogleg trust radius
  FactorizationKind factorization = FactorizationKind::Block;
  std::function<void(const IterationReport&)> progress;  // called after every iteration
};

struct OptimizerResult {
  int iterations = 0;
  double initialChi2 = 0.0;
  double finalChi2 = 0.0;
  double finalWeightedCost = 0.0;
  bool converged = false;
  double finalTrustParameter = 0.0;  // LM: λ at exit (a warm start for the next solve)
  bool budgetSpent = false;          // stopped on maxIterations, not on a test
  std::string stopReason;
};

class NonlinearOptimizer {
 public:
  /// fixedSlots: variables held constant (e.g. the first pose for the gauge). The graph and
  /// the set of variables must not change during the optimizer's life; values may.
  NonlinearOptimizer(const FactorGraph& graph, const Values& values, std::vector<char> fixedSlots,
                     OptimizerOptions options = {});

  /// Improves values in place. weights: per-factor (robust reweighting) or nullptr. Factors
  /// of weight exactly 0 are left out of the Hessian's pattern (fitPattern).
  OptimizerResult optimize(Values& values, const double* weights = nullptr);

  const HessianLayout& layout() const { return layout_; }
  /// The Cholesky factor of the last undamped Hessian built by factorizeAt().
  HessianFactorization& cholesky() { return cholesky_; }
  /// Builds and factorizes the undamped Hessian at values (for marginals). False if singular.
  bool factorizeAt(const Values& values, const double* weights = nullptr);
  const OptimizerOptions& options() const { return options_; }
  OptimizerOptions& options() { return options_; }

 private:
  OptimizerResult runLevenbergMarquardt(Values& values, const double* weights);
  OptimizerResult runGaussNewton(Values& values, const double* weights);
  OptimizerResult runDogleg(Values& values, const double* weights);
  bool remainingDecreaseNegligible(double cost, std::vector<double>& work,
                                   std::vector<double>& solution);
  bool stepIsNegligible(const std::vector<double>& step) const;
  /// Moves to the trial point; returns why to stop (converged) or nullptr to go on.
  const char* acceptStep(Values& values, const Values& trialValues,
                         const LinearizationCost& trialCost, LinearizationCost& cost,
                         std::vector<double>& step, std::vector<double>& work);
  /// Rebuilds the layout (and the symbolic factorization) if the factors of nonzero weight
  /// are not exactly those it holds. Rejected closures' fill would otherwise dominate every
  /// factorization (parking-garage with 1000 wrong closures: 183 ms per LM iteration against
  /// 13 ms without them).
  void fitPattern(const Values& values, const double* weights);
  void report(int iteration, const LinearizationCost& cost, double trust, bool accepted,
              double seconds) const;

  const FactorGraph& graph_;
  OptimizerOptions options_;
  std::vector<char> fixedSlots_;
  HessianLayout layout_;
  NormalEquations bufferA_, bufferB_;
  NormalEquations* current_ = &bufferA_;  // linearized at the accepted values
  NormalEquations* trial_ = &bufferB_;    // linearized at a candidate step
  HessianFactorization cholesky_;
};

/// y = A·x for the upper-triangle CSC A of a layout (lower parts of diagonal blocks ignored).
void symmetricMultiply(const HessianLayout& layout, const std::vector<double>& A,
                       const std::vector<double>& x, std::vector<double>& y);

}  // namespace loopd
