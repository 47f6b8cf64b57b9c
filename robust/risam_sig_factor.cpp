#include "robust/risam_sig_factor.h"

#include <cmath>
#include <stdexcept>
#include <string>

namespace loopd {

void RisamSigFactor::evaluate(const double* const* x, double* r, double* const* J) const {
  inner_->evaluate(x, r, J);
  double c2 = 0.0;
  for (int k = 0; k < dim(); ++k) c2 += r[k] * r[k];
  const double e = chi2AtEstimate();
  const double w = shape_.weight(e >= 0.0 ? e : c2, mu_);
  const double s = std::sqrt(w);
  for (int k = 0; k < dim(); ++k) r[k] *= s;
  if (J == nullptr) return;
  for (int i = 0; i < size(); ++i)
    if (J[i] != nullptr)
      for (int k = 0, n = dim() * varDim(varType(i)); k < n; ++k) J[i][k] *= s;
}

std::unique_ptr<Factor> RisamSigFactor::clone() const {
  auto c = std::make_unique<RisamSigFactor>(*this);
  c->inner_ = inner_->clone();
  return c;
}

double RisamSigFactor::chi2AtEstimate() const {
  if (at_ == nullptr) return -1.0;
  std::array<const double*, kMaxFactorKeys> xp{};
  for (int i = 0; i < size(); ++i) {
    const int s = at_->slot(key(i));
    if (s < 0) return -1.0;
    xp[i] = at_->data(s);
  }
  std::array<double, 4 * kMaxVarDim> r{};
  if (dim() > static_cast<int>(r.size())) return -1.0;
  inner_->evaluate(xp.data(), r.data(), nullptr);
  double c2 = 0.0;
  for (int k = 0; k < dim(); ++k) c2 += r[k] * r[k];
  return c2;
}

namespace {

template <size_t N>
FactorPtr makeSig(const FactorPtr& f, double mu, SigShape shape, const Values* at, FactorId id) {
  auto w = std::make_shared<RisamSigFactor>(std::make_index_sequence<N>{}, f, mu, shape, at);
  w->setId(id);
  return w;
}

}  // namespace

FactorPtr makeRisamSig(const FactorPtr& f, double mu, SigShape shape, const Values* at,
                       FactorId id) {
  switch (f->size()) {
    case 1:
      return makeSig<1>(f, mu, shape, at, id);
    case 2:
      return makeSig<2>(f, mu, shape, at, id);
    case 3:
      return makeSig<3>(f, mu, shape, at, id);
    case 4:
      return makeSig<4>(f, mu, shape, at, id);
    default:
      throw std::invalid_argument("risam: factor with " + std::to_string(f->size()) + " keys");
  }
}

}  // namespace loopd
