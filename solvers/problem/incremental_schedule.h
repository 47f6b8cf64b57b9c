#pragma once
// How a robot would have delivered a dataset: poses in index order, one step per new pose
// carrying every factor whose ends have all appeared (a landmark appears with its first
// sighting from an appeared pose).
#include <vector>

#include "solvers/problem/pose_graph_problem.h"

namespace loopd {

struct IncrementalStep {
  Key pose;                  // the pose this step introduces
  std::vector<int> factors;  // indices into the problem's graph (no ambiguous alternatives)
  std::vector<int> groups;   // indices into problem.ambiguous: due once every key of every
                             // alternative has appeared
};

std::vector<IncrementalStep> incrementalSchedule(const PoseGraphProblem& problem);

}  // namespace loopd
