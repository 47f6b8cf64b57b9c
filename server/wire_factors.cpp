#include "server/wire_factors.h"

#include <stdexcept>

#include "server/anchored_sighting_factor.h"
#include "server/wire.h"
#include "solvers/factors/anchored_between_factor.h"
#include "solvers/factors/landmark_factors.h"
#include "solvers/factors/prior_factors.h"

namespace loopd::server {

using W = loopd::factor_t;

namespace {

FactorRole roleOf(int role) {
  switch (role) {
    case W::ROLE_PRIOR:
      return FactorRole::Prior;
    case W::ROLE_ODOMETRY:
      return FactorRole::Odometry;
    case W::ROLE_LANDMARK:
      return FactorRole::Landmark;
    default:
      return FactorRole::LoopClosure;
  }
}

}  // namespace

SE2 se2Of(const Values& v, Key k) { return v.se2(v.slot(k)); }
SE3 se3Of(const Values& v, Key k) { return v.se3(v.slot(k)); }

SE3 se3From(const std::vector<double>& m) { return SE3::fromTranslationQuaternion(m.data()); }

std::shared_ptr<Factor> buildFactor(const W& f) {
  const Eigen::MatrixXd info = informationOf(f);
  const Key a = toKey(f.keys[0]);
  const Key b = f.num_keys > 1 ? toKey(f.keys[1]) : 0;
  const auto& m = f.measurement;
  const FactorRole role = roleOf(f.role);
  std::shared_ptr<Factor> out;
  switch (f.type) {
    case W::PRIOR_SE2:
      out = std::make_shared<PriorFactorSE2>(a, SE2(m[0], m[1], m[2]), Eigen::Matrix3d(info));
      break;
    case W::PRIOR_SE3:
      out = std::make_shared<PriorFactorSE3>(a, se3From(m), Mat6(info));
      break;
    case W::PRIOR_POINT2:
      out = std::make_shared<PriorFactorPoint2>(a, Vec2(m[0], m[1]), Eigen::Matrix2d(info));
      break;
    case W::PRIOR_POINT3:
      out = std::make_shared<PriorFactorPoint3>(a, Vec3(m[0], m[1], m[2]), Mat3(info));
      break;
    case W::BETWEEN_SE2:
      out = std::make_shared<BetweenFactorSE2>(a, b, SE2(m[0], m[1], m[2]), Eigen::Matrix3d(info),
                                               role);
      break;
    case W::BETWEEN_SE3:
      out = std::make_shared<BetweenFactorSE3>(a, b, se3From(m), Mat6(info), role);
      break;
    case W::POSE_POINT2:
      out = std::make_shared<PosePointFactor2>(a, b, Vec2(m[0], m[1]), Eigen::Matrix2d(info), role);
      break;
    case W::POSE_POINT3:
      out = std::make_shared<PosePointFactor3>(a, b, Vec3(m[0], m[1], m[2]), Mat3(info), role);
      break;
    case W::BEARING_RANGE2:
      out = std::make_shared<BearingRangeFactor2>(a, b, Vec2(m[0], m[1]), Eigen::Matrix2d(info),
                                                  role);
      break;
    default:
      throw std::invalid_argument("unknown factor type");
  }
  out->setRole(role);
  return out;
}

bool isInterRobot(const W& f) {
  return (f.type == W::BETWEEN_SE2 || f.type == W::BETWEEN_SE3) &&
         f.keys[0].robot != f.keys[1].robot;
}

bool isSighting(const W& f) {
  return f.type == W::POSE_POINT2 || f.type == W::POSE_POINT3 || f.type == W::BEARING_RANGE2;
}

bool isCrossRobotSighting(const W& f) {
  return isSighting(f) && f.keys[0].robot != f.keys[1].robot;
}

std::shared_ptr<Factor> anchoredFactor(const Factor& built) {
  return anchoredFactor(built, keyRobot(built.key(1)));
}

std::shared_ptr<Factor> anchoredFactor(const Factor& built, std::uint32_t otherFrame) {
  const Key xr = built.key(0), other = built.key(1);
  const Key ar = anchorKey(keyRobot(xr)), as = anchorKey(otherFrame);
  std::shared_ptr<Factor> out;
  if (const auto* b = dynamic_cast<const BetweenFactorSE2*>(&built))
    out = std::make_shared<AnchoredBetweenFactorSE2>(ar, xr, as, other, b->measured(),
                                                     b->information(), FactorRole::LoopClosure);
  else if (const auto* b = dynamic_cast<const BetweenFactorSE3*>(&built))
    out = std::make_shared<AnchoredBetweenFactorSE3>(ar, xr, as, other, b->measured(),
                                                     b->information(), FactorRole::LoopClosure);
  else if (const auto* p = dynamic_cast<const PosePointFactor2*>(&built))
    out = std::make_shared<AnchoredPosePointFactor2>(ar, xr, as, other, p->measured(),
                                                     p->information(), built.role());
  else if (const auto* p = dynamic_cast<const PosePointFactor3*>(&built))
    out = std::make_shared<AnchoredPosePointFactor3>(ar, xr, as, other, p->measured(),
                                                     p->information(), built.role());
  else if (const auto* p = dynamic_cast<const BearingRangeFactor2*>(&built))
    out = std::make_shared<AnchoredBearingRangeFactor2>(ar, xr, as, other, p->measured(),
                                                        p->information(), built.role());
  else
    throw std::invalid_argument(std::string("no anchored form of ") + built.typeName());
  out->setId(built.id());
  out->setRobustRequest(built.robustRequest());
  return out;
}

bool isAnchored(const Factor& f) { return f.size() == 4; }

Key ownerTiedLandmark(const Factor& f) {
  if (isAnchored(f)) return 0;
  for (int i = 0; i < f.size(); ++i)
    if (f.varType(i) == VarType::Point2 || f.varType(i) == VarType::Point3) return f.key(i);
  return 0;
}

InterEdge interEdgeOf(Key pose, Key other, VarType otherType, std::uint32_t otherFrame) {
  InterEdge e;
  e.r = keyRobot(pose);
  e.s = otherFrame;
  if (otherType == VarType::Point2 || otherType == VarType::Point3) {
    e.landmark = other;
    e.needed = otherType == VarType::Point2 ? 2 : 3;
  }
  return e;
}

InterEdge interEdgeOf(const Factor& f) {
  return interEdgeOf(f.key(1), f.key(3), f.varType(3), keyRobot(f.key(2)));  // A_s names s
}

}  // namespace loopd::server
