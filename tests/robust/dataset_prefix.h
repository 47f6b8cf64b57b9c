#pragma once
// "intel.g2o:600": the first 600 poses of a benchmark dataset and the edges among them,
// renumbered (keeps robust tests fast); a plain name is the whole file.
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "solvers/io/dataset_reader.h"

namespace loopd::test {

/// The poses with id < n and the edges among them (edge indices renumbered).
inline io::Dataset cutPrefix(io::Dataset d, std::int64_t n) {
  std::vector<io::Vertex> poses;
  for (const auto& v : d.poses)
    if (v.id < n) poses.push_back(v);
  std::vector<io::Edge> edges;
  for (const auto& e : d.edges)
    if (e.from < n && e.to < n) {
      edges.push_back(e);
      edges.back().index = static_cast<int>(edges.size()) - 1;
    }
  d.poses = std::move(poses);
  d.edges = std::move(edges);
  return d;
}

inline io::Dataset loadPrefix(const std::string& spec) {
  const size_t colon = spec.find(':');
  io::Dataset d = io::readDataset(std::string(LOOPD_DATASETS_DIR) + "/" + spec.substr(0, colon));
  if (colon == std::string::npos) return d;
  return cutPrefix(std::move(d), std::stoll(spec.substr(colon + 1)));
}

}  // namespace loopd::test
