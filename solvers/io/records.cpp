#include "solvers/io/records.h"

#include <cmath>
#include <string>

namespace loopd::io::detail {

namespace {

// q = (qx, qy, qz, qw). A unit quaternion is kept bit for bit, so what the writer prints reads
// back unchanged; anything else is normalised.
void normaliseQuaternion(const LineScanner& in, double* q) {
  const double n = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  if (!std::isfinite(n)) in.fail(std::string(in.tag()) + " quaternion norm overflows");
  if (n < 1e-12) in.fail(std::string(in.tag()) + " quaternion has zero norm");
  if (std::abs(n - 1.0) > 1e-12) {
    for (int i = 0; i < 4; ++i) q[i] /= n;
  }
}

}  // namespace

Vertex readVertex(const LineScanner& in, VertexType type) {
  const int size = vertexValueSize(type);
  in.expectCount(1 + size);
  Vertex v;
  v.type = type;
  v.line = in.line();
  v.id = in.id(0);
  for (int i = 0; i < size; ++i) v.value[i] = in.number(1 + i);
  if (type == VertexType::SE3) normaliseQuaternion(in, &v.value[3]);
  return v;
}

Edge readEdge(const LineScanner& in, EdgeType type, Uncertainty uncertainty,
              const TriangleEntry* order) {
  const int size = edgeMeasurementSize(type);
  const int dim = edgeDimension(type);
  in.expectCount(2 + size + dim * (dim + 1) / 2);
  Edge e;
  e.type = type;
  e.line = in.line();
  e.from = in.id(0);
  e.to = in.id(1);
  for (int i = 0; i < size; ++i) e.measurement[i] = in.number(2 + i);
  if (type == EdgeType::BetweenSE3) normaliseQuaternion(in, &e.measurement[3]);
  if (!order) order = rowMajorUpper(dim);
  e.information = uncertainty == Uncertainty::Information
                      ? readInformation(in, 2 + size, dim, order)
                      : readCovarianceAsInformation(in, 2 + size, dim, order);
  return e;
}

}  // namespace loopd::io::detail
