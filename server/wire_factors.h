#pragma once
// The engine's wire → solver factors: a validated factor_t as a solver factor, an inter-robot
// one through the robots' anchors (engine.h), and the anchor keys and poses they use.
#include <cstdint>
#include <memory>
#include <vector>

#include "loopd/factor_t.hpp"
#include "solvers/core/values.h"
#include "solvers/factors/factor.h"

namespace loopd::server {

/// The pose at key k of v (k must be there).
SE2 se2Of(const Values& v, Key k);
SE3 se3Of(const Values& v, Key k);
/// An SE3 from the wire's seven numbers (translation, then quaternion).
SE3 se3From(const std::vector<double>& m);
/// A validated wire factor as a solver factor on its own keys (intra-robot form).
std::shared_ptr<Factor> buildFactor(const loopd::factor_t& f);
/// A between factor whose two keys belong to different robots.
bool isInterRobot(const loopd::factor_t& f);
/// A landmark sighting (pose, landmark).
bool isSighting(const loopd::factor_t& f);
/// A landmark sighting whose pose belongs to another robot than the landmark.
bool isCrossRobotSighting(const loopd::factor_t& f);
/// An inter-robot between factor or a cross-robot sighting (`built`: its single-frame form)
/// evaluated through the robots' anchors: keys A_r, x_r, A_s, then x_s or l_s, where s is
/// `otherFrame`, the robot whose frame the other key lives in (its own robot, or for a landmark
/// namespace the robot that adopted it). The anchors must exist (Engine::joinRobots). Keeps
/// `built`'s id and robust request.
std::shared_ptr<Factor> anchoredFactor(const Factor& built, std::uint32_t otherFrame);
/// The same, with the other key in its own robot's frame.
std::shared_ptr<Factor> anchoredFactor(const Factor& built);
/// An anchored (inter-robot) factor: the robots it joins are recorded as inter-robot edges.
bool isAnchored(const Factor& f);
/// The landmark a factor of its owner's own frame ties there (a sighting from one of the
/// owner's poses, a prior on it), or 0: anchored factors and factors on poses only tie none.
Key ownerTiedLandmark(const Factor& f);

/// An anchored factor as an edge between its two robots' frames (frame_groups.h).
struct InterEdge {
  std::uint32_t r = 0, s = 0;  // the pose's robot, the robot whose frame the other key is in
  Key landmark = 0;            // a sighting's landmark; 0 for a between factor
  int needed = 0;  // distinct landmarks of a pair that fix its frames (2 in 2D, 3 in 3D)
};
InterEdge interEdgeOf(const Factor& anchored);
/// The edge a factor from `pose` to `other` (a pose or a landmark in `otherFrame`'s frame) makes.
InterEdge interEdgeOf(Key pose, Key other, VarType otherType, std::uint32_t otherFrame);

}  // namespace loopd::server
