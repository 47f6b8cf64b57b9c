#include "robust/held_kernel_factor.h"

#include <cmath>
#include <stdexcept>
#include <utility>

#include "robust/wrapper_support.h"

namespace loopd {

template <size_t... I>
HeldKernelFactor::HeldKernelFactor(std::index_sequence<I...>, FactorPtr inner, KernelType kernel,
                                   double parameter)
    : Factor({{inner->key(I), inner->varType(I)}...}, inner->dim(), inner->role()),
      inner_(std::move(inner)),
      kernel_(kernel),
      parameter_(parameter) {
  setId(inner_->id());
}

std::shared_ptr<HeldKernelFactor> HeldKernelFactor::make(FactorPtr inner, KernelType kernel,
                                                         double parameter) {
  if (!inner) throw std::invalid_argument("HeldKernelFactor: null inner factor");
  if (parameter <= 0.0) parameter = defaultKernelParameter(kernel, inner->dim());
  return makeWrapper<HeldKernelFactor>(inner, 4, kernel, parameter);
}

void HeldKernelFactor::evaluate(const double* const* x, double* r, double* const* J) const {
  inner_->evaluate(x, r, J);
  if (weight_ != 1.0) scaleBlocks(*this, size(), std::sqrt(weight_), r, J);
}

std::unique_ptr<Factor> HeldKernelFactor::clone() const {
  auto c = std::make_unique<HeldKernelFactor>(*this);
  c->inner_ = inner_->clone();
  return c;
}

double HeldKernelFactor::weightAt(const Values& values) const {
  return kernelWeight(kernel_, inner_->chi2(values), parameter_);
}

double HeldKernelFactor::holdWeightAt(const Values& values) {
  const double w = weightAt(values);
  const double change = std::abs(w - weight_);
  weight_ = w;
  return change;
}

}  // namespace loopd
