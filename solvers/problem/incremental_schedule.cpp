#include "solvers/problem/incremental_schedule.h"

#include <algorithm>
#include <unordered_map>
#include <unordered_set>

namespace loopd {

std::vector<IncrementalStep> incrementalSchedule(const PoseGraphProblem& problem) {
  std::vector<Key> poses;
  for (Key k : problem.initial.keys())
    if (keyKind(k) == KeyKind::Pose) poses.push_back(k);
  std::sort(poses.begin(), poses.end());
  std::unordered_map<Key, size_t> rank;
  for (size_t i = 0; i < poses.size(); ++i) rank[poses[i]] = i;

  // A factor is due at the step of its latest pose; pure-landmark factors have none.
  std::vector<IncrementalStep> steps(poses.size());
  for (size_t i = 0; i < poses.size(); ++i) steps[i].pose = poses[i];
  for (int f = 0; f < problem.graph.size(); ++f) {
    const Factor& factor = *problem.graph[f];
    size_t due = 0;
    bool hasPose = false;
    for (int k = 0; k < factor.size(); ++k) {
      auto it = rank.find(factor.key(k));
      if (it != rank.end()) {
        due = std::max(due, it->second);
        hasPose = true;
      }
    }
    if (hasPose) steps[due].factors.push_back(f);
    else if (!steps.empty()) steps.back().factors.push_back(f);
  }
  return steps;
}

}  // namespace loopd
