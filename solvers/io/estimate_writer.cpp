#include "solvers/io/estimate_writer.h"

#include <cerrno>
#include <charconv>
#include <cstdio>
#include <cstring>
#include <memory>
#include <unordered_set>

namespace loopd::io {

namespace {

const char* vertexTag(VertexType t) {
  switch (t) {
    case VertexType::SE2:
      return "VERTEX_SE2";
    case VertexType::SE3:
      return "VERTEX_SE3:QUAT";
    case VertexType::Point2:
      return "VERTEX_XY";
    case VertexType::Point3:
      return "VERTEX_TRACKXYZ";
  }
  return nullptr;
}

const char* edgeTag(EdgeType t) {
  switch (t) {
    case EdgeType::BetweenSE2:
      return "EDGE_SE2";
    case EdgeType::BetweenSE3:
      return "EDGE_SE3:QUAT";
    case EdgeType::PosePoint2:
      return "EDGE_SE2_XY";
    case EdgeType::PosePoint3:
      return "EDGE_SE3_TRACKXYZ";
    case EdgeType::BearingRange2:
      return nullptr;
  }
  return nullptr;
}

// Builds the file text in memory: one write, and no locale or stream state to get wrong.
class G2oText {
 public:
  void vertex(const Vertex& v) {
    text_ += vertexTag(v.type);
    integer(v.id);
    for (int i = 0; i < vertexValueSize(v.type); ++i) number(v.value[i]);
    text_ += '\n';
  }
  void edge(const Edge& e) {
    text_ += edgeTag(e.type);
    integer(e.from);
    integer(e.to);
    for (int i = 0; i < edgeMeasurementSize(e.type); ++i) number(e.measurement[i]);
    const int dim = edgeDimension(e.type);
    for (int r = 0; r < dim; ++r) {
      for (int c = r; c < dim; ++c) number(e.information(r, c));
    }
    text_ += '\n';
  }
  void hypotheses(const HypothesisGroup& g) {
    text_ += "HYPOTHESES";
    integer(g.count);
    if (g.null) text_ += " null";
    text_ += '\n';
  }
  const std::string& text() const { return text_; }

 private:
  void integer(std::int64_t v) {
    char buf[24];
    const auto res = std::to_chars(buf, buf + sizeof buf, v);
    text_ += ' ';
    text_.append(buf, res.ptr);
  }
  // Shortest representation that reads back to the same double.
  void number(double v) {
    char buf[32];
    const auto res = std::to_chars(buf, buf + sizeof buf, v);
    text_ += ' ';
    text_.append(buf, res.ptr);
  }

  std::string text_;
};

void appendVertices(G2oText& out, const Dataset& ds) {
  for (const Vertex& v : ds.poses) out.vertex(v);
  for (const Vertex& v : ds.landmarks) out.vertex(v);
}

void save(const std::string& path, const std::string& text) {
  std::unique_ptr<std::FILE, int (*)(std::FILE*)> f(std::fopen(path.c_str(), "wb"), &std::fclose);
  if (!f) throw DatasetError(path, 0, std::strerror(errno));
  if (std::fwrite(text.data(), 1, text.size(), f.get()) != text.size()) {
    throw DatasetError(path, 0, std::strerror(errno));
  }
  // fclose flushes: a full disk shows up here.
  if (std::fclose(f.release()) != 0) throw DatasetError(path, 0, std::strerror(errno));
}

}  // namespace

void writeG2oVertices(const std::string& path, const Dataset& estimate) {
  G2oText out;
  appendVertices(out, estimate);
  save(path, out.text());
}

void writeG2oGraph(const std::string& path, const Dataset& graph) {
  std::unordered_set<std::int64_t> poseIds;
  for (const Vertex& v : graph.poses) poseIds.insert(v.id);
  for (const Vertex& v : graph.landmarks) {
    if (poseIds.count(v.id)) {
      throw DatasetError(path, 0,
                         "landmark " + std::to_string(v.id) +
                             " has the id of a pose; g2o has one id space for both");
    }
  }
  G2oText out;
  appendVertices(out, graph);
  size_t nextGroup = 0;
  for (size_t i = 0; i < graph.edges.size(); ++i) {
    const Edge& e = graph.edges[i];
    while (nextGroup < graph.hypotheses.size() &&
           graph.hypotheses[nextGroup].firstEdge == static_cast<int>(i))
      out.hypotheses(graph.hypotheses[nextGroup++]);
    if (!edgeTag(e.type)) {
      throw DatasetError(
          path, 0,
          "edge " + std::to_string(e.index) + " is bearing-range, which g2o cannot express");
    }
    out.edge(e);
  }
  // TORO's EQUIV pairs, after every edge (the edges keep their indices), as the identity
  // constraints they are solved as: g2o has no EQUIV.
  for (const auto& [a, b] : graph.equivalences) out.edge(equivalenceEdge(a, b, 0));
  save(path, out.text());
}

}  // namespace loopd::io
