#pragma once
// Scoring an estimate against a reference trajectory and, with a TRUTH.json from
// loopd-outliers, the rejections of a robust solver.
//   ATE: RMSE of positions after the rigid (rotation + translation, no scale) Umeyama/Horn
//        alignment of the estimate onto the reference, over the poses both have.
//   RPE: mean over consecutive pose ids (both present) of the translation norm and rotation
//        angle of (ΔT_ref)⁻¹·ΔT_est, ΔT = T_iᵀ… the relative pose from i to i+1.
//   precision = TP / |rejected| (1 when nothing was rejected), recall = TP / |outliers|
//        (1 when there are none), TP = |rejected ∩ outliers|.
#include <cstdint>
#include <string>
#include <vector>

#include "solvers/io/dataset.h"

namespace loopd::tools {

struct TrajectoryErrors {
  int poses = 0;         // matched poses
  double ateRmse = 0.0;  // m
  double ateMax = 0.0;
  double rpeTrans = 0.0;   // mean, m
  double rpeRotDeg = 0.0;  // mean, degrees
  int rpePairs = 0;
};

/// Throws std::invalid_argument when the datasets share fewer than 2 poses or mix 2D and 3D.
TrajectoryErrors trajectoryErrors(const io::Dataset& reference, const io::Dataset& estimate);

struct DecisionScores {
  int truePositives = 0, falsePositives = 0, falseNegatives = 0;
  double precision = 1.0, recall = 1.0;
};

DecisionScores scoreRejections(const std::vector<std::int64_t>& rejected,
                               const std::vector<std::int64_t>& outliers);

/// Σ rᵀr of the graph's edges NOT listed in outliers, at the estimate's vertices (same ids;
/// the graph's vertices are replaced). Uses the solver's factors (buildProblem).
double inlierChi2(const io::Dataset& graph, const io::Dataset& estimate,
                  const std::vector<std::int64_t>& outliers);

/// The integer array under key in a flat JSON object (e.g. "outliers", "rejected"); empty if
/// the key is absent. Throws std::runtime_error for a malformed array.
std::vector<std::int64_t> jsonIntArray(const std::string& json, const std::string& key);
/// A number (or integer) field; fallback if absent.
double jsonNumber(const std::string& json, const std::string& key, double fallback);
/// The poses and landmarks of a g2o file that may hold only vertex lines (loopd-solve --out):
/// VERTEX_SE2, VERTEX_SE3:QUAT, VERTEX_XY, VERTEX_TRACKXYZ; other lines are skipped. Throws
/// std::runtime_error naming the file and line for a malformed vertex.
io::Dataset readVertices(const std::string& path);
/// Reads a whole file; throws std::runtime_error naming it.
std::string readTextFile(const std::string& path);

}  // namespace loopd::tools
