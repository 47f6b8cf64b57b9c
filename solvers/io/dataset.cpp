#include "solvers/io/dataset.h"

namespace loopd::io {

int vertexValueSize(VertexType t) {
  switch (t) {
    case VertexType::SE2:
      return 3;
    case VertexType::SE3:
      return 7;
    case VertexType::Point2:
      return 2;
    case VertexType::Point3:
      return 3;
  }
  return 0;
}

int edgeDimension(EdgeType t) {
  switch (t) {
    case EdgeType::BetweenSE2:
      return 3;
    case EdgeType::BetweenSE3:
      return 6;
    case EdgeType::PosePoint2:
      return 2;
    case EdgeType::PosePoint3:
      return 3;
    case EdgeType::BearingRange2:
      return 2;
  }
  return 0;
}

int edgeMeasurementSize(EdgeType t) { return t == EdgeType::BetweenSE3 ? 7 : edgeDimension(t); }

Edge equivalenceEdge(std::int64_t a, std::int64_t b, int index) {
  Edge e;
  e.type = EdgeType::BetweenSE2;
  e.from = a;
  e.to = b;
  e.information.topLeftCorner<3, 3>() = Eigen::Matrix3d::Identity() * kEquivalenceInformation;
  e.index = index;
  return e;
}

namespace {

std::string formatError(const std::string& file, int line, const std::string& reason) {
  return line > 0 ? file + ":" + std::to_string(line) + ": " + reason : file + ": " + reason;
}

}  // namespace

DatasetError::DatasetError(const std::string& file, int line, const std::string& reason)
    : std::runtime_error(formatError(file, line, reason)),
      file_(file),
      line_(line),
      reason_(reason) {}

}  // namespace loopd::io
