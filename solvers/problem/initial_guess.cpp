#include "solvers/problem/initial_guess.h"

#include "solvers/factors/between_factor_se2.h"
#include "solvers/factors/between_factor_se3.h"
#include "solvers/factors/landmark_factors.h"

namespace loopd {

namespace {

// The value of `key` from whichever of known/guess has it.
const Values* holder(Key key, const Values& known, const Values& guess) {
  if (known.contains(key)) return &known;
  if (guess.contains(key)) return &guess;
  return nullptr;
}

// Predicts the unknown end of f from the known one; true if it inserted a value.
bool predictThrough(const Factor& f, const Values& known, Values& guess) {
  if (f.size() != 2) return false;
  const Values* a = holder(f.key(0), known, guess);
  const Values* b = holder(f.key(1), known, guess);
  if ((a == nullptr) == (b == nullptr)) return false;  // both or neither known
  if (const auto* e = dynamic_cast<const BetweenFactorSE2*>(&f)) {
    if (a)
      guess.insert(f.key(1), a->se2(a->slot(f.key(0))) * e->measured());
    else
      guess.insert(f.key(0), b->se2(b->slot(f.key(1))) * e->measured().inverse());
    return true;
  }
  if (const auto* e = dynamic_cast<const BetweenFactorSE3*>(&f)) {
    if (a)
      guess.insert(f.key(1), a->se3(a->slot(f.key(0))) * e->measured());
    else
      guess.insert(f.key(0), b->se3(b->slot(f.key(1))) * e->measured().inverse());
    return true;
  }
  if (!a) return false;  // a landmark cannot place its observer
  const int s = a->slot(f.key(0));
  if (const auto* e = dynamic_cast<const PosePointFactor2*>(&f)) {
    guess.insertPoint2(f.key(1), a->se2(s).transform(e->measured()));
    return true;
  }
  if (const auto* e = dynamic_cast<const PosePointFactor3*>(&f)) {
    guess.insertPoint3(f.key(1), a->se3(s).transform(e->measured()));
    return true;
  }
  if (const auto* e = dynamic_cast<const BearingRangeFactor2*>(&f)) {
    const SE2 x = a->se2(s);
    const double angle = x.theta + e->measured()[0];
    guess.insertPoint2(f.key(1), x.t() + e->measured()[1] * Vec2(std::cos(angle), std::sin(angle)));
    return true;
  }
  return false;
}

}  // namespace

bool predictMissingValues(const std::vector<FactorPtr>& newFactors, const Values& known,
                          Values& guess) {
  // Odometry first so a new pose hangs off its predecessor rather than a loop closure.
  std::vector<const Factor*> order;
  for (const auto& f : newFactors)
    if (f->role() == FactorRole::Odometry) order.push_back(f.get());
  for (const auto& f : newFactors)
    if (f->role() != FactorRole::Odometry) order.push_back(f.get());
  bool progress = true;
  while (progress) {
    progress = false;
    for (const Factor* f : order) progress |= predictThrough(*f, known, guess);
  }
  for (const auto& f : newFactors)
    for (int k = 0; k < f->size(); ++k)
      if (!holder(f->key(k), known, guess)) return false;
  return true;
}

}  // namespace loopd
