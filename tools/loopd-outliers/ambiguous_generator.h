#pragma once
// Ambiguous measurements for the multi-hypothesis benchmarks: N true loop closures (or, with
// landmarks, N re-sightings) of a dataset become HYPOTHESES groups — the true edge at a random
// position among k alternatives, the others decoys, optionally with a null hypothesis.
//
//   target:      decoy = same measurement, wrong target near the true one: for a loop
//                closure a → b the older end moves by an offset in ±[2, window] poses, to a
//                pose not at the same place (≥ half the base shift or 10° away in the file's
//                estimate: a revisit of the same spot would be a true closure); for a
//                sighting, another landmark already seen, nearest in the file's estimate
//   measurement: decoy = same keys, wrong measurement: translation moved by [0.5, 2] ×
//                (median loop-closure length, at least 1 m) in a uniform direction, rotation
//                by ±[10°, 45°] (3D: about a uniform axis); landmark: position moved likewise
//   mixed:       each decoy one of the two, at random
// Groups replace the true edge in place, so edge indices after it shift; the truth file
// names the decoys' indices as "outliers" (loopd-eval's precision/recall) and the true
// alternative's position per group ("true_choice", compared with loopd-solve's "chosen").
#include <cstdint>
#include <string>
#include <vector>

#include "solvers/io/dataset.h"

namespace loopd::tools {

// Aliased: a wrong measurement 2–4 standard deviations (of the edge's own information) from
// the true one: plausible at first, the case where many hypotheses stay alive.
enum class DecoyMode { Target, Measurement, Mixed, Aliased };

struct AmbiguousOptions {
  int count = 50;        // N
  int alternatives = 3;  // k ≥ 2 (the true one included)
  bool null = false;     // add a null hypothesis to every group
  DecoyMode decoys = DecoyMode::Target;
  int window = 10;         // target decoys: offset at most this many poses
  bool landmarks = false;  // pick landmark re-sightings instead of loop closures
  std::uint64_t seed = 1;
};

struct AmbiguousResult {
  io::Dataset graph;
  std::vector<int> decoys;      // 0-based edge indices of all decoys in graph
  std::vector<int> trueChoice;  // per group in file order: position of the true alternative
  std::vector<int> trueEdges;   // per group: edge index of the true alternative
};

const char* decoyModeName(DecoyMode m);
/// "target", "measurement", "mixed"; throws std::invalid_argument otherwise.
DecoyMode decoyModeFromName(const std::string& name);

/// Throws std::invalid_argument when the dataset has fewer than N eligible edges, or for bad
/// options. Deterministic for a seed.
AmbiguousResult makeAmbiguous(const io::Dataset& input, const AmbiguousOptions& options);

/// TRUTH.json: {"input", "mode": "ambiguous", "count", "alternatives", "null", "decoys",
/// "seed", "outliers": [decoy edge indices], "true_choice": [...], "true_edges": [...]}.
std::string ambiguousTruthJson(const std::string& inputPath, const AmbiguousOptions& options,
                               const AmbiguousResult& result);

}  // namespace loopd::tools
