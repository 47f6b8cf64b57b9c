#include "solvers/io/dataset_builder.h"

#include "solvers/io/odometry_init.h"

namespace loopd::io::detail {

namespace {

bool is3dVertex(VertexType t) { return t == VertexType::SE3 || t == VertexType::Point3; }
bool is3dEdge(EdgeType t) { return t == EdgeType::BetweenSE3 || t == EdgeType::PosePoint3; }

std::string edgeName(const Edge& e) {
  return "edge " + std::to_string(e.from) + " -> " + std::to_string(e.to);
}

}  // namespace

DatasetBuilder::DatasetBuilder(const std::string& path, const char* format, bool landmarkIdsShared)
    : landmarkIdsShared_(landmarkIdsShared) {
  ds_.path = path;
  ds_.format = format;
}

void DatasetBuilder::noteDimension(const LineScanner& in, bool is3d) {
  if (dimensionLine_ == 0) {
    dimensionLine_ = in.line();
    ds_.is3d = is3d;
  } else if (is3d != ds_.is3d) {
    in.fail(std::string(in.tag()) + " is " + (is3d ? "3D" : "2D") + " but line " +
            std::to_string(dimensionLine_) + " made this a " + (ds_.is3d ? "3D" : "2D") + " file");
  }
}

void DatasetBuilder::addVertex(const LineScanner& in, const Vertex& v) {
  expectNoOpenGroup(in);
  noteDimension(in, is3dVertex(v.type));
  auto& ids = v.isLandmark() && !landmarkIdsShared_ ? landmarkIds_ : vertexIds_;
  const auto [it, inserted] = ids.emplace(v.id, Seen{v.isLandmark(), v.line});
  if (!inserted) {
    in.fail("vertex " + std::to_string(v.id) + " is already defined on line " +
            std::to_string(it->second.line));
  }
  (v.isLandmark() ? ds_.landmarks : ds_.poses).push_back(v);
  ds_.hadVertices = true;
}

void DatasetBuilder::addEdge(const LineScanner& in, Edge e) {
  noteDimension(in, is3dEdge(e.type));
  // Pose and landmark ids are distinct variables only when they live in separate spaces.
  if (e.from == e.to && (isBetween(e.type) || landmarkIdsShared_)) {
    in.fail(std::string(in.tag()) + " connects vertex " + std::to_string(e.from) + " to itself");
  }
  e.index = static_cast<int>(ds_.edges.size());
  if (groupEdgesPending_ > 0) {
    const HypothesisGroup& g = ds_.hypotheses.back();
    const Edge& first = g.firstEdge < e.index ? ds_.edges[g.firstEdge] : e;
    if (e.type != first.type) {
      in.fail("the alternatives of HYPOTHESES on line " + std::to_string(g.line) + " must all be " +
              std::string(in.tag()) + "-like edges of one type (line " +
              std::to_string(first.line) + " differs)");
    }
    --groupEdgesPending_;
  }
  ds_.edges.push_back(e);
}

void DatasetBuilder::beginHypotheses(const LineScanner& in, int count, bool null) {
  expectNoOpenGroup(in);
  if (count < 1) in.fail("HYPOTHESES needs at least one alternative");
  if (count == 1 && !null) in.fail("HYPOTHESES 1 without null is an ordinary edge");
  HypothesisGroup g;
  g.firstEdge = static_cast<int>(ds_.edges.size());
  g.count = count;
  g.null = null;
  g.line = in.line();
  ds_.hypotheses.push_back(g);
  groupEdgesPending_ = count;
}

void DatasetBuilder::expectNoOpenGroup(const LineScanner& in) const {
  if (groupEdgesPending_ > 0) {
    const HypothesisGroup& g = ds_.hypotheses.back();
    in.fail("HYPOTHESES on line " + std::to_string(g.line) + " expects " + std::to_string(g.count) +
            " edge lines, but " + std::to_string(groupEdgesPending_) + " are missing before this " +
            std::string(in.tag()) + " line");
  }
}

void DatasetBuilder::addEquivalence(const LineScanner& in, std::int64_t a, std::int64_t b) {
  expectNoOpenGroup(in);
  if (a == b) in.fail(std::string(in.tag()) + " joins vertex " + std::to_string(a) + " to itself");
  ds_.equivalences.emplace_back(a, b);
  equivalenceLines_.push_back(in.line());
}

std::string DatasetBuilder::vertexProblem(std::int64_t id, bool landmark) const {
  const auto& ids = landmark && !landmarkIdsShared_ ? landmarkIds_ : vertexIds_;
  const auto it = ids.find(id);
  const std::string kind = landmark ? "landmark" : "pose";
  if (it == ids.end()) {
    return kind + " " + std::to_string(id) + " is not defined by any vertex line in this file";
  }
  if (it->second.landmark != landmark) {
    return "vertex " + std::to_string(id) + " (line " + std::to_string(it->second.line) +
           ") is a " + (landmark ? "pose" : "landmark") + ", but is used as a " + kind;
  }
  return {};
}

Dataset DatasetBuilder::finish() {
  if (ds_.edges.empty()) throw DatasetError(ds_.path, 0, "the file has no edges");
  if (groupEdgesPending_ > 0) {
    const HypothesisGroup& g = ds_.hypotheses.back();
    throw DatasetError(ds_.path, g.line,
                       "HYPOTHESES expects " + std::to_string(g.count) +
                           " edge lines, but the file ends " + std::to_string(groupEdgesPending_) +
                           " short");
  }
  if (!ds_.hypotheses.empty() && !ds_.hadVertices) {
    throw DatasetError(ds_.path, ds_.hypotheses.front().line,
                       "HYPOTHESES needs a file with vertex lines (poses are not composed from "
                       "ambiguous edges)");
  }
  if (!ds_.hadVertices) {
    initialiseFromOdometry(ds_, landmarkIdsShared_);
    return std::move(ds_);
  }
  for (const Edge& e : ds_.edges) {
    std::string why = vertexProblem(e.from, false);
    if (why.empty()) why = vertexProblem(e.to, !isBetween(e.type));
    if (!why.empty()) throw DatasetError(ds_.path, e.line, edgeName(e) + ": " + why);
  }
  for (std::size_t i = 0; i < ds_.equivalences.size(); ++i) {
    const auto [a, b] = ds_.equivalences[i];
    std::string why = vertexProblem(a, false);
    if (why.empty()) why = vertexProblem(b, false);
    if (!why.empty()) throw DatasetError(ds_.path, equivalenceLines_[i], why);
  }
  return std::move(ds_);
}

}  // namespace loopd::io::detail
