// GncBackend's second looks at single decisions, judged by the truncated cost: rejected
// closures that would fit the map's own uncertainty, accepted clusters that hold it bent, and
// a start from the largest pairwise-consistent set of closures.
#include <algorithm>
#include <cstdio>
#include <limits>

#include "robust/gnc_run.h"
#include "robust/pairwise_consistency.h"

namespace loopd {
namespace {

double median(std::vector<double> v, double fallback) {
  if (v.empty()) return fallback;
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

}  // namespace

// Sets the weights of `factors` to `weight`, re-solves, decides against the gate, and keeps
// the result if the truncated cost (capped at the gate, or at `judgeCaps`) dropped (else goes
// back). Logs what happened as `what`.
bool GncBackend::Run::tryDecisions(const std::vector<int>& factors, double weight, const char* what,
                                   int cap, const std::vector<double>* judgeCaps) {
  const Candidate previous = snapshot();
  auto cost = [&] { return judgeCaps ? tlsCost(*judgeCaps) : tlsCost(); };
  const double before = cost();
  for (int i : factors) weights_[i] = weight;
  ++b_.refine_;
  solveWeighted(cap);
  refine(cap);
  const double after = cost();
  const bool kept = after < before;
  if (!kept) restore(previous);
  char buf[224];
  std::snprintf(buf, sizeof buf, "; %s: %zu closures, %s (truncated cost %.6g -> %.6g)", what,
                factors.size(), kept ? "kept" : "dropped", before, after);
  log_ += buf;
  return kept;
}

// The uncertain factors the current weights accept (or reject).
std::vector<int> GncBackend::Run::uncertainWhere(bool accepted) const {
  std::vector<int> out;
  for (int i = 0; i < n_; ++i)
    if (cbar_[i] > 0.0 && this->accepted(i) == accepted) out.push_back(i);
  return out;
}

// The predicted change of the truncated cost per group (NaN: unknown): admitting a rejected
// group trades its gate terms for the cost rise, rejecting an accepted one trades the cost
// drop for its gate terms. Negative: worth trying.
std::vector<double> GncBackend::Run::predictedNet(const std::vector<std::vector<int>>& groups,
                                                  GroupChange change) {
  std::vector<double> net = predictedCostChange(graph_, estimate_, groups, change, jointMarginal_);
  for (size_t g = 0; g < groups.size(); ++g) {
    double gates = 0.0;
    for (int i : groups[g]) gates += gate_[i];
    net[g] = change == GroupChange::Add ? net[g] - gates : gates - net[g];
  }
  return net;
}

// Re-check of the rejected closures against the map's own uncertainty: accepting a closure
// (or a cluster) G raises the cost by about rᵀ(I + JΣJᵀ)⁻¹r (robust/closure_leverage.h)
// instead of Σ_G gate_i. Those for which that is a net drop are accepted together, kept if the
// truncated cost did drop (a stiff true closure left out of a locally misfit map: manhattan
// with 1000 outliers). Clusters too: a stretch held off by wrong closures can be too stiff for
// one true closure to pull back.
bool GncBackend::Run::admitFitting(int cap) {
  c2_ = gate_;
  const std::vector<int> rejectedOnes = uncertainWhere(false);
  std::vector<std::vector<int>> groups;
  for (int i : rejectedOnes) groups.push_back({i});
  if (decides_)
    for (auto& c : closureClusters(graph_, estimate_, rejectedOnes, gnc_.admitWindow))
      if (c.size() > 1 && static_cast<int>(c.size()) <= gnc_.maxCluster)
        groups.push_back(std::move(c));
  const std::vector<double> net = predictedNet(groups, GroupChange::Add);
  // The rise (net + the group's gates) within the noise (admitWithinNoise).
  const bool noiseBound = decides_ && gnc_.admitWithinNoise && noiseAware_ && b_.scale_ > 0.0;
  auto withinNoise = [&](const std::vector<int>& group, double groupNet) {
    if (!noiseBound) return true;
    double rise = groupNet, bound = 0.0;
    for (int i : group) {
      rise += gate_[i];
      bound += medianCap(i);
    }
    return rise <= bound;
  };
  std::vector<char> take(n_, 0);
  for (size_t g = 0; g < groups.size(); ++g)
    if (net[g] < 0.0 && withinNoise(groups[g], net[g]))
      for (int i : groups[g]) take[i] = 1;
  std::vector<int> admit;
  for (int i : rejectedOnes)
    if (take[i]) admit.push_back(i);
  return !admit.empty() && tryDecisions(admit, 1.0, "re-check, rejected that fit", cap);
}

// The converse: a few wrong closures that agree with each other can hold the map bent with
// true closures pushed out (manhattan, a group of 10 with 3 accepted and 2 true ones
// rejected). Removing an accepted cluster G lowers the cost by rᵀ(I − JΣJᵀ)⁻¹r and adds
// Σ_G gate_i: clusters for which that is a net drop are rejected together (if that fails, the
// most promising alone), kept if the truncated cost dropped.
bool GncBackend::Run::dropBending(int cap) {
  c2_ = gate_;
  std::vector<std::vector<int>> clusters;
  for (auto& c : closureClusters(graph_, estimate_, uncertainWhere(true), gnc_.dropWindow))
    if (static_cast<int>(c.size()) <= gnc_.maxCluster) clusters.push_back(std::move(c));
  const std::vector<double> net = predictedNet(clusters, GroupChange::Remove);
  std::vector<int> reject;
  int most = -1;
  double mostNet = 0.0;
  for (size_t c = 0; c < clusters.size(); ++c) {
    if (!(net[c] < 0.0)) continue;
    reject.insert(reject.end(), clusters[c].begin(), clusters[c].end());
    if (net[c] < mostNet) mostNet = net[c], most = static_cast<int>(c);
  }
  if (reject.empty()) return false;
  if (tryDecisions(reject, 0.0, "drop check, accepted clusters that bend the map", cap))
    return true;
  return clusters[most].size() < reject.size() &&
         tryDecisions(clusters[most], 0.0, "drop check, the most promising cluster", cap);
}

// Each change can make the other possible (a dropped group lets true closures back in).
// Solves capped at `cap` iterations (0: to convergence).
void GncBackend::Run::runChecks(int cap) {
  for (int round = 0; round < gnc_.checkRounds; ++round) {
    const bool admitted = gnc_.recheckRejected && admitFitting(cap);
    const bool dropped = decides_ && gnc_.dropClusters && dropBending(cap);
    if (!admitted && !dropped) break;
  }
}

// Consistent groups of wrong closures can bend the map from both starts (intel, 1000 in
// groups of 10). Start once more from the largest pairwise consistent set of closures (PCM) —
// its linear initialization with the trusted factors — decide 0/1 against the gate there, and
// keep it if its truncated cost is lower.
void GncBackend::Run::tryConsistentStart() {
  c2_ = gate_;
  ConsistencyOptions pcm;
  pcm.probability = gnc_.consistencyProbability;
  pcm.checkpoint = b_.interruptCheckpoint();
  pcm.unjudgedPairsAgree = true;  // each robot's own closures, with several robots
  std::vector<double> qOdometry, qClosures;
  for (int i = 0; i < n_; ++i) {
    const double q = (cbar_[i] > 0.0 ? r2_[i] : graph_[i]->chi2(estimate_)) / half_[i];
    if (graph_[i]->role() == FactorRole::Odometry)
      qOdometry.push_back(q);
    else if (cbar_[i] > 0.0 && accepted(i))
      qClosures.push_back(q);
  }
  pcm.odometryScale = median(qOdometry, 1.0);
  pcm.closureScale = median(qClosures, 1.0);
  const ConsistentSet set = pairwiseConsistentClosures(graph_, odometryStart_, pcm);
  const Values consistentStart = set.size > 0 ? b_.trustedLinearStart(set.member) : Values();
  char buf[256];
  if (consistentStart.size() != estimate_.size()) {
    std::snprintf(buf, sizeof buf, "; consistent set: %d of %d closures, no start", set.size,
                  set.judged);
    log_ += buf;
    return;
  }
  const Candidate kept = snapshot();
  estimate_.assignFrom(consistentStart);
  for (int i = 0; i < n_; ++i)
    if (cbar_[i] > 0.0) weights_[i] = set.member[i] ? 1.0 : 0.0;
  solveWeighted(refineCap_);
  // The gate from this (clean) solution's accepted closures, if it acts; adopted with the
  // candidate.
  std::vector<double> candidateGate = gate_;
  const double usedScale = b_.scale_, usedGate = b_.tailGate_;
  const bool ownGate = noiseAware_ && estimateGate(candidateGate);
  // The set is a selection of the best-fitting closures, so its tail understates the true
  // closures' (intel: q99·(q99/q90)³ at 0.04 of χ²_dim(0.5) with the median at 0.003): a
  // tightened gate is not taken below medianFactor × the median.
  if (ownGate)
    for (int i = 0; i < n_; ++i)
      if (cbar_[i] > 0.0 && candidateGate[i] < cbar_[i])
        candidateGate[i] =
            std::max(candidateGate[i], std::min(cbar_[i] / gnc_.widenFactor, medianCap(i)));
  const double candidateScale = b_.scale_, candidateTail = b_.tailGate_;
  b_.scale_ = usedScale, b_.tailGate_ = usedGate;
  const std::vector<double> keptGate = gate_;
  gate_ = candidateGate;
  refine(refineCap_);
  // The same decisions at a cost lower by rounding are not a better answer (taking its gate
  // then cut parking-garage's true tail).
  auto sameDecisions = [&] {
    for (int i = 0; i < n_; ++i)
      if (cbar_[i] > 0.0 && accepted(i) != (kept.weights[i] >= acceptAt_)) return false;
    return true;
  };
  // First, both at the candidate's own gate if it is tighter (judgeAtOwnGate).
  bool tighterOwn = ownGate && gnc_.judgeAtOwnGate;
  double keptAtOwn = kept.cost;
  for (int i = 0; i < n_; ++i)
    if (cbar_[i] > 0.0) {
      tighterOwn = tighterOwn && candidateGate[i] * gnc_.widenFactor < keptGate[i];
      keptAtOwn += std::min(kept.r2[i], candidateGate[i]) - std::min(kept.r2[i], keptGate[i]);
    }
  const double atOwn = tlsCost();
  const bool winsAtOwn = tighterOwn && atOwn < keptAtOwn && !sameDecisions();
  if (winsAtOwn) {
    std::snprintf(buf, sizeof buf, "; at its own gate %.3g x chi2_dim(0.5): %.6g vs %.6g",
                  candidateTail, atOwn, keptAtOwn);
    log_ += buf;
  }
  gate_ = keptGate;  // both judged by the same truncated cost
  c2_ = gate_;
  // A set of mutually consistent wrong closures (groups) can join the true ones: the checks
  // can still drop them before the candidate is judged.
  if (!winsAtOwn && !(tlsCost() < kept.cost)) runChecks(refineCap_);
  const double after = tlsCost();
  const bool keep = winsAtOwn || (after < kept.cost && !sameDecisions());
  if (keep && ownGate) {
    gate_ = candidateGate;
    b_.scale_ = candidateScale, b_.tailGate_ = candidateTail;
  }
  if (!keep) restore(kept);
  std::snprintf(buf, sizeof buf,
                "; from the consistent set (%d of %d closures; scales %.3g, %.3g, "
                "calibrated x%.3g on %d short cycles): %s (truncated cost %.6g vs %.6g)",
                set.size, set.judged, pcm.odometryScale, pcm.closureScale, set.calibration,
                set.calibrationPairs, keep ? "kept" : "dropped", after, kept.cost);
  log_ += buf;
  if (keep && ownGate && belowDefaults(gate_) && gnc_.readmit)
    readmitAtTail(std::numeric_limits<double>::infinity());
}

}  // namespace loopd
