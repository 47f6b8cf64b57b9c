#pragma once
// A one-robot pose graph split into two robots at pose `at`, as the server holds it: robot 1's
// poses (re-indexed from 0) in its own frame, its first pose at the origin, placed by its
// anchor; factors across the split become AnchoredBetweenFactorSE2s on (A_0, x, A_1, y).
#include <memory>

#include "solvers/factors/anchored_between_factor.h"
#include "solvers/factors/between_factor_se2.h"
#include "solvers/graph/factor_graph.h"
#include "solvers/init/common_frame.h"

namespace loopd::test {

struct TwoRobotSplit {
  FactorGraph graph;
  Values values;  // each robot's poses in its own frame; both anchors (A_1 at `robotOneAnchor`)
};

inline Key splitKey(Key k, std::uint64_t at) {
  const std::uint64_t i = keyIndex(k);
  return i < at ? poseKey(i, 0) : poseKey(i - at, 1);
}

/// `graph`'s SE(2) between factors (the rest left out) and `values`' poses, split at pose `at`;
/// with `link` false, the factors across the split are left out too (the robots not joined:
/// no anchors either).
inline TwoRobotSplit splitInTwo(const FactorGraph& graph, const Values& values, std::uint64_t at,
                                const SE2& robotOneAnchor, bool link = true) {
  TwoRobotSplit out;
  const SE2 origin = values.se2(values.slot(poseKey(at)));
  for (int s = 0; s < values.size(); ++s) {
    const Key k = values.key(s);
    if (keyKind(k) != KeyKind::Pose) continue;
    out.values.insert(splitKey(k, at),
                      keyIndex(k) < at ? values.se2(s) : origin.inverse() * values.se2(s));
  }
  if (link) {
    out.values.insert(anchorKey(0), SE2());
    out.values.insert(anchorKey(1), robotOneAnchor);
  }
  for (const FactorPtr& f : graph.factors()) {
    const auto* b = dynamic_cast<const BetweenFactorSE2*>(f.get());
    if (!b) continue;
    const Key x = splitKey(f->key(0), at), y = splitKey(f->key(1), at);
    std::shared_ptr<Factor> g;
    if (keyRobot(x) == keyRobot(y))
      g = std::make_shared<BetweenFactorSE2>(x, y, b->measured(), b->information(), f->role());
    else if (link)
      g = std::make_shared<AnchoredBetweenFactorSE2>(anchorKey(keyRobot(x)), x,
                                                     anchorKey(keyRobot(y)), y, b->measured(),
                                                     b->information(), f->role());
    if (!g) continue;
    g->setId(f->id());
    out.graph.add(std::move(g));
  }
  return out;
}

}  // namespace loopd::test
