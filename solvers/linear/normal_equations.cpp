#include "solvers/linear/normal_equations.h"

#include <algorithm>

namespace loopd {

NormalEquations::NormalEquations(const HessianLayout& layout)
    : layout_(layout), hessian_(layout.nonZeros(), 0.0), gradient_(layout.dimension(), 0.0) {}

namespace {

// Pointers to each key's storage for factor f, through the layout's resolved slots.
inline void gatherInputs(const HessianLayout& layout, const Factor& factor, int f,
                         const Values& values, const double** x) {
  for (int k = 0; k < factor.size(); ++k) x[k] = values.data(layout.factorSlot(f, k));
}

}  // namespace

LinearizationCost NormalEquations::build(const FactorGraph& graph, const Values& values,
                                         const double* weights) {
  std::fill(hessian_.begin(), hessian_.end(), 0.0);
  std::fill(gradient_.begin(), gradient_.end(), 0.0);
  LinearizationCost cost;
  const std::vector<int>& offset = layout_.slotOffset();

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

    for (int a = 0; a < nk; ++a) {
      const int sa = layout_.factorSlot(f, a);
      const int oa = offset[sa];
      if (oa < 0) continue;
      const int da = varDim(factor.varType(a));
      // g_a += w·J_aᵀ r
      for (int c = 0; c < da; ++c) {
        const double* col = J[a] + c * d;
        double s = 0.0;
        for (int i = 0; i < d; ++i) s += col[i] * r[i];
        gradient_[oa + c] += w * s;
      }
      for (int b = 0; b < nk; ++b) {
        const int start = layout_.blockStart(f, a, b);
        if (start < 0) continue;  // fixed, or stored as (b, a)
        const int sb = layout_.factorSlot(f, b);
        const int db = varDim(factor.varType(b));
        const int len = layout_.columnLength(sb);
        // H_ab += w·J_aᵀ J_b, column cb of b is contiguous over the rows of a.
        for (int cb = 0; cb < db; ++cb) {
          const double* colB = J[b] + cb * d;
          double* dst = hessian_.data() + start + cb * len;
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
  return cost;
}

LinearizationCost NormalEquations::cost(const FactorGraph& graph, const Values& values,
                                        const double* weights) const {
  LinearizationCost cost;
  const double* x[kMaxFactorKeys];
  double r[kMaxResidualDim];
  for (int f = 0; f < graph.size(); ++f) {
    const Factor& factor = *graph[f];
    gatherInputs(layout_, factor, f, values, x);
    factor.evaluate(x, r, nullptr);
    double e2 = 0.0;
    for (int i = 0; i < factor.dim(); ++i) e2 += r[i] * r[i];
    cost.chi2 += e2;
    cost.weighted += (weights ? weights[f] : 1.0) * e2;
  }
  return cost;
}

void NormalEquations::factorChi2(const FactorGraph& graph, const Values& values,
                                 std::vector<double>& out) const {
  out.resize(graph.size());
  const double* x[kMaxFactorKeys];
  double r[kMaxResidualDim];
  for (int f = 0; f < graph.size(); ++f) {
    const Factor& factor = *graph[f];
    gatherInputs(layout_, factor, f, values, x);
    factor.evaluate(x, r, nullptr);
    double e2 = 0.0;
    for (int i = 0; i < factor.dim(); ++i) e2 += r[i] * r[i];
    out[f] = e2;
  }
}

}  // namespace loopd
