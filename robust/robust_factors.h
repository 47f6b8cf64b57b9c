#pragma once
// Robust factor wrappers: each wraps an (uncertain) inner factor and changes how its whitened
// residual r and Jacobians J reach the solver. None of them changes the inner factor.
//
//   KernelFactor            M-estimator by IRLS: w = w(rᵀr) at the evaluation point, returns
//                           √w·r and √w·J (weight frozen at the linearization point, as GTSAM's
//                           robust noise models and g2o's kernels do).
//   SwitchableFactor        Sünderhauf & Protzel: extra Scalar key s, residual Ψ(s)·r with
//                           Ψ(s) = clamp(s, 0, 1); ∂/∂x = Ψ·J, ∂/∂s = r (exact, not Ψ·r).
//   SwitchPriorFactor       (s − γ)/σ on a switch variable (role Odometry: trusted, and not a
//                           "Prior", so it never removes the batch gauge).
//   MaxMixtureFactor        Olson & Agarwal: inlier N(0, Ω⁻¹) or a broad null hypothesis
//                           (weight w₀, information Ω/σ₀²), best component (with its
//                           normaliser) chosen at each evaluation.
//   WeightedFactor          fixed weight: √w·r, √w·J.
//   GraduatedFactor         riSAM's SIG kernel at a fixed μ, IRLS like KernelFactor.
#include <cmath>
#include <memory>

#include "solvers/factors/factor.h"

namespace loopd {

enum class KernelType { Huber, Cauchy, GemanMcClure, DCS };

const char* kernelName(KernelType k);

/// χ² quantile of the chi-square distribution with dof degrees of freedom (dof 1…6) at
/// p ∈ {0.25, 0.5, 0.9, 0.95, 0.99}; other p are computed by bisection on the CDF.
double chi2Quantile(int dof, double p);

/// IRLS weight of a kernel for χ² = rᵀr with parameter p:
///   Huber(k):  1 if √χ² ≤ k else k/√χ²                  (ρ = χ² or 2k√χ² − k²)
///   Cauchy(k): 1/(1 + χ²/k²)                            (ρ = k²·ln(1 + χ²/k²))
///   GM(k):     k⁴/(k² + χ²)²                             (ρ = k²χ²/(k² + χ²))
///   DCS(Φ):    min(1, 2Φ/(Φ + χ²))²                     (Agarwal et al. 2013)
double kernelWeight(KernelType kernel, double chi2, double parameter);

/// The kernel's cost ρ(χ²) (above; DCS: χ² up to Φ, then Φ(3χ² − Φ)/(Φ + χ²)), whose
/// derivative in χ² is kernelWeight. Not finite χ²: the kernel's limit.
double kernelCost(KernelType kernel, double chi2, double parameter);

/// Default parameter for a factor of dimension dim: Huber/Cauchy/GM: k = √χ²_dim(0.95);
/// DCS: Φ = 1.
double defaultKernelParameter(KernelType kernel, int dim);

/// riSAM's SIG kernel weight: c²(c² + (χ²)^μ(1 − μ)) / (c² + (χ²)^μ)², μ ∈ [0, 1].
double sigWeight(double chi2, double mu, double c);

class KernelFactor final : public Factor {
 public:
  /// parameter ≤ 0: defaultKernelParameter(kernel, inner->dim()).
  static std::shared_ptr<KernelFactor> make(FactorPtr inner, KernelType kernel,
                                            double parameter = 0.0);
  template <size_t... I>
  KernelFactor(std::index_sequence<I...>, FactorPtr inner, KernelType kernel, double parameter);

  void evaluate(const double* const* x, double* r, double* const* J) const override;
  std::unique_ptr<Factor> clone() const override;
  const char* typeName() const override { return "Kernel"; }
  /// ρ of the inner χ² (kernelCost).
  double objective(const double* const* x) const override;
  /// The inner factor at the kernel's weight at x, ρ'(χ²): ρ is concave in χ² for every
  /// kernel here, so w·χ² + const bounds it from above, touching it at x (IRLS as MM).
  bool heldAt(const double* const* x, FactorPtr& inner, double& weight) const override;

  const FactorPtr& inner() const { return inner_; }
  KernelType kernel() const { return kernel_; }
  double parameter() const { return parameter_; }
  /// The kernel weight at values (inner χ² evaluated there).
  double weightAt(const Values& values) const;

 private:
  FactorPtr inner_;
  KernelType kernel_;
  double parameter_;
};

class SwitchableFactor final : public Factor {
 public:
  /// inner must have at most kMaxFactorKeys − 1 keys; the switch is key size() − 1.
  static std::shared_ptr<SwitchableFactor> make(FactorPtr inner, Key switchKey);
  template <size_t... I>
  SwitchableFactor(std::index_sequence<I...>, FactorPtr inner, Key switchKey);

  void evaluate(const double* const* x, double* r, double* const* J) const override;
  std::unique_ptr<Factor> clone() const override;
  const char* typeName() const override { return "Switchable"; }

  const FactorPtr& inner() const { return inner_; }
  Key switchKey() const { return key(size() - 1); }
  static double psi(double s) { return s < 0.0 ? 0.0 : (s > 1.0 ? 1.0 : s); }

 private:
  FactorPtr inner_;
};

class SwitchPriorFactor final : public Factor {
 public:
  SwitchPriorFactor(Key s, double gamma = 1.0, double sigma = 1.0);
  void evaluate(const double* const* x, double* r, double* const* J) const override;
  std::unique_ptr<Factor> clone() const override;
  const char* typeName() const override { return "SwitchPrior"; }

 private:
  double gamma_, sigma_;
};

class MaxMixtureFactor final : public Factor {
 public:
  static std::shared_ptr<MaxMixtureFactor> make(FactorPtr inner, double nullWeight = 1e-7,
                                                double nullSigma = 1.6e7);
  template <size_t... I>
  MaxMixtureFactor(std::index_sequence<I...>, FactorPtr inner, double nullWeight, double nullSigma);

  void evaluate(const double* const* x, double* r, double* const* J) const override;
  std::unique_ptr<Factor> clone() const override;
  const char* typeName() const override { return "MaxMixture"; }
  /// The better component's cost relative to the inlier's normaliser: χ² up to switchChi2(),
  /// then χ²/σ₀² plus the null's normaliser (continuous at the switch point).
  double objective(const double* const* x) const override;
  /// The better component at x held: the inner factor at weight 1 or 1/σ₀².
  bool heldAt(const double* const* x, FactorPtr& inner, double& weight) const override;

  const FactorPtr& inner() const { return inner_; }
  /// The null hypothesis wins when χ² exceeds this (both components share the mean):
  /// ½χ²(1 − 1/σ₀²) > dim·ln σ₀ − ln w₀.
  double switchChi2() const { return switchChi2_; }
  bool nullChosenAt(const Values& values) const;

 private:
  FactorPtr inner_;
  double nullWeight_, nullSigma_, switchChi2_;

  /// The null component is the better one at this inner χ² (past the switch point, or not
  /// finite): the one rule evaluate(), objective(), heldAt() and nullChosenAt() follow.
  bool nullWins(double chi2) const { return chi2 > switchChi2_ || !std::isfinite(chi2); }
};

class WeightedFactor final : public Factor {
 public:
  static std::shared_ptr<WeightedFactor> make(FactorPtr inner, double weight);
  template <size_t... I>
  WeightedFactor(std::index_sequence<I...>, FactorPtr inner, double weight);
  void evaluate(const double* const* x, double* r, double* const* J) const override;
  std::unique_ptr<Factor> clone() const override;
  const char* typeName() const override { return "Weighted"; }
  double weight() const { return weight_; }
  const FactorPtr& inner() const { return inner_; }

 private:
  FactorPtr inner_;
  double weight_;
};

class GraduatedFactor final : public Factor {
 public:
  static std::shared_ptr<GraduatedFactor> make(FactorPtr inner, double mu, double c);
  template <size_t... I>
  GraduatedFactor(std::index_sequence<I...>, FactorPtr inner, double mu, double c);
  void evaluate(const double* const* x, double* r, double* const* J) const override;
  std::unique_ptr<Factor> clone() const override;
  const char* typeName() const override { return "Graduated"; }
  double mu() const { return mu_; }
  double weightAt(const Values& values) const;
  const FactorPtr& inner() const { return inner_; }

 private:
  FactorPtr inner_;
  double mu_, c_;
};

}  // namespace loopd
