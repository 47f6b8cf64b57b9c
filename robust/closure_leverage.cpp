#include "robust/closure_leverage.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <array>
#include <limits>
#include <numeric>
#include <stdexcept>
#include <unordered_map>

namespace loopd {
namespace {

// The variables a group touches, in first-seen order, with their columns in a local block.
struct GroupVariables {
  std::vector<Key> keys;
  std::unordered_map<Key, int> column;
  int columns = 0;

  void add(const Factor& f) {
    for (int k = 0; k < f.size(); ++k)
      if (column.emplace(f.key(k), columns).second) {
        keys.push_back(f.key(k));
        columns += varDim(f.varType(k));
      }
  }
};

// rᵀ(I ± JΣJᵀ)⁻¹r for one group, Σ its variables' joint marginal (in vars' order); NaN if
// it cannot be told.
double groupChange(const FactorGraph& graph, const Values& values, const std::vector<int>& group,
                   GroupChange change, const Eigen::MatrixXd& S, const GroupVariables& vars) {
  constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
  int rows = 0;
  for (int i : group) rows += graph[i]->dim();
  Eigen::VectorXd r(rows);
  Eigen::MatrixXd J = Eigen::MatrixXd::Zero(rows, vars.columns);
  int row = 0;
  for (int i : group) {
    const Factor& f = *graph[i];
    std::array<const double*, kMaxFactorKeys> x{};
    std::array<JacobianBlock, kMaxFactorKeys> blocks{};
    std::array<double*, kMaxFactorKeys> jac{};
    for (int k = 0; k < f.size(); ++k) {
      const int slot = values.slot(f.key(k));
      if (slot < 0) return kNaN;
      x[k] = values.data(slot);
      jac[k] = blocks[k].data();
    }
    f.evaluate(x.data(), r.data() + row, jac.data());
    for (int k = 0; k < f.size(); ++k)
      J.block(row, vars.column.at(f.key(k)), f.dim(), varDim(f.varType(k))) +=
          Eigen::Map<const Eigen::MatrixXd>(blocks[k].data(), f.dim(), varDim(f.varType(k)));
    row += f.dim();
  }
  const double sign = change == GroupChange::Add ? 1.0 : -1.0;
  const Eigen::MatrixXd M = Eigen::MatrixXd::Identity(rows, rows) + sign * (J * S * J.transpose());
  const Eigen::LDLT<Eigen::MatrixXd> ldlt(M);
  if (ldlt.info() != Eigen::Success || !ldlt.isPositive() || !(ldlt.vectorD().minCoeff() > 1e-12))
    return kNaN;
  return r.dot(ldlt.solve(r));
}

}  // namespace

std::vector<double> predictedCostChange(const FactorGraph& graph, const Values& values,
                                        const std::vector<std::vector<int>>& groups,
                                        GroupChange change, const JointMarginalsFn& marginals) {
  std::vector<double> out(groups.size(), std::numeric_limits<double>::quiet_NaN());
  std::vector<GroupVariables> vars(groups.size());
  std::vector<std::vector<Key>> keySets;
  std::vector<size_t> asked;  // groups whose variables all exist
  for (size_t g = 0; g < groups.size(); ++g) {
    for (int i : groups[g]) vars[g].add(*graph[i]);
    bool known = true;
    for (Key k : vars[g].keys) known = known && values.slot(k) >= 0;
    if (!known) continue;
    keySets.push_back(vars[g].keys);
    asked.push_back(g);
  }
  if (asked.empty()) return out;
  std::vector<Eigen::MatrixXd> sigma;
  try {
    sigma = marginals(keySets);
  } catch (const std::runtime_error&) {  // singular at the estimate: cannot be told
    return out;
  } catch (const std::logic_error&) {  // a variable it does not know
    return out;
  }
  for (size_t a = 0; a < asked.size() && a < sigma.size(); ++a) {
    const size_t g = asked[a];
    if (sigma[a].rows() == vars[g].columns && sigma[a].cols() == vars[g].columns)
      out[g] = groupChange(graph, values, groups[g], change, sigma[a], vars[g]);
  }
  return out;
}

std::vector<std::vector<int>> closureClusters(const FactorGraph& graph, const Values& values,
                                              const std::vector<int>& factors, int window) {
  struct Ends {
    int low, high, member;
  };
  std::vector<Ends> pairs;
  std::vector<std::vector<int>> clusters;
  for (int m = 0; m < static_cast<int>(factors.size()); ++m) {
    const Factor& f = *graph[factors[m]];
    int a = -1, b = -1;
    if (f.size() == 2) {
      a = values.slot(f.key(0)), b = values.slot(f.key(1));
    } else if (f.size() == 4 && keyKind(f.key(0)) == KeyKind::Anchor &&
               keyKind(f.key(2)) == KeyKind::Anchor) {
      a = values.slot(f.key(1)), b = values.slot(f.key(3));  // a closure between robots
    }
    if (a < 0 || b < 0)
      clusters.push_back({factors[m]});
    else
      pairs.push_back({std::min(a, b), std::max(a, b), m});
  }
  // Union–find over the pairs, swept in order of the low end.
  std::sort(pairs.begin(), pairs.end(), [](const Ends& x, const Ends& y) { return x.low < y.low; });
  std::vector<int> parent(pairs.size());
  std::iota(parent.begin(), parent.end(), 0);
  auto root = [&](int i) {
    while (parent[i] != i) i = parent[i] = parent[parent[i]];
    return i;
  };
  for (size_t i = 0; i < pairs.size(); ++i)
    for (size_t j = i + 1; j < pairs.size() && pairs[j].low - pairs[i].low <= window; ++j)
      if (std::abs(pairs[j].high - pairs[i].high) <= window) parent[root(j)] = root(i);
  std::unordered_map<int, size_t> index;
  for (size_t i = 0; i < pairs.size(); ++i) {
    auto [it, fresh] = index.emplace(root(static_cast<int>(i)), clusters.size());
    if (fresh) clusters.emplace_back();
    clusters[it->second].push_back(factors[pairs[i].member]);
  }
  return clusters;
}

}  // namespace loopd
