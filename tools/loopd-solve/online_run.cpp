#include "tools/loopd-solve/online_run.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <stdexcept>

#include "solvers/problem/incremental_schedule.h"
#include "solvers/problem/initial_guess.h"

namespace loopd::tools {

OnlineRunStats runOnline(Backend& backend, const PoseGraphProblem& problem, bool quiet) {
  const std::vector<IncrementalStep> steps = incrementalSchedule(problem);
  std::vector<double> ms;
  ms.reserve(steps.size());
  const auto start = std::chrono::steady_clock::now();
  for (size_t i = 0; i < steps.size(); ++i) {
    BackendUpdate u;
    for (int f : steps[i].factors) u.factors.push_back(problem.graph[f]);
    // The first pose starts where the file (or composed odometry) put it.
    if (!backend.estimate().contains(steps[i].pose)) {
      if (i == 0 || u.factors.empty()) {
        const int s = problem.initial.slot(steps[i].pose);
        u.initial.insertFrom(problem.initial, s);
      }
    }
    if (!predictMissingValues(u.factors, backend.estimate(), u.initial))
      throw std::runtime_error("cannot initialise the variables of pose " +
                               keyToString(steps[i].pose) + " from earlier ones");
    const auto t0 = std::chrono::steady_clock::now();
    backend.update(u);
    ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0)
                     .count());
    if (!quiet && (i + 1) % 1000 == 0)
      std::fprintf(stderr, "  update %zu/%zu  last %.2f ms  elapsed %.1f s\n", i + 1,
                   steps.size(), ms.back(),
                   std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
  }
  backend.optimize();

  OnlineRunStats s;
  s.updates = static_cast<int>(ms.size());
  if (ms.empty()) return s;
  double sum = 0.0;
  for (double v : ms) sum += v;
  s.meanMs = sum / ms.size();
  s.maxMs = *std::max_element(ms.begin(), ms.end());
  std::vector<double> sorted = ms;
  const size_t k = std::min(sorted.size() - 1, static_cast<size_t>(std::ceil(0.99 * sorted.size())) - 1);
  std::nth_element(sorted.begin(), sorted.begin() + k, sorted.end());
  s.p99Ms = sorted[k];
  return s;
}

}  // namespace loopd::tools
