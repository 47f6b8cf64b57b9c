#include "tools/loopd-eval/trajectory_metrics.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <map>
#include <sstream>
#include <stdexcept>
#include <unordered_map>
#include <unordered_set>

#include "solvers/problem/pose_graph_problem.h"
#include "tools/loopd-eval/json_input.h"

namespace loopd::tools {

namespace {

Eigen::Isometry3d poseOf(const io::Vertex& v) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  if (v.type == io::VertexType::SE2) {
    T.linear() = Eigen::AngleAxisd(v.value[2], Eigen::Vector3d::UnitZ()).toRotationMatrix();
    T.translation() = Eigen::Vector3d(v.value[0], v.value[1], 0.0);
  } else {
    Eigen::Quaterniond q(v.value[6], v.value[3], v.value[4], v.value[5]);
    T.linear() = q.normalized().toRotationMatrix();
    T.translation() = Eigen::Vector3d(v.value[0], v.value[1], v.value[2]);
  }
  return T;
}

double rotationAngle(const Eigen::Matrix3d& R) {
  const double c = std::clamp((R.trace() - 1.0) * 0.5, -1.0, 1.0);
  return std::acos(c);
}

}  // namespace

TrajectoryErrors trajectoryErrors(const io::Dataset& reference, const io::Dataset& estimate) {
  const std::string refName = reference.path.empty() ? "the reference" : reference.path;
  const std::string estName = estimate.path.empty() ? "the estimate" : estimate.path;
  std::map<std::int64_t, const io::Vertex*> ref;
  for (const auto& v : reference.poses) ref[v.id] = &v;
  std::vector<std::int64_t> ids;
  std::map<std::int64_t, const io::Vertex*> est;
  for (const auto& v : estimate.poses) est[v.id] = &v;
  // Scoring only the shared poses would hide a partial estimate or another dataset's.
  size_t missing = 0, extra = 0;
  std::int64_t firstMissing = 0, firstExtra = 0;
  for (const auto& [id, v] : ref) {
    if (est.count(id))
      ids.push_back(id);
    else if (missing++ == 0)
      firstMissing = id;
  }
  for (const auto& [id, v] : est)
    if (!ref.count(id) && extra++ == 0) firstExtra = id;
  if (missing)
    throw std::invalid_argument(estName + " lacks " + std::to_string(missing) + " of the " +
                                std::to_string(ref.size()) + " poses of " + refName +
                                " (first missing: id " + std::to_string(firstMissing) + ")");
  if (extra)
    throw std::invalid_argument(estName + " has " + std::to_string(extra) + " poses " + refName +
                                " lacks (first: id " + std::to_string(firstExtra) +
                                "): not an estimate of the same graph");
  if (ids.size() < 2) throw std::invalid_argument("reference and estimate share < 2 poses");
  const bool is3d = ref[ids[0]]->type == io::VertexType::SE3;
  auto dim = [](const io::Vertex* v) { return v->type == io::VertexType::SE3 ? "3D" : "2D"; };
  for (std::int64_t id : ids) {
    const bool r3 = ref[id]->type == io::VertexType::SE3, e3 = est[id]->type == io::VertexType::SE3;
    if (r3 != e3)
      throw std::invalid_argument("reference and estimate mix 2D and 3D poses: pose " +
                                  std::to_string(id) + " is " + dim(ref[id]) + " in " + refName +
                                  ", " + dim(est[id]) + " in " + estName);
    if (r3 != is3d)
      throw std::invalid_argument(refName + " mixes 2D and 3D poses: pose " +
                                  std::to_string(ids[0]) + " is " + dim(ref[ids[0]]) + ", pose " +
                                  std::to_string(id) + " " + dim(ref[id]));
  }

  const int n = static_cast<int>(ids.size());
  std::vector<Eigen::Isometry3d> R(n), E(n);
  for (int i = 0; i < n; ++i) R[i] = poseOf(*ref[ids[i]]), E[i] = poseOf(*est[ids[i]]);

  TrajectoryErrors out;
  out.poses = n;
  const int d = is3d ? 3 : 2;
  Eigen::MatrixXd src(d, n), dst(d, n);
  for (int i = 0; i < n; ++i) {
    src.col(i) = E[i].translation().head(d);
    dst.col(i) = R[i].translation().head(d);
  }
  const Eigen::MatrixXd T = Eigen::umeyama(src, dst, false);
  const Eigen::MatrixXd A = T.topLeftCorner(d, d);
  const Eigen::VectorXd b = T.topRightCorner(d, 1);
  double sum = 0.0;
  for (int i = 0; i < n; ++i) {
    const double e = (A * src.col(i) + b - dst.col(i)).norm();
    sum += e * e;
    out.ateMax = std::max(out.ateMax, e);
  }
  out.ateRmse = std::sqrt(sum / n);

  double st = 0.0, sr = 0.0;
  for (int i = 0; i + 1 < n; ++i) {
    const Eigen::Isometry3d dr = R[i].inverse() * R[i + 1];
    const Eigen::Isometry3d de = E[i].inverse() * E[i + 1];
    const Eigen::Isometry3d err = dr.inverse() * de;
    st += err.translation().norm();
    sr += rotationAngle(err.linear());
    ++out.rpePairs;
  }
  if (out.rpePairs > 0) {
    out.rpeTrans = st / out.rpePairs;
    out.rpeRotDeg = sr / out.rpePairs * 180.0 / M_PI;
  }
  return out;
}

DecisionScores scoreRejections(const std::vector<std::int64_t>& rejected,
                               const std::vector<std::int64_t>& outliers) {
  const std::unordered_set<std::int64_t> truth(outliers.begin(), outliers.end());
  const std::unordered_set<std::int64_t> rej(rejected.begin(), rejected.end());
  DecisionScores s;
  for (std::int64_t id : rej) (truth.count(id) ? s.truePositives : s.falsePositives)++;
  for (std::int64_t id : truth)
    if (!rej.count(id)) ++s.falseNegatives;
  if (!rej.empty()) s.precision = static_cast<double>(s.truePositives) / rej.size();
  if (!truth.empty()) s.recall = static_cast<double>(s.truePositives) / truth.size();
  return s;
}

double inlierChi2(const io::Dataset& graph, const io::Dataset& estimate,
                  const std::vector<std::int64_t>& outliers) {
  io::Dataset g = graph;
  std::unordered_map<std::int64_t, const io::Vertex*> poses, landmarks;
  for (const auto& v : estimate.poses) poses[v.id] = &v;
  for (const auto& v : estimate.landmarks) landmarks[v.id] = &v;
  for (auto& v : g.poses) {
    auto it = poses.find(v.id);
    if (it == poses.end())
      throw std::invalid_argument("estimate lacks pose " + std::to_string(v.id));
    v.value = it->second->value;
  }
  for (auto& v : g.landmarks) {
    auto it = landmarks.find(v.id);
    if (it != landmarks.end()) v.value = it->second->value;
  }
  const PoseGraphProblem p = buildProblem(g);
  const std::unordered_set<std::int64_t> skip(outliers.begin(), outliers.end());
  double chi2 = 0.0;
  for (const auto& f : p.graph.factors()) {
    const auto id = static_cast<std::int64_t>(f->id());
    if (id < static_cast<std::int64_t>(g.edges.size()) && !skip.count(id))
      chi2 += f->chi2(p.initial);
  }
  return chi2;
}

io::Dataset readVertices(const std::string& path) {
  std::istringstream in(readTextFile(path));
  io::Dataset d;
  d.path = path;
  d.format = "g2o";
  d.hadVertices = true;
  std::string line;
  int lineNo = 0;
  std::unordered_map<std::int64_t, int> poseLines, landmarkLines;
  while (std::getline(in, line)) {
    ++lineNo;
    std::istringstream ls(line);
    std::string tag;
    if (!(ls >> tag)) continue;
    io::Vertex v;
    int n = 0;
    if (tag == "VERTEX_SE2")
      v.type = io::VertexType::SE2, n = 3;
    else if (tag == "VERTEX_SE3:QUAT")
      v.type = io::VertexType::SE3, n = 7;
    else if (tag == "VERTEX_XY")
      v.type = io::VertexType::Point2, n = 2;
    else if (tag == "VERTEX_TRACKXYZ")
      v.type = io::VertexType::Point3, n = 3;
    else
      continue;
    ls >> v.id;
    for (int k = 0; k < n; ++k) ls >> v.value[k];
    if (!ls) throw std::runtime_error(path + ":" + std::to_string(lineNo) + ": malformed " + tag);
    v.line = lineNo;
    auto& seen = v.isLandmark() ? landmarkLines : poseLines;
    const auto [it, fresh] = seen.emplace(v.id, lineNo);
    if (!fresh)
      throw std::runtime_error(path + ":" + std::to_string(lineNo) + ": " +
                               (v.isLandmark() ? "landmark" : "pose") + " id " +
                               std::to_string(v.id) + " given twice (first on line " +
                               std::to_string(it->second) + ")");
    if (v.isLandmark())
      d.landmarks.push_back(v);
    else
      d.poses.push_back(v);
    if (v.type == io::VertexType::SE3) d.is3d = true;
  }
  return d;
}

}  // namespace loopd::tools
