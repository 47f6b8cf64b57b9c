#include "robust/per_factor_backend.h"

#include <stdexcept>
#include <unordered_set>

namespace loopd {

PerFactorRobustBackend::PerFactorRobustBackend(std::unique_ptr<Backend> solver)
    : DecoratorBackend(std::move(solver), "PerFactorRobustBackend") {}

bool PerFactorRobustBackend::handlesHere(const Factor& f) const {
  if (!isUncertain(f.role())) return false;
  const std::string& v = f.robustRequest().variant;
  if (v.empty() || v == inner_->name()) return false;
  return v == "none" || wrapSpecFor(v, 0.0).has_value();
}

UpdateResult PerFactorRobustBackend::update(const BackendUpdate& u) {
  BackendUpdate inner;
  inner.initial = u.initial;
  inner.removals = u.removals;
  inner.ambiguous = u.ambiguous;
  inner.factors.reserve(u.factors.size());
  std::vector<std::pair<FactorId, Handled>> newHandled;
  std::vector<std::pair<FactorId, Key>> newSwitches;
  std::uint64_t nextSwitch = nextSwitch_;
  for (const FactorPtr& f : u.factors) {
    if (!f) throw std::invalid_argument(name() + ": null factor in update");
    if (f->id() & kPriorIdBit)
      throw std::invalid_argument(name() + ": factor id " + std::to_string(f->id()) +
                                  " uses bit 62 (reserved for internal factors)");
    if (!handlesHere(*f)) {
      inner.factors.push_back(f);
      continue;
    }
    const RobustRequest& req = f->robustRequest();
    std::shared_ptr<Factor> given;
    if (req.variant == "none") {
      given = f->clone();
    } else {
      const WrapSpec spec = *wrapSpecFor(req.variant, req.parameter);
      Key s = 0;
      if (spec.method == RobustMethod::Switchable) {
        const auto it = switches_.find(f->id());
        if (it != switches_.end()) {
          s = it->second;  // re-added under the same id: keep its switch and prior
        } else {
          s = makeKey(keyRobot(f->key(0)), KeyKind::Switch, kSwitchIndexBase + nextSwitch++);
          inner.initial.insertScalar(s, spec.switchPrior);
          inner.factors.push_back(switchPrior(s, spec, f->id() | kPriorIdBit));
          newSwitches.emplace_back(f->id(), s);
        }
      }
      given = std::const_pointer_cast<Factor>(wrapFactor(f, spec, s));
    }
    given->setId(f->id());
    given->setRole(FactorRole::Odometry);  // trusted: the solver's own scheme leaves it alone
    inner.factors.push_back(given);
    newHandled.emplace_back(f->id(), Handled{f, given});
  }

  UpdateResult result = inner_->update(inner);  // throws (state unchanged) if invalid

  // Switch priors stay when their factor is removed, so the switch variable stays determined.
  nextSwitch_ = nextSwitch;
  for (FactorId id : u.removals) handled_.erase(id);
  for (auto& [id, h] : newHandled) handled_[id] = std::move(h);
  for (auto& [id, s] : newSwitches) switches_[id] = s;
  asSentStale_ = true;
  return result;
}

const FactorGraph& PerFactorRobustBackend::graph() const {
  if (handled_.empty() && switches_.empty()) return inner_->graph();
  if (asSentStale_) {
    asSent_ = FactorGraph();
    for (const auto& f : inner_->graph().factors()) {
      if (f->id() & kPriorIdBit) continue;  // this layer's switch priors
      const auto it = handled_.find(f->id());
      asSent_.add(it == handled_.end() ? f : it->second.sent);
    }
    asSentStale_ = false;
  }
  return asSent_;
}

std::vector<std::pair<FactorId, double>> PerFactorRobustBackend::decisions() const {
  std::vector<std::pair<FactorId, double>> out = inner_->decisions();
  const Values& x = inner_->estimate();
  for (const auto& [id, h] : handled_) out.emplace_back(id, wrappedWeight(*h.given, x));
  return out;
}

std::vector<FactorId> PerFactorRobustBackend::rejected() const {
  std::vector<FactorId> out = inner_->rejected();
  const Values& x = inner_->estimate();
  for (const auto& [id, h] : handled_)
    if (wrappedWeight(*h.given, x) < kRejectBelow) out.push_back(id);
  return out;
}

}  // namespace loopd
