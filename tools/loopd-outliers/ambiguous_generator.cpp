#include "tools/loopd-outliers/ambiguous_generator.h"

#include <Eigen/Cholesky>
#include <Eigen/Geometry>
#include <algorithm>
#include <stdexcept>
#include <unordered_map>
#include <unordered_set>

#include "tools/common/json_writer.h"
#include "tools/loopd-outliers/generator_util.h"

namespace loopd::tools {

namespace {

constexpr double kDeg = M_PI / 180.0;

bool isSighting(const io::Edge& e) { return !isBetween(e); }

/// Everything a decoy needs to know about the dataset.
struct Context {
  std::vector<std::int64_t> poseIds;                         // sorted
  std::unordered_map<std::int64_t, std::int64_t> rank;       // pose id → index in poseIds
  std::unordered_map<std::int64_t, std::int64_t> firstSeen;  // landmark → earliest pose rank
  std::unordered_map<std::int64_t, Eigen::Vector3d> landmarkAt;
  std::unordered_map<std::int64_t, Eigen::Vector4d> poseAt;  // x y z heading (file estimate)
  double shift = 1.0;  // measurement decoys: base translation change (m)
};

Context makeContext(const io::Dataset& in) {
  Context c;
  for (const auto& v : in.poses) c.poseIds.push_back(v.id);
  std::sort(c.poseIds.begin(), c.poseIds.end());
  for (size_t i = 0; i < c.poseIds.size(); ++i) c.rank[c.poseIds[i]] = static_cast<std::int64_t>(i);
  for (const auto& v : in.poses) {
    // Heading: SE2 θ; SE3 the yaw of the quaternion (only used to tell places apart).
    const double heading =
        v.type == io::VertexType::SE2
            ? v.value[2]
            : std::atan2(2.0 * (v.value[6] * v.value[5] + v.value[3] * v.value[4]),
                         1.0 - 2.0 * (v.value[4] * v.value[4] + v.value[5] * v.value[5]));
    c.poseAt[v.id] = Eigen::Vector4d(v.value[0], v.value[1],
                                     v.type == io::VertexType::SE3 ? v.value[2] : 0.0, heading);
  }
  for (const auto& v : in.landmarks)
    c.landmarkAt[v.id] = Eigen::Vector3d(v.value[0], v.value[1],
                                         v.type == io::VertexType::Point3 ? v.value[2] : 0.0);
  std::vector<double> lengths;
  for (const auto& e : in.edges) {
    if (isLoop(e)) lengths.push_back(translationNorm(e));
    if (isSighting(e)) {
      const std::int64_t r = c.rank.at(e.from);
      auto [it, inserted] = c.firstSeen.emplace(e.to, r);
      if (!inserted) it->second = std::min(it->second, r);
    }
  }
  if (!lengths.empty()) c.shift = std::max(1.0, median(lengths));
  return c;
}

bool eligible(const io::Edge& e, const Context& c, bool landmarks) {
  if (!landmarks) return isLoop(e);
  // A re-sighting: the landmark must already exist when the group joins.
  return isSighting(e) && c.firstSeen.at(e.to) < c.rank.at(e.from);
}

/// Same keys, wrong measurement.
io::Edge measurementDecoy(const io::Edge& truth, const Context& c, Rng& rng) {
  io::Edge d = truth;
  auto& m = d.measurement;
  const double len = rng.uniform(0.5, 2.0) * c.shift;
  const double turn = rng.sign() * rng.uniform(10.0, 45.0) * kDeg;
  switch (truth.type) {
    case io::EdgeType::BetweenSE2: {
      const double dir = rng.uniform(-M_PI, M_PI);
      m[0] += len * std::cos(dir);
      m[1] += len * std::sin(dir);
      m[2] = std::remainder(m[2] + turn, 2.0 * M_PI);
      break;
    }
    case io::EdgeType::BetweenSE3: {
      Eigen::Vector3d dir(rng.normal(), rng.normal(), rng.normal());
      if (dir.norm() < 1e-12) dir = Eigen::Vector3d::UnitX();
      Eigen::Vector3d axis(rng.normal(), rng.normal(), rng.normal());
      if (axis.norm() < 1e-12) axis = Eigen::Vector3d::UnitZ();
      const Eigen::Vector3d t = Eigen::Vector3d(m[0], m[1], m[2]) + dir.normalized() * len;
      Eigen::Quaterniond q(m[6], m[3], m[4], m[5]);
      q = (q * Eigen::Quaterniond(Eigen::AngleAxisd(turn, axis.normalized()))).normalized();
      if (q.w() < 0) q.coeffs() = -q.coeffs();
      m = {t.x(), t.y(), t.z(), q.x(), q.y(), q.z(), q.w()};
      break;
    }
    case io::EdgeType::PosePoint2:
    case io::EdgeType::PosePoint3: {
      Eigen::Vector3d dir(rng.normal(), rng.normal(),
                          truth.type == io::EdgeType::PosePoint3 ? rng.normal() : 0.0);
      if (dir.norm() < 1e-12) dir = Eigen::Vector3d::UnitX();
      dir = dir.normalized() * len;
      for (int i = 0; i < (truth.type == io::EdgeType::PosePoint3 ? 3 : 2); ++i) m[i] += dir[i];
      break;
    }
    case io::EdgeType::BearingRange2:
      m[0] = std::remainder(m[0] + turn, 2.0 * M_PI);
      m[1] = std::max(0.1, m[1] + rng.sign() * len);
      break;
  }
  return d;
}

/// Same keys, a measurement δ ∈ [2, 4] standard deviations away: e = δ·L⁻ᵀu for Ω = LLᵀ and
/// a random unit u, so eᵀΩe = δ², applied on the measurement's tangent (m·Exp(e) for poses).
io::Edge aliasedDecoy(const io::Edge& truth, Rng& rng) {
  io::Edge d = truth;
  auto& m = d.measurement;
  const int dim = truth.type == io::EdgeType::BetweenSE3   ? 6
                  : truth.type == io::EdgeType::BetweenSE2 ? 3
                  : truth.type == io::EdgeType::PosePoint3 ? 3
                                                           : 2;
  const Eigen::MatrixXd omega = truth.information.topLeftCorner(dim, dim);
  Eigen::VectorXd u(dim);
  for (int i = 0; i < dim; ++i) u[i] = rng.normal();
  if (u.norm() < 1e-12) u[0] = 1.0;
  u *= rng.uniform(2.0, 4.0) / u.norm();
  const Eigen::LLT<Eigen::MatrixXd> llt(omega);
  const Eigen::VectorXd e = llt.matrixU().solve(u);  // Lᵀe = u
  switch (truth.type) {
    case io::EdgeType::BetweenSE2: {  // m·(e_t, e_θ): the residual's own (local) frame
      const double c = std::cos(m[2]), s = std::sin(m[2]);
      m[0] += c * e[0] - s * e[1];
      m[1] += s * e[0] + c * e[1];
      m[2] = std::remainder(m[2] + e[2], 2.0 * M_PI);
      break;
    }
    case io::EdgeType::BetweenSE3: {
      const Eigen::Vector3d w = e.tail<3>();
      Eigen::Quaterniond q(m[6], m[3], m[4], m[5]);
      const Eigen::Vector3d t = q * Eigen::Vector3d(e.head<3>());
      for (int i = 0; i < 3; ++i) m[i] += t[i];
      if (w.norm() > 1e-15) q = q * Eigen::Quaterniond(Eigen::AngleAxisd(w.norm(), w.normalized()));
      q.normalize();
      if (q.w() < 0) q.coeffs() = -q.coeffs();
      m[3] = q.x(), m[4] = q.y(), m[5] = q.z(), m[6] = q.w();
      break;
    }
    case io::EdgeType::PosePoint2:
    case io::EdgeType::PosePoint3:
      for (int i = 0; i < dim; ++i) m[i] += e[i];
      break;
    case io::EdgeType::BearingRange2:
      m[0] = std::remainder(m[0] + e[0], 2.0 * M_PI);
      m[1] = std::max(0.1, m[1] + e[1]);
      break;
  }
  return d;
}

/// Same measurement, wrong target near the true one; false when none is free.
bool targetDecoy(const io::Edge& truth, const Context& c, int window,
                 std::unordered_set<std::int64_t>& used, Rng& rng, io::Edge& out) {
  out = truth;
  if (isSighting(truth)) {
    // Another landmark seen before this pose, among the nearest to the true one.
    const std::int64_t pose = c.rank.at(truth.from);
    const Eigen::Vector3d at = c.landmarkAt.at(truth.to);
    std::vector<std::pair<double, std::int64_t>> near;
    for (const auto& [id, seen] : c.firstSeen)
      if (seen < pose && !used.count(id)) near.emplace_back((c.landmarkAt.at(id) - at).norm(), id);
    if (near.empty()) return false;
    const size_t pool = std::min<size_t>(near.size(), 4);
    std::partial_sort(near.begin(), near.begin() + pool, near.end());
    out.to = near[rng.integer(0, static_cast<std::int64_t>(pool) - 1)].second;
    used.insert(out.to);
    return true;
  }
  // Loop closure: move the older end; stay at least 2 poses below the newer end so the group
  // joins when the true closure would have.
  const bool fromOlder = c.rank.at(truth.from) < c.rank.at(truth.to);
  const std::int64_t older = c.rank.at(fromOlder ? truth.from : truth.to);
  const std::int64_t newer = c.rank.at(fromOlder ? truth.to : truth.from);
  for (int attempt = 0; attempt < 50; ++attempt) {
    const std::int64_t r = older + static_cast<std::int64_t>(rng.sign()) * rng.integer(2, window);
    if (r < 0 || r > newer - 2) continue;
    const std::int64_t id = c.poseIds[r];
    if (used.count(id)) continue;
    // A pose at the true target's place is a revisit, not a decoy: it must be wrong.
    const Eigen::Vector4d a = c.poseAt.at(id), b = c.poseAt.at(c.poseIds[older]);
    if ((a.head<3>() - b.head<3>()).norm() < 0.5 * c.shift &&
        std::abs(std::remainder(a[3] - b[3], 2.0 * M_PI)) < 10.0 * kDeg)
      continue;
    used.insert(id);
    (fromOlder ? out.from : out.to) = id;
    return true;
  }
  return false;
}

}  // namespace

const char* decoyModeName(DecoyMode m) {
  switch (m) {
    case DecoyMode::Target:
      return "target";
    case DecoyMode::Measurement:
      return "measurement";
    case DecoyMode::Mixed:
      return "mixed";
    case DecoyMode::Aliased:
      return "aliased";
  }
  return "?";
}

DecoyMode decoyModeFromName(const std::string& n) {
  if (n == "target") return DecoyMode::Target;
  if (n == "measurement") return DecoyMode::Measurement;
  if (n == "mixed") return DecoyMode::Mixed;
  if (n == "aliased") return DecoyMode::Aliased;
  throw std::invalid_argument("--decoys takes target, measurement, mixed or aliased, got '" + n +
                              "'");
}

AmbiguousResult makeAmbiguous(const io::Dataset& input, const AmbiguousOptions& opt) {
  if (opt.count < 0) throw std::invalid_argument("ambiguous count must be >= 0");
  if (opt.alternatives < 2) throw std::invalid_argument("alternatives must be >= 2");
  if (opt.window < 2) throw std::invalid_argument("decoy window must be >= 2");
  if (!input.hypotheses.empty())
    throw std::invalid_argument("the input already has HYPOTHESES groups");
  const Context c = makeContext(input);
  std::vector<int> candidates;
  for (const auto& e : input.edges)
    if (eligible(e, c, opt.landmarks)) candidates.push_back(e.index);
  if (static_cast<int>(candidates.size()) < opt.count)
    throw std::invalid_argument("the dataset has " + std::to_string(candidates.size()) + " " +
                                (opt.landmarks ? "landmark re-sightings" : "loop closures") +
                                ", fewer than " + std::to_string(opt.count) + " asked for");
  Rng rng(opt.seed);
  // N distinct edges, uniformly (partial Fisher–Yates).
  for (int i = 0; i < opt.count; ++i)
    std::swap(candidates[i],
              candidates[rng.integer(i, static_cast<std::int64_t>(candidates.size()) - 1)]);
  std::vector<char> chosen(input.edges.size(), 0);
  for (int i = 0; i < opt.count; ++i) chosen[candidates[i]] = 1;

  AmbiguousResult out;
  out.graph = input;
  out.graph.edges.clear();
  auto push = [&](io::Edge e) {
    e.index = static_cast<int>(out.graph.edges.size());
    out.graph.edges.push_back(e);
    return e.index;
  };
  for (const io::Edge& e : input.edges) {
    if (!chosen[e.index]) {
      push(e);
      continue;
    }
    io::HypothesisGroup g;
    g.firstEdge = static_cast<int>(out.graph.edges.size());
    g.count = opt.alternatives;
    g.null = opt.null;
    g.line = e.line;
    const int truePosition = static_cast<int>(rng.integer(0, opt.alternatives - 1));
    std::unordered_set<std::int64_t> used = {
        isSighting(e) ? e.to : (c.rank.at(e.from) < c.rank.at(e.to) ? e.from : e.to)};
    for (int a = 0; a < opt.alternatives; ++a) {
      if (a == truePosition) {
        out.trueEdges.push_back(push(e));
        continue;
      }
      io::Edge decoy;
      const bool wantTarget = opt.decoys == DecoyMode::Target ||
                              (opt.decoys == DecoyMode::Mixed && rng.uniform() < 0.5);
      if (opt.decoys == DecoyMode::Aliased)
        decoy = aliasedDecoy(e, rng);
      else if (!(wantTarget && targetDecoy(e, c, opt.window, used, rng, decoy)))
        decoy = measurementDecoy(e, c, rng);
      out.decoys.push_back(push(decoy));
    }
    out.trueChoice.push_back(truePosition);
    out.graph.hypotheses.push_back(g);
  }
  return out;
}

std::string ambiguousTruthJson(const std::string& inputPath, const AmbiguousOptions& opt,
                               const AmbiguousResult& r) {
  auto ints = [](const std::vector<int>& v) {
    return std::vector<std::int64_t>(v.begin(), v.end());
  };
  JsonObject o;
  o.add("input", inputPath)
      .add("mode", "ambiguous")
      .add("count", opt.count)
      .add("alternatives", opt.alternatives)
      .add("null", opt.null)
      .add("decoys", decoyModeName(opt.decoys))
      .add("seed", static_cast<std::int64_t>(opt.seed))
      .add("outliers", ints(r.decoys))
      .add("true_choice", ints(r.trueChoice))
      .add("true_edges", ints(r.trueEdges));
  return o.str();
}

}  // namespace loopd::tools
