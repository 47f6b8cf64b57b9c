#pragma once
// --incremental: feed a problem to a Backend pose by pose, as a robot would, timing updates.
#include "solvers/backend/backend.h"
#include "solvers/problem/pose_graph_problem.h"

namespace loopd::tools {

struct UpdateTimes {
  int count = 0;
  double meanMs = 0.0, p99Ms = 0.0, maxMs = 0.0;
};

struct OnlineRunStats {
  UpdateTimes all;
  UpdateTimes exploration;  // updates that carry no loop closure
  UpdateTimes closures;     // updates that carry at least one
};

/// One update per pose (incrementalSchedule); new variables are initialised by composing
/// from the current estimate (odometry); the run ends with backend.optimize().
OnlineRunStats runOnline(Backend& backend, const PoseGraphProblem& problem, bool quiet);

}  // namespace loopd::tools
