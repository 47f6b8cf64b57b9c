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
  if (steps.empty()) return steps;
  // The step of a factor's latest pose (last step for pure-landmark factors).
  auto dueStep = [&](const Factor& factor, size_t& due, bool& hasPose) {
    for (int k = 0; k < factor.size(); ++k) {
      auto it = rank.find(factor.key(k));
      if (it != rank.end()) {
        due = std::max(due, it->second);
        hasPose = true;
      }
    }
  };
  std::vector<char> inGroup(problem.graph.size(), 0);
  for (size_t g = 0; g < problem.ambiguous.size(); ++g) {
    size_t due = 0;
    bool hasPose = false;
    for (int f : problem.ambiguous[g].factors) {
      inGroup[f] = 1;
      dueStep(*problem.graph[f], due, hasPose);
    }
    steps[hasPose ? due : steps.size() - 1].groups.push_back(static_cast<int>(g));
  }
  for (int f = 0; f < problem.graph.size(); ++f) {
    if (inGroup[f]) continue;
    size_t due = 0;
    bool hasPose = false;
    dueStep(*problem.graph[f], due, hasPose);
    steps[hasPose ? due : steps.size() - 1].factors.push_back(f);
  }
  return steps;
}

}  // namespace loopd
