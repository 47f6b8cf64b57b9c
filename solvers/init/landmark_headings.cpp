#include "solvers/init/landmark_headings.h"

#include <cmath>
#include <stdexcept>

#include "solvers/factors/between_factor_se2.h"
#include "solvers/factors/landmark_factors.h"
#include "solvers/init/breadth_first.h"
#include "solvers/init/sparse_normal_solve.h"

namespace loopd {

namespace {

constexpr int kPoseDim = 4;   // t (2), then (c, s)
constexpr int kPointDim = 2;  // p

using Vec4 = Eigen::Matrix<double, 4, 1>;

// M(v)·(c, s) = R(θ)·v for (c, s) = (cos θ, sin θ).
Mat2 rotatedBy(const Vec2& v) {
  Mat2 M;
  M << v.x(), -v.y(), v.y(), v.x();
  return M;
}

// The relaxed unknowns: poses and landmarks reachable from the anchor through the factors
// used here (others stay known, so the system stays regular).
using Unknowns = ReachableUnknowns;

bool usedHere(const Factor& f) {
  return dynamic_cast<const BetweenFactorSE2*>(&f) || dynamic_cast<const PosePointFactor2*>(&f);
}

Unknowns numberRelaxed(const FactorGraph& graph, const Values& values, int anchorSlot) {
  return numberReachable(graph, values, anchorSlot, usedHere, [&values](int s) {
    return values.type(s) == VarType::SE2 ? kPoseDim : kPointDim;
  });
}

// Normal equations of residuals  r = Jᵢ·xᵢ + Jⱼ·xⱼ − c  (weight W) in which a known
// variable's term moves into c.
struct RelaxedSystem {
  const Unknowns& u;
  const Values& guess;
  InitTriplets triplets;
  Eigen::VectorXd rhs;
  RelaxedSystem(const Unknowns& unknowns, const Values& values, int factors)
      : u(unknowns), guess(values), rhs(Eigen::VectorXd::Zero(unknowns.count)) {
    triplets.reserve(static_cast<size_t>(factors) * 4 * kPoseDim * kPoseDim);  // no regrowth
  }

  // A known variable's value in the relaxed coordinates.
  template <int D>
  Eigen::Matrix<double, D, 1> known(int s) const {
    Eigen::Matrix<double, D, 1> x;
    const double* d = guess.data(s);
    x.template head<2>() << d[0], d[1];
    if constexpr (D == kPoseDim) x.template tail<2>() << std::cos(d[2]), std::sin(d[2]);
    return x;
  }

  template <int R, int Di, int Dj>
  void add(int si, int sj, const Eigen::Matrix<double, R, Di>& Ji,
           const Eigen::Matrix<double, R, Dj>& Jj, Eigen::Matrix<double, R, 1> c,
           const Eigen::Matrix<double, R, R>& W) {
    const int ii = u.index[si], jj = u.index[sj];
    if (ii < 0) c -= Ji * known<Di>(si);
    if (jj < 0) c -= Jj * known<Dj>(sj);
    if (ii >= 0) {
      const Eigen::Matrix<double, Di, R> JiW = Ji.transpose() * W;
      addBlock<Di, Di>(ii, ii, JiW * Ji);
      rhs.segment<Di>(ii) += JiW * c;
      if (jj >= 0) {
        const Eigen::Matrix<double, Di, Dj> Hij = JiW * Jj;
        addBlock<Di, Dj>(ii, jj, Hij);
        addBlock<Dj, Di>(jj, ii, Hij.transpose());
      }
    }
    if (jj >= 0) {
      const Eigen::Matrix<double, Dj, R> JjW = Jj.transpose() * W;
      addBlock<Dj, Dj>(jj, jj, JjW * Jj);
      rhs.segment<Dj>(jj) += JjW * c;
    }
  }
  template <int A, int B>
  void addBlock(int r, int c, const Eigen::Matrix<double, A, B>& M) {
    for (int a = 0; a < A; ++a)
      for (int b = 0; b < B; ++b)
        if (M(a, b) != 0.0) triplets.emplace_back(r + a, c + b, M(a, b));
  }
};

}  // namespace

bool hasPointSightings2D(const FactorGraph& graph) {
  for (const auto& f : graph.factors())
    if (dynamic_cast<const PosePointFactor2*>(f.get())) return true;
  return false;
}

std::vector<double> landmarkAidedHeadings2D(const FactorGraph& graph, const Values& guess,
                                            int anchorSlot,
                                            const std::vector<double>& weightHeadings) {
  std::vector<double> theta = weightHeadings;
  theta[anchorSlot] = guess.se2(anchorSlot).theta;
  const Unknowns u = numberRelaxed(graph, guess, anchorSlot);
  if (u.count == 0) return theta;
  RelaxedSystem system(u, guess, graph.size());
  for (const auto& f : graph.factors()) {
    if (const auto* b = dynamic_cast<const BetweenFactorSE2*>(f.get())) {
      const int i = guess.slot(b->key(0)), j = guess.slot(b->key(1));
      // r = xⱼ − A·xᵢ, x = (t, c, s):  A = [I, M(zt); 0, Rot(zθ)].
      Eigen::Matrix<double, 4, 4> A = Eigen::Matrix<double, 4, 4>::Zero();
      A.topLeftCorner<2, 2>().setIdentity();
      A.topRightCorner<2, 2>() = rotatedBy(b->measured().t());
      A.bottomRightCorner<2, 2>() = rot2(b->measured().theta);
      const Mat2 R = rot2(weightHeadings[i]);
      Eigen::Matrix<double, 4, 4> W = Eigen::Matrix<double, 4, 4>::Zero();
      W.topLeftCorner<2, 2>() = R * b->information().topLeftCorner<2, 2>() * R.transpose();
      W.bottomRightCorner<2, 2>() = b->information()(2, 2) * Mat2::Identity();
      system.add<4, kPoseDim, kPoseDim>(i, j, -A, Eigen::Matrix<double, 4, 4>::Identity(),
                                        Vec4::Zero(), W);
    } else if (const auto* p = dynamic_cast<const PosePointFactor2*>(f.get())) {
      const int i = guess.slot(p->key(0)), k = guess.slot(p->key(1));
      // r = pₖ − tᵢ − M(z)·(c, s)ᵢ.
      Eigen::Matrix<double, 2, 4> Ji;
      Ji << -Mat2::Identity(), -rotatedBy(p->measured());
      const Mat2 R = rot2(weightHeadings[i]);
      system.add<2, kPoseDim, kPointDim>(i, k, Ji, Mat2::Identity(), Vec2::Zero(),
                                         R * p->information() * R.transpose());
    }
  }
  const Eigen::MatrixXd x = solveNormalEquations(u.count, system.triplets, system.rhs);
  if (!x.allFinite()) throw std::runtime_error("landmark-aided headings: not finite");
  for (int s = 0; s < guess.size(); ++s)
    if (u.index[s] >= 0 && guess.type(s) == VarType::SE2)
      theta[s] = std::atan2(x(u.index[s] + 3, 0), x(u.index[s] + 2, 0));
  return theta;
}

}  // namespace loopd
