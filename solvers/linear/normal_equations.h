#pragma once
// Assembles H = Σ JᵀWJ (upper-triangle CSC, pattern from HessianLayout) and g = Σ JᵀWr for a
// factor graph at given values: one pass over the factors, fixed-size stack buffers only.
#include <vector>

#include "solvers/linear/hessian_layout.h"

namespace loopd {

struct LinearizationCost {
  double chi2 = 0.0;      // Σ rᵀr, unweighted
  double weighted = 0.0;  // Σ wᵢ rᵢᵀrᵢ, what the weighted problem minimises
};

class NormalEquations {
 public:
  explicit NormalEquations(const HessianLayout& layout);
  /// Resizes the buffers to the layout after it was rebuilt in place.
  void fitLayout();

  /// weights: one per factor (robust reweighting) or nullptr for all ones. Factors the layout
  /// leaves out must have weight 0 (std::logic_error otherwise).
  LinearizationCost build(const FactorGraph& graph, const Values& values,
                          const double* weights = nullptr);

  const HessianLayout& layout() const { return layout_; }
  std::vector<double>& hessian() { return hessian_; }  // CSC values (layout pattern)
  const std::vector<double>& hessian() const { return hessian_; }
  const std::vector<double>& gradient() const { return gradient_; }  // Jᵀr

  /// Residual-only pass: Σ rᵀr and Σ wᵢ rᵢᵀrᵢ at values.
  LinearizationCost cost(const FactorGraph& graph, const Values& values,
                         const double* weights = nullptr) const;

  /// Per-factor rᵀr at values (robust variants grade factors with it).
  void factorChi2(const FactorGraph& graph, const Values& values, std::vector<double>& out) const;

 private:
  template <typename PerFactor>
  void forEachChi2(const FactorGraph& graph, const Values& values, PerFactor&& perFactor) const;

  const HessianLayout& layout_;
  std::vector<double> hessian_;
  std::vector<double> gradient_;
};

}  // namespace loopd
