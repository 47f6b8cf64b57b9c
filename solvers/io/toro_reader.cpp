// TORO 2D: VERTEX2 id x y θ; EDGE2 a b dx dy dθ I11 I12 I22 I33 I13 I23; EQUIV a b.
#include <string_view>

#include "solvers/io/dataset_builder.h"
#include "solvers/io/dataset_reader.h"
#include "solvers/io/format_tags.h"
#include "solvers/io/records.h"

namespace loopd::io {

namespace {

constexpr std::string_view kVertex = "VERTEX2", kEdge = "EDGE2", kEquiv = "EQUIV";

// TORO's information order: I11 I12 I22 I33 I13 I23 (0-based (row, col) below).
constexpr detail::TriangleEntry kToroOrder[] = {{0, 0}, {0, 1}, {1, 1}, {2, 2}, {0, 2}, {1, 2}};

}  // namespace

bool detail::isToroTag(std::string_view tag) {
  return tag == kVertex || tag == kEdge || tag == kEquiv;
}

Dataset parseToro(std::string_view text, const std::string& name) {
  detail::LineScanner in(name, text);
  detail::DatasetBuilder out(name, "toro", /*landmarkIdsShared=*/true);
  while (in.next()) {
    if (in.tag() == kVertex) {
      out.addVertex(in, detail::readVertex(in, VertexType::SE2));
    } else if (in.tag() == kEdge) {
      out.addEdge(in, detail::readEdge(in, EdgeType::BetweenSE2, detail::Uncertainty::Information,
                                       kToroOrder));
    } else if (in.tag() == kEquiv) {
      in.expectCount(2);
      out.addEquivalence(in, in.id(0), in.id(1));
    } else {
      in.fail("unknown TORO tag " + detail::quoted(in.tag()));
    }
  }
  return out.finish();
}

}  // namespace loopd::io
