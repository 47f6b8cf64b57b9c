#include "solvers/init/initialization.h"

#include <cmath>
#include <deque>
#include <map>
#include <stdexcept>

#include "solvers/factors/between_factor_se2.h"
#include "solvers/factors/between_factor_se3.h"
#include "solvers/factors/landmark_factors.h"
#include "solvers/init/breadth_first.h"
#include "solvers/init/common_frame.h"
#include "solvers/init/landmark_headings.h"
#include "solvers/init/sparse_normal_solve.h"

namespace loopd {

namespace {

// Unknowns of a linear initialisation problem: `dim` scalars per free variable; the anchor
// (and anything not connected) is known.
using LinearUnknowns = ReachableUnknowns;

// Adds w·(x_j − A·x_i − c) residual blocks of size D to normal equations, with x_i/x_j
// either unknown (index ≥ 0) or known (value taken from `known`).
template <int D>
struct BlockNormalEquations {
  InitTriplets triplets;
  Eigen::MatrixXd rhs;  // count × columns
  const LinearUnknowns& u;
  BlockNormalEquations(const LinearUnknowns& unknowns, int columns)
      : rhs(Eigen::MatrixXd::Zero(unknowns.count, columns)), u(unknowns) {}

  using MatD = Eigen::Matrix<double, D, D>;
  using RowsD = Eigen::Matrix<double, D, Eigen::Dynamic>;
  // Residual  x_j − A x_i − c  (c: D×columns), weight W (D×D, symmetric PSD).
  void add(int si, int sj, const MatD& A, const RowsD& c, const MatD& W, const RowsD& knownI,
           const RowsD& knownJ) {
    const int ii = u.index[si], jj = u.index[sj];
    // J_i = −A, J_j = I.
    const MatD Hii = A.transpose() * W * A, Hjj = W, Hij = -A.transpose() * W;
    RowsD c2 = c;
    if (ii < 0) c2 += A * knownI;
    if (jj < 0) c2 -= knownJ;
    if (ii >= 0) {
      addBlock(ii, ii, Hii);
      rhs.middleRows<D>(ii) += -A.transpose() * W * c2;  // −J_iᵀ W (−c2) = Aᵀ… sign below
    }
    if (jj >= 0) {
      addBlock(jj, jj, Hjj);
      rhs.middleRows<D>(jj) += W * c2;
    }
    if (ii >= 0 && jj >= 0) {
      addBlock(ii, jj, Hij);
      addBlock(jj, ii, Hij.transpose());
    }
  }
  void addBlock(int r, int c, const MatD& M) {
    for (int a = 0; a < D; ++a)
      for (int b = 0; b < D; ++b)
        if (M(a, b) != 0.0) triplets.emplace_back(r + a, c + b, M(a, b));
  }
  Eigen::MatrixXd solve() const { return solveNormalEquations(u.count, triplets, rhs); }
};

// Breadth-first reachability from the anchor over between and pose–point factors, so
// variables in other components stay known (at their guess) and the systems stay regular.
LinearUnknowns numberConnected(const FactorGraph& graph, const Values& values, int anchorSlot,
                               bool posesOnly, int dim) {
  return numberReachable(
      graph, values, anchorSlot,
      [posesOnly](const Factor& f) { return !posesOnly || keyKind(f.key(1)) == KeyKind::Pose; },
      [dim](int) { return dim; });
}

// Orientation of every pose along a breadth-first spanning tree (odometry first), used only
// to pick each edge's multiple of 2π.
std::vector<double> treeOrientations(const FactorGraph& graph, const Values& values,
                                     int anchorSlot) {
  struct Arc {
    int to;
    double dtheta;
    bool odometry;
  };
  std::vector<std::vector<Arc>> adj(values.size());
  for (const auto& f : graph.factors()) {
    const auto* b = dynamic_cast<const BetweenFactorSE2*>(f.get());
    if (!b) continue;
    const int i = values.slot(b->key(0)), j = values.slot(b->key(1));
    const bool odo = b->role() == FactorRole::Odometry;
    adj[i].push_back({j, b->measured().theta, odo});
    adj[j].push_back({i, -b->measured().theta, odo});
  }
  for (auto& a : adj)
    std::stable_partition(a.begin(), a.end(), [](const Arc& x) { return x.odometry; });
  std::vector<double> theta(values.size(), 0.0);
  for (int s = 0; s < values.size(); ++s)
    if (values.type(s) == VarType::SE2) theta[s] = values.se2(s).theta;
  std::vector<char> seen(values.size(), 0);
  std::deque<int> queue{anchorSlot};
  seen[anchorSlot] = 1;
  theta[anchorSlot] = values.se2(anchorSlot).theta;
  while (!queue.empty()) {
    const int s = queue.front();
    queue.pop_front();
    for (const Arc& a : adj[s])
      if (!seen[a.to]) {
        seen[a.to] = 1;
        theta[a.to] = theta[s] + a.dtheta;
        queue.push_back(a.to);
      }
  }
  return theta;
}

int anchorSlotOf(const Values& values, Key anchor) {
  const int s = values.slot(anchor);
  if (s < 0)
    throw std::invalid_argument("initialisation anchor " + keyToString(anchor) + " missing");
  return s;
}

}  // namespace

Values initializeOrientationFirst2D(const FactorGraph& graph, const Values& guess, Key anchor) {
  const int anchorSlot = anchorSlotOf(guess, anchor);
  Values out = guess;

  // 1) Orientations: θj − θi = zθ + 2πk, k from the spanning tree.
  const std::vector<double> tree = treeOrientations(graph, guess, anchorSlot);
  const LinearUnknowns ut = numberConnected(graph, guess, anchorSlot, true, 1);
  BlockNormalEquations<1> angles(ut, 1);
  for (const auto& f : graph.factors()) {
    const auto* b = dynamic_cast<const BetweenFactorSE2*>(f.get());
    if (!b) continue;
    const int i = guess.slot(b->key(0)), j = guess.slot(b->key(1));
    const double z = b->measured().theta;
    const double k = std::round((tree[j] - tree[i] - z) / (2.0 * M_PI));
    Eigen::Matrix<double, 1, Eigen::Dynamic> c(1, 1), ki(1, 1), kj(1, 1);
    c(0, 0) = z + 2.0 * M_PI * k;
    ki(0, 0) = tree[i];
    kj(0, 0) = tree[j];
    Eigen::Matrix<double, 1, 1> W;
    W(0, 0) = b->information()(2, 2);
    angles.add(i, j, Eigen::Matrix<double, 1, 1>::Identity(), c, W, ki, kj);
  }
  std::vector<double> theta = tree;
  if (ut.count > 0) {
    const Eigen::MatrixXd sol = angles.solve();
    for (int s = 0; s < guess.size(); ++s)
      if (ut.index[s] >= 0) theta[s] = sol(ut.index[s], 0);
  }
  // Landmark re-sightings correct headings that between factors alone dead-reckon. A graph
  // the relaxation cannot fix (a pose held by one sighting only) keeps these headings.
  if (hasPointSightings2D(graph)) {
    try {
      theta = landmarkAidedHeadings2D(graph, guess, anchorSlot, theta);
    } catch (const std::runtime_error&) {
    }
  }

  // 2) Positions (and landmarks): tj − ti = R(θi)·tz with the rotated translation weight.
  const LinearUnknowns up = numberConnected(graph, guess, anchorSlot, false, 2);
  BlockNormalEquations<2> pos(up, 1);
  auto position = [&](int s) -> Eigen::Matrix<double, 2, Eigen::Dynamic> {
    return Eigen::Map<const Vec2>(guess.data(s));
  };
  for (const auto& f : graph.factors()) {
    if (f->size() != 2) continue;
    const int i = guess.slot(f->key(0)), j = guess.slot(f->key(1));
    Vec2 z;
    Mat2 info;
    if (const auto* b = dynamic_cast<const BetweenFactorSE2*>(f.get())) {
      z = b->measured().t();
      info = b->information().topLeftCorner<2, 2>();
    } else if (const auto* p = dynamic_cast<const PosePointFactor2*>(f.get())) {
      z = p->measured();
      info = Mat2::Identity();
    } else {
      continue;
    }
    const Mat2 R = rot2(theta[i]);
    const Mat2 W = R * info * R.transpose();
    pos.add(i, j, Mat2::Identity(), R * z, W, position(i), position(j));
  }
  if (up.count > 0) {
    const Eigen::MatrixXd sol = pos.solve();
    for (int s = 0; s < guess.size(); ++s)
      if (up.index[s] >= 0) {
        double* d = out.data(s);
        d[0] = sol(up.index[s], 0);
        d[1] = sol(up.index[s] + 1, 0);
      }
  }
  for (int s = 0; s < guess.size(); ++s)
    if (guess.type(s) == VarType::SE2) out.data(s)[2] = wrapAngle(theta[s]);
  return out;
}

Values initializeChordal3D(const FactorGraph& graph, const Values& guess, Key anchor) {
  const int anchorSlot = anchorSlotOf(guess, anchor);
  Values out = guess;

  // 1) Rotations: for each row a of R, a_j = R_ijᵀ a_i; all three rows share one matrix.
  const LinearUnknowns ur = numberConnected(graph, guess, anchorSlot, true, 3);
  BlockNormalEquations<3> rot(ur, 3);
  auto rowsOf = [&](int s) -> Eigen::Matrix<double, 3, Eigen::Dynamic> {
    return guess.se3(s).R.transpose();  // column k = row k of R
  };
  for (const auto& f : graph.factors()) {
    const auto* b = dynamic_cast<const BetweenFactorSE3*>(f.get());
    if (!b) continue;
    const int i = guess.slot(b->key(0)), j = guess.slot(b->key(1));
    const double w = b->information().bottomRightCorner<3, 3>().trace() / 3.0;
    rot.add(i, j, b->measured().R.transpose(), Eigen::Matrix3d::Zero(), Mat3::Identity() * w,
            rowsOf(i), rowsOf(j));
  }
  std::vector<Mat3> R(guess.size(), Mat3::Identity());
  for (int s = 0; s < guess.size(); ++s)
    if (guess.type(s) == VarType::SE3) R[s] = guess.se3(s).R;
  if (ur.count > 0) {
    const Eigen::MatrixXd sol = rot.solve();
    for (int s = 0; s < guess.size(); ++s)
      if (ur.index[s] >= 0) R[s] = projectToSO3(sol.middleRows<3>(ur.index[s]).transpose());
  }

  // 2) Positions (and landmarks): tj − ti = Ri·tz.
  const LinearUnknowns up = numberConnected(graph, guess, anchorSlot, false, 3);
  BlockNormalEquations<3> pos(up, 1);
  auto position = [&](int s) -> Eigen::Matrix<double, 3, Eigen::Dynamic> {
    return guess.type(s) == VarType::SE3 ? guess.se3(s).t : guess.point3(s);
  };
  for (const auto& f : graph.factors()) {
    if (f->size() != 2) continue;
    const int i = guess.slot(f->key(0)), j = guess.slot(f->key(1));
    Vec3 z;
    Mat3 info;
    if (const auto* b = dynamic_cast<const BetweenFactorSE3*>(f.get())) {
      z = b->measured().t;
      info = b->information().topLeftCorner<3, 3>();
    } else if (const auto* p = dynamic_cast<const PosePointFactor3*>(f.get())) {
      z = p->measured();
      info = Mat3::Identity();
    } else {
      continue;
    }
    const Mat3 W = R[i] * info * R[i].transpose();
    pos.add(i, j, Mat3::Identity(), R[i] * z, W, position(i), position(j));
  }
  const Eigen::MatrixXd sol = up.count > 0 ? pos.solve() : Eigen::MatrixXd();
  for (int s = 0; s < guess.size(); ++s) {
    if (guess.type(s) == VarType::SE3) {
      const Vec3 t = up.index[s] >= 0 ? Vec3(sol.middleRows<3>(up.index[s])) : guess.se3(s).t;
      out.set(s, SE3(R[s], t));
    } else if (guess.type(s) == VarType::Point3 && up.index[s] >= 0) {
      out.setPoint3(s, sol.middleRows<3>(up.index[s]));
    }
  }
  return out;
}

Values initializeLinear(const FactorGraph& graph, const Values& guess, Key anchor) {
  const int s = anchorSlotOf(guess, anchor);
  if (guess.type(s) == VarType::SE3) return initializeChordal3D(graph, guess, anchor);
  return initializeOrientationFirst2D(graph, guess, anchor);
}

Values initializeLinearFromLowestPose(const FactorGraph& graph, const Values& guess) {
  // Each robot's lowest pose, in key order (robot ids are the keys' high bits, so the first is
  // the lowest pose key of all): the roots of the solves.
  const std::map<std::uint32_t, int> lowest = lowestPoseOfEachRobot(guess);
  if (lowest.empty() || graph.empty()) return Values();
  if (!holdsSeveralFrames(guess))
    return initializeLinear(graph, guess, guess.key(lowest.begin()->second));

  const FactorGraph plain = withAnchoredBetweensPlain(graph);
  Values common = inCommonFrame(guess);
  std::vector<char> reached(static_cast<size_t>(guess.size()), 0);
  for (const auto& [robot, root] : lowest) {
    if (reached[static_cast<size_t>(root)]) continue;
    common = initializeLinear(plain, common, guess.key(root));
    const ReachableUnknowns r = numberReachable(
        plain, common, root, [](const Factor&) { return true; }, [](int) { return 1; });
    reached[static_cast<size_t>(root)] = 1;
    for (size_t s = 0; s < r.index.size(); ++s)
      if (r.index[s] >= 0) reached[s] = 1;
  }
  return inOwnFrames(common, guess);
}

}  // namespace loopd
