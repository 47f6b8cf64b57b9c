// Cross-robot landmark sightings (engine.h): a pose of robot r sighting a landmark of robot s
// relates r's frame to s's. Through the robots' anchors it is an ordinary factor once the two
// frames are joined. A sighting cannot join them alone (one point leaves the rotation between
// the frames free, and the solver would meet a singular system), so a pair's sightings are
// kept back until another factor joins the frames or they reach enough distinct landmarks fixed
// in s's frame to fix the transform (frame_groups.h); the newcomer's anchor then starts at the
// least-squares alignment of the landmarks as each robot places them (frame_alignment.h). Any
// robot may introduce a landmark: a sighting of one its owner has not sent is kept back too,
// and places it through the anchors once the frames are joined (holding the batch instead held
// every later batch of the robot behind it). Such a landmark fixes nothing between the frames
// until its owner ties it (mergeGroupsJoinedByLandmarks).
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <set>

#include "server/engine.h"
#include "server/frame_alignment.h"
#include "server/frame_groups.h"
#include "server/wire.h"
#include "solvers/factors/landmark_factors.h"

namespace loopd::server {

namespace {

// Where the sighting factor puts its landmark in its pose's frame.
Vec2 sightedPoint2(const Factor& f) {
  if (const auto* p = dynamic_cast<const PosePointFactor2*>(&f)) return p->measured();
  const Vec2& br = static_cast<const BearingRangeFactor2&>(f).measured();
  return Vec2(br[1] * std::cos(br[0]), br[1] * std::sin(br[0]));
}

}  // namespace

void Engine::stageSightings(const std::vector<std::pair<FactorPtr, Owner>>& sightings, Staged& st) {
  std::map<RobotPair, Key> firstKeptBack;  // pairs with nothing kept back before this batch
  for (const auto& [f, owner] : sightings) {
    const RobotPair pair = std::minmax(keyRobot(f->key(0)), frameOf(f->key(1)));
    std::vector<KeptBack>& list = pending_[pair];
    if (list.empty()) firstKeptBack.emplace(pair, f->key(1));
    list.push_back({f, owner});
  }
  auto valueSlot = [&](Key k) -> std::pair<const Values*, int> {
    const Values* v = holder(k);
    return {v, v->slot(k)};
  };
  if (pending_.empty()) return;
  auto groupOf = [](const std::map<std::uint32_t, std::uint32_t>& groups, std::uint32_t r) {
    const auto g = groups.find(r);
    return g == groups.end() ? r : g->second;
  };
  const OwnerTies ties = ownerTiesAt(&st);
  // The edges, and the landmarks some robot of their owner's group sights, change only when a
  // pair's sightings go in; the frame groups are recomputed only after a join changed them.
  std::map<FactorId, InterEdge> current;
  std::set<Key> sightedInGroup;
  std::map<std::uint32_t, std::uint32_t> groups;
  auto refresh = [&](bool regroup) {
    current = currentInterEdges(&st);
    if (regroup) groups = frameGroupsOf(current, ties);
    sightedInGroup.clear();
    for (const auto& [id, e] : current)
      if (e.landmark != 0 && groupOf(groups, e.r) == groupOf(groups, e.s))
        sightedInGroup.insert(e.landmark);
  };
  refresh(true);
  for (auto it = pending_.begin(); it != pending_.end();) {
    const auto [a, b] = it->first;
    if (groupOf(groups, a) != groupOf(groups, b)) {
      if (!robots_.count(a) || !robots_.count(b)) {
        ++it;
        continue;
      }
      // Would the pair's sightings join the frames (the rule frameGroupsOf applies to them once
      // anchored)? Only landmarks fixed in their owner's group count: one nobody has placed,
      // or only other robots sight, cannot align the frames.
      std::map<FactorId, InterEdge> edges = current;
      auto counts = [&](const KeptBack& p) {
        const Key l = p.factor->key(1);
        return known(l) && (ties(l) || sightedInGroup.count(l));
      };
      for (const KeptBack& p : it->second)
        if (counts(p))
          edges[p.factor->id()] = interEdgeOf(p.factor->key(0), p.factor->key(1),
                                              p.factor->varType(1), frameOf(p.factor->key(1)));
      const std::map<std::uint32_t, std::uint32_t> withPair = frameGroupsOf(edges, ties);
      if (groupOf(withPair, a) != groupOf(withPair, b)) {
        ++it;
        continue;
      }
      // The landmarks as each robot places them: b's frame in a's aligns them.
      const bool se3 = robots_.at(a).poseType == VarType::SE3;
      std::vector<PointPair2> pairs2;
      std::vector<PointPair3> pairs3;
      for (const KeptBack& p : it->second) {
        if (!counts(p)) continue;
        const Factor& f = *p.factor;
        const auto [pv, ps] = valueSlot(f.key(0));
        const auto [lv, ls] = valueSlot(f.key(1));
        const bool poseOfA = keyRobot(f.key(0)) == a;
        if (se3) {
          const Vec3 seen =
              pv->se3(ps).transform(static_cast<const PosePointFactor3&>(f).measured());
          const Vec3 landmark = lv->point3(ls);
          pairs3.push_back(poseOfA ? PointPair3{landmark, seen} : PointPair3{seen, landmark});
        } else {
          const Vec2 seen = pv->se2(ps).transform(sightedPoint2(f));
          const Vec2 landmark = lv->point2(ls);
          pairs2.push_back(poseOfA ? PointPair2{landmark, seen} : PointPair2{seen, landmark});
        }
      }
      SE2 m2;
      SE3 m3;
      bool fixed = false;
      if (se3) {
        const auto m = alignFrames(pairs3);
        fixed = m.has_value();
        if (fixed) m3 = *m;
      } else {
        const auto m = alignFrames(pairs2);
        fixed = m.has_value();
        if (fixed) m2 = *m;
      }
      if (!fixed) {
        ++it;
        continue;
      }
      spdlog::info("robots {} and {}: {} landmark sightings fix their frames; joining them", a, b,
                   it->second.size());
      joinRobots(a, b, m2, m3, st);
    }
    const bool joined = groupOf(groups, a) != groupOf(groups, b);
    for (const KeptBack& p : it->second) {
      placeSightedLandmark(*p.factor, st);
      st.update.factors.push_back(anchoredFactor(*p.factor, frameOf(p.factor->key(1))));
      st.owners.push_back(p.owner);
    }
    it = pending_.erase(it);
    refresh(joined);
  }
  // Once per pair until it is joined (at info: a front-end's sightings not in the map yet).
  for (const auto& [pair, landmark] : firstKeptBack)
    if (pending_.count(pair)) {
      const std::uint32_t owner = keyRobot(landmark);
      const std::string noPoses =
          robots_.count(owner) || isLandmarkNamespace(owner)
              ? ""
              : "; robot " + std::to_string(owner) +
                    " has sent no poses: if it names a shared landmark map, run "
                    "loopd with --landmark-namespace " +
                    std::to_string(owner);
      spdlog::info(
          "sightings between robots {} and {} (first: {}) are kept back until a loop closure "
          "joins their frames or they name enough landmarks their owners' groups sight too (2 in "
          "2D, 3 in 3D){}",
          pair.first, pair.second, keyToString(landmark), noPoses);
    }
}

void Engine::mergeGroupsJoinedByLandmarks(Staged& st) {
  // Only where two anchored groups exist (every robot an edge names is anchored: anchored
  // factors exist only between anchored ones) and the batch adds a factor on a landmark.
  std::set<std::uint32_t> roots;
  for (const auto& [r, info] : robots_)
    if (info.anchored) roots.insert(root(r));
  if (roots.size() < 2) return;
  const bool onALandmark =
      std::any_of(st.update.factors.begin(), st.update.factors.end(), [](const FactorPtr& f) {
        return ownerTiedLandmark(*f) != 0 || (isAnchored(*f) && interEdgeOf(*f).landmark != 0);
      });
  if (!onALandmark) return;
  for (const auto& [r, g] : frameGroupsOf(currentInterEdges(&st), ownerTiesAt(&st)))
    if (root(r) != root(g)) {
      spdlog::info("robot group of {} joins robot {}'s: enough landmarks both sight are tied",
                   root(r), root(g));
      joinRobots(g, r, SE2(), SE3(), st);
    }
}

std::set<Key> Engine::landmarksLeftToSightings(
    const loopd::factor_batch_t& b, const Values& knownVals, const Values& guess,
    const std::map<std::uint32_t, std::uint32_t>& adoptions) const {
  std::set<Key> left;
  for (const auto& wf : b.factors) {
    if (!isCrossFrameSighting(wf, adoptions)) continue;
    const Key x = toKey(wf.keys[0]), l = toKey(wf.keys[1]);
    if (!knownVals.contains(l) && !guess.contains(l) &&
        (knownVals.contains(x) || guess.contains(x)))
      left.insert(l);
  }
  for (const auto& a : b.ambiguous)
    for (const auto& f : a.alternatives)
      for (const auto& k : f.keys) left.erase(toKey(k));
  return left;
}

void Engine::placeSightedLandmark(const Factor& f, Staged& st) {
  const Key x = f.key(0), l = f.key(1);
  if (known(l)) return;  // earlier sightings (or the staged rounds) placed it
  // Every value it needs is known or staged (this batch's guesses and new anchors included).
  auto at = [&](Key k) -> const Values& { return *holder(k); };
  const std::uint32_t r = keyRobot(x), s = frameOf(l);
  const Key ar = anchorKey(r), as = anchorKey(s);
  Values one;
  if (f.varType(1) == VarType::Point3) {
    const SE3 sFromR = se3Of(at(as), as).inverse() * se3Of(at(ar), ar);
    const Vec3 seen = se3Of(at(x), x).transform(static_cast<const PosePointFactor3&>(f).measured());
    one.insertPoint3(l, sFromR.transform(seen));
  } else {
    const SE2 sFromR = se2Of(at(as), as).inverse() * se2Of(at(ar), ar);
    one.insertPoint2(l, sFromR.transform(se2Of(at(x), x).transform(sightedPoint2(f))));
  }
  st.update.initial.insertFrom(one, 0);
  stagedValues_.insertFrom(one, 0);
  spdlog::debug("robot {} introduces {} (its owner has not sighted it yet)", r, keyToString(l));
}

bool Engine::dropKeptBack(FactorId id) {
  for (auto* kept : {&pending_, &pendingClosures_})
    for (auto it = kept->begin(); it != kept->end(); ++it) {
      auto& list = it->second;
      const auto at = std::find_if(list.begin(), list.end(),
                                   [&](const KeptBack& p) { return p.factor->id() == id; });
      if (at == list.end()) continue;
      list.erase(at);
      if (list.empty()) kept->erase(it);
      return true;
    }
  return false;
}

}  // namespace loopd::server
