#pragma once
// A pose-graph file as read, before it becomes a factor graph: vertices and edges in file
// order with their line numbers, so every later error can point back at the file.
#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

namespace loopd::io {

enum class VertexType { SE2, SE3, Point2, Point3 };

enum class EdgeType {
  BetweenSE2,     // EDGE_SE2, EDGE2, ODOMETRY:   measurement x y θ
  BetweenSE3,     // EDGE_SE3:QUAT:               measurement x y z qx qy qz qw
  PosePoint2,     // EDGE_SE2_XY, LANDMARK:       landmark x y in the pose frame
  PosePoint3,     // EDGE_SE3_TRACKXYZ:           landmark x y z in the pose frame
  BearingRange2,  // (no file tag yet)            bearing (rad), range (m)
};

/// Dimension of a vertex's value as stored (SE3 stores x y z qx qy qz qw).
int vertexValueSize(VertexType t);
/// A pose-to-pose edge (odometry or loop closure), as opposed to a landmark sighting.
inline bool isBetween(EdgeType t) { return t == EdgeType::BetweenSE2 || t == EdgeType::BetweenSE3; }
/// Dimension of an edge's residual (and of its information matrix).
int edgeDimension(EdgeType t);
/// Dimension of an edge's measurement as stored (SE3: 7).
int edgeMeasurementSize(EdgeType t);

struct Vertex {
  VertexType type = VertexType::SE2;
  std::int64_t id = 0;            // as in the file
  std::array<double, 7> value{};  // first vertexValueSize(type) entries used
  int line = 0;                   // 1-based line in the file; 0 when synthesised
  bool isLandmark() const { return type == VertexType::Point2 || type == VertexType::Point3; }
};

struct Edge {
  EdgeType type = EdgeType::BetweenSE2;
  std::int64_t from = 0;  // a pose id
  std::int64_t to = 0;    // a pose id, or a landmark id for PosePoint*/BearingRange2
  std::array<double, 7> measurement{};
  // Full symmetric; the top-left dim×dim block is used.
  Eigen::Matrix<double, 6, 6> information = Eigen::Matrix<double, 6, 6>::Zero();
  int line = 0;
  /// The 0-based index of this edge among the file's edges (the `rejected` numbering).
  int index = 0;
};

/// `HYPOTHESES k [null]` (g2o files): the next k edges are the alternatives of one ambiguous
/// measurement, at most one of them true; with `null`, possibly none.
struct HypothesisGroup {
  int firstEdge = 0;  // index of the first alternative in Dataset::edges
  int count = 0;      // k: the alternatives are edges firstEdge … firstEdge + k − 1
  bool null = false;
  int line = 0;  // the HYPOTHESES line
};

/// How tightly an EQUIV pair is held together: the information of its identity constraint.
constexpr double kEquivalenceInformation = 1e6;

struct Dataset {
  std::string path;
  std::string format;  // "g2o", "toro", "victoria"
  bool is3d = false;
  bool hadVertices = false;       // false: poses were composed from odometry
  std::vector<Vertex> poses;      // SE2 or SE3, file order
  std::vector<Vertex> landmarks;  // Point2 or Point3, file order
  std::vector<Edge> edges;        // file order
  /// TORO EQUIV lines: pairs of pose ids that are the same place (solved as an identity
  /// between constraint of information kEquivalenceInformation·I).
  std::vector<std::pair<std::int64_t, std::int64_t>> equivalences;
  /// Ambiguous measurements in file order (their edges are in `edges` too).
  std::vector<HypothesisGroup> hypotheses;
};

/// An EQUIV pair as the edge it is solved as: the identity between a and b, information
/// kEquivalenceInformation·I, numbered `index` among the edges.
Edge equivalenceEdge(std::int64_t a, std::int64_t b, int index);

/// Every reader failure: names the file, the 1-based line (0 if not line-specific), and why.
class DatasetError : public std::runtime_error {
 public:
  DatasetError(const std::string& file, int line, const std::string& reason);
  const std::string& file() const { return file_; }
  int line() const { return line_; }
  const std::string& reason() const { return reason_; }

 private:
  std::string file_;
  int line_;
  std::string reason_;
};

}  // namespace loopd::io
