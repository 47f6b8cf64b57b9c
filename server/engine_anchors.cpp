// Multi-robot anchors (engine.h): the robots' root priors, joining two robot groups through
// an inter-robot factor, regrouping after removals, and poses in the common frame.
#include "server/engine.h"

#include <spdlog/spdlog.h>

#include <algorithm>

#include "server/frame_groups.h"
#include "server/wire_factors.h"
#include "solvers/factors/between_factor_se2.h"
#include "solvers/factors/between_factor_se3.h"
#include "solvers/factors/prior_factors.h"

namespace loopd::server {

FactorPtr Engine::priorAt(Key k, const Values& from, int slot, double information) {
  std::shared_ptr<Factor> f;
  if (from.type(slot) == VarType::SE3)
    f = std::make_shared<PriorFactorSE3>(k, from.se3(slot), Mat6::Identity() * information);
  else
    f = std::make_shared<PriorFactorSE2>(k, from.se2(slot),
                                         Eigen::Matrix3d::Identity() * information);
  f->setId(newFactorId());
  return f;
}

std::int64_t Engine::joinRobots(std::uint32_t r, std::uint32_t s, const SE2& m2, const SE3& m3,
                                Staged& st) {
  RobotInfo& R = robots_.at(r);
  RobotInfo& S = robots_.at(s);
  BackendUpdate& u = st.update;
  const bool se3 = R.poseType == VarType::SE3;
  auto addFactor = [&](FactorPtr f) {
    u.factors.push_back(std::move(f));
    st.owners.push_back({"", -1, false});
  };
  auto anchorValue = [&](Key a, Values& into) {
    const Values* h = u.initial.contains(a) ? &u.initial : holder(a);
    into.insertFrom(*h, h->slot(a));
  };
  auto insertAnchor = [&](Key a, const SE2& v2, const SE3& v3, double info) -> FactorId {
    Values one;
    if (se3)
      one.insert(a, v3);
    else
      one.insert(a, v2);
    u.initial.insertFrom(one, 0);
    stagedValues_.insertFrom(one, 0);
    if (info <= 0.0) return FactorId{0};
    FactorPtr p = priorAt(a, one, 0, info);
    const FactorId id = p->id();
    addFactor(std::move(p));
    return id;
  };
  if (!R.anchored && !S.anchored) {
    R.anchorPrior = insertAnchor(anchorKey(r), SE2(), SE3(), opt_.priorInformation);
    R.anchored = true;
    R.parent = r;
    spdlog::info("robot {} anchors a common frame", r);
  }
  if (R.anchored != S.anchored) {
    // The newcomer's anchor from M (s's frame in r's): A_s = A_r·M, A_r = A_s·M⁻¹.
    const bool newIsS = !S.anchored;
    const std::uint32_t n = newIsS ? s : r, o = newIsS ? r : s;
    Values av;
    anchorValue(anchorKey(o), av);
    SE2 a2;
    SE3 a3;
    if (se3)
      a3 = newIsS ? av.se3(0) * m3 : av.se3(0) * m3.inverse();
    else
      a2 = newIsS ? av.se2(0) * m2 : av.se2(0) * m2.inverse();
    RobotInfo& N = robots_.at(n);
    N.anchorPrior = insertAnchor(anchorKey(n), a2, a3, 0.0);  // the factors determine it
    N.anchored = true;
    N.parent = root(o);
    N.placedFrom = o;
    spdlog::info("robot {} joins robot {}'s frame", n, root(o));
    return n;
  }
  const std::uint32_t rr = root(r), rs = root(s);
  if (rr == rs) return -1;
  // Two anchored groups: s's group root loses its strong prior (a negligible one keeps it
  // well posed) and the group follows the factor.
  RobotInfo& RS = robots_.at(rs);
  if (RS.anchorPrior != 0) u.removals.push_back(RS.anchorPrior);
  RS.anchorPrior = 0;
  RS.parent = rr;
  RS.placedFrom = r;
  spdlog::info("robot group of {} merges into robot {}'s frame", rs, rr);
  return rs;
}

void Engine::regroup(std::vector<Key>& moved) {
  // Inter-robot factors (or an owner's ties of landmarks others sight) were removed: recompute
  // the groups of joined robots from the live ones; a group left without a root prior gets one
  // (at its current value) on its lowest robot.
  regroupNeeded_ = false;
  settledJoins_.clear();  // pairs may now share a frame through other robots than before
  const std::map<std::uint32_t, std::uint32_t> groups =
      frameGroupsOf(interEdges_, ownerTiesAt(nullptr));
  std::map<std::uint32_t, std::uint32_t> parent;  // anchored robot → its group's root
  for (auto& [r, info] : robots_)
    if (info.anchored) parent[r] = groups.count(r) ? groups.at(r) : r;
  auto find = [&](std::uint32_t r) { return parent.at(r); };
  std::map<std::uint32_t, bool> hasRootPrior;
  for (auto& [r, p] : parent) hasRootPrior[find(r)] |= robots_.at(r).anchorPrior != 0;
  BackendUpdate u;
  for (auto& [r, p] : parent) {
    const std::uint32_t g = find(r);
    robots_.at(r).parent = g;
    if (g == r && !hasRootPrior[g]) {
      const Values& est = backend_->estimate();
      FactorPtr prior = priorAt(anchorKey(r), est, est.slot(anchorKey(r)), opt_.priorInformation);
      robots_.at(r).anchorPrior = prior->id();
      u.factors.push_back(prior);
      spdlog::info("robot {} roots a group again (inter-robot factors removed)", r);
    }
  }
  if (u.factors.empty()) return;
  try {
    for (Key k : backend_->update(u).moved) moved.push_back(k);
    for (const auto& f : u.factors) live_[f->id()] = f;
  } catch (const std::exception& e) {
    spdlog::error("re-anchoring failed: {}", e.what());
  }
}

bool Engine::commonFramePose(Key k, std::vector<double>& out) const {
  const Values& est = backend_->estimate();
  const int s = est.slot(k);
  if (s < 0) return false;
  const std::uint32_t r = frameOf(k);
  const bool anchored = robotJoined(r) && est.contains(anchorKey(r));
  if (est.type(s) == VarType::SE2) {
    const SE2 x = anchored ? se2Of(est, anchorKey(r)) * est.se2(s) : est.se2(s);
    out = {x.x, x.y, x.theta};
  } else if (est.type(s) == VarType::SE3) {
    const SE3 x = anchored ? se3Of(est, anchorKey(r)) * est.se3(s) : est.se3(s);
    out.assign(7, 0.0);
    x.toTranslationQuaternion(out.data());
  } else if (est.type(s) == VarType::Point2) {
    const Vec2 p = anchored ? se2Of(est, anchorKey(r)).transform(est.point2(s)) : est.point2(s);
    out = {p.x(), p.y()};
  } else if (est.type(s) == VarType::Point3) {
    const Vec3 p = anchored ? se3Of(est, anchorKey(r)).transform(est.point3(s)) : est.point3(s);
    out = {p.x(), p.y(), p.z()};
  } else {
    return false;
  }
  return true;
}

}  // namespace loopd::server
