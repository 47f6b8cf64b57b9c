#include "solvers/init/common_frame.h"

#include <memory>

#include "solvers/factors/anchored_between_factor.h"
#include "solvers/factors/between_factor_se2.h"
#include "solvers/factors/between_factor_se3.h"

namespace loopd {
namespace {

bool movesWithFrame(Key k) {
  const KeyKind kind = keyKind(k);
  return kind == KeyKind::Pose || kind == KeyKind::Landmark;
}

// slot of robot r's anchor in `values` (−1: none), per robot asked.
int anchorSlot(const Values& values, std::uint32_t robot) {
  return values.contains(anchorKey(robot)) ? values.slot(anchorKey(robot)) : -1;
}

// x ← A·x (or A⁻¹·x) for a pose or point slot, A the anchor in slot a of `anchors`.
void moveByFrame(Values& out, int s, const Values& anchors, int a, bool inverse) {
  switch (out.type(s)) {
    case VarType::SE2: {
      const SE2 A = inverse ? anchors.se2(a).inverse() : anchors.se2(a);
      out.set(s, A * out.se2(s));
      break;
    }
    case VarType::SE3: {
      const SE3 A = inverse ? anchors.se3(a).inverse() : anchors.se3(a);
      out.set(s, A * out.se3(s));
      break;
    }
    case VarType::Point2:
      out.setPoint2(s, inverse ? anchors.se2(a).transformTo(out.point2(s))
                               : anchors.se2(a).transform(out.point2(s)));
      break;
    case VarType::Point3:
      out.setPoint3(s, inverse ? anchors.se3(a).transformTo(out.point3(s))
                               : anchors.se3(a).transform(out.point3(s)));
      break;
    default:
      break;
  }
}

}  // namespace

std::map<std::uint32_t, int> lowestPoseOfEachRobot(const Values& values) {
  std::map<std::uint32_t, int> lowest;
  for (int s = 0; s < values.size(); ++s) {
    const Key k = values.key(s);
    if (keyKind(k) != KeyKind::Pose) continue;
    const auto it = lowest.find(keyRobot(k));
    if (it == lowest.end() || k < values.key(it->second)) lowest[keyRobot(k)] = s;
  }
  return lowest;
}

bool holdsSeveralFrames(const Values& values) {
  bool seen = false;
  std::uint32_t robot = 0;
  for (Key k : values.keys()) {
    if (keyKind(k) == KeyKind::Anchor) return true;
    if (keyKind(k) != KeyKind::Pose) continue;
    if (seen && keyRobot(k) != robot) return true;
    seen = true, robot = keyRobot(k);
  }
  return false;
}

Values inCommonFrame(const Values& values) {
  Values out = values;
  for (int s = 0; s < values.size(); ++s) {
    if (!movesWithFrame(values.key(s))) continue;
    const int a = anchorSlot(values, keyRobot(values.key(s)));
    if (a >= 0) moveByFrame(out, s, values, a, false);
  }
  return out;
}

FactorGraph withAnchoredBetweensPlain(const FactorGraph& graph) {
  FactorGraph out;
  for (const FactorPtr& f : graph.factors()) {
    std::shared_ptr<Factor> plain;
    if (const auto* a = dynamic_cast<const AnchoredBetweenFactorSE2*>(f.get()))
      plain = std::make_shared<BetweenFactorSE2>(f->key(1), f->key(3), a->measured(),
                                                 a->information(), f->role());
    else if (const auto* a3 = dynamic_cast<const AnchoredBetweenFactorSE3*>(f.get()))
      plain = std::make_shared<BetweenFactorSE3>(f->key(1), f->key(3), a3->measured(),
                                                 a3->information(), f->role());
    if (!plain) {
      out.add(f);
      continue;
    }
    plain->setId(f->id());
    out.add(std::move(plain));
  }
  return out;
}

Values inOwnFrames(const Values& common, const Values& ownFrames) {
  Values out = common;
  // Each anchored robot's lowest pose: where its own frame is pinned. A robot with an anchor
  // but no pose (landmarks only) keeps its anchor.
  for (const auto& [robot, s] : lowestPoseOfEachRobot(ownFrames)) {
    const int a = anchorSlot(out, robot);
    if (a < 0) continue;
    if (ownFrames.type(s) == VarType::SE3)
      out.set(a, common.se3(s) * ownFrames.se3(s).inverse());
    else
      out.set(a, common.se2(s) * ownFrames.se2(s).inverse());
  }
  for (int s = 0; s < out.size(); ++s) {
    if (!movesWithFrame(out.key(s))) continue;
    const int a = anchorSlot(out, keyRobot(out.key(s)));
    if (a >= 0) moveByFrame(out, s, out, a, true);
  }
  return out;
}

}  // namespace loopd
