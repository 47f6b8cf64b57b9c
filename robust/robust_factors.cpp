#include "robust/robust_factors.h"

#include <array>
#include <cmath>
#include <stdexcept>
#include <utility>
#include <vector>

#include "robust/wrapper_support.h"

namespace loopd {

namespace {

// Regularized lower incomplete gamma P(a, x) by its power series (fine for the small dof and
// moderate x used for χ² thresholds).
double gammaP(double a, double x) {
  if (x <= 0.0) return 0.0;
  double term = 1.0 / a, sum = term;
  for (int n = 1; n < 5000; ++n) {
    term *= x / (a + n);
    sum += term;
    if (term < sum * 1e-16) break;
  }
  return std::exp(-x + a * std::log(x) - std::lgamma(a)) * sum;
}

int effectiveDim(const Factor& f) { return f.dim(); }

double chi2At(const Factor& inner, const Values& values) { return inner.chi2(values); }

}  // namespace

const char* kernelName(KernelType k) {
  switch (k) {
    case KernelType::Huber:
      return "huber";
    case KernelType::Cauchy:
      return "cauchy";
    case KernelType::GemanMcClure:
      return "gm";
    case KernelType::DCS:
      return "dcs";
  }
  return "?";
}

namespace {

double chi2QuantileBisection(int dof, double p) {
  double lo = 0.0, hi = 1.0;
  while (gammaP(0.5 * dof, 0.5 * hi) < p) hi *= 2.0;
  for (int it = 0; it < 200; ++it) {
    const double mid = 0.5 * (lo + hi);
    (gammaP(0.5 * dof, 0.5 * mid) < p ? lo : hi) = mid;
  }
  return 0.5 * (lo + hi);
}

constexpr double kTableP[] = {0.25, 0.5, 0.9, 0.95, 0.99};

}  // namespace

double chi2Quantile(int dof, double p) {
  if (dof < 1) throw std::invalid_argument("chi2Quantile: dof < 1");
  if (!(p > 0.0 && p < 1.0)) throw std::invalid_argument("chi2Quantile: p outside (0, 1)");
  // The common thresholds, computed once (thread-safe static initialization).
  static const std::vector<std::array<double, 5>> table = [] {
    std::vector<std::array<double, 5>> t(kMaxResidualDim + 1);
    for (int d = 1; d <= kMaxResidualDim; ++d)
      for (int k = 0; k < 5; ++k) t[d][k] = chi2QuantileBisection(d, kTableP[k]);
    return t;
  }();
  if (dof <= kMaxResidualDim)
    for (int k = 0; k < 5; ++k)
      if (p == kTableP[k]) return table[dof][k];
  return chi2QuantileBisection(dof, p);
}

double kernelWeight(KernelType kernel, double chi2, double p) {
  if (!std::isfinite(chi2)) return 0.0;
  switch (kernel) {
    case KernelType::Huber: {
      const double n = std::sqrt(chi2);
      return n <= p ? 1.0 : p / n;
    }
    case KernelType::Cauchy:
      return 1.0 / (1.0 + chi2 / (p * p));
    case KernelType::GemanMcClure: {
      const double k2 = p * p;
      const double d = k2 + chi2;
      return k2 * k2 / (d * d);
    }
    case KernelType::DCS: {
      const double s = std::min(1.0, 2.0 * p / (p + chi2));
      return s * s;
    }
  }
  return 1.0;
}

double kernelCost(KernelType kernel, double chi2, double p) {
  const double k2 = p * p;
  switch (kernel) {
    case KernelType::Huber: {
      const double n = std::sqrt(chi2);
      return n <= p ? chi2 : 2.0 * p * n - k2;
    }
    case KernelType::Cauchy:
      return k2 * std::log1p(chi2 / k2);
    case KernelType::GemanMcClure:
      return std::isfinite(chi2) ? k2 * chi2 / (k2 + chi2) : k2;
    case KernelType::DCS:
      if (chi2 <= p) return chi2;
      return std::isfinite(chi2) ? p * (3.0 * chi2 - p) / (p + chi2) : 3.0 * p;
  }
  return chi2;
}

double defaultKernelParameter(KernelType kernel, int dim) {
  if (kernel == KernelType::DCS) return 1.0;
  return std::sqrt(chi2Quantile(std::max(dim, 1), 0.95));
}

double sigWeight(double chi2, double mu, double c) {
  if (!std::isfinite(chi2)) return 0.0;
  const double c2 = c * c;
  const double rm = std::pow(std::max(chi2, 0.0), mu);
  const double d = c2 + rm;
  return c2 * (c2 + rm * (1.0 - mu)) / (d * d);
}

// --- KernelFactor -----------------------------------------------------------------------

template <size_t... I>
KernelFactor::KernelFactor(std::index_sequence<I...>, FactorPtr inner, KernelType kernel,
                           double parameter)
    : Factor({{inner->key(I), inner->varType(I)}...}, inner->dim(), inner->role()),
      inner_(std::move(inner)),
      kernel_(kernel),
      parameter_(parameter) {
  setId(inner_->id());
}

std::shared_ptr<KernelFactor> KernelFactor::make(FactorPtr inner, KernelType kernel,
                                                 double parameter) {
  if (!inner) throw std::invalid_argument("KernelFactor: null inner factor");
  if (parameter <= 0.0) parameter = defaultKernelParameter(kernel, inner->dim());
  return makeWrapper<KernelFactor>(inner, 4, kernel, parameter);
}

void KernelFactor::evaluate(const double* const* x, double* r, double* const* J) const {
  inner_->evaluate(x, r, J);
  double c = 0.0;
  for (int k = 0; k < dim(); ++k) c += r[k] * r[k];
  const double w = kernelWeight(kernel_, c, parameter_);
  if (w != 1.0) scaleBlocks(*this, size(), std::sqrt(w), r, J);
}

double KernelFactor::objective(const double* const* x) const {
  return kernelCost(kernel_, inner_->chi2(x), parameter_);
}

bool KernelFactor::heldAt(const double* const* x, FactorPtr& inner, double& weight) const {
  inner = inner_;
  weight = kernelWeight(kernel_, inner_->chi2(x), parameter_);
  return true;
}

std::unique_ptr<Factor> KernelFactor::clone() const {
  auto c = std::make_unique<KernelFactor>(*this);
  c->inner_ = inner_->clone();
  return c;
}

double KernelFactor::weightAt(const Values& values) const {
  return kernelWeight(kernel_, chi2At(*inner_, values), parameter_);
}

// --- SwitchableFactor --------------------------------------------------------------------

template <size_t... I>
SwitchableFactor::SwitchableFactor(std::index_sequence<I...>, FactorPtr inner, Key switchKey)
    : Factor({{inner->key(I), inner->varType(I)}..., {switchKey, VarType::Scalar}}, inner->dim(),
             inner->role()),
      inner_(std::move(inner)) {
  setId(inner_->id());
}

std::shared_ptr<SwitchableFactor> SwitchableFactor::make(FactorPtr inner, Key switchKey) {
  return makeWrapper<SwitchableFactor>(inner, kMaxFactorKeys - 1, switchKey);
}

void SwitchableFactor::evaluate(const double* const* x, double* r, double* const* J) const {
  const int n = size() - 1;
  inner_->evaluate(x, r, J);
  const double s = x[n][0];
  const double p = psi(s);
  if (J != nullptr && J[n] != nullptr)
    for (int k = 0; k < dim(); ++k) J[n][k] = r[k];  // ∂(Ψ(s)·r)/∂s = r (linear Ψ)
  scaleBlocks(*this, n, p, r, J);
}

std::unique_ptr<Factor> SwitchableFactor::clone() const {
  auto c = std::make_unique<SwitchableFactor>(*this);
  c->inner_ = inner_->clone();
  return c;
}

SwitchPriorFactor::SwitchPriorFactor(Key s, double gamma, double sigma)
    : Factor({{s, VarType::Scalar}}, 1, FactorRole::Odometry), gamma_(gamma), sigma_(sigma) {
  if (!(sigma > 0.0)) throw std::invalid_argument("SwitchPriorFactor: sigma must be > 0");
}

void SwitchPriorFactor::evaluate(const double* const* x, double* r, double* const* J) const {
  r[0] = (x[0][0] - gamma_) / sigma_;
  if (J != nullptr && J[0] != nullptr) J[0][0] = 1.0 / sigma_;
}

std::unique_ptr<Factor> SwitchPriorFactor::clone() const {
  return std::make_unique<SwitchPriorFactor>(*this);
}

// --- MaxMixtureFactor --------------------------------------------------------------------

template <size_t... I>
MaxMixtureFactor::MaxMixtureFactor(std::index_sequence<I...>, FactorPtr inner, double nullWeight,
                                   double nullSigma)
    : Factor({{inner->key(I), inner->varType(I)}...}, inner->dim(), inner->role()),
      inner_(std::move(inner)),
      nullWeight_(nullWeight),
      nullSigma_(nullSigma) {
  if (!(nullWeight > 0.0 && nullWeight < 1.0) || !(nullSigma > 1.0))
    throw std::invalid_argument("MaxMixtureFactor: need 0 < null weight < 1, null sigma > 1");
  // Component cost: −ln w + ½ln|2πΣ| + ½χ²; the inlier has w = 1, the null Σ·σ₀², χ²/σ₀².
  const double s2 = nullSigma_ * nullSigma_;
  switchChi2_ = 2.0 * (effectiveDim(*inner_) * std::log(nullSigma_) - std::log(nullWeight_)) /
                (1.0 - 1.0 / s2);
  setId(inner_->id());
}

std::shared_ptr<MaxMixtureFactor> MaxMixtureFactor::make(FactorPtr inner, double nullWeight,
                                                         double nullSigma) {
  return makeWrapper<MaxMixtureFactor>(inner, 4, nullWeight, nullSigma);
}

void MaxMixtureFactor::evaluate(const double* const* x, double* r, double* const* J) const {
  inner_->evaluate(x, r, J);
  double c = 0.0;
  for (int k = 0; k < dim(); ++k) c += r[k] * r[k];
  if (nullWins(c)) scaleBlocks(*this, size(), 1.0 / nullSigma_, r, J);
}

std::unique_ptr<Factor> MaxMixtureFactor::clone() const {
  auto c = std::make_unique<MaxMixtureFactor>(*this);
  c->inner_ = inner_->clone();
  return c;
}

double MaxMixtureFactor::objective(const double* const* x) const {
  const double c = inner_->chi2(x);
  if (!nullWins(c)) return c;
  const double s2 = nullSigma_ * nullSigma_;
  return c / s2 + switchChi2_ * (1.0 - 1.0 / s2);  // the null's normaliser, as in the ctor
}

bool MaxMixtureFactor::heldAt(const double* const* x, FactorPtr& inner, double& weight) const {
  const double c = inner_->chi2(x);
  inner = inner_;
  weight = nullWins(c) ? 1.0 / (nullSigma_ * nullSigma_) : 1.0;
  return true;
}

bool MaxMixtureFactor::nullChosenAt(const Values& values) const {
  return nullWins(chi2At(*inner_, values));
}

// --- WeightedFactor, GraduatedFactor ------------------------------------------------------

template <size_t... I>
WeightedFactor::WeightedFactor(std::index_sequence<I...>, FactorPtr inner, double weight)
    : Factor({{inner->key(I), inner->varType(I)}...}, inner->dim(), inner->role()),
      inner_(std::move(inner)),
      weight_(weight) {
  if (!(weight >= 0.0)) throw std::invalid_argument("WeightedFactor: weight must be >= 0");
  setId(inner_->id());
}

std::shared_ptr<WeightedFactor> WeightedFactor::make(FactorPtr inner, double weight) {
  return makeWrapper<WeightedFactor>(inner, 4, weight);
}

void WeightedFactor::evaluate(const double* const* x, double* r, double* const* J) const {
  inner_->evaluate(x, r, J);
  if (weight_ != 1.0) scaleBlocks(*this, size(), std::sqrt(weight_), r, J);
}

std::unique_ptr<Factor> WeightedFactor::clone() const {
  auto c = std::make_unique<WeightedFactor>(*this);
  c->inner_ = inner_->clone();
  return c;
}

template <size_t... I>
GraduatedFactor::GraduatedFactor(std::index_sequence<I...>, FactorPtr inner, double mu, double c)
    : Factor({{inner->key(I), inner->varType(I)}...}, inner->dim(), inner->role()),
      inner_(std::move(inner)),
      mu_(mu),
      c_(c) {
  setId(inner_->id());
}

std::shared_ptr<GraduatedFactor> GraduatedFactor::make(FactorPtr inner, double mu, double c) {
  return makeWrapper<GraduatedFactor>(inner, 4, mu, c);
}

void GraduatedFactor::evaluate(const double* const* x, double* r, double* const* J) const {
  inner_->evaluate(x, r, J);
  double c = 0.0;
  for (int k = 0; k < dim(); ++k) c += r[k] * r[k];
  const double w = sigWeight(c, mu_, c_);
  scaleBlocks(*this, size(), std::sqrt(w), r, J);
}

std::unique_ptr<Factor> GraduatedFactor::clone() const {
  auto c = std::make_unique<GraduatedFactor>(*this);
  c->inner_ = inner_->clone();
  return c;
}

double GraduatedFactor::weightAt(const Values& values) const {
  return sigWeight(chi2At(*inner_, values), mu_, c_);
}

}  // namespace loopd
