#pragma once
// Which robots share a frame, from the anchored factors between them (engine.h): an
// inter-robot between factor joins its two robots' frames on its own; landmark sightings
// join a pair once they reach enough distinct landmarks to fix the transform between the
// frames (two points in 2D, three in 3D), since one point leaves the rotation free.
#include <cstdint>
#include <map>
#include <utility>
#include <vector>

#include "server/wire_factors.h"

namespace loopd::server {

/// Robot → the lowest robot of its group, for every robot an edge or `extraJoins` names.
std::map<std::uint32_t, std::uint32_t> frameGroupsOf(
    const std::map<FactorId, InterEdge>& edges,
    const std::vector<std::pair<std::uint32_t, std::uint32_t>>& extraJoins = {});

}  // namespace loopd::server
