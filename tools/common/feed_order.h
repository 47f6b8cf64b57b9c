#pragma once
// The order in which a dataset's poses are played to a server (loopd-feed, the server
// benchmarks): by id, optionally only the first N; cut into consecutive segments, one robot
// each; one segment after the other or round-robin over the robots. An edge is due at the
// step its last pose appears.
#include <cstdint>
#include <unordered_map>
#include <vector>

#include "loopd/factor_t.hpp"
#include "solvers/io/dataset.h"

namespace loopd::tools {

class FeedOrder {
 public:
  /// Throws std::runtime_error when the file has no poses. `poses` < 0 feeds them all;
  /// `robots` is capped at the number of poses fed.
  FeedOrder(const io::Dataset& ds, long poses, int robots, bool interleave);

  const std::vector<std::int64_t>& poses() const { return order_; }  // ids, in feed order
  int robots() const { return robots_; }
  /// 0-based robot of a fed pose.
  int robotOf(std::int64_t pose) const { return robotOf_.at(pose); }
  /// Whether poses()[step] is its robot's first in feed order (it carries the initial value).
  bool startsItsRobot(size_t step) const { return startsRobot_.at(step); }
  /// The step (index into poses()) an edge is due at: its last end's, a sighting's pose's;
  /// -1 when an end is not fed.
  long dueAt(const io::Edge& e) const;
  /// The edge as the wire's factor_t in its robots' frames, robot ids + robotOffset.
  loopd::factor_t factor(const io::Edge& e, int robotOffset = 0) const;
  /// An EQUIV pair's edge (io::equivalenceEdge), trusted as loopd-solve trusts it: odometry
  /// within one robot, a loop closure with robust "none" (never down-weighted) across two.
  loopd::factor_t equivalenceFactor(const io::Edge& e, int robotOffset = 0) const;
  /// The landmarks (file ids, ascending) that fed poses of more than one robot sight. The
  /// server takes no cross-robot sightings yet, so each robot's sightings of such a landmark
  /// go to a landmark of its own, and the robots share no constraint through it.
  std::vector<std::int64_t> sharedLandmarks(const io::Dataset& ds) const;

 private:
  std::vector<std::int64_t> order_;
  int robots_ = 1;
  std::unordered_map<std::int64_t, int> robotOf_;
  std::unordered_map<std::int64_t, long> rank_;
  std::vector<std::int64_t> sortedIds_;  // the fed poses' ids, ascending
  std::vector<bool> startsRobot_;
};

}  // namespace loopd::tools
