#include "tools/loopd-outliers/outlier_generator.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <random>
#include <stdexcept>

#include "tools/common/json_writer.h"
#include "tools/loopd-outliers/generator_util.h"

namespace loopd::tools {

const char* outlierModeName(OutlierMode m) {
  switch (m) {
    case OutlierMode::Random:
      return "random";
    case OutlierMode::Local:
      return "local";
    case OutlierMode::Group:
      return "group";
  }
  return "?";
}

OutlierMode outlierModeFromName(const std::string& n) {
  if (n == "random") return OutlierMode::Random;
  if (n == "local") return OutlierMode::Local;
  if (n == "group") return OutlierMode::Group;
  throw std::invalid_argument("--mode takes random, local or group, got '" + n + "'");
}

namespace {

// Rotation uniform, translation of uniform direction and length uniform in [0, L].
std::array<double, 7> uniformMeasurement(Rng& rng, bool is3d, double L) {
  std::array<double, 7> m{};
  const double len = rng.uniform(0.0, L);
  if (!is3d) {
    const double dir = rng.uniform(-M_PI, M_PI);
    m[0] = len * std::cos(dir);
    m[1] = len * std::sin(dir);
    m[2] = rng.uniform(-M_PI, M_PI);
    return m;
  }
  Eigen::Vector3d d(rng.normal(), rng.normal(), rng.normal());
  if (d.norm() < 1e-12) d = Eigen::Vector3d::UnitX();
  d = d.normalized() * len;
  Eigen::Vector4d q(rng.normal(), rng.normal(), rng.normal(), rng.normal());
  if (q.norm() < 1e-12) q = Eigen::Vector4d(0, 0, 0, 1);
  q.normalize();
  if (q[3] < 0) q = -q;
  return {d.x(), d.y(), d.z(), q[0], q[1], q[2], q[3]};
}

// generateDataset.py's measurement: near the identity, translation axes ~ N(0, 0.3 m), angles
// ~ N(0, 10°) (3D: yaw, pitch, roll, composed Z·Y·X), as a g2o measurement (x y θ, or
// x y z qx qy qz qw with qw ≥ 0).
std::array<double, 7> vertigoMeasurement(Rng& rng, bool is3d) {
  constexpr double kSigmaT = 0.3, kSigmaR = 10.0 * M_PI / 180.0;
  std::array<double, 7> m{};
  if (!is3d) {
    m[0] = kSigmaT * rng.normal();
    m[1] = kSigmaT * rng.normal();
    m[2] = kSigmaR * rng.normal();
    return m;
  }
  for (int k = 0; k < 3; ++k) m[k] = kSigmaT * rng.normal();
  const double yaw = kSigmaR * rng.normal(), pitch = kSigmaR * rng.normal(),
               roll = kSigmaR * rng.normal();
  Eigen::Quaterniond q = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()) *
                         Eigen::AngleAxisd(pitch, Eigen::Vector3d::UnitY()) *
                         Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitX());
  if (q.w() < 0) q.coeffs() = -q.coeffs();
  m[3] = q.x(), m[4] = q.y(), m[5] = q.z(), m[6] = q.w();
  return m;
}

}  // namespace

const char* outlierMeasurementName(OutlierMeasurement m) {
  return m == OutlierMeasurement::Vertigo ? "vertigo" : "uniform";
}

OutlierResult addOutliers(const io::Dataset& input, const OutlierOptions& opt) {
  if (opt.count < 0) throw std::invalid_argument("outlier count must be >= 0");
  if (opt.groupSize < 1) throw std::invalid_argument("group size must be >= 1");
  if (opt.localWindow < 2) throw std::invalid_argument("local window must be >= 2");
  std::vector<std::int64_t> ids;
  for (const auto& v : input.poses) ids.push_back(v.id);
  std::sort(ids.begin(), ids.end());
  const std::int64_t n = static_cast<std::int64_t>(ids.size());
  const int groupSize = opt.mode == OutlierMode::Group ? opt.groupSize : 1;
  // A group's pairs are (a + j, b + j), j < K, with b >= a + 2 and b + K - 1 <= n - 1: the
  // smallest graph that holds one is a = 0, b = 2, n = K + 2 (n = 3 for a single pair).
  if (n < groupSize + 2)
    throw std::invalid_argument("too few poses for outliers: " + std::to_string(n) + ", " +
                                (opt.mode == OutlierMode::Group
                                     ? "groups of " + std::to_string(groupSize) + " need "
                                     : std::string("a pair needs ")) +
                                std::to_string(groupSize + 2));

  // The dataset's loop-closure scale and information.
  std::vector<const io::Edge*> loops, betweens;
  for (const auto& e : input.edges) {
    if (isBetween(e)) betweens.push_back(&e);
    if (isLoop(e)) loops.push_back(&e);
  }
  const std::vector<const io::Edge*>& ref = loops.empty() ? betweens : loops;
  if (ref.empty()) throw std::invalid_argument("dataset has no between edges");
  const bool is3d = ref.front()->type == io::EdgeType::BetweenSE3;
  const int dim = is3d ? 6 : 3;
  std::vector<double> lengths;
  std::vector<std::pair<double, const io::Edge*>> traces;
  for (const io::Edge* e : ref) {
    lengths.push_back(translationNorm(*e));
    traces.emplace_back(e->information.topLeftCorner(dim, dim).trace(), e);
  }
  double L = median(lengths);
  if (!(L > 1e-6)) {
    lengths.clear();
    for (const io::Edge* e : betweens) lengths.push_back(translationNorm(*e));
    L = std::max(1.0, median(lengths));
  }
  std::sort(traces.begin(), traces.end(),
            [](const auto& a, const auto& b) { return a.first < b.first; });
  const Eigen::Matrix<double, 6, 6> information = traces[traces.size() / 2].second->information;

  OutlierResult out;
  out.graph = input;
  out.inlierEdges = static_cast<int>(input.edges.size());
  Rng rng(opt.seed);
  const std::int64_t span = groupSize - 1;  // the group's last pair is (a + span, b + span)
  int made = 0;
  while (made < opt.count) {
    std::int64_t a, b;
    const bool local =
        opt.mode == OutlierMode::Local || (opt.mode == OutlierMode::Group && opt.localGroups);
    if (local) {
      a = rng.integer(0, n - 3 - span);
      b = a + rng.integer(2, opt.localWindow);
      if (b + span > n - 1) b = n - 1 - span;
      if (b < a + 2) continue;
    } else {
      a = rng.integer(0, n - 3 - span);
      b = rng.integer(a + 2, n - 1 - span);
    }
    // One measurement for the whole group.
    const std::array<double, 7> m = opt.measurement == OutlierMeasurement::Vertigo
                                        ? vertigoMeasurement(rng, is3d)
                                        : uniformMeasurement(rng, is3d, L);
    const int k = std::min(groupSize, opt.count - made);
    for (int j = 0; j < k; ++j) {
      io::Edge e;
      e.type = is3d ? io::EdgeType::BetweenSE3 : io::EdgeType::BetweenSE2;
      e.from = ids[a + j];
      e.to = ids[b + j];
      e.measurement = m;
      e.information = information;
      e.line = 0;
      e.index = static_cast<int>(out.graph.edges.size());
      out.outliers.push_back(e.index);
      out.graph.edges.push_back(e);
      ++made;
    }
  }
  return out;
}

std::string outlierTruthJson(const std::string& inputPath, const OutlierOptions& opt,
                             const OutlierResult& r) {
  std::vector<std::int64_t> outliers(r.outliers.begin(), r.outliers.end());
  JsonObject o;
  o.add("input", inputPath)
      .add("mode", outlierModeName(opt.mode))
      .add("count", opt.count)
      .add("seed", static_cast<std::int64_t>(opt.seed))
      .add("group_size", opt.mode == OutlierMode::Group ? opt.groupSize : 1)
      .add("measurement", outlierMeasurementName(opt.measurement))
      .add("outliers", outliers)
      .add("inlier_edges", r.inlierEdges);
  return o.str();
}

}  // namespace loopd::tools
