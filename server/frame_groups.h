#pragma once
// Which robots share a frame, from the anchored factors between them (engine.h): an
// inter-robot between factor joins its two robots' frames on its own. A landmark is a point
// that relates the frames of the robots sighting it, but only where it is fixed: in its
// owner's frame when the owner's own factors tie it there (a sighting from one of its poses, a
// prior), in another robot's when that robot sights it. Two groups are joined once enough
// distinct landmarks are sighted from both to fix the transform between them (two points in
// 2D, three in 3D, since one point leaves the rotation free); that may join further groups,
// so it is applied until nothing changes.
#include <cstdint>
#include <functional>
#include <map>
#include <utility>
#include <vector>

#include "server/wire_factors.h"

namespace loopd::server {

/// Whether a landmark's owner (the robot whose frame it lives in: InterEdge::s) ties it to its
/// own frame with factors of its own.
using OwnerTies = std::function<bool(Key landmark)>;

/// Robot → the lowest robot of its group, for every robot an edge or `extraJoins` names.
std::map<std::uint32_t, std::uint32_t> frameGroupsOf(
    const std::map<FactorId, InterEdge>& edges, const OwnerTies& tiedToOwner,
    const std::vector<std::pair<std::uint32_t, std::uint32_t>>& extraJoins = {});

}  // namespace loopd::server
