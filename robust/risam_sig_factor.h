#pragma once
// riSAM's SIG kernel around an uncertain factor, as the inner backend holds it
// (robust/risam_backend.h).
#include <array>
#include <utility>

#include "robust/robust_factors.h"
#include "solvers/core/values.h"
#include "solvers/factors/factor.h"

namespace loopd {

/// The SIG kernel's shape c applied to χ² scaled by chi2Scale.
struct SigShape {
  double c = 0.0, chi2Scale = 1.0;
  double weight(double chi2, double mu) const { return sigWeight(chi2Scale * chi2, mu, c); }
};

/// riSAM's SIG kernel at a fixed μ whose IRLS weight is taken at the inner backend's current
/// ESTIMATE, not at the point it is linearized at. iSAM2 linearizes a (re-)added factor at its
/// linearization point θ, which lags the estimate θ ⊕ Δ by up to the relinearization threshold;
/// for a stiff closure (manhattan: 2e7 information on x) that lag alone is a χ² of 10⁴–10⁵, so a
/// weight taken at θ switches the closure off at the μ = 1 step right after the convex step
/// had fitted it (χ² 0.9 at the estimate) — a true closure rejected at arrival. Where the
/// estimate lacks a variable (not yet added) the weight falls back to the evaluation point.
class RisamSigFactor final : public Factor {
 public:
  template <size_t... I>
  RisamSigFactor(std::index_sequence<I...>, FactorPtr inner, double mu, SigShape shape,
                 const Values* at)
      : Factor({{inner->key(I), inner->varType(I)}...}, inner->dim(), inner->role()),
        inner_(std::move(inner)),
        mu_(mu),
        shape_(shape),
        at_(at) {
    setId(inner_->id());
  }

  void evaluate(const double* const* x, double* r, double* const* J) const override;
  std::unique_ptr<Factor> clone() const override;
  const char* typeName() const override { return "Graduated"; }
  /// μ changed in place: takes effect where the factor is next linearized.
  void setMu(double mu) const { mu_ = mu; }

 private:
  /// χ² of the inner factor at the estimate; −1 if a variable is missing there.
  double chi2AtEstimate() const;

  FactorPtr inner_;
  mutable double mu_;
  SigShape shape_;
  const Values* at_;
};

/// f in the SIG kernel at μ under the id `id`, its weight taken at `at` (nullptr: at the
/// evaluation point). f has 1–4 keys; otherwise std::invalid_argument.
FactorPtr makeRisamSig(const FactorPtr& f, double mu, SigShape shape, const Values* at,
                       FactorId id);

}  // namespace loopd
