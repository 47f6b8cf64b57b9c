#include "solvers/linear/normal_equations.h"

#include <algorithm>
#include <stdexcept>
#include <string>

namespace loopd {

NormalEquations::NormalEquations(const HessianLayout& layout)
    : layout_(layout), hessian_(layout.nonZeros(), 0.0), gradient_(layout.dimension(), 0.0) {}

void NormalEquations::fitLayout() {
  hessian_.assign(layout_.nonZeros(), 0.0);
  gradient_.assign(layout_.dimension(), 0.0);
}

namespace {

// Pointers to each key's storage for factor f, through the layout's resolved slots.
inline void gatherInputs(const HessianLayout& layout, const Factor& factor, int f,
                         const Values& values, const double** x) {
  for (int k = 0; k < factor.size(); ++k) x[k] = values.data(layout.factorSlot(f, k));
}

bool uniformDim(const Factor& factor, int dim) {
  for (int k = 0; k < factor.size(); ++k)
    if (varDim(factor.varType(k)) != dim) return false;
  return true;
}

// H_ab += w·J_aᵀJ_b and g_a += w·J_aᵀr with fixed-size products (pose graphs: all blocks
// 3×3 in 2D, 6×6 in 3D). Column cb of block (a, b) is contiguous over a's rows.
template <int D, int V>
void accumulateFixed(const HessianLayout& layout, int f, int nk, double* const* J, const double* r,
                     double w, double* H, double* g) {
  using JMat = Eigen::Matrix<double, D, V>;
  const Eigen::Map<const Eigen::Matrix<double, D, 1>> res(r);
  for (int a = 0; a < nk; ++a) {
    const int oa = layout.slotOffset()[layout.factorSlot(f, a)];
    if (oa < 0) continue;
    const Eigen::Map<const JMat> Ja(J[a]);
    Eigen::Map<Eigen::Matrix<double, V, 1>>(g + oa).noalias() += w * (Ja.transpose() * res);
    for (int b = 0; b < nk; ++b) {
      const int start = layout.blockStart(f, a, b);
      if (start < 0) continue;  // fixed, or stored as (b, a)
      const Eigen::Map<const JMat> Jb(J[b]);
      const int len = layout.columnLength(layout.factorSlot(f, b));
      Eigen::Map<Eigen::Matrix<double, V, V>, 0, Eigen::OuterStride<>> dst(
          H + start, Eigen::OuterStride<>(len));
      dst.noalias() += w * (Ja.transpose() * Jb);
    }
  }
}

// The same for any mix of block sizes (landmarks, switch variables, …).
void accumulateGeneric(const HessianLayout& layout, const Factor& factor, int f, double* const* J,
                       const double* r, double w, double* H, double* g) {
  const int nk = factor.size(), d = factor.dim();
  for (int a = 0; a < nk; ++a) {
    const int oa = layout.slotOffset()[layout.factorSlot(f, a)];
    if (oa < 0) continue;
    const int da = varDim(factor.varType(a));
    for (int c = 0; c < da; ++c) {
      const double* col = J[a] + c * d;
      double s = 0.0;
      for (int i = 0; i < d; ++i) s += col[i] * r[i];
      g[oa + c] += w * s;
    }
    for (int b = 0; b < nk; ++b) {
      const int start = layout.blockStart(f, a, b);
      if (start < 0) continue;
      const int sb = layout.factorSlot(f, b);
      const int db = varDim(factor.varType(b));
      const int len = layout.columnLength(sb);
      for (int cb = 0; cb < db; ++cb) {
        const double* colB = J[b] + cb * d;
        double* dst = H + start + cb * len;
        for (int ca = 0; ca < da; ++ca) {
          const double* colA = J[a] + ca * d;
          double s = 0.0;
          for (int i = 0; i < d; ++i) s += colA[i] * colB[i];
          dst[ca] += w * s;
        }
      }
    }
  }
}

}  // namespace

LinearizationCost NormalEquations::build(const FactorGraph& graph, const Values& values,
                                         const double* weights) {
  std::fill(hessian_.begin(), hessian_.end(), 0.0);
  std::fill(gradient_.begin(), gradient_.end(), 0.0);
  LinearizationCost cost;
  const double* x[kMaxFactorKeys];
  double r[kMaxResidualDim];
  JacobianBlock jac[kMaxFactorKeys];
  double* J[kMaxFactorKeys];
  for (int k = 0; k < kMaxFactorKeys; ++k) J[k] = jac[k].data();

  for (int f = 0; f < graph.size(); ++f) {
    const Factor& factor = *graph[f];
    const int nk = factor.size(), d = factor.dim();
    gatherInputs(layout_, factor, f, values, x);
    factor.evaluate(x, r, J);
    double e2 = 0.0;
    for (int i = 0; i < d; ++i) e2 += r[i] * r[i];
    const double w = weights ? weights[f] : 1.0;
    cost.chi2 += e2;
    cost.weighted += w * e2;
    if (w == 0.0) continue;
    if (!layout_.isActive(f))
      throw std::logic_error("NormalEquations: factor " + std::to_string(f) +
                             " has a weight but no place in the layout");

    if (d == 3 && uniformDim(factor, 3)) {
      accumulateFixed<3, 3>(layout_, f, nk, J, r, w, hessian_.data(), gradient_.data());
    } else if (d == 6 && uniformDim(factor, 6)) {
      accumulateFixed<6, 6>(layout_, f, nk, J, r, w, hessian_.data(), gradient_.data());
    } else {
      accumulateGeneric(layout_, factor, f, J, r, w, hessian_.data(), gradient_.data());
    }
  }
  return cost;
}

template <typename PerFactor>
void NormalEquations::forEachChi2(const FactorGraph& graph, const Values& values,
                                  PerFactor&& perFactor) const {
  const double* x[kMaxFactorKeys];
  double r[kMaxResidualDim];
  for (int f = 0; f < graph.size(); ++f) {
    const Factor& factor = *graph[f];
    gatherInputs(layout_, factor, f, values, x);
    factor.evaluate(x, r, nullptr);
    double e2 = 0.0;
    for (int i = 0; i < factor.dim(); ++i) e2 += r[i] * r[i];
    perFactor(f, e2);
  }
}

LinearizationCost NormalEquations::cost(const FactorGraph& graph, const Values& values,
                                        const double* weights) const {
  LinearizationCost cost;
  forEachChi2(graph, values, [&](int f, double e2) {
    cost.chi2 += e2;
    cost.weighted += (weights ? weights[f] : 1.0) * e2;
  });
  return cost;
}

void NormalEquations::factorChi2(const FactorGraph& graph, const Values& values,
                                 std::vector<double>& out) const {
  out.resize(graph.size());
  forEachChi2(graph, values, [&](int f, double e2) { out[f] = e2; });
}

}  // namespace loopd
