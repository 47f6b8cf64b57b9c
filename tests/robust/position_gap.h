#pragma once
// How far two 2D estimates lie apart: the largest distance between a variable's position (a
// pose's or a point's) in both, by key.
#include <algorithm>
#include <limits>
#include <set>
#include <vector>

#include "solvers/core/values.h"
#include "solvers/factors/factor.h"

namespace loopd::test {

/// Over the 2D variables of `a` (with `touchedBy`, only those some of its factors touch: one
/// whose every sighting was rejected is left undetermined). A variable `b` lacks: infinity.
inline double largestPositionGap(const Values& a, const Values& b,
                                 const std::vector<FactorPtr>* touchedBy = nullptr) {
  std::set<Key> keys;
  if (touchedBy) {
    for (const FactorPtr& f : *touchedBy)
      for (int k = 0; k < f->size(); ++k) keys.insert(f->key(k));
  } else {
    for (int s = 0; s < a.size(); ++s) keys.insert(a.key(s));
  }
  auto position = [](const Values& v, int slot) {
    return v.type(slot) == VarType::SE2 ? v.se2(slot).t() : v.point2(slot);
  };
  double gap = 0.0;
  for (Key key : keys) {
    const int s = a.slot(key), t = b.slot(key);
    if (s < 0 || (a.type(s) != VarType::SE2 && a.type(s) != VarType::Point2)) continue;
    if (t < 0) return std::numeric_limits<double>::infinity();
    gap = std::max(gap, (position(a, s) - position(b, t)).norm());
  }
  return gap;
}

}  // namespace loopd::test
