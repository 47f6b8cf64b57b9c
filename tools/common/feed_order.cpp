#include "tools/common/feed_order.h"

#include <algorithm>
#include <stdexcept>
#include <string>
#include <utility>

#include "solvers/problem/pose_graph_problem.h"
#include "tools/common/edge_factor.h"

namespace loopd::tools {

FeedOrder::FeedOrder(const io::Dataset& ds, long poses, int robotsWanted, bool interleave,
                     int fixedOwner, bool ownerIsNamespace) {
  std::vector<std::int64_t> ids;
  for (const auto& v : ds.poses) ids.push_back(v.id);
  std::sort(ids.begin(), ids.end());
  if (poses >= 0 && static_cast<size_t>(poses) < ids.size()) ids.resize(static_cast<size_t>(poses));
  if (ids.empty()) throw std::runtime_error("no poses in " + ds.path);
  sortedIds_ = ids;
  const size_t n = ids.size();
  const size_t robots = std::min<size_t>(static_cast<size_t>(std::max(1, robotsWanted)), n);
  robots_ = static_cast<int>(robots);
  std::vector<std::vector<std::int64_t>> segment(robots);
  for (size_t i = 0; i < n; ++i) {
    const int r = static_cast<int>(i * robots / n);
    robotOf_[ids[i]] = r;
    segment[static_cast<size_t>(r)].push_back(ids[i]);
  }
  if (!interleave)
    order_ = ids;
  else
    for (size_t k = 0; order_.size() < n; ++k)
      for (size_t r = 0; r < robots; ++r)
        if (k < segment[r].size()) order_.push_back(segment[r][k]);
  if (!ownerIsNamespace && fixedOwner >= robots_)
    throw std::invalid_argument("landmark owner " + std::to_string(fixedOwner) +
                                " is not one of the " + std::to_string(robots_) + " robots");
  if (ownerIsNamespace && fixedOwner < robots_)
    throw std::invalid_argument("landmark namespace " + std::to_string(fixedOwner) +
                                " is one of the " + std::to_string(robots_) + " robots");
  std::vector<bool> started(robots, false);
  startsRobot_.resize(n);
  for (size_t i = 0; i < n; ++i) {
    rank_[order_[i]] = static_cast<long>(i);
    const auto r = static_cast<size_t>(robotOf_[order_[i]]);
    startsRobot_[i] = !started[r];
    started[r] = true;
  }
  // Each landmark's owner: the robot of the pose whose sighting of it is published first, in
  // loopd-feed's order: a sighting at its pose's step, one in a HYPOTHESES group at the
  // group's (after every sent sighting if the group is not fed); at one step, the earlier
  // pose's. Ownership going by that order, the owner's first sighting, which introduces the
  // landmark to the server, is published no later than any other robot's sighting of it: the
  // server never has to place it from another robot's sighting (with a fixed owner it may:
  // it keeps those sightings back until the frames are joined). Without groups spanning
  // poses, this is the robot of the first fed pose (in feed order) sighting the landmark, and
  // a sighting due at the same step as the first is that pose's: the owner's own.
  std::vector<long> groupStep(ds.edges.size(), -2);  // -2: in no group
  for (const io::HypothesisGroup& g : ds.hypotheses) {
    const long at = dueAt(ds, g);
    for (int k = 0; k < g.count; ++k) groupStep.at(static_cast<size_t>(g.firstEdge + k)) = at;
  }
  std::unordered_map<std::int64_t, std::pair<long, long>> first;  // landmark → (step, rank)
  for (size_t i = 0; i < ds.edges.size(); ++i) {
    const io::Edge& e = ds.edges[i];
    if (io::isBetween(e.type)) continue;
    const auto pose = rank_.find(e.from);
    if (pose == rank_.end()) continue;  // not fed: counts for nothing
    const long rank = pose->second;
    const long step = groupStep[i] == -2  ? rank
                      : groupStep[i] >= 0 ? groupStep[i]
                                          : static_cast<long>(n) + rank;
    const auto [it, fresh] = first.emplace(e.to, std::make_pair(step, rank));
    if (fresh || std::make_pair(step, rank) < it->second) {
      it->second = {step, rank};
      landmarkOwner_[e.to] = fixedOwner >= 0 ? fixedOwner : robotOf_.at(e.from);
    }
  }
}

long FeedOrder::dueAt(const io::Edge& e) const {
  const auto a = rank_.find(e.from);
  const auto b = io::isBetween(e.type) ? rank_.find(e.to) : a;
  if (a == rank_.end() || b == rank_.end()) return -1;
  return std::max(a->second, b->second);
}

long FeedOrder::dueAt(const io::Dataset& ds, const io::HypothesisGroup& g) const {
  long at = 0;
  for (int k = 0; k < g.count; ++k) {
    const long d = dueAt(ds.edges.at(static_cast<size_t>(g.firstEdge + k)));
    if (d < 0) return -1;
    at = std::max(at, d);
  }
  return at;
}

loopd::factor_t FeedOrder::factor(const io::Edge& e, int robotOffset) const {
  const int from = robotOf(e.from);
  const int to = io::isBetween(e.type) ? robotOf(e.to) : from;
  // Odometry: one robot's poses next to each other in id order (as loopd-solve reads files).
  const bool odometry =
      io::isBetween(e.type) && from == to && neighboursInIdOrder(sortedIds_, e.from, e.to);
  loopd::factor_t f = edgeFactor(e, from + robotOffset, to + robotOffset, odometry);
  // A segment boundary's odometry (neighbouring ids, two robots) is a loop closure on the
  // wire, trusted as loopd-solve trusts odometry: a robust solver must not drop it.
  if (io::isBetween(e.type) && from != to && neighboursInIdOrder(sortedIds_, e.from, e.to))
    f.robust = "none";
  // A sighting names its landmark's owner: the pose's robot, or another (cross-robot).
  if (!io::isBetween(e.type)) f.keys.at(1).robot = landmarkOwner(e.to) + robotOffset;
  return f;
}

loopd::factor_t FeedOrder::equivalenceFactor(const io::Edge& e, int robotOffset) const {
  const int from = robotOf(e.from), to = robotOf(e.to);
  loopd::factor_t f = edgeFactor(e, from + robotOffset, to + robotOffset, from == to);
  if (from != to) f.robust = "none";  // the wire's odometry joins one robot's poses
  return f;
}

std::vector<std::int64_t> FeedOrder::sharedLandmarks(const io::Dataset& ds) const {
  std::unordered_map<std::int64_t, int> firstRobot;  // landmark → robot of a sighting
  std::vector<std::int64_t> shared;
  for (const auto& e : ds.edges) {
    if (io::isBetween(e.type)) continue;
    const auto r = robotOf_.find(e.from);
    if (r == robotOf_.end()) continue;  // not fed
    const auto [it, fresh] = firstRobot.emplace(e.to, r->second);
    if (!fresh && it->second != r->second && it->second >= 0) {
      shared.push_back(e.to);
      it->second = -1;  // counted
    }
  }
  std::sort(shared.begin(), shared.end());
  return shared;
}

std::vector<std::int64_t> FeedOrder::landmarksOnlyOthersSight(const io::Dataset& ds) const {
  std::unordered_map<std::int64_t, bool> byOwner;  // landmark → its owner sights it
  for (const auto& e : ds.edges) {
    if (io::isBetween(e.type)) continue;
    const auto r = robotOf_.find(e.from);
    if (r == robotOf_.end()) continue;  // not fed
    byOwner[e.to] = byOwner[e.to] || r->second == landmarkOwner_.at(e.to);
  }
  std::vector<std::int64_t> only;
  for (const auto& [landmark, owned] : byOwner)
    if (!owned) only.push_back(landmark);
  std::sort(only.begin(), only.end());
  return only;
}

}  // namespace loopd::tools
