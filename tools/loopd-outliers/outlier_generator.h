#pragma once
// Synthetic wrong loop closures after Vertigo's generateDataset.py protocol (Sünderhauf &
// Protzel), for benchmarks and tests. Outliers are appended after the dataset's own edges,
// so their 0-based edge indices are inlierEdges … inlierEdges + count − 1.
//
//   random: a < b uniform over the poses (b ≥ a + 2, never an odometry pair)
//   local:  a uniform, b ∈ [a + 2, a + window]
//   group:  groups of K edges (a + j, b + j), j = 0…K−1, all with the SAME measurement
//           (mutually consistent); (a, b) random, or local with localGroups
// Measurement (OutlierMeasurement::Uniform, the default): rotation uniform (2D: θ ∈ [−π, π);
// 3D: uniform unit quaternion), translation direction uniform and length uniform in [0, L],
// L = the median translation of the dataset's loop closures (of all between edges if it has
// none). OutlierMeasurement::Vertigo: generateDataset.py's own, near the identity (a place
// recognized where the robot is not): each translation axis ~ N(0, 0.3 m), each angle
// (3D: yaw, pitch, roll) ~ N(0, 10°). Information: that of the dataset's loop closure with
// the median trace (or of its median-trace between edge).
// Deterministic for a seed (own uniform draws on std::mt19937_64, no library distributions).
#include <cstdint>
#include <string>
#include <vector>

#include "solvers/io/dataset.h"

namespace loopd::tools {

enum class OutlierMode { Random, Local, Group };
enum class OutlierMeasurement { Uniform, Vertigo };

struct OutlierOptions {
  int count = 100;
  OutlierMode mode = OutlierMode::Random;
  int groupSize = 10;
  int localWindow = 50;
  bool localGroups = false;  // group mode: place groups like local outliers
  OutlierMeasurement measurement = OutlierMeasurement::Uniform;
  std::uint64_t seed = 1;
};

struct OutlierResult {
  io::Dataset graph;          // input edges, then the outliers
  std::vector<int> outliers;  // 0-based edge indices of the added edges in graph
  int inlierEdges = 0;        // number of original edges
};

const char* outlierModeName(OutlierMode m);
/// "uniform", "vertigo".
const char* outlierMeasurementName(OutlierMeasurement m);
/// "random", "local", "group"; throws std::invalid_argument otherwise.
OutlierMode outlierModeFromName(const std::string& name);

/// Throws std::invalid_argument for a dataset with fewer than K + 2 poses (group mode, K the
/// group size; 3 otherwise), landmark-only data, or bad options.
OutlierResult addOutliers(const io::Dataset& input, const OutlierOptions& options);

/// TRUTH.json: {"input", "mode", "count", "seed", "group_size", "measurement" ("uniform" or
/// "vertigo"), "outliers": [...], "inlier_edges"}.
std::string outlierTruthJson(const std::string& inputPath, const OutlierOptions& options,
                             const OutlierResult& result);

}  // namespace loopd::tools
