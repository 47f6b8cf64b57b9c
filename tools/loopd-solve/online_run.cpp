#include "tools/loopd-solve/online_run.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <stdexcept>

#include "solvers/problem/incremental_schedule.h"
#include "solvers/problem/initial_guess.h"

namespace loopd::tools {

namespace {

UpdateTimes summarize(std::vector<double> ms) {
  UpdateTimes t;
  t.count = static_cast<int>(ms.size());
  if (ms.empty()) return t;
  double sum = 0.0;
  for (double v : ms) sum += v;
  t.meanMs = sum / ms.size();
  t.maxMs = *std::max_element(ms.begin(), ms.end());
  const size_t k = std::min(ms.size() - 1, static_cast<size_t>(std::ceil(0.99 * ms.size())) - 1);
  std::nth_element(ms.begin(), ms.begin() + k, ms.end());
  t.p99Ms = ms[k];
  return t;
}

bool carriesLoopClosure(const BackendUpdate& u) {
  if (!u.ambiguous.empty()) return true;
  for (const auto& f : u.factors)
    if (f->role() == FactorRole::LoopClosure) return true;
  return false;
}

}  // namespace

OnlineRunStats runOnline(Backend& backend, const PoseGraphProblem& problem, bool quiet) {
  const std::vector<IncrementalStep> steps = incrementalSchedule(problem);
  std::vector<double> ms, explorationMs, closureMs;
  ms.reserve(steps.size());
  const auto start = std::chrono::steady_clock::now();
  for (size_t i = 0; i < steps.size(); ++i) {
    BackendUpdate u;
    for (int f : steps[i].factors) u.factors.push_back(problem.graph[f]);
    for (int g : steps[i].groups) u.ambiguous.push_back(ambiguousFactor(problem, g));
    // The first pose starts where the file (or composed odometry) put it.
    if (!backend.estimate().contains(steps[i].pose)) {
      if (i == 0 || u.factors.empty()) {
        const int s = problem.initial.slot(steps[i].pose);
        u.initial.insertFrom(problem.initial, s);
      }
    }
    if (!backend.handlesAmbiguous()) flattenAmbiguous(u);
    if (!predictMissingValues(u.factors, backend.estimate(), u.initial))
      throw std::runtime_error("cannot initialise the variables of pose " +
                               keyToString(steps[i].pose) + " from earlier ones");
    const auto t0 = std::chrono::steady_clock::now();
    backend.update(u);
    ms.push_back(
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
    (carriesLoopClosure(u) ? closureMs : explorationMs).push_back(ms.back());
    if (!quiet && (i + 1) % 1000 == 0)
      std::fprintf(stderr, "  update %zu/%zu  last %.2f ms  elapsed %.1f s\n", i + 1, steps.size(),
                   ms.back(),
                   std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
  }
  backend.optimize();

  OnlineRunStats s;
  s.all = summarize(ms);
  s.exploration = summarize(std::move(explorationMs));
  s.closures = summarize(std::move(closureMs));
  return s;
}

}  // namespace loopd::tools
