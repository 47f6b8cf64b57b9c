#include "robust/robust_wrapping.h"

namespace loopd {

std::optional<WrapSpec> wrapSpecFor(const std::string& variant, double parameter) {
  WrapSpec s;
  s.parameter = parameter;
  if (variant == "huber")
    s.kernel = KernelType::Huber;
  else if (variant == "cauchy")
    s.kernel = KernelType::Cauchy;
  else if (variant == "gm")
    s.kernel = KernelType::GemanMcClure;
  else if (variant == "dcs")
    s.kernel = KernelType::DCS;
  else if (variant == "sc")
    s.method = RobustMethod::Switchable;
  else if (variant == "mm")
    s.method = RobustMethod::MaxMixture;
  else
    return std::nullopt;
  return s;
}

FactorPtr wrapFactor(const FactorPtr& f, const WrapSpec& spec, Key switchKey) {
  switch (spec.method) {
    case RobustMethod::Kernel:
      return KernelFactor::make(f, spec.kernel, spec.parameter);
    case RobustMethod::Switchable:
      return SwitchableFactor::make(f, switchKey);
    case RobustMethod::MaxMixture:
      return MaxMixtureFactor::make(f, spec.parameter > 0.0 ? spec.parameter : 1e-7,
                                    spec.nullSigma);
  }
  return f;
}

FactorPtr switchPrior(Key switchKey, const WrapSpec& spec, FactorId id) {
  auto prior = std::make_shared<SwitchPriorFactor>(switchKey, spec.switchPrior,
                                                   spec.parameter > 0.0 ? spec.parameter : 1.0);
  prior->setId(id);
  return prior;
}

double wrappedWeight(const Factor& w, const Values& x) {
  if (auto k = dynamic_cast<const KernelFactor*>(&w)) return k->weightAt(x);
  if (auto s = dynamic_cast<const SwitchableFactor*>(&w)) {
    const int slot = x.slot(s->switchKey());
    return slot < 0 ? 1.0 : SwitchableFactor::psi(x.scalar(slot));
  }
  if (auto m = dynamic_cast<const MaxMixtureFactor*>(&w)) return m->nullChosenAt(x) ? 0.0 : 1.0;
  return 1.0;
}

}  // namespace loopd
