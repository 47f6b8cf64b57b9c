// The noise-aware gate of GncBackend (GncOptions::tailExponent): estimated from the accepted
// closures' normalized χ², shrunk while a bent solution's gate proves too wide, widened back
// to the true closures' own tail once the solution has settled.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

#include "robust/gnc_run.h"

namespace loopd {

TailGate tailGate(std::vector<double> q, double exponent, double medianFactor) {
  TailGate t;
  std::vector<double> v;
  for (double x : q)
    if (std::isfinite(x) && x >= 0.0) v.push_back(x);
  if (v.size() < 10) return t;
  std::sort(v.begin(), v.end());
  auto at = [&](double p) { return v[std::min(v.size() - 1, static_cast<size_t>(p * v.size()))]; };
  t.scale = at(0.5);
  const double p90 = at(0.9), p99 = at(0.99);
  if (!(p90 > 0.0)) return t;
  t.tail = p99 * std::pow(p99 / p90, exponent);
  t.gate = std::min(medianFactor * t.scale, t.tail);
  return t;
}

// The accepted closures' normalized χ² (χ²/χ²_dim(0.5)).
std::vector<double> GncBackend::Run::acceptedNormalized() const {
  std::vector<double> q;
  for (int i = 0; i < n_; ++i)
    if (cbar_[i] > 0.0 && accepted(i)) q.push_back(r2_[i] / half_[i]);
  return q;
}

double GncBackend::Run::medianCap(int i) const { return gnc_.medianFactor * b_.scale_ * half_[i]; }

// The noise-aware gate from the closures the current solution accepts: the tail of their
// normalized χ². It acts (returns true, `out` set) when it is wider (heavy tail, manhattan:
// out = max(c̄², g·χ²_dim(0.5))) or, with `tighten`, tighter (under-confident information,
// every g·χ²_dim(0.5) below c̄²/widenFactor: parking-garage, intel; out = g·χ²_dim(0.5))
// than c̄² by widenFactor. Sets the backend's reported scale and gate.
bool GncBackend::Run::estimateGate(std::vector<double>& out) {
  const TailGate t = tailGate(acceptedNormalized(), gnc_.tailExponent, gnc_.medianFactor);
  b_.scale_ = t.scale;
  b_.tailGate_ = t.gate;
  bool wider = false, tighter = t.gate > 0.0 && gnc_.tighten;
  std::vector<double> g(n_, 0.0);
  for (int i = 0; i < n_; ++i)
    if (cbar_[i] > 0.0) {
      g[i] = t.gate * half_[i];
      if (std::max(cbar_[i], g[i]) > gnc_.widenFactor * cbar_[i]) wider = true;
      if (!(g[i] * gnc_.widenFactor < cbar_[i])) tighter = false;
    }
  if (wider) {
    out.assign(n_, 0.0);
    for (int i = 0; i < n_; ++i) out[i] = cbar_[i] > 0.0 ? std::max(cbar_[i], g[i]) : 0.0;
    return true;
  }
  if (tighter) {
    out = g;
    return true;
  }
  return false;
}

// The gate re-estimated from the current solution; taken (gate and thresholds) if it shrinks
// by more than widenFactor for every uncertain factor, else nothing changes.
bool GncBackend::Run::shrinkGate() {
  std::vector<double> next;
  const double usedScale = b_.scale_, usedGate = b_.tailGate_;
  bool shrinks = estimateGate(next);
  for (int i = 0; i < n_ && shrinks; ++i)
    if (cbar_[i] > 0.0) shrinks = next[i] * gnc_.widenFactor < gate_[i];
  if (!shrinks) {
    b_.scale_ = usedScale, b_.tailGate_ = usedGate;
    return false;
  }
  gate_ = next;
  c2_ = gate_;
  return true;
}

// A tightened (or shrunk) gate is usually the median cap (medianFactor × the median): it gets
// the solution out of bent minima, but true closures' tail can reach beyond it
// (parking-garage: the largest 208× the median). Once the solution has settled, decide once
// more against the accepted closures' own tail extrapolation q99·(q99/q90)^tailExponent (no
// median cap), at most `cap` and at most c̄²/widenFactor (still a tightened gate): rejected
// closures consistent with the solution come back.
void GncBackend::Run::readmitAtTail(double cap) {
  // The uncapped tail itself: a cap of medianFactor × a median of 0 would be a gate of 0.
  const double g = std::min(tailGate(acceptedNormalized(), gnc_.tailExponent, 0.0).tail, cap);
  bool wider = false;
  std::vector<double> next = gate_;
  for (int i = 0; i < n_; ++i)
    if (cbar_[i] > 0.0) {
      next[i] = std::min(g * half_[i], cbar_[i] / gnc_.widenFactor);
      if (next[i] > gate_[i]) wider = true;
    }
  if (!wider) return;
  const Candidate previous = snapshot();
  const std::vector<double> previousGate = gate_;
  gate_ = next;
  c2_ = gate_;
  const int before = rejectedCount();
  refine(refineCap_);
  const int after = rejectedCount();
  char buf[128];
  std::snprintf(buf, sizeof buf,
                "; re-check at the tail gate %.3g x chi2_dim(0.5): %d -> %d rejected", g, before,
                after);
  log_ += buf;
  if (weights_ == previous.weights) {
    // Nothing came back: the tighter gate, which separated just as well, stands (the wider
    // one would let later checks take in wrong closures that happen to fit a weakly held
    // stretch: intel with 1000 outliers, one or two accepted).
    restore(previous);
    gate_ = previousGate;
    c2_ = gate_;
    log_ += ", gate kept";
    return;
  }
  b_.tailGate_ = g;
}

// The gate once more, from the final solution: if the first was estimated from a bent map and
// the settled one's closures say it is over twice too wide (intel, 1000 in groups: the
// consistent-set start kept, the median 10x below the first one's), decide again against it
// (re-admitting the tail as above) and re-run the checks.
void GncBackend::Run::regateAtEnd() {
  for (int round = 0; decides_ && gnc_.regateAtEnd && noiseAware_ && round < gnc_.maxGateRounds;
       ++round) {
    if (!shrinkGate()) break;
    gated_ = true;
    refine(0);
    char buf[96];
    std::snprintf(buf, sizeof buf, "; final gate: %.3g x chi2_dim(0.5)", b_.tailGate_);
    log_ += buf;
    const double shrunk = b_.tailGate_;
    if (gnc_.readmit && belowDefaults(gate_))
      readmitAtTail(std::numeric_limits<double>::infinity());
    runChecks(0);
    if (b_.tailGate_ != shrunk) break;  // the true tail widened it back: estimating again repeats
  }
}

// Clean data whose closures' tail reaches a little past c̄² (torus3D: the tail gate 4.62 ×
// χ²₆(0.5) = 24.7 against c̄² = 16.81, within widenFactor, so the gate does not act). There a
// few stiff true closures that hold tension together are cheaper rejected at c̄² than kept
// (torus3D: 21 of 4049, χ² 6–13 at the all-in optimum, 35–67 without them; out, the
// truncated cost at c̄² is 50 lower). The tail gate is the noise model's own bound on true
// closures, and judged at it keeping them is cheaper. So when every rejected closure misfits
// by less than the median cap (not an outlier's misfit: a wrong closure is far beyond it),
// re-admit them together, decide again against the gate, and keep that answer if its
// truncated cost capped at max(gate, tail gate) is lower.
void GncBackend::Run::admitTogetherAtTail() {
  if (!decides_ || !noiseAware_ || gated_ || !gnc_.admitTogetherAtTail || !(b_.tailGate_ > 0.0) ||
      !(b_.scale_ > 0.0))
    return;
  const std::vector<int> rejectedOnes = uncertainWhere(false);
  if (rejectedOnes.empty()) return;
  for (int i : rejectedOnes)
    if (!(r2_[i] <= medianCap(i))) return;
  std::vector<double> caps(n_, 0.0);
  bool wider = false;
  for (int i = 0; i < n_; ++i)
    if (c2_[i] > 0.0) {
      caps[i] = std::max(gate_[i], b_.tailGate_ * half_[i]);
      wider = wider || caps[i] > gate_[i];
    }
  if (!wider) return;
  char what[96];
  std::snprintf(what, sizeof what,
                "rejected re-admitted together, judged at the tail gate %.3g x chi2_dim(0.5)",
                b_.tailGate_);
  tryDecisions(rejectedOnes, 1.0, what, 0, &caps);
}

}  // namespace loopd
