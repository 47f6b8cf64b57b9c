#include "tools/common/feed_order.h"

#include <algorithm>
#include <stdexcept>

#include "solvers/problem/pose_graph_problem.h"
#include "tools/common/edge_factor.h"

namespace loopd::tools {

FeedOrder::FeedOrder(const io::Dataset& ds, long poses, int robotsWanted, bool interleave) {
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
  std::vector<bool> started(robots, false);
  startsRobot_.resize(n);
  for (size_t i = 0; i < n; ++i) {
    rank_[order_[i]] = static_cast<long>(i);
    const auto r = static_cast<size_t>(robotOf_[order_[i]]);
    startsRobot_[i] = !started[r];
    started[r] = true;
  }
}

long FeedOrder::dueAt(const io::Edge& e) const {
  const auto a = rank_.find(e.from);
  const auto b = io::isBetween(e.type) ? rank_.find(e.to) : a;
  if (a == rank_.end() || b == rank_.end()) return -1;
  return std::max(a->second, b->second);
}

loopd::factor_t FeedOrder::factor(const io::Edge& e, int robotOffset) const {
  const int from = robotOf(e.from);
  const int to = io::isBetween(e.type) ? robotOf(e.to) : from;
  // Odometry: one robot's poses next to each other in id order (as loopd-solve reads files).
  const bool odometry =
      io::isBetween(e.type) && from == to && neighboursInIdOrder(sortedIds_, e.from, e.to);
  return edgeFactor(e, from + robotOffset, to + robotOffset, odometry);
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

}  // namespace loopd::tools
