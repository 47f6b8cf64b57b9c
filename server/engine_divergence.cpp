// A solver step that leaves NaN, infinite or absurd values (ranAway(): a measurement of
// absurd size, a variant that ran away) must not reach the estimate channel or poison every
// later update: the engine rebuilds the solver from the graph it had before, and the round
// is refused.
#include <spdlog/spdlog.h>

#include "server/engine.h"
#include "solvers/problem/initial_guess.h"

namespace loopd::server {

namespace {

// A part of the graph none of whose variables has a value left: its first variable starts at
// the origin, the rest is composed from it. False if every variable has a value.
bool seedOneMissing(const std::vector<FactorPtr>& factors, Values& initial) {
  for (const FactorPtr& f : factors)
    for (int k = 0; k < f->size(); ++k) {
      const Key key = f->key(k);
      if (initial.contains(key)) continue;
      switch (f->varType(k)) {
        case VarType::SE2:
          initial.insert(key, SE2());
          break;
        case VarType::SE3:
          initial.insert(key, SE3());
          break;
        case VarType::Point2:
          initial.insertPoint2(key, Vec2::Zero());
          break;
        case VarType::Point3:
          initial.insertPoint3(key, Vec3::Zero());
          break;
        case VarType::Scalar:
          initial.insertScalar(key, 0.0);
          break;
      }
      return true;
    }
  return false;
}

}  // namespace

bool ranAway(const Values& estimate) { return !estimate.allWithin(kRunawayMagnitude); }

bool Engine::recoverIfDiverged(const char* what, const Values* lastGood) {
  if (!ranAway(backend_->estimate())) return false;
  spdlog::error(
      "the {} solver diverged on {} (NaN, infinite or absurd estimate); rebuilding it from {}",
      backend_->name(), what, lastGood ? "the estimate before" : "the graph before");
  try {
    recoverFromDivergence(lastGood);
  } catch (const std::exception& e) {
    spdlog::critical("solver could not be rebuilt: {}", e.what());
  }
  return true;
}

void Engine::recoverFromDivergence(const Values* lastGood) {
  const Values& x = backend_->estimate();
  BackendUpdate all;
  for (const auto& [id, f] : live_) all.factors.push_back(f);
  for (const auto& [id, g] : groups_) all.ambiguous.push_back(g.factor);
  // Start from the last good estimate where there is one, else from the sane part of the
  // diverged one; the rest is composed along the odometry from its neighbours. (feedRebuilt
  // keeps only the graph's own variables of these.)
  for (int s = 0; lastGood && s < lastGood->size(); ++s)
    if (lastGood->slotWithin(s, kRunawayMagnitude)) all.initial.insertFrom(*lastGood, s);
  for (int s = 0; s < x.size(); ++s)
    if (!all.initial.contains(x.key(s)) && x.slotWithin(s, kRunawayMagnitude))
      all.initial.insertFrom(x, s);
  std::vector<FactorPtr> everything = all.factors;
  for (const auto& a : all.ambiguous)
    everything.insert(everything.end(), a.alternatives.begin(), a.alternatives.end());
  while (!predictMissingValues(everything, Values(), all.initial))
    if (!seedOneMissing(everything, all.initial)) break;
  std::unique_ptr<PerFactorRobustBackend> next = makeSolver(backend_->name());
  // No optimize() here: it may be what diverged. The next idle optimize converges.
  feedRebuilt(*next, std::move(all));
  backend_ = std::move(next);
  lastDecisions_.clear();
  lastGroupDecisions_.clear();
  dirty_ = true;
  std::lock_guard<std::mutex> l(countersMu_);
  ++counters_.divergences;
}

}  // namespace loopd::server
