#pragma once
// Scoring an estimate against a reference trajectory and, with a TRUTH.json from
// loopd-outliers, the rejections of a robust solver.
//   ATE: RMSE of positions after the rigid (rotation + translation, no scale) Umeyama/Horn
//        alignment of the estimate onto the reference, over all poses (both files must hold
//        the same pose ids).
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

/// The two must hold the same pose ids (landmarks are not compared). Throws
/// std::invalid_argument naming the file (Dataset::path) when a reference pose is missing from
/// the estimate or the estimate has a pose the reference lacks (how many, and the first id),
/// when a pose is 2D in one and 3D in the other (or a file mixes both), or when there are
/// fewer than 2 poses.
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

/// The poses and landmarks of a g2o file that may hold only vertex lines (loopd-solve --out):
/// VERTEX_SE2, VERTEX_SE3:QUAT, VERTEX_XY, VERTEX_TRACKXYZ; other lines are skipped. Throws
/// std::runtime_error naming the file and line for a malformed vertex or a pose (landmark) id
/// given twice (poses and landmarks may share ids, as Victoria Park's do).
io::Dataset readVertices(const std::string& path);
}  // namespace loopd::tools
