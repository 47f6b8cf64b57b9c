#include "server/frame_groups.h"

#include <algorithm>
#include <set>

namespace loopd::server {

std::map<std::uint32_t, std::uint32_t> frameGroupsOf(
    const std::map<FactorId, InterEdge>& edges,
    const std::vector<std::pair<std::uint32_t, std::uint32_t>>& extraJoins) {
  std::map<std::uint32_t, std::uint32_t> parent;
  auto find = [&](std::uint32_t r) {
    if (!parent.count(r)) parent[r] = r;
    while (parent[r] != r) r = parent[r] = parent[parent[r]];
    return r;
  };
  auto join = [&](std::uint32_t r, std::uint32_t s) {
    const std::uint32_t a = find(r), c = find(s);
    if (a != c) parent[std::max(a, c)] = std::min(a, c);
  };
  // Sightings per unordered pair: the distinct landmarks, and how many fix the frames.
  std::map<std::pair<std::uint32_t, std::uint32_t>, std::pair<std::set<Key>, int>> sighted;
  for (const auto& [id, e] : edges) {
    if (e.landmark == 0) {
      join(e.r, e.s);
      continue;
    }
    find(e.r);
    find(e.s);
    auto& [landmarks, needed] = sighted[std::minmax(e.r, e.s)];
    landmarks.insert(e.landmark);
    needed = std::max(needed, e.needed);
  }
  for (const auto& [pair, what] : sighted)
    if (static_cast<int>(what.first.size()) >= what.second) join(pair.first, pair.second);
  for (const auto& [r, s] : extraJoins) join(r, s);
  std::map<std::uint32_t, std::uint32_t> out;
  for (const auto& [r, p] : parent) out[r] = find(r);
  return out;
}

}  // namespace loopd::server
