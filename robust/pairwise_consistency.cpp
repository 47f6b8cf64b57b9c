#include "robust/pairwise_consistency.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numeric>
#include <unordered_map>
#include <utility>

#include "robust/robust_factors.h"
#include "solvers/factors/between_factor_se2.h"
#include "solvers/factors/between_factor_se3.h"
#include "solvers/init/common_frame.h"

namespace loopd {
namespace {

// Poses of both dimensions as rigid motions of 3-space (2D: rotation about z, z = 0), so one
// cycle test serves both.
struct Rigid {
  Mat3 R = Mat3::Identity();
  Vec3 t = Vec3::Zero();
  Rigid operator*(const Rigid& o) const { return {R * o.R, R * o.t + t}; }
  Rigid inverse() const { return {R.transpose(), -(R.transpose() * t)}; }
};

Rigid fromSE2(const SE2& x) {
  Rigid r;
  r.R.topLeftCorner<2, 2>() = x.R();
  r.t << x.x, x.y, 0.0;
  return r;
}

Rigid fromSE3(const SE3& x) { return {x.R, x.t}; }

// sin θ of a rotation (θ ∈ [0, π]); θ = atan2(sin θ, cos θ) with cos θ = (trace − 1)/2.
double rotationSine(const Mat3& R) {
  const Vec3 v(R(2, 1) - R(1, 2), R(0, 2) - R(2, 0), R(1, 0) - R(0, 1));
  return 0.5 * v.norm();
}

// A between factor's measurement and isotropic variances (trace/dim of its covariance's
// translation and rotation blocks); false for other factors.
struct Link {
  Key from = 0, to = 0;
  Rigid z;
  double varT = 0.0, varR = 0.0;
};

bool asLink(const Factor& f, Link& out) {
  if (const auto* b = dynamic_cast<const BetweenFactorSE2*>(&f)) {
    const Eigen::Matrix3d cov = b->information().inverse();
    out = {f.key(0), f.key(1), fromSE2(b->measured()), 0.5 * (cov(0, 0) + cov(1, 1)), cov(2, 2)};
  } else if (const auto* b3 = dynamic_cast<const BetweenFactorSE3*>(&f)) {
    const Mat6 cov = b3->information().inverse();
    out = {f.key(0), f.key(1), fromSE3(b3->measured()), cov.topLeftCorner<3, 3>().trace() / 3.0,
           cov.bottomRightCorner<3, 3>().trace() / 3.0};
  } else {
    return false;
  }
  return std::isfinite(out.varT) && std::isfinite(out.varR) && out.varT >= 0.0 && out.varR >= 0.0;
}

// Greedy clique: take nodes in `order`, each if adjacent to every node taken so far.
std::vector<int> greedyClique(const std::vector<std::uint64_t>& adjacency, size_t words,
                              const std::vector<int>& order) {
  std::vector<std::uint64_t> candidates(words, ~std::uint64_t{0});
  std::vector<int> clique;
  for (int v : order) {
    if (!(candidates[v / 64] >> (v % 64) & 1u)) continue;
    clique.push_back(v);
    const std::uint64_t* row = &adjacency[static_cast<size_t>(v) * words];
    for (size_t w = 0; w < words; ++w) candidates[w] &= row[w];
  }
  return clique;
}

}  // namespace

ConsistentSet pairwiseConsistentClosures(const FactorGraph& given, const Values& ownFrames,
                                         const ConsistencyOptions& options) {
  // Several robots: every pose in the common frame, inter-robot closures as plain ones
  // (factor for factor, so the indices stay the graph's).
  const bool severalFrames = holdsSeveralFrames(ownFrames);
  const FactorGraph plain = severalFrames ? withAnchoredBetweensPlain(given) : FactorGraph();
  const Values common = severalFrames ? inCommonFrame(ownFrames) : Values();
  const FactorGraph& graph = severalFrames ? plain : given;
  const Values& odometry = severalFrames ? common : ownFrames;
  ConsistentSet out;
  out.member.assign(graph.size(), 0);

  // The odometry chain: poses in key order; step k joins chain poses k and k+1.
  std::vector<Key> poseKeys;
  bool planar = true;
  for (int s = 0; s < odometry.size(); ++s) {
    if (keyKind(odometry.key(s)) != KeyKind::Pose) continue;
    poseKeys.push_back(odometry.key(s));
    planar = planar && odometry.type(s) == VarType::SE2;
  }
  std::sort(poseKeys.begin(), poseKeys.end());
  const int n = static_cast<int>(poseKeys.size());
  if (n < 3) return out;
  std::unordered_map<Key, int> index;
  std::vector<Rigid> pose(n);
  for (int k = 0; k < n; ++k) {
    index[poseKeys[k]] = k;
    const int s = odometry.slot(poseKeys[k]);
    pose[k] = planar ? fromSE2(odometry.se2(s)) : fromSE3(odometry.se3(s));
  }
  const double dimT = planar ? 2.0 : 3.0, dimR = planar ? 1.0 : 3.0;
  const double lever = planar ? 1.0 : 2.0;  // axes a rotation error displaces a point along

  struct Judged {
    int a, b;  // chain indices of the closure's ends
    Rigid z, zInverse;
    double varT, varR;
  };
  std::vector<char> hasStep(n, 0);
  std::vector<double> stepT(n, 0.0), stepR(n, 0.0);
  std::vector<Judged> judged;
  std::vector<int> judgedFactor;  // graph index of each judged closure
  for (int i = 0; i < graph.size(); ++i) {
    const Factor& f = *graph[i];
    Link l;
    if (f.size() != 2 || !asLink(f, l)) continue;
    const auto a = index.find(l.from), b = index.find(l.to);
    if (a == index.end() || b == index.end()) continue;
    if (f.role() == FactorRole::Odometry) {
      const int lo = std::min(a->second, b->second);
      if (std::abs(a->second - b->second) != 1 || hasStep[lo]) continue;
      hasStep[lo] = 1;
      stepT[lo] = options.odometryScale * l.varT;
      stepR[lo] = options.odometryScale * l.varR;
    } else if (f.role() == FactorRole::LoopClosure) {
      judged.push_back({a->second, b->second, l.z, l.z.inverse(), options.closureScale * l.varT,
                        options.closureScale * l.varR});
      judgedFactor.push_back(i);
    }
  }

  // Prefix sums over steps below chain pose k: Σ dim_t·σ_t², Σσ_r², Σσ_r²·p, Σσ_r²·|p|²
  // (p: the step's end position, where its rotation error acts), and the chain segment.
  std::vector<double> sumT(n, 0.0), sumR(n, 0.0), sumRpp(n, 0.0);
  std::vector<Vec3> sumRp(n, Vec3::Zero());
  std::vector<int> segment(n, 0);
  for (int k = 1; k < n; ++k) {
    const int s = k - 1;
    const Vec3& p = pose[k].t;
    sumT[k] = sumT[s] + dimT * stepT[s];
    sumR[k] = sumR[s] + stepR[s];
    sumRp[k] = sumRp[s] + stepR[s] * p;
    sumRpp[k] = sumRpp[s] + stepR[s] * p.squaredNorm();
    segment[k] = segment[s] + (hasStep[s] ? 0 : 1);
  }
  // A closure between two chains is judged from the lower chain to the higher, as its inverse
  // if need be (the same variances: the test is isotropic in each block), so that two closures
  // between the same chains pair their ends: robots' closures come in either direction.
  for (Judged& c : judged)
    if (segment[c.a] > segment[c.b]) {
      std::swap(c.a, c.b);
      std::swap(c.z, c.zInverse);
    }
  // The chain between poses u and v: translation variance at point q, rotation variance.
  auto chain = [&](int u, int v, const Vec3& q, double& varT, double& varR) {
    const int lo = std::min(u, v), hi = std::max(u, v);
    const double r0 = sumR[hi] - sumR[lo];
    varT += sumT[hi] - sumT[lo] +
            lever * (q.squaredNorm() * r0 - 2.0 * q.dot(sumRp[hi] - sumRp[lo]) + sumRpp[hi] -
                     sumRpp[lo]);
    varR += dimR * r0;
  };

  const int m = static_cast<int>(judged.size());
  out.judged = m;
  if (m == 0) return out;

  std::vector<Rigid> inverse(n);
  for (int k = 0; k < n; ++k) inverse[k] = pose[k].inverse();
  // The cycle of closures i and j: Δ and the denominators of the statistic's two terms;
  // false across chain breaks.
  struct Cycle {
    Rigid delta;
    double varT = 0.0, varR = 0.0;
  };
  auto cycleOf = [&](int i, int j, Cycle& c) {
    const Judged& ci = judged[i];
    const Judged& cj = judged[j];
    if (segment[ci.a] != segment[cj.a] || segment[ci.b] != segment[cj.b]) return false;
    // Δ = z_j⁻¹·(x_c⁻¹x_a)·z_i·(x_b⁻¹x_d)
    c.delta = cj.zInverse * (inverse[cj.a] * pose[ci.a]) * ci.z * (inverse[ci.b] * pose[cj.b]);
    const Vec3& pd = pose[cj.b].t;
    c.varT = dimT * (ci.varT + cj.varT) + lever * (ci.varR * (pd - pose[ci.b].t).squaredNorm() +
                                                   cj.varR * (pd - pose[cj.a].t).squaredNorm());
    c.varR = dimR * (ci.varR + cj.varR);
    chain(cj.a, ci.a, pd, c.varT, c.varR);
    chain(ci.b, cj.b, pd, c.varT, c.varR);
    c.varT = std::max(c.varT, 1e-300);
    c.varR = std::max(c.varR, 1e-300);
    return true;
  };
  auto translationTerm = [&](const Cycle& c) { return dimT * c.delta.t.squaredNorm() / c.varT; };
  auto rotationTerm = [&](const Cycle& c, double sine) {
    const double angle = std::atan2(sine, 0.5 * (c.delta.R.trace() - 1.0));
    return dimR * angle * angle / c.varR;
  };
  // The cycle statistic of closures i and j; infinite across chain breaks.
  auto cycle = [&](int i, int j) {
    Cycle c;
    if (!cycleOf(i, j, c)) return std::numeric_limits<double>::infinity();
    return translationTerm(c) + rotationTerm(c, rotationSine(c.delta.R));
  };
  // cycle(i, j) < threshold, with the same bits where it is computed, but without the angle's
  // atan2 where the translation term alone, or with its lower bound θ ≥ sin θ, already
  // reaches the threshold (the margin covers sin θ's rounding). 3.7–6.3× faster than
  // computing every statistic, with the same sets (robust/README, thirty-fourth session).
  auto consistent = [&](int i, int j, double threshold) {
    Cycle c;
    if (!cycleOf(i, j, c)) return options.unjudgedPairsAgree;
    const double t = translationTerm(c);
    if (!(t < threshold)) return false;
    const double sine = rotationSine(c.delta.R);
    if (t + dimR * sine * sine / c.varR * (1.0 - 1e-9) >= threshold) return false;
    return t + rotationTerm(c, sine) < threshold;
  };

  // Calibration on short cycles (both chains within calibrationWindow poses): these are
  // mostly pairs of true closures from one revisit, and their statistic barely depends on
  // the odometry's drift, so its median against χ²_dim(0.5) is the factor by which the
  // stated (and scaled) covariances are off.
  double calibration = 1.0;
  if (options.calibrationWindow > 0) {
    std::vector<int> byA(m);
    std::iota(byA.begin(), byA.end(), 0);
    std::sort(byA.begin(), byA.end(), [&](int x, int y) { return judged[x].a < judged[y].a; });
    std::vector<double> shortCycles;
    for (size_t p = 0; p < byA.size(); ++p)
      for (size_t q = p + 1; q < byA.size(); ++q) {
        const Judged& ci = judged[byA[p]];
        const Judged& cj = judged[byA[q]];
        if (cj.a - ci.a > options.calibrationWindow) break;
        if (std::abs(cj.b - ci.b) > options.calibrationWindow) continue;
        if (cj.a == ci.a && cj.b == ci.b) continue;
        const double s = cycle(byA[p], byA[q]);
        if (std::isfinite(s)) shortCycles.push_back(s);
      }
    out.calibrationPairs = static_cast<int>(shortCycles.size());
    if (out.calibrationPairs >= options.minCalibrationPairs) {
      std::nth_element(shortCycles.begin(), shortCycles.begin() + shortCycles.size() / 2,
                       shortCycles.end());
      calibration = std::min(1.0, std::max(shortCycles[shortCycles.size() / 2], 1e-300) /
                                      chi2Quantile(planar ? 3 : 6, 0.5));
    }
  }
  out.calibration = calibration;
  if (options.calibrationOnly) return out;

  const double gate = chi2Quantile(planar ? 3 : 6, options.probability);
  const size_t words = (static_cast<size_t>(m) + 63) / 64;
  std::vector<std::uint64_t> adjacency(static_cast<size_t>(m) * words, 0);
  std::vector<int> degree(m, 0);
  auto connect = [&](int i, int j) {
    adjacency[static_cast<size_t>(i) * words + j / 64] |= std::uint64_t{1} << (j % 64);
    adjacency[static_cast<size_t>(j) * words + i / 64] |= std::uint64_t{1} << (i % 64);
    ++degree[i];
    ++degree[j];
  };
  const double threshold = gate * calibration;
  for (int i = 0; i < m; ++i) {
    if (options.checkpoint) options.checkpoint();
    for (int j = i + 1; j < m; ++j)
      if (consistent(i, j, threshold)) connect(i, j);
  }

  std::vector<int> order(m);
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(), [&](int x, int y) { return degree[x] > degree[y]; });
  std::vector<int> best;
  for (int seed = 0; seed < std::min(options.cliqueSeeds, m); ++seed) {
    std::vector<int> seeded = order;
    std::rotate(seeded.begin(), seeded.begin() + seed, seeded.begin() + seed + 1);
    std::vector<int> clique = greedyClique(adjacency, words, seeded);
    if (clique.size() > best.size()) best = std::move(clique);
  }
  for (int v : best) out.member[judgedFactor[v]] = 1;
  out.size = static_cast<int>(best.size());
  return out;
}

}  // namespace loopd
