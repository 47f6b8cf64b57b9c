// riSAM's kernel shape and tests: the μ schedule, the SIG shape c², the rejection and tail
// tests, and the noise-aware gate that widens or tightens them, with the batch GNC check of
// the first one (RisamOptions).
#include "robust/risam_backend.h"

#include <algorithm>
#include <cmath>
#include <exception>
#include <unordered_set>
#include <vector>

#include "robust/gnc_backend.h"
#include "solvers/incremental/isam2.h"

namespace loopd {

double RisamBackend::nextMu(double mu) const {
  return std::min(1.0, mu + 1.2 * (mu - options_.muInit + 0.1));
}

double RisamBackend::shapeSquared(int dim) const {
  if (options_.shape > 0.0) return options_.shape * options_.shape;
  if (tight_) return tightChi2(gate_, dim);
  const double d = chi2Quantile(std::max(dim, 1), 0.95);
  return gate_ > 0.0 && options_.widenShape
             ? std::max(d, gate_ * chi2Quantile(std::max(dim, 1), 0.5))
             : d;
}

double RisamBackend::rejectChi2(int dim) const {
  if (tight_) return tightChi2(atTail_ ? tail_ : gate_, dim);
  const double d = chi2Quantile(std::max(dim, 1), options_.rejectChi2Probability);
  return gate_ > 0.0 ? std::max(d, gate_ * chi2Quantile(std::max(dim, 1), 0.5)) : d;
}

double RisamBackend::rejectChi2AtLeast(int dim, double p) const {
  const double r = rejectChi2(dim);
  if (tight_ || !(p > 0.0)) return r;
  return std::max(r, chi2Quantile(std::max(dim, 1), p));
}

double RisamBackend::costCapChi2(int dim) const {
  return rejectChi2AtLeast(dim, options_.costCapProbability);
}

double RisamBackend::tailChi2(int dim) const {
  return tight_ ? tightChi2(tail_, dim) : rejectChi2(dim);
}

double RisamBackend::tightChi2(double gate, int dim) const {
  return std::min(gate * chi2Quantile(std::max(dim, 1), 0.5),
                  chi2Quantile(std::max(dim, 1), 0.95) / options_.widenFactor);
}

void RisamBackend::gateDirection(double gate, bool& wider, bool& tighter) const {
  wider = false;
  tighter = options_.tighten;
  for (int dim = 1; dim <= 6; ++dim) {
    const double g = gate * chi2Quantile(dim, 0.5), d = chi2Quantile(dim, 0.95);
    wider = wider || g > options_.widenFactor * d;
    tighter = tighter && g * options_.widenFactor < d;
  }
}

void RisamBackend::refreshGate() {
  if (options_.shape > 0.0 || options_.tailExponent < 0.0) return;
  if (graduated_.size() < static_cast<size_t>(options_.gateMinSamples)) return;
  gateAtCount_ = graduated_.size();
  const TailGate t = tailGate(acceptedNormalized(), options_.tailExponent, options_.medianFactor);
  // Wider (heavy tails): only ever widened. Tighter for every dimension (under-confident
  // information, with `tighten`): from then on it follows the estimate and stays tight (the
  // online scale swings with drift: parking-garage local 100 went 0.01 → 24 → 0.001, and
  // widening in the swing let wrong closures bend the map).
  if (!(t.gate > 0.0)) return;
  bool wider = false, tighter = false;
  gateDirection(t.gate, wider, tighter);
  // The first gate that does not tighten may have been read off a map the defaults let wrong
  // closures bend (RisamOptions::batchGateCheck).
  if (!tight_ && !tighter && !onlineGateChecked_) {
    onlineGateChecked_ = true;
    confirmedGate_ = t.gate;
    if (options_.batchGateCheck && innerIsam2_ && adoptBatchGate()) return;
  }
  if (tight_ || tighter) {
    gate_ = t.gate;
    tail_ = t.tail;
    tight_ = true;
  } else if (wider && t.gate > gate_) {
    if (rebaseFrameWidening(t.gate)) return;
    gate_ = t.gate;
  }
}

bool RisamBackend::rebaseFrameWidening(double reading) {
  if (!options_.frameWideningCheck || !framesJoined_ || !innerIsam2_ ||
      !(reading > options_.widenFactor * std::max(confirmedGate_, gate_)))
    return false;
  ++frameWideningChecks_;
  const std::unique_ptr<GncBackend> gnc = solveBatchGnc();
  const TailGate t = gnc ? batchTailGate(*gnc) : TailGate{};
  if (!(t.gate > 0.0) || !(t.gate * options_.widenFactor < reading)) {
    confirmedGate_ = reading;
    return false;
  }
  confirmedGate_ = std::max(gate_, t.gate);
  takeBatchSolution(gnc->estimate());
  ++frameWideningsRebased_;
  return true;
}

void RisamBackend::takeBatchSolution(const Values& x) {
  innerIsam2_->resetEstimate(x);
  const std::vector<FactorId> ids = graduatedIds();
  inner_->update(regraduate(ids, 1.0));
  inner_->optimize();
  markFarOut(ids);
}

std::unique_ptr<GncBackend> RisamBackend::solveBatchGnc(
    const std::function<bool()>& interrupt) const {
  GncOptions go;
  go.interrupt = interrupt;
  auto gnc = std::make_unique<GncBackend>(BackendOptions{}, go);
  BackendUpdate all;
  all.initial = inner_->estimate();
  for (const auto& f : originals_.factors()) all.factors.push_back(f);
  try {
    gnc->update(all);  // solves: a batch backend's update() runs its optimize()
  } catch (const GncInterrupted&) {
    throw;
  } catch (const std::exception&) {
    return nullptr;  // a look that cannot run leaves the answer as it was
  }
  if (!gnc->estimate().allFinite()) return nullptr;
  return gnc;
}

bool RisamBackend::adoptBatchGate(bool widenThisAnswer) {
  ++batchGateChecks_;
  const std::unique_ptr<GncBackend> gnc = solveBatchGnc();
  if (!gnc) return false;
  const Values& x = gnc->estimate();
  const TailGate t = batchTailGate(*gnc);
  if (!(t.gate > 0.0)) return false;
  bool wider = false, tighter = false;
  gateDirection(t.gate, wider, tighter);
  if (!tighter && !(widenThisAnswer && wider && t.gate > gate_)) return false;
  if (tighter) {
    gate_ = t.gate;
    tail_ = t.tail;
    tight_ = true;
    regraduatedAtGate_ = gate_;  // graduated below, at μ = 1 from the GNC's solution
  } else {
    if (onlineGate_ < 0.0) onlineGate_ = gate_, onlineTail_ = tail_;  // back at the next update
    gate_ = t.gate;
  }
  takeBatchSolution(x);
  ++batchGatesAdopted_;
  return true;
}

TailGate RisamBackend::batchTailGate(const GncBackend& gnc) const {
  const Values& x = gnc.estimate();
  const std::vector<FactorId> out = gnc.rejected();
  const std::unordered_set<FactorId> rejectedByGnc(out.begin(), out.end());
  std::vector<double> q;
  for (const auto& [id, g] : graduated_)
    if (!rejectedByGnc.count(id))
      q.push_back(g.original->chi2(x) / chi2Quantile(std::max(g.original->dim(), 1), 0.5));
  return tailGate(q, options_.tailExponent, options_.medianFactor);
}

bool RisamBackend::releaseTightGate(const GncBackend& gnc) {
  if (!tight_ || !options_.releaseTightGate) return false;
  const TailGate t = batchTailGate(gnc);
  if (!(t.gate > 0.0)) return false;
  bool wider = false, tighter = false;
  gateDirection(t.gate, wider, tighter);
  if (tighter) return false;
  tight_ = false;
  atTail_ = false;
  gate_ = t.gate;
  tail_ = 0.0;
  onlineGate_ = -1.0;  // released for good: no online tight gate to go back to
  regraduatedAtGate_ = 0.0;
  return true;
}

RisamBackend::GateState RisamBackend::gateState() const {
  return {gate_, onlineGate_, tail_, regraduatedAtGate_, tight_, atTail_};
}

void RisamBackend::setGateState(const GateState& s) {
  gate_ = s.gate;
  onlineGate_ = s.onlineGate;
  tail_ = s.tail;
  regraduatedAtGate_ = s.regraduatedAtGate;
  tight_ = s.tight;
  atTail_ = s.atTail;
}

std::vector<FactorId> RisamBackend::graduatedIds() const {
  std::vector<FactorId> ids;
  ids.reserve(graduated_.size());
  for (const auto& [id, g] : graduated_) ids.push_back(id);
  return ids;
}

std::vector<double> RisamBackend::acceptedNormalized() const {
  const Values& x = inner_->estimate();
  std::vector<double> q;
  q.reserve(graduated_.size());
  for (const auto& [id, g] : graduated_) {
    const int dim = std::max(g.original->dim(), 1);
    const double c2 = g.original->chi2(x);
    if (c2 <= rejectChi2(dim)) q.push_back(c2 / chi2Quantile(dim, 0.5));
  }
  return q;
}

bool RisamBackend::settledTailGate(TailGate& out) const {
  if (options_.shape > 0.0 || options_.tailExponent < 0.0) return false;
  const std::vector<double> q = acceptedNormalized();
  if (q.size() < static_cast<size_t>(options_.gateMinSamples)) return false;
  out = tailGate(q, options_.tailExponent, options_.medianFactor);
  return true;
}

bool RisamBackend::shrinkGateAtEnd() {
  TailGate settled;
  if (tight_ || !(gate_ > 0.0) || !settledTailGate(settled)) return false;
  const double next = settled.gate;
  if (!(next >= 0.0)) return false;
  bool hasDim[7] = {};
  for (const auto& [id, g] : graduated_) hasDim[std::min(std::max(g.original->dim(), 1), 6)] = true;
  for (int dim = 1; dim <= 6; ++dim) {
    if (!hasDim[dim]) continue;
    const double shrunk =
        std::max(chi2Quantile(dim, options_.rejectChi2Probability), next * chi2Quantile(dim, 0.5));
    if (!(shrunk * options_.widenFactor < rejectChi2(dim))) return false;
  }
  if (onlineGate_ < 0.0) onlineGate_ = gate_, onlineTail_ = tail_;
  gate_ = next;
  return true;
}

bool RisamBackend::shrinkTightGateAtEnd() {
  TailGate next;
  if (!tight_ || !settledTailGate(next)) return false;
  if (!(next.gate > 0.0) || !(next.gate * options_.widenFactor < gate_)) return false;
  if (onlineGate_ < 0.0) onlineGate_ = gate_, onlineTail_ = tail_;
  gate_ = next.gate;
  tail_ = next.tail;
  return true;
}

SigShape RisamBackend::sigShape(int dim) const {
  const double effective = shapeSquared(dim);
  if (!tight_) return {std::sqrt(effective), 1.0};
  // The default shape on χ² scaled up: the same weights at μ = 1 as c² = `effective`, but the
  // convex end keeps closures in (c²/(c² + 1) at μ = 0: 0.93 instead of 0.008 on
  // parking-garage), so graduation starts from the least-squares map, not the odometry alone.
  const double base = chi2Quantile(std::max(dim, 1), 0.95);
  return {std::sqrt(base), base / effective};
}

}  // namespace loopd
