#pragma once
// Vertex and edge lines as every format writes them: `TAG id value...` and
// `TAG from to measurement... triangle...`; the readers say what differs (the tag, the order
// of the triangle, information or covariance). Internal to the readers.
#include "solvers/io/dataset.h"
#include "solvers/io/information.h"
#include "solvers/io/line_scanner.h"

namespace loopd::io::detail {

/// `TAG id value...` with exactly vertexValueSize(type) values; an SE(3) quaternion is
/// normalised.
Vertex readVertex(const LineScanner& in, VertexType type);

/// How a line stores the edge's uncertainty after the measurement.
enum class Uncertainty { Information, Covariance };

/// `TAG from to measurement... triangle...`: exactly edgeMeasurementSize(type) measurement
/// values (an SE(3) quaternion is normalised), then the upper triangle of the
/// edgeDimension(type)² matrix in `order` (nullptr: row by row, as g2o). A covariance is
/// checked and stored inverted, so Edge::information is always an information matrix.
Edge readEdge(const LineScanner& in, EdgeType type, Uncertainty uncertainty,
              const TriangleEntry* order = nullptr);

}  // namespace loopd::io::detail
