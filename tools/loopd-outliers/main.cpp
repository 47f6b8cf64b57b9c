// loopd-outliers: append synthetic wrong loop closures to a dataset (Vertigo's protocol) and
// write the whole graph plus a TRUTH.json naming the added edges.
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <stdexcept>
#include <string>

#include "solvers/io/dataset_reader.h"
#include "solvers/io/estimate_writer.h"
#include "tools/common/cli.h"
#include "tools/loopd-outliers/outlier_generator.h"

using namespace loopd;

namespace {

const char* kUsage =
    "usage: loopd-outliers INPUT --count N --mode random|local|group [--group-size K]\n"
    "                      [--window W] [--local-groups] [--seed S] --out OUT.g2o\n"
    "                      --truth TRUTH.json\n\n"
    "Appends N wrong loop closures (Vertigo's protocol): random pose pairs, local pairs\n"
    "(b - a in [2, W], default W = 50) or groups of K (default 10) consecutive pairs sharing\n"
    "one random measurement. Measurements: uniform rotation, translation uniform up to the\n"
    "median loop-closure length; information of the median loop closure. Deterministic per\n"
    "seed (default 1). Writes OUT.g2o (all edges; the outliers last) and TRUTH.json\n"
    "{input, mode, count, seed, group_size, outliers: [0-based edge indices], inlier_edges}.\n";

long parseInt(const std::string& flag, const std::string& v, long lo, long hi) {
  char* end = nullptr;
  const long n = std::strtol(v.c_str(), &end, 10);
  if (v.empty() || *end != '\0' || n < lo || n > hi)
    throw std::invalid_argument(flag + " takes an integer in [" + std::to_string(lo) + ", " +
                                std::to_string(hi) + "], got '" + v + "'");
  return n;
}

}  // namespace

int main(int argc, char** argv) {
  std::string input, out, truth;
  tools::OutlierOptions opt;
  bool haveCount = false, haveMode = false;
  try {
    for (int i = 1; i < argc; ++i) {
      const std::string a = argv[i];
      auto value = [&] { return tools::flagValue(argc, argv, i); };
      if (a == "--help" || a == "-h") {
        std::cout << kUsage;
        return 0;
      } else if (a == "--count") {
        opt.count = static_cast<int>(parseInt(a, value(), 0, 10000000));
        haveCount = true;
      } else if (a == "--mode") {
        opt.mode = tools::outlierModeFromName(value());
        haveMode = true;
      } else if (a == "--group-size") {
        opt.groupSize = static_cast<int>(parseInt(a, value(), 1, 100000));
      } else if (a == "--window") {
        opt.localWindow = static_cast<int>(parseInt(a, value(), 2, 100000000));
      } else if (a == "--local-groups") {
        opt.localGroups = true;
      } else if (a == "--seed") {
        opt.seed = static_cast<std::uint64_t>(parseInt(a, value(), 0, 0x7fffffffffffffffL));
      } else if (a == "--out") {
        out = value();
      } else if (a == "--truth") {
        truth = value();
      } else if (a == "--ambiguous") {
        throw std::invalid_argument("--ambiguous is not implemented yet");
      } else if (!a.empty() && a[0] == '-') {
        throw std::invalid_argument("unknown option " + a);
      } else if (input.empty()) {
        input = a;
      } else {
        throw std::invalid_argument("more than one input file");
      }
    }
    if (input.empty()) throw std::invalid_argument("no input file");
    if (!haveCount) throw std::invalid_argument("--count is required");
    if (!haveMode) throw std::invalid_argument("--mode is required");
    if (out.empty() || truth.empty()) throw std::invalid_argument("--out and --truth are required");
  } catch (const std::exception& e) {
    std::fprintf(stderr, "loopd-outliers: %s\n\n%s", e.what(), kUsage);
    return 2;
  }
  try {
    const io::Dataset dataset = io::readDataset(input);
    const tools::OutlierResult r = tools::addOutliers(dataset, opt);
    io::writeG2oGraph(out, r.graph);
    std::ofstream t(truth);
    if (!t) throw std::runtime_error("cannot write " + truth);
    t << tools::outlierTruthJson(input, opt, r);
    if (!t) throw std::runtime_error("error writing " + truth);
    std::fprintf(stderr, "%s: %d edges + %d %s outliers -> %s\n", input.c_str(), r.inlierEdges,
                 static_cast<int>(r.outliers.size()), tools::outlierModeName(opt.mode), out.c_str());
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "loopd-outliers: %s\n", e.what());
    return 1;
  }
}
