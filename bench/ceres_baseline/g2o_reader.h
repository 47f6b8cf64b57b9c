// Minimal g2o reader for the Ceres baseline: VERTEX_SE2, EDGE_SE2, VERTEX_SE3:QUAT,
// EDGE_SE3:QUAT only. Independent of loopd's own readers on purpose.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <array>
#include <string>
#include <vector>

namespace ceres_baseline {

struct Edge2 {
  int i = 0, j = 0;                // vertex indices (positions in Graph::ids)
  double dx = 0, dy = 0, dth = 0;  // measurement Z
  Eigen::Matrix3d sqrt_info;       // W with WᵀW = Ω (upper Cholesky factor)
};

struct Edge3 {
  int i = 0, j = 0;
  Eigen::Vector3d t = Eigen::Vector3d::Zero();
  Eigen::Quaterniond q = Eigen::Quaterniond::Identity();  // unit
  Eigen::Matrix<double, 6, 6> sqrt_info;                  // translation first
};

struct Graph {
  int dim = 0;                 // 2 or 3 (0: empty file)
  bool had_vertices = false;   // false: initial values composed from odometry
  std::vector<long long> ids;  // vertex ids, ascending; index = position
  // SE(2) state, one entry per vertex (parameter blocks for Ceres)
  std::vector<std::array<double, 2>> xy;
  std::vector<double> th;
  // SE(3) state
  std::vector<std::array<double, 3>> t;
  std::vector<std::array<double, 4>> q;  // Eigen order x, y, z, w
  std::vector<Edge2> e2;
  std::vector<Edge3> e3;

  std::size_t poses() const { return ids.size(); }
  std::size_t edges() const { return dim == 3 ? e3.size() : e2.size(); }
};

// Reads `path` into `g`. On failure returns false and sets `err` to "FILE:LINE: reason"
// (or "FILE: reason"). Never throws for bad content.
bool read_g2o(const std::string& path, Graph& g, std::string& err);

}  // namespace ceres_baseline
