#include "robust/per_factor_backend.h"

#include <algorithm>
#include <stdexcept>
#include <unordered_set>

#include "solvers/backend/moved_keys.h"
#include "solvers/batch/batch_backend.h"

namespace loopd {

namespace {

// The batch solvers (lm, gn, dogleg, and gnc-* built on them) re-solve the whole graph and
// accept a step only if the cost they evaluate falls. iSAM2 takes each update's step with
// the weights of its linearization point (IRLS already), so a plain kernel suits it.
bool judgesStepsByCost(const Backend& b) { return dynamic_cast<const BatchBackend*>(&b); }

// The values a solve of u starts from: the estimate, with u's initial values for new keys.
Values startOf(const Values& estimate, const Values& initial) {
  Values start = estimate;
  for (int s = 0; s < initial.size(); ++s)
    if (!start.contains(initial.key(s))) start.insertFrom(initial, s);
  return start;
}

bool hasAllKeys(const Factor& f, const Values& x) {
  for (int k = 0; k < f.size(); ++k)
    if (!x.contains(f.key(k))) return false;
  return true;
}

}  // namespace

PerFactorRobustBackend::PerFactorRobustBackend(std::unique_ptr<Backend> solver)
    : DecoratorBackend(std::move(solver), "PerFactorRobustBackend"),
      holdKernels_(judgesStepsByCost(*inner_)) {}

bool PerFactorRobustBackend::handlesHere(const Factor& f) const {
  if (!isUncertain(f.role())) return false;
  const std::string& v = f.robustRequest().variant;
  if (v.empty() || v == inner_->name()) return false;
  return v == "none" || wrapSpecFor(v, 0.0).has_value();
}

bool PerFactorRobustBackend::mayDownWeight(const Factor& f) const {
  if (!isUncertain(f.role())) return false;
  if (handlesHere(f)) return f.robustRequest().variant != "none";
  return inner_->judgesUncertain();
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
  std::optional<Values> start;  // for held weights: where the solve starts (built once)
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
    std::shared_ptr<HeldKernelFactor> held;
    const std::optional<WrapSpec> spec = wrapSpecFor(req.variant, req.parameter);
    if (req.variant == "none") {
      given = f->clone();
    } else if (holdKernels_ && spec->method == RobustMethod::Kernel) {
      // The kernel's weight where the solve starts (the odometry's prediction for new poses).
      if (!start) start = startOf(inner_->estimate(), u.initial);
      held = HeldKernelFactor::make(f, spec->kernel, spec->parameter);
      if (hasAllKeys(*f, *start)) held->holdWeightAt(*start);  // else the solver refuses u
      given = held;
    } else {
      Key s = 0;
      if (spec->method == RobustMethod::Switchable) {
        const auto it = switches_.find(f->id());
        if (it != switches_.end()) {
          s = it->second;  // re-added under the same id: keep its switch and prior
        } else {
          s = makeKey(keyRobot(f->key(0)), KeyKind::Switch, kSwitchIndexBase + nextSwitch++);
          inner.initial.insertScalar(s, spec->switchPrior);
          inner.factors.push_back(switchPrior(s, *spec, f->id() | kPriorIdBit));
          newSwitches.emplace_back(f->id(), s);
        }
      }
      given = std::const_pointer_cast<Factor>(wrapFactor(f, *spec, s));
    }
    given->setId(f->id());
    given->setRole(FactorRole::Odometry);  // trusted: the solver's own scheme leaves it alone
    inner.factors.push_back(given);
    newHandled.emplace_back(f->id(), Handled{f, given, held});
  }

  const Values before = holdKernels_ ? inner_->estimate() : Values();
  UpdateResult result = inner_->update(inner);  // throws (state unchanged) if invalid

  // Switch priors stay when their factor is removed, so the switch variable stays determined.
  nextSwitch_ = nextSwitch;
  for (FactorId id : u.removals) handled_.erase(id);
  for (auto& [id, h] : newHandled) handled_[id] = std::move(h);
  for (auto& [id, s] : newSwitches) switches_[id] = s;
  asSentStale_ = true;
  if (holdKernels_) {
    settleHeldWeights();
    result.moved = movedKeys(before, inner_->estimate(), BackendOptions{}.moveThreshold);
  }
  return result;
}

void PerFactorRobustBackend::optimize() {
  inner_->optimize();
  if (holdKernels_) settleHeldWeights();
}

void PerFactorRobustBackend::settleHeldWeights() {
  for (int round = 0;; ++round) {
    const Values& x = inner_->estimate();
    double change = 0.0;
    for (auto& [id, h] : handled_)
      if (h.held) change = std::max(change, h.held->holdWeightAt(x));
    if (change <= kWeightTolerance || round == kMaxWeightRounds) return;
    inner_->optimize();
  }
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

double PerFactorRobustBackend::weightOf(const Handled& h, const Values& x) {
  return h.held ? h.held->weightAt(x) : wrappedWeight(*h.given, x);
}

std::vector<std::pair<FactorId, double>> PerFactorRobustBackend::decisions() const {
  std::vector<std::pair<FactorId, double>> out = inner_->decisions();
  const Values& x = inner_->estimate();
  for (const auto& [id, h] : handled_) out.emplace_back(id, weightOf(h, x));
  return out;
}

std::vector<FactorId> PerFactorRobustBackend::rejected() const {
  std::vector<FactorId> out = inner_->rejected();
  const Values& x = inner_->estimate();
  for (const auto& [id, h] : handled_)
    if (weightOf(h, x) < kRejectBelow) out.push_back(id);
  return out;
}

}  // namespace loopd
