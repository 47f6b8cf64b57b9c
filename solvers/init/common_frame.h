#pragma once
// Several robots' graphs in one frame, for the linear starts. A robot whose frame is joined to
// others keeps its poses and landmarks in its own frame, placed by its anchor A_r (a variable
// keyed anchorKey(r)); inter-robot closures are AnchoredBetweenFactors on
// (A_r, x_r, A_s, x_s). The linear initializations join two-key factors only, so they left a
// joined robot at its guess, bent or not. Here: each variable's common-frame value A_r·x, the
// anchored between factors as plain between factors of those values, and the way back.
#include <cstdint>
#include <map>

#include "solvers/core/values.h"
#include "solvers/graph/factor_graph.h"

namespace loopd {

/// Per robot, the slot of its lowest pose key in `values`.
std::map<std::uint32_t, int> lowestPoseOfEachRobot(const Values& values);

/// Whether the values hold a robot's anchor or the poses of more than one robot.
bool holdsSeveralFrames(const Values& values);

/// The values with each pose and landmark of a robot whose anchor they hold moved into the
/// common frame (A_r·x); anchors and other variables as they are.
Values inCommonFrame(const Values& values);

/// The graph with each anchored between factor replaced by the plain between factor of its two
/// poses (same measurement, information, role and id), for values inCommonFrame; every other
/// factor shared as it is.
FactorGraph withAnchoredBetweensPlain(const FactorGraph& graph);

/// Back from the common frame: each robot with an anchor in `ownFrames` (the values the common
/// ones came from, slot for slot) keeps its lowest pose where `ownFrames` has it, its anchor
/// takes what places that pose at its common-frame value, and its other variables follow into
/// that frame (a robot without poses keeps its anchor).
Values inOwnFrames(const Values& common, const Values& ownFrames);

}  // namespace loopd
