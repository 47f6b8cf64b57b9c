// loopd-solve: run any Backend variant offline on a dataset file, batch or as a robot would
// feed it (--incremental), and write the estimate, stats JSON and marginal covariances.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <iostream>

#include "robust/ambiguous_choice.h"
#include "robust/backend_registry.h"
#include "robust/mh_backend.h"
#include "solvers/core/allocator_tuning.h"
#include "solvers/init/initialization.h"
#include "solvers/io/dataset_reader.h"
#include "solvers/io/estimate_writer.h"
#include "solvers/problem/pose_graph_problem.h"
#include "solvers/problem/untied_variables.h"
#include "tools/common/json_writer.h"
#include "tools/common/process_stats.h"
#include "tools/loopd-solve/covariance_writer.h"
#include "tools/loopd-solve/online_run.h"
#include "tools/loopd-solve/solve_options.h"

using namespace loopd;
using Clock = std::chrono::steady_clock;

namespace {

double since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

// The file's name for a variable: "pose 12", "landmark 3".
std::string vertexName(Key k) {
  return (keyKind(k) == KeyKind::Landmark ? "landmark " : "pose ") + std::to_string(keyIndex(k));
}

// Not an error (the rest solves as it would alone), but such a part's placement is arbitrary.
// Returns how many variables it holds.
std::size_t warnIfUntied(const PoseGraphProblem& problem, const std::string& input) {
  const std::vector<Key> untied =
      untiedVariables(problem.graph, problem.initial, problem.firstPose);
  if (untied.empty()) return 0;
  std::string named = vertexName(untied[0]);
  if (untied.size() > 1) named += ", " + vertexName(untied[1]);
  if (untied.size() > 2) named += ", …";
  const bool one = untied.size() == 1;
  const std::string gauge = vertexName(problem.firstPose);
  std::fprintf(stderr,
               "loopd-solve: warning: %s: %zu of %d variables (%s) %s tied to %s by no chain of "
               "edges and %s no prior: %s placement relative to %s is arbitrary (the solve leaves "
               "%s near the file's), and %s marginals do not exist\n",
               input.c_str(), untied.size(), problem.initial.size(), named.c_str(),
               one ? "is" : "are", gauge.c_str(), one ? "has" : "have", one ? "its" : "their",
               gauge.c_str(), one ? "it" : "them", one ? "its" : "their");
  return untied.size();
}

bool isIncremental(const std::string& solver) {
  for (const BackendInfo& b : availableBackends())
    if (b.name == solver) return b.incremental;
  return false;
}

int run(const tools::SolveOptions& opt) {
  const auto tParse = Clock::now();
  io::Dataset dataset = io::readDataset(opt.input);
  PoseGraphProblem problem = buildProblem(dataset);
  const std::vector<AmbiguousFactor> measurements = ambiguousFactors(problem);  // HYPOTHESES groups
  const double parseSeconds = since(tParse);
  const double initialChi2 = problem.graph.chi2(problem.initial);
  const std::size_t untied = warnIfUntied(problem, opt.input);
  if (!opt.quiet)
    std::fprintf(stderr, "%s: %d poses, %d landmarks, %d factors, initial chi2 %.6f (%.3f s)\n",
                 opt.input.c_str(), problem.poses, problem.landmarks, problem.graph.size(),
                 initialChi2, parseSeconds);

  BackendOptions bo;
  bo.maxIterations = opt.maxIterations;
  bo.linearInitialization = opt.linearInit;
  bo.robustParameter = opt.robustParameter;
  bo.maxHypotheses = opt.maxHypotheses;
  if (!opt.quiet && !opt.incremental)
    bo.progress = [](const IterationReport& r) {
      std::fprintf(stderr, "  iter %3d  chi2 %.9g  %s %.3g  %s  %.2f ms\n", r.iteration, r.chi2,
                   "trust", r.trustParameter, r.accepted ? "accepted" : "rejected",
                   r.seconds * 1e3);
    };
  std::unique_ptr<Backend> backend = makeBackend(opt.solver, bo);

  tools::JsonObject stats;
  const auto tSolve = Clock::now();
  tools::OnlineRunStats online;
  if (opt.incremental) {
    online = tools::runOnline(*backend, problem, opt.quiet);
  } else {
    BackendUpdate all = wholeProblemUpdate(problem);
    // isam2 at once starts where the batch solvers start. The robust incremental variants keep
    // the file's values: a start from every factor would be bent by wrong closures, and one
    // from the trusted factors alone (tried) leaves their kernels to reject true closures.
    if (opt.solver == "isam2" && opt.linearInit)
      all.initial = initializeLinear(problem.graph, problem.initial, problem.firstPose);
    if (!backend->handlesAmbiguous()) flattenAmbiguous(all);
    backend->update(all);
    // An incremental variant's update() takes the steps one update takes online; the whole
    // file at once is solved to convergence, as a batch variant's update() does.
    if (isIncremental(opt.solver)) backend->optimize();
  }
  const double solveSeconds = since(tSolve);
  const SolveSummary summary = backend->summary();
  const double finalChi2 = backend->chi2();
  if (!opt.quiet)
    std::fprintf(stderr, "%s: final chi2 %.9g after %d iterations (%s), solve %.3f s\n",
                 backend->name().c_str(), finalChi2, summary.iterations, summary.stopReason.c_str(),
                 solveSeconds);

  // Not an error (the estimate is the best reached), but not to be missed either.
  if (!summary.converged && !summary.stopReason.empty())
    std::fprintf(stderr, "loopd-solve: warning: %s stopped before converging: %s\n",
                 backend->name().c_str(), summary.stopReason.c_str());

  // A diverged solve (NaN or infinite values) is an error, and its estimate is not written:
  // downstream readers would take it for poses.
  const bool diverged = !backend->estimate().allFinite() || !std::isfinite(finalChi2);
  if (diverged)
    std::fprintf(stderr, "loopd-solve: %s diverged: the estimate is not finite (%s); %s\n",
                 backend->name().c_str(), summary.stopReason.c_str(),
                 opt.out.empty() ? "exit status 3" : "no estimate written, exit status 3");
  if (!opt.out.empty() && !diverged) {
    storeEstimate(backend->estimate(), dataset);
    io::writeG2oVertices(opt.out, dataset);
  }
  if (!opt.covariances.empty() && !diverged) {
    const auto tCov = Clock::now();
    tools::writeCovariances(opt.covariances, *backend, dataset);
    if (!opt.quiet) std::fprintf(stderr, "covariances written in %.3f s\n", since(tCov));
  }
  if (!opt.stats.empty()) {
    std::vector<std::int64_t> rejected;
    for (FactorId id : backend->rejected()) rejected.push_back(static_cast<std::int64_t>(id));
    std::sort(rejected.begin(), rejected.end());
    stats.add("solver", backend->name())
        .add("input", opt.input)
        .add("poses", problem.poses)
        .add("landmarks", problem.landmarks)
        .add("factors", problem.graph.size())
        .add("initial_chi2", initialChi2)
        .add("final_chi2", finalChi2)
        .add("iterations", summary.iterations)
        .add("parse_s", parseSeconds)
        .add("solve_s", solveSeconds)
        .add("converged", summary.converged)
        .add("diverged", diverged)
        .add("stop_reason", summary.stopReason)
        .add("incremental", opt.incremental)
        .add("untied_variables", static_cast<std::int64_t>(untied));
    if (opt.incremental) {
      stats.add("updates", online.all.count)
          .add("update_ms_mean", online.all.meanMs)
          .add("update_ms_p99", online.all.p99Ms)
          .add("update_ms_max", online.all.maxMs)
          .add("exploration_updates", online.exploration.count)
          .add("exploration_update_ms_mean", online.exploration.meanMs)
          .add("exploration_update_ms_max", online.exploration.maxMs)
          .add("closure_updates", online.closures.count)
          .add("closure_update_ms_mean", online.closures.meanMs)
          .add("closure_update_ms_p99", online.closures.p99Ms)
          .add("closure_update_ms_max", online.closures.maxMs);
    }
    stats.add("rejected", rejected);
    if (!measurements.empty()) {
      std::vector<std::int64_t> chosen;
      for (int c : chosenAlternatives(*backend, measurements)) chosen.push_back(c);
      stats.add("chosen", chosen);
    }
    if (const auto* mh = dynamic_cast<const MhBackend*>(backend.get())) {
      std::vector<double> scores;
      for (const auto& h : mh->hypotheses(10)) scores.push_back(h.score);
      const MhBackend::Storage storage = mh->cliqueStorage(), peak = mh->peakCliqueStorage();
      stats.add("max_hypotheses", opt.maxHypotheses)
          .add("live_hypotheses", mh->liveHypotheses())
          .add("mean_live_hypotheses", mh->meanLiveHypotheses())
          .add("hypothesis_scores", scores)
          .add("branches_built", static_cast<std::int64_t>(mh->branchesBuilt()))
          .add("branches_predicted_away", static_cast<std::int64_t>(mh->branchesPredictedAway()))
          .add("clique_mb", storage.sharedBytes / 1e6)
          .add("clique_mb_unshared", storage.unsharedBytes / 1e6)
          .add("peak_clique_mb", peak.sharedBytes / 1e6)
          .add("peak_clique_mb_unshared", peak.unsharedBytes / 1e6);
    }
    stats.add("peak_rss_mb", tools::peakRssMb());
    stats.writeFile(opt.stats);
  }
  return diverged ? 3 : 0;
}

}  // namespace

int main(int argc, char** argv) {
  keepFreedMemoryForReuse();
  tools::SolveOptions opt;
  try {
    opt = tools::parseSolveOptions(argc, argv);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "loopd-solve: %s\n\n%s", e.what(), tools::solveUsage().c_str());
    return 2;
  }
  try {
    return run(opt);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "loopd-solve: %s\n", e.what());
    return 1;
  }
}
