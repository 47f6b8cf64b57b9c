#pragma once
// The order in which a dataset's poses are played to a server (loopd-feed, the server
// benchmarks): by id, optionally only the first N; cut into consecutive segments, one robot
// each; one segment after the other or round-robin over the robots. An edge is due at the
// step its last pose appears. Each landmark belongs to one robot, by default the one whose
// sighting of it is published first (or one robot for all: a shared landmark map); every
// robot's sightings of it go to that robot's landmark.
#include <cstdint>
#include <unordered_map>
#include <vector>

#include "loopd/factor_t.hpp"
#include "solvers/io/dataset.h"

namespace loopd::tools {

class FeedOrder {
 public:
  /// Throws std::runtime_error when the file has no poses. `poses` < 0 feeds them all;
  /// `robots` is capped at the number of poses fed. `landmarkOwner` ≥ 0 gives every landmark
  /// to that robot (std::invalid_argument unless it is below robots()), or with
  /// `ownerIsNamespace` to that landmark namespace, a robot id without poses
  /// (std::invalid_argument unless it is at least robots()); < 0, each to its first sighter.
  FeedOrder(const io::Dataset& ds, long poses, int robots, bool interleave, int landmarkOwner = -1,
            bool ownerIsNamespace = false);

  const std::vector<std::int64_t>& poses() const { return order_; }  // ids, in feed order
  int robots() const { return robots_; }
  /// 0-based robot of a fed pose.
  int robotOf(std::int64_t pose) const { return robotOf_.at(pose); }
  /// Whether poses()[step] is its robot's first in feed order (it carries the initial value).
  bool startsItsRobot(size_t step) const { return startsRobot_.at(step); }
  /// The step (index into poses()) an edge is due at: its last end's, a sighting's pose's;
  /// -1 when an end is not fed.
  long dueAt(const io::Edge& e) const;
  /// The step a HYPOTHESES group of `ds` is due at (loopd-feed sends it whole): its last
  /// alternative's; -1 when an alternative is not fed.
  long dueAt(const io::Dataset& ds, const io::HypothesisGroup& g) const;
  /// The edge as the wire's factor_t in its robots' frames, robot ids + robotOffset. The
  /// odometry edge across a segment boundary is a loop closure with robust "none". A
  /// sighting names its pose's robot and its landmark's owner (landmarkOwner), which may be
  /// another robot: a cross-robot sighting.
  loopd::factor_t factor(const io::Edge& e, int robotOffset = 0) const;
  /// An EQUIV pair's edge (io::equivalenceEdge), trusted as loopd-solve trusts it: odometry
  /// within one robot, a loop closure with robust "none" (never down-weighted) across two.
  loopd::factor_t equivalenceFactor(const io::Edge& e, int robotOffset = 0) const;
  /// 0-based robot owning a landmark (file id): the constructor's `landmarkOwner`, or else the
  /// robot of the fed pose whose sighting of it is published first, i.e. the first in feed order (a
  /// sighting in a HYPOTHESES group counts at its group's step, one in a group never sent after all
  /// others); its landmark key is the one every robot's sightings name. Throws std::out_of_range
  /// when no fed pose sights it.
  int landmarkOwner(std::int64_t landmarkId) const { return landmarkOwner_.at(landmarkId); }
  /// The landmarks (file ids, ascending) that fed poses of more than one robot sight. The other
  /// robots' sightings of one go to its owner's landmark (cross-robot sightings), which ties
  /// the robots' frames together.
  std::vector<std::int64_t> sharedLandmarks(const io::Dataset& ds) const;
  /// The landmarks (file ids, ascending) that fed poses sight but none of their owner's: with
  /// a fixed owner, the server places them from other robots' sightings (empty otherwise).
  std::vector<std::int64_t> landmarksOnlyOthersSight(const io::Dataset& ds) const;

 private:
  std::vector<std::int64_t> order_;
  int robots_ = 1;
  std::unordered_map<std::int64_t, int> robotOf_;
  std::unordered_map<std::int64_t, long> rank_;
  std::vector<std::int64_t> sortedIds_;  // the fed poses' ids, ascending
  std::vector<bool> startsRobot_;
  std::unordered_map<std::int64_t, int> landmarkOwner_;
};

}  // namespace loopd::tools
