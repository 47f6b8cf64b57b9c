// loopd-outliers: append synthetic wrong loop closures to a dataset (Vertigo's protocol) and
// write the whole graph plus a TRUTH.json naming the added edges.
#include <cstdio>
#include <iostream>
#include <stdexcept>
#include <string>

#include "solvers/io/dataset_reader.h"
#include "solvers/io/estimate_writer.h"
#include "tools/common/cli.h"
#include "tools/common/json_writer.h"
#include "tools/loopd-outliers/ambiguous_generator.h"
#include "tools/loopd-outliers/outlier_generator.h"

using namespace loopd;

namespace {

const char* kUsage =
    "usage: loopd-outliers INPUT --count N --mode random|local|group [--group-size K]\n"
    "                      [--window W] [--local-groups] [--vertigo] [--seed S] --out OUT.g2o\n"
    "                      --truth TRUTH.json\n\n"
    "Appends N wrong loop closures (ends after Vertigo's protocol): random pose pairs,\n"
    "local pairs (b - a in [2, W], default W = 50) or groups of K (default 10) consecutive\n"
    "pairs sharing one random measurement, the first pair (a, b) random, or with\n"
    "--local-groups (group mode only) local (b - a in [2, W]). Measurements: uniform\n"
    "rotation, translation uniform up to the median loop-closure length; with --vertigo,\n"
    "Vertigo's own instead (translation axes ~ N(0, 0.3 m), angles ~ N(0, 10 deg): near the\n"
    "identity) and W = 20 unless --window is given. Information of the median loop closure.\n"
    "Deterministic per seed (default 1). --group-size and --window are accepted, unused, by\n"
    "the modes that do not take them (tools/compare passes them to every mode).\n"
    "Writes OUT.g2o (all edges; the outliers last) and TRUTH.json {input, mode, count, seed,\n"
    "group_size, measurement, outliers: [0-based edge indices], inlier_edges}.\n\n"
    "       loopd-outliers INPUT --ambiguous N [--alternatives K] [--null]\n"
    "                      [--decoys target|measurement|mixed|aliased] [--window W] [--landmarks]\n"
    "                      [--seed S] --out OUT.g2o --truth TRUTH.json\n\n"
    "Turns N true loop closures (--landmarks: landmark re-sightings) into ambiguous\n"
    "measurements: a 'HYPOTHESES K [null]' group (default K = 3) holding the true edge at a\n"
    "random position and K - 1 decoys: a wrong target within W poses (default 10; for a\n"
    "sighting, a nearby landmark already seen), or a wrong measurement (translation moved by\n"
    "0.5-2 x the median loop length, rotation by 10-45 degrees); 'aliased': a wrong\n"
    "measurement only 2-4 of the edge's own standard deviations away (whitened), which the\n"
    "data may take long to tell apart -- the stress case for --max-hypotheses. TRUTH.json: {input, "
    "mode:\n"
    "ambiguous, count, alternatives, null, decoys, seed, outliers: [decoy edge indices],\n"
    "true_choice: [per group], true_edges: [per group]}. --alternatives, --null, --decoys\n"
    "and --landmarks need --ambiguous; --group-size and --local-groups do not combine with it.\n";

long parseInt(const std::string& flag, const std::string& v, long lo, long hi) {
  return static_cast<long>(tools::parseIntFlag(flag, v, lo, hi));
}

}  // namespace

int main(int argc, char** argv) {
  std::string input, out, truth;
  tools::OutlierOptions opt;
  tools::AmbiguousOptions amb;
  bool haveCount = false, haveMode = false, ambiguous = false, haveWindow = false;
  std::string groupOnly,
      ambiguousOnly;  // the last option given that needs group mode / --ambiguous
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
        groupOnly = a;
      } else if (a == "--window") {
        opt.localWindow = amb.window = static_cast<int>(parseInt(a, value(), 2, 100000000));
        haveWindow = true;
      } else if (a == "--local-groups") {
        opt.localGroups = true;
        groupOnly = a;
      } else if (a == "--vertigo") {
        opt.measurement = tools::OutlierMeasurement::Vertigo;
      } else if (a == "--seed") {
        opt.seed = amb.seed =
            static_cast<std::uint64_t>(parseInt(a, value(), 0, 0x7fffffffffffffffL));
      } else if (a == "--out") {
        out = value();
      } else if (a == "--truth") {
        truth = value();
      } else if (a == "--ambiguous") {
        amb.count = static_cast<int>(parseInt(a, value(), 0, 10000000));
        ambiguous = true;
      } else if (a == "--alternatives") {
        amb.alternatives = static_cast<int>(parseInt(a, value(), 2, 1000));
        ambiguousOnly = a;
      } else if (a == "--null") {
        amb.null = true;
        ambiguousOnly = a;
      } else if (a == "--decoys") {
        amb.decoys = tools::decoyModeFromName(value());
        ambiguousOnly = a;
      } else if (a == "--landmarks") {
        amb.landmarks = true;
        ambiguousOnly = a;
      } else if (!a.empty() && a[0] == '-') {
        throw std::invalid_argument("unknown option " + a);
      } else if (input.empty()) {
        input = a;
      } else {
        throw std::invalid_argument("more than one input file");
      }
    }
    if (input.empty()) throw std::invalid_argument("no input file");
    if (ambiguous && (haveCount || haveMode))
      throw std::invalid_argument("--ambiguous does not combine with --count/--mode");
    if (ambiguous && opt.measurement == tools::OutlierMeasurement::Vertigo)
      throw std::invalid_argument("--vertigo does not combine with --ambiguous");
    if (ambiguous && !groupOnly.empty())
      throw std::invalid_argument(groupOnly + " does not combine with --ambiguous");
    if (!ambiguous && !ambiguousOnly.empty())
      throw std::invalid_argument(ambiguousOnly + " needs --ambiguous");
    if (!ambiguous && !haveCount) throw std::invalid_argument("--count is required");
    if (!ambiguous && !haveMode) throw std::invalid_argument("--mode is required");
    // tools/compare passes --group-size (and --window) whatever the mode: those stay harmless.
    if (opt.localGroups && opt.mode != tools::OutlierMode::Group)
      throw std::invalid_argument("--local-groups needs --mode group");
    if (!haveWindow) amb.window = 10;
    if (!haveWindow && opt.measurement == tools::OutlierMeasurement::Vertigo)
      opt.localWindow = 20;  // generateDataset.py's local window
    if (out.empty() || truth.empty()) throw std::invalid_argument("--out and --truth are required");
  } catch (const std::exception& e) {
    std::fprintf(stderr, "loopd-outliers: %s\n\n%s", e.what(), kUsage);
    return 2;
  }
  try {
    const io::Dataset dataset = io::readDataset(input);
    if (ambiguous) {
      const tools::AmbiguousResult r = tools::makeAmbiguous(dataset, amb);
      io::writeG2oGraph(out, r.graph);
      tools::writeTextFile(truth, tools::ambiguousTruthJson(input, amb, r));
      std::fprintf(stderr,
                   "%s: %d loop closures made ambiguous (%d alternatives%s, %s decoys) -> %s\n",
                   input.c_str(), amb.count, amb.alternatives, amb.null ? " + null" : "",
                   tools::decoyModeName(amb.decoys), out.c_str());
      return 0;
    }
    const tools::OutlierResult r = tools::addOutliers(dataset, opt);
    io::writeG2oGraph(out, r.graph);
    tools::writeTextFile(truth, tools::outlierTruthJson(input, opt, r));
    std::fprintf(stderr, "%s: %d edges + %d %s outliers -> %s\n", input.c_str(), r.inlierEdges,
                 static_cast<int>(r.outliers.size()), tools::outlierModeName(opt.mode),
                 out.c_str());
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "loopd-outliers: %s\n", e.what());
    return 1;
  }
}
