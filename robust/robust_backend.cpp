#include "robust/robust_backend.h"

#include <algorithm>
#include <stdexcept>
#include <unordered_set>

namespace loopd {

RobustBackend::RobustBackend(std::string name, std::unique_ptr<Backend> inner,
                             RobustBackendOptions options)
    : DecoratorBackend(std::move(inner), "RobustBackend"),
      name_(std::move(name)),
      options_(options) {}

UpdateResult RobustBackend::update(const BackendUpdate& u) {
  BackendUpdate inner;
  inner.initial = u.initial;
  inner.removals = u.removals;
  inner.factors.reserve(u.factors.size() * 2);
  std::unordered_set<FactorId> removing(u.removals.begin(), u.removals.end());
  std::vector<std::pair<FactorId, FactorPtr>> newWrapped;
  std::vector<std::pair<FactorId, Key>> newSwitches;
  std::uint64_t nextSwitch = nextSwitch_;
  for (const FactorPtr& f : u.factors) {
    if (!f) throw std::invalid_argument(name_ + ": null factor in update");
    if (f->id() & kInternalIdBit)
      throw std::invalid_argument(name_ + ": factor id " + std::to_string(f->id()) +
                                  " uses the top bit (reserved for internal factors)");
    if (!isUncertain(f->role())) {
      inner.factors.push_back(f);
      continue;
    }
    Key s = 0;
    if (options_.method == RobustMethod::Switchable) {
      auto it = switches_.find(f->id());
      if (it != switches_.end()) {
        s = it->second;  // re-added under the same id: keep its switch and prior
      } else {
        s = makeKey(keyRobot(f->key(0)), KeyKind::Switch, nextSwitch++);
        if (inner.initial.contains(s) || inner_->estimate().contains(s))
          throw std::invalid_argument(name_ + ": switch key " + keyToString(s) + " in use");
        inner.initial.insertScalar(s, options_.switchPrior);
        inner.factors.push_back(switchPrior(s, options_, f->id() | kInternalIdBit));
        newSwitches.emplace_back(f->id(), s);
      }
    }
    FactorPtr w = wrapFactor(f, options_, s);
    inner.factors.push_back(w);
    newWrapped.emplace_back(f->id(), w);
  }

  UpdateResult result = inner_->update(inner);  // throws (state unchanged) if invalid

  // Commit the bookkeeping only once the inner backend accepted the update. Switch priors
  // stay when their factor is removed, so the switch variable stays determined.
  nextSwitch_ = nextSwitch;
  commitOriginals(u, removing);
  for (FactorId id : u.removals) wrapped_.erase(id);
  for (auto& [id, w] : newWrapped) wrapped_[id] = w;
  for (auto& [id, s] : newSwitches) switches_[id] = s;
  return result;
}

std::vector<std::pair<FactorId, double>> RobustBackend::decisions() const {
  std::vector<std::pair<FactorId, double>> out;
  out.reserve(wrapped_.size());
  for (const auto& f : originals_.factors()) {
    auto it = wrapped_.find(f->id());
    if (it != wrapped_.end())
      out.emplace_back(f->id(), wrappedWeight(*it->second, inner_->estimate()));
  }
  return out;
}

std::vector<FactorId> RobustBackend::rejected() const {
  std::vector<FactorId> out;
  for (const auto& [id, w] : decisions())
    if (w < options_.rejectBelow) out.push_back(id);
  return out;
}

Key RobustBackend::switchOf(FactorId id) const {
  auto it = switches_.find(id);
  return it == switches_.end() ? 0 : it->second;
}

}  // namespace loopd
