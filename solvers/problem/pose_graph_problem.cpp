#include "solvers/problem/pose_graph_problem.h"

#include <algorithm>
#include <stdexcept>

#include "solvers/factors/between_factor_se2.h"
#include "solvers/factors/between_factor_se3.h"
#include "solvers/factors/landmark_factors.h"

namespace loopd {

Key vertexKey(const io::Vertex& v) {
  return v.isLandmark() ? landmarkKey(static_cast<std::uint64_t>(v.id))
                        : poseKey(static_cast<std::uint64_t>(v.id));
}

namespace {

void insertVertex(Values& values, const io::Vertex& v) {
  const Key k = vertexKey(v);
  switch (v.type) {
    case io::VertexType::SE2:
      values.insert(k, SE2(v.value[0], v.value[1], v.value[2]));
      break;
    case io::VertexType::SE3:
      values.insert(k, SE3::fromTranslationQuaternion(v.value.data()));
      break;
    case io::VertexType::Point2:
      values.insertPoint2(k, Vec2(v.value[0], v.value[1]));
      break;
    case io::VertexType::Point3:
      values.insertPoint3(k, Vec3(v.value[0], v.value[1], v.value[2]));
      break;
  }
}

FactorPtr makeFactor(const io::Edge& e, bool odometry) {
  const Key a = poseKey(static_cast<std::uint64_t>(e.from));
  const auto& m = e.measurement;
  const FactorRole betweenRole = odometry ? FactorRole::Odometry : FactorRole::LoopClosure;
  switch (e.type) {
    case io::EdgeType::BetweenSE2:
      return std::make_shared<BetweenFactorSE2>(a, poseKey(static_cast<std::uint64_t>(e.to)),
                                                SE2(m[0], m[1], m[2]),
                                                e.information.topLeftCorner<3, 3>(), betweenRole);
    case io::EdgeType::BetweenSE3:
      return std::make_shared<BetweenFactorSE3>(a, poseKey(static_cast<std::uint64_t>(e.to)),
                                                SE3::fromTranslationQuaternion(m.data()),
                                                e.information, betweenRole);
    case io::EdgeType::PosePoint2:
      return std::make_shared<PosePointFactor2>(a, landmarkKey(static_cast<std::uint64_t>(e.to)),
                                                Vec2(m[0], m[1]),
                                                e.information.topLeftCorner<2, 2>());
    case io::EdgeType::PosePoint3:
      return std::make_shared<PosePointFactor3>(a, landmarkKey(static_cast<std::uint64_t>(e.to)),
                                                Vec3(m[0], m[1], m[2]),
                                                e.information.topLeftCorner<3, 3>());
    case io::EdgeType::BearingRange2:
      return std::make_shared<BearingRangeFactor2>(a, landmarkKey(static_cast<std::uint64_t>(e.to)),
                                                   Vec2(m[0], m[1]),
                                                   e.information.topLeftCorner<2, 2>());
  }
  throw std::logic_error("unknown edge type");
}

}  // namespace

bool neighboursInIdOrder(const std::vector<std::int64_t>& sortedPoseIds, std::int64_t a,
                         std::int64_t b) {
  if (a > b) std::swap(a, b);
  const auto it = std::lower_bound(sortedPoseIds.begin(), sortedPoseIds.end(), a);
  return it != sortedPoseIds.end() && *it == a && it + 1 != sortedPoseIds.end() && *(it + 1) == b;
}

PoseGraphProblem buildProblem(const io::Dataset& ds) {
  PoseGraphProblem p;
  p.is3d = ds.is3d;
  p.poses = static_cast<int>(ds.poses.size());
  p.landmarks = static_cast<int>(ds.landmarks.size());
  for (const auto& v : ds.poses) insertVertex(p.initial, v);
  for (const auto& v : ds.landmarks) insertVertex(p.initial, v);
  if (!ds.poses.empty()) {
    const auto lowest = std::min_element(ds.poses.begin(), ds.poses.end(),
                                         [](const auto& x, const auto& y) { return x.id < y.id; });
    p.firstPose = vertexKey(*lowest);
  }
  std::vector<std::int64_t> poseIds;
  poseIds.reserve(ds.poses.size());
  for (const auto& v : ds.poses) poseIds.push_back(v.id);
  std::sort(poseIds.begin(), poseIds.end());
  p.graph.reserve(ds.edges.size() + ds.equivalences.size());
  for (const auto& e : ds.edges) {
    FactorPtr f;
    try {
      f = makeFactor(e, neighboursInIdOrder(poseIds, e.from, e.to));
    } catch (const std::invalid_argument& ex) {
      throw std::invalid_argument(ds.path + ":" + std::to_string(e.line) + ": " + ex.what());
    }
    std::const_pointer_cast<Factor>(f)->setId(static_cast<FactorId>(e.index));
    p.graph.add(std::move(f));
  }
  for (const io::HypothesisGroup& g : ds.hypotheses) {
    AmbiguousGroup group;
    group.null = g.null;
    for (int i = 0; i < g.count; ++i) {
      const int f = g.firstEdge + i;
      // An alternative is never trusted, even between consecutive poses.
      auto factor = std::const_pointer_cast<Factor>(p.graph[f]);
      if (factor->role() == FactorRole::Odometry) factor->setRole(FactorRole::LoopClosure);
      group.factors.push_back(f);
    }
    p.ambiguous.push_back(std::move(group));
  }
  // TORO EQUIV: the two poses are one place. The file states it rather than measures it, so it
  // is trusted as odometry is: a robust variant never weighs it.
  for (const auto& [a, b] : ds.equivalences) {
    auto f = std::const_pointer_cast<Factor>(
        makeFactor(io::equivalenceEdge(a, b, p.graph.size()), /*odometry=*/true));
    f->setId(static_cast<FactorId>(p.graph.size()));
    p.graph.add(std::move(f));
  }
  return p;
}

AmbiguousFactor ambiguousFactor(const PoseGraphProblem& p, int group) {
  AmbiguousFactor a;
  a.id = static_cast<FactorId>(group);
  a.nullHypothesis = p.ambiguous[group].null;
  for (int f : p.ambiguous[group].factors) a.alternatives.push_back(p.graph[f]);
  return a;
}

std::vector<AmbiguousFactor> ambiguousFactors(const PoseGraphProblem& p) {
  std::vector<AmbiguousFactor> out;
  out.reserve(p.ambiguous.size());
  for (int g = 0; g < static_cast<int>(p.ambiguous.size()); ++g)
    out.push_back(ambiguousFactor(p, g));
  return out;
}

BackendUpdate wholeProblemUpdate(const PoseGraphProblem& p) {
  BackendUpdate all;
  std::vector<char> alternative(p.graph.size(), 0);
  for (const AmbiguousGroup& g : p.ambiguous)
    for (int f : g.factors) alternative[f] = 1;
  for (int f = 0; f < p.graph.size(); ++f)
    if (!alternative[f]) all.factors.push_back(p.graph[f]);
  all.ambiguous = ambiguousFactors(p);
  all.initial = p.initial;
  return all;
}

void storeEstimate(const Values& estimate, io::Dataset& ds) {
  auto store = [&](io::Vertex& v) {
    const int s = estimate.slot(vertexKey(v));
    if (s < 0) return;
    switch (v.type) {
      case io::VertexType::SE2: {
        const SE2 x = estimate.se2(s);
        v.value[0] = x.x;
        v.value[1] = x.y;
        v.value[2] = x.theta;
        break;
      }
      case io::VertexType::SE3:
        estimate.se3(s).toTranslationQuaternion(v.value.data());
        break;
      case io::VertexType::Point2:
      case io::VertexType::Point3: {
        const int d = v.type == io::VertexType::Point2 ? 2 : 3;
        for (int i = 0; i < d; ++i) v.value[i] = estimate.data(s)[i];
        break;
      }
    }
  };
  for (auto& v : ds.poses) store(v);
  for (auto& v : ds.landmarks) store(v);
}

}  // namespace loopd
