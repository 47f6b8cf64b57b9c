#include "server/frame_groups.h"

#include <algorithm>
#include <set>

namespace loopd::server {

std::map<std::uint32_t, std::uint32_t> frameGroupsOf(
    const std::map<FactorId, InterEdge>& edges, const OwnerTies& tiedToOwner,
    const std::vector<std::pair<std::uint32_t, std::uint32_t>>& extraJoins) {
  std::map<std::uint32_t, std::uint32_t> parent;
  auto find = [&](std::uint32_t r) {
    if (!parent.count(r)) parent[r] = r;
    while (parent[r] != r) r = parent[r] = parent[parent[r]];
    return r;
  };
  auto join = [&](std::uint32_t r, std::uint32_t s) {
    const std::uint32_t a = find(r), c = find(s);
    if (a == c) return false;
    parent[std::max(a, c)] = std::min(a, c);
    return true;
  };
  // Per landmark: the robots it is fixed in (its sighters, and its owner if tied) and how many
  // distinct landmarks fix a pair of frames.
  struct Landmark {
    std::set<std::uint32_t> robots;
    std::uint32_t owner = 0;  // the robot whose frame it lives in
    int needed = 0;
  };
  std::map<Key, Landmark> landmarks;
  for (const auto& [id, e] : edges) {
    find(e.r);
    find(e.s);
    if (e.landmark == 0) {
      join(e.r, e.s);
      continue;
    }
    Landmark& l = landmarks[e.landmark];
    l.robots.insert(e.r);
    l.owner = e.s;
    l.needed = std::max(l.needed, e.needed);
  }
  for (const auto& [r, s] : extraJoins) join(r, s);
  for (auto& [key, l] : landmarks)
    if (tiedToOwner(key)) l.robots.insert(l.owner);
  for (bool joined = true; joined;) {
    joined = false;
    // Per unordered pair of groups: the landmarks fixed in both, and how many are needed.
    std::map<std::pair<std::uint32_t, std::uint32_t>, std::pair<int, int>> shared;
    for (const auto& [key, l] : landmarks) {
      std::set<std::uint32_t> groups;
      for (std::uint32_t r : l.robots) groups.insert(find(r));
      for (auto g = groups.begin(); g != groups.end(); ++g)
        for (auto h = std::next(g); h != groups.end(); ++h) {
          auto& [count, needed] = shared[{*g, *h}];
          ++count;
          needed = std::max(needed, l.needed);
        }
    }
    for (const auto& [pair, what] : shared)
      if (what.first >= what.second) joined |= join(pair.first, pair.second);
  }
  std::map<std::uint32_t, std::uint32_t> out;
  for (const auto& [r, p] : parent) out[r] = find(r);
  return out;
}

}  // namespace loopd::server
