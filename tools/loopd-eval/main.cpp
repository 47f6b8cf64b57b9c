// loopd-eval: score an estimate against a reference (ATE, RPE) and, with the truth of
// loopd-outliers and a loopd-solve stats file, the solver's rejections.
#include <cstdio>
#include <iostream>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "solvers/io/dataset_reader.h"
#include "tools/common/cli.h"
#include "tools/common/json_writer.h"
#include "tools/loopd-eval/json_input.h"
#include "tools/loopd-eval/trajectory_metrics.h"

using namespace loopd;

namespace {

const char* kUsage =
    "usage: loopd-eval --reference OPT.g2o --estimate EST.g2o [--truth TRUTH.json]\n"
    "                  [--stats STATS.json] [--graph OUT.g2o] [--json OUT.json] [--quiet]\n\n"
    "ATE: RMSE of positions after rigid Umeyama alignment of the estimate to the reference.\n"
    "(Both are read for their vertex lines only.)\n"
    "RPE: mean translation / rotation error of consecutive relative poses.\n"
    "--truth + --stats: precision and recall of the stats' \"rejected\" against the truth's\n"
    "\"outliers\" (and, for loopd-outliers --ambiguous truth, the stats' \"chosen\" against\n"
    "\"true_choice\"). --graph (with --truth): chi2 of the estimate over the true edges only.\n"
    "Both files must hold the same pose ids; a truth file must hold \"outliers\" (edge indices\n"
    "of --graph, when given), a stats file \"rejected\". --quiet: no summary on stdout (--json\n"
    "is still written).\n";

}  // namespace

int main(int argc, char** argv) {
  std::string reference, estimate, truth, stats, graph, json;
  bool quiet = false;
  try {
    for (int i = 1; i < argc; ++i) {
      const std::string a = argv[i];
      auto value = [&] { return tools::flagValue(argc, argv, i); };
      if (a == "--help" || a == "-h") {
        std::cout << kUsage;
        return 0;
      } else if (a == "--reference")
        reference = value();
      else if (a == "--estimate")
        estimate = value();
      else if (a == "--truth")
        truth = value();
      else if (a == "--stats")
        stats = value();
      else if (a == "--graph")
        graph = value();
      else if (a == "--json")
        json = value();
      else if (a == "--quiet" || a == "-q")
        quiet = true;
      else
        throw std::invalid_argument("unknown argument " + a);
    }
    if (reference.empty() || estimate.empty())
      throw std::invalid_argument("--reference and --estimate are required");
  } catch (const std::exception& e) {
    std::fprintf(stderr, "loopd-eval: %s\n\n%s", e.what(), kUsage);
    return 2;
  }
  if (!stats.empty() && truth.empty()) {
    std::fprintf(stderr, "loopd-eval: --stats needs --truth\n\n%s", kUsage);
    return 2;
  }
  try {
    const io::Dataset ref = tools::readVertices(reference);
    const io::Dataset est = tools::readVertices(estimate);
    const tools::TrajectoryErrors t = tools::trajectoryErrors(ref, est);
    // Read (and check) every input before printing anything.
    const char* kTruth = "a loopd-outliers truth file";
    const char* kStats = "a loopd-solve stats file";
    std::vector<std::int64_t> outliers, rejected, expected, chosen;
    bool ambiguous = false;
    if (!truth.empty()) {
      outliers = tools::readIntArray(truth, "outliers", 0, kTruth);
      ambiguous = tools::jsonHasKey(tools::readTextFile(truth), "true_choice");
    }
    std::optional<io::Dataset> g;
    if (!graph.empty()) {
      g = io::readDataset(graph);
      const auto edges = static_cast<std::int64_t>(g->edges.size());
      for (std::int64_t i : outliers)
        if (i >= edges)
          throw std::runtime_error(truth + ": outlier edge " + std::to_string(i) + " but " + graph +
                                   " has " + std::to_string(edges) +
                                   " edges (a truth file of another graph?)");
    }
    if (!stats.empty()) {
      rejected = tools::readIntArray(stats, "rejected", 0, kStats);
      if (ambiguous) {
        expected = tools::readIntArray(truth, "true_choice", 0, kTruth);
        chosen = tools::readIntArray(stats, "chosen", -1, kStats);  // -1: none
        if (chosen.size() != expected.size())
          throw std::runtime_error(stats + ": \"chosen\" has " + std::to_string(chosen.size()) +
                                   " entries, " + truth + "'s \"true_choice\" " +
                                   std::to_string(expected.size()));
      }
    }

    tools::JsonObject out;
    out.add("reference", reference)
        .add("estimate", estimate)
        .add("poses", t.poses)
        .add("ate_rmse", t.ateRmse)
        .add("ate_max", t.ateMax)
        .add("rpe_trans", t.rpeTrans)
        .add("rpe_rot_deg", t.rpeRotDeg);
    if (!quiet)
      std::printf("poses %d  ATE rmse %.6g m (max %.6g)  RPE %.6g m / %.6g deg\n", t.poses,
                  t.ateRmse, t.ateMax, t.rpeTrans, t.rpeRotDeg);
    if (!stats.empty()) {
      const tools::DecisionScores s = tools::scoreRejections(rejected, outliers);
      if (!quiet)
        std::printf("outliers %zu  rejected %zu  TP %d FP %d FN %d  precision %.4f  recall %.4f\n",
                    outliers.size(), rejected.size(), s.truePositives, s.falsePositives,
                    s.falseNegatives, s.precision, s.recall);
      out.add("outliers", static_cast<std::int64_t>(outliers.size()))
          .add("rejected", static_cast<std::int64_t>(rejected.size()))
          .add("true_positives", s.truePositives)
          .add("false_positives", s.falsePositives)
          .add("false_negatives", s.falseNegatives)
          .add("precision", s.precision)
          .add("recall", s.recall);
      // Ambiguous measurements (loopd-outliers --ambiguous): the choice against the truth.
      if (ambiguous) {
        int correct = 0, none = 0;
        for (size_t i = 0; i < chosen.size(); ++i) {
          correct += chosen[i] == expected[i];
          none += chosen[i] < 0;
        }
        const double accuracy = expected.empty() ? 1.0 : double(correct) / expected.size();
        if (!quiet)
          std::printf("ambiguous %zu  true alternative chosen %d (%.4f)  none chosen %d\n",
                      expected.size(), correct, accuracy, none);
        out.add("ambiguous", static_cast<std::int64_t>(expected.size()))
            .add("chosen_correct", correct)
            .add("chosen_accuracy", accuracy)
            .add("chosen_none", none);
      }
    }
    if (g) {
      const double c = tools::inlierChi2(*g, est, outliers);
      if (!quiet) std::printf("chi2 over true edges %.9g\n", c);
      out.add("inlier_chi2", c);
    }
    if (!json.empty()) out.writeFile(json);
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "loopd-eval: %s\n", e.what());
    return 1;
  }
}
