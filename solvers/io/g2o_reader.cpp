// g2o: VERTEX_SE2 / EDGE_SE2, VERTEX_SE3:QUAT / EDGE_SE3:QUAT, VERTEX_XY / EDGE_SE2_XY,
// VERTEX_TRACKXYZ / EDGE_SE3_TRACKXYZ, FIX. Information: upper triangle, row by row.
// Poses and landmarks share one id space.
#include <string_view>

#include "solvers/io/dataset_builder.h"
#include "solvers/io/dataset_reader.h"
#include "solvers/io/format_tags.h"
#include "solvers/io/records.h"

namespace loopd::io {

namespace {

struct VertexTag {
  std::string_view tag;
  VertexType type;
};
struct EdgeTag {
  std::string_view tag;
  EdgeType type;
};

constexpr VertexTag kVertexTags[] = {
    {"VERTEX_SE2", VertexType::SE2},
    {"VERTEX_SE3:QUAT", VertexType::SE3},
    {"VERTEX_XY", VertexType::Point2},
    {"VERTEX_TRACKXYZ", VertexType::Point3},
};
constexpr EdgeTag kEdgeTags[] = {
    {"EDGE_SE2", EdgeType::BetweenSE2},
    {"EDGE_SE3:QUAT", EdgeType::BetweenSE3},
    {"EDGE_SE2_XY", EdgeType::PosePoint2},
    {"EDGE_SE3_TRACKXYZ", EdgeType::PosePoint3},
};
constexpr std::string_view kFix = "FIX";
constexpr std::string_view kHypotheses = "HYPOTHESES";  // loopd's ambiguous-measurement group

template <class Entry, std::size_t N>
const Entry* lookUp(const Entry (&table)[N], std::string_view tag) {
  for (const Entry& e : table) {
    if (e.tag == tag) return &e;
  }
  return nullptr;
}

}  // namespace

bool detail::isG2oTag(std::string_view tag) {
  return lookUp(kVertexTags, tag) || lookUp(kEdgeTags, tag) || tag == kFix || tag == kHypotheses;
}

Dataset parseG2o(std::string_view text, const std::string& name) {
  detail::LineScanner in(name, text);
  detail::DatasetBuilder out(name, "g2o", /*landmarkIdsShared=*/true);
  while (in.next()) {
    if (const VertexTag* v = lookUp(kVertexTags, in.tag())) {
      out.addVertex(in, detail::readVertex(in, v->type));
    } else if (const EdgeTag* e = lookUp(kEdgeTags, in.tag())) {
      out.addEdge(in, detail::readEdge(in, e->type, detail::Uncertainty::Information));
    } else if (in.tag() == kHypotheses) {
      in.expectAtLeast(1);
      if (in.count() > 2) in.fail("HYPOTHESES takes a count and an optional 'null'");
      const std::int64_t k = in.id(0);
      if (k > 1000) in.fail("HYPOTHESES count " + std::to_string(k) + " is over 1000");
      bool null = false;
      if (in.count() == 2) {
        if (in.field(1) != "null")
          in.fail("HYPOTHESES: expected 'null', got " + detail::quoted(in.field(1)));
        null = true;
      }
      out.beginHypotheses(in, static_cast<int>(k), null);
    } else if (in.tag() == kFix) {
      out.expectNoOpenGroup(in);
      // Gauge fixing: the solvers choose their own gauge, but the ids must still be ids.
      in.expectAtLeast(1);
      for (std::size_t i = 0; i < in.count(); ++i) in.id(i);
    } else {
      in.fail("unknown g2o tag " + detail::quoted(in.tag()));
    }
  }
  return out.finish();
}

}  // namespace loopd::io
