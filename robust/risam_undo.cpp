// Arrivals undone (RisamOptions::runawayFactor, collateralFactor): update() keeps the
// estimate before each arrival, and one that runs the map away or pushes accepted closures
// out at a lower truncated cost is taken back, its closures parked and fed again singly.
#include "robust/risam_backend.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <unordered_set>

#include "solvers/incremental/isam2.h"

namespace loopd {

namespace {

// χ² of f with each variable read from `base` at its slot in x (the estimate's own storage,
// or a raw copy of its first `size` slots); NaN if a variable is at or past `size`.
double chi2FromStorage(const Factor& f, const Values& x, const double* base, int size) {
  std::array<const double*, kMaxFactorKeys> at{};
  for (int k = 0; k < f.size(); ++k) {
    const int s = x.slot(f.key(k));
    if (s < 0 || s >= size) return std::numeric_limits<double>::quiet_NaN();
    at[k] = base + static_cast<size_t>(s) * kValueStride;
  }
  return f.chi2(at.data());
}

}  // namespace

UpdateResult RisamBackend::update(const BackendUpdate& u) {
  std::vector<FactorId> arriving;  // u's uncertain factors
  for (const FactorPtr& f : u.factors)
    if (f && isUncertain(f->role())) arriving.push_back(f->id());
  const int incoming = static_cast<int>(arriving.size());
  const bool checkRunaway = options_.runawayFactor > 0.0;
  const bool checkCollateral = options_.collateralFactor > 0.0;
  const Values& x = inner_->estimate();
  // Only arrivals with uncertain factors can run away or push others out.
  if (incoming == 0 || innerIsam2_ == nullptr || !(checkRunaway || checkCollateral) || x.empty())
    return updateArrival(u);
  // The estimate before is kept as raw storage in a reused buffer (slots only grow): a Values
  // copy, with its key index, cost city10000 (≈ 10⁴ closure arrivals) as much as the whole
  // online solve.
  const int beforeSize = x.size();
  const size_t n = static_cast<size_t>(beforeSize) * kValueStride;
  runawayStart_.resize(n);
  std::copy(x.data(0), x.data(0) + n, runawayStart_.begin());
  const double extent = x.largestMagnitude();
  const int absorbedBefore = absorbedUpdates_;
  UpdateResult result = updateArrival(u);
  // Absorbed arrivals are checked too: "absorbed" looks at the closures only.
  if (checkRunaway && extent > 0.0 &&
      !(inner_->estimate().largestMagnitude() <= options_.runawayFactor * extent)) {
    undoArrival(u, beforeSize, true);
    ++runawaysUndone_;
    return result;
  }
  const bool graduated = absorbedUpdates_ == absorbedBefore && lastInnerUpdates_ > 1;
  // Single closures are checked only when fed again from a contested arrival: checking every
  // one undid hundreds of arrivals on manhattan + 1000 local (each a full relinearization)
  // for the same answer.
  if (!checkCollateral || !graduated || (incoming < 2 && !refeeding_)) return result;
  const double limit =
      std::max(static_cast<double>(options_.collateralMin), options_.collateralFactor * incoming);
  // Pushed-out closures are a cheap sign; the truncated cost (Σ trusted χ² + Σ min(χ², the
  // rejection test)) decides, so a true closure that pushes out wrong ones accepted before it
  // (a group bending the map) stays: undoing that arrival would cost more than it saves.
  if (!(pushedOut(arriving, beforeSize) > limit) || !(undoCostChange(arriving, beforeSize) < 0.0))
    return result;
  undoArrival(u, beforeSize, false);
  ++contestedUndone_;
  if (incoming > 1) refeedSingly(std::move(arriving));
  return result;
}

int RisamBackend::pushedOut(const std::vector<FactorId>& arriving, int beforeSize) const {
  auto isArriving = [&](FactorId id) {
    return std::find(arriving.begin(), arriving.end(), id) != arriving.end();
  };
  // Graduated factors outside the arrival touch only variables from before it.
  const Values& x = inner_->estimate();
  int count = 0;
  for (const auto& [id, g] : graduated_) {
    if (g.parked || g.decided || isArriving(id)) continue;
    const Factor& f = *g.original;
    const double threshold = rejectChi2(f.dim());
    if (chi2FromStorage(f, x, x.data(0), x.size()) > threshold &&
        chi2FromStorage(f, x, runawayStart_.data(), beforeSize) <= threshold)
      ++count;
  }
  return count;
}

double RisamBackend::undoCostChange(const std::vector<FactorId>& arriving, int beforeSize) const {
  const Values& x = inner_->estimate();
  double undone = 0.0;
  for (const auto& f : originals_.factors()) {
    const bool uncertain = graduated_.count(f->id()) > 0;
    const double threshold = uncertain ? rejectChi2(f->dim()) : 0.0;
    const double before = chi2FromStorage(*f, x, runawayStart_.data(), beforeSize);
    if (std::find(arriving.begin(), arriving.end(), f->id()) != arriving.end())
      undone += threshold;  // undone: the arrival's closures rejected
    else if (std::isfinite(before))
      undone += uncertain ? std::min(before, threshold) : before;
    // else: a trusted factor of the arrival's new variables, at their initial values (0)
  }
  // Online, as the rejection test judges: the wider cap is for optimize()'s answers.
  return undone - truncatedCost(&RisamBackend::rejectChi2);
}

void RisamBackend::refeedSingly(std::vector<FactorId> ids) {
  const Values& x = inner_->estimate();
  std::vector<std::pair<double, FactorId>> order;
  for (FactorId id : ids) {
    auto it = graduated_.find(id);
    if (it != graduated_.end() && it->second.parked)
      order.emplace_back(it->second.original->chi2(x), id);
  }
  std::sort(order.begin(), order.end(), [](const auto& a, const auto& b) {
    return a.first > b.first || (a.first == b.first && a.second < b.second);
  });
  struct Refeeding {
    bool& flag;
    explicit Refeeding(bool& f) : flag(f) { flag = true; }
    ~Refeeding() { flag = false; }
  } refeeding(refeeding_);
  for (const auto& [chi2, id] : order) {
    if (!graduated_[id].parked) continue;  // came back with an earlier one (it fit)
    BackendUpdate one;
    one.factors.push_back(graduated_[id].original);
    forget(id);   // a new arrival again (see forget)
    update(one);  // one uncertain factor: undone and parked again, or in
  }
}

void RisamBackend::forget(FactorId id) {
  auto it = graduated_.find(id);
  if (it == graduated_.end()) return;
  if (it->second.parked) unpark(id);
  toPark_.erase(std::remove(toPark_.begin(), toPark_.end(), id), toPark_.end());
  const Factor& f = *it->second.original;
  for (int k = 0; k < f.size(); ++k) {
    auto ids = byKey_.find(f.key(k));
    if (ids != byKey_.end())
      ids->second.erase(std::remove(ids->second.begin(), ids->second.end(), id), ids->second.end());
  }
  graduated_.erase(it);
}

void RisamBackend::undoArrival(const BackendUpdate& u, int beforeSize, bool settle) {
  BackendUpdate out;
  for (const FactorPtr& f : u.factors) {
    if (!f || !isUncertain(f->role())) continue;
    auto it = graduated_.find(f->id());
    if (it == graduated_.end() || it->second.parked) continue;
    out.removals.push_back(it->second.internalId);
    park(f->id());
    toPark_.erase(std::remove(toPark_.begin(), toPark_.end(), f->id()), toPark_.end());
  }
  if (!out.removals.empty()) inner_->update(out);
  // The variables from before the arrival at their values then; the arrival's new ones at
  // their initial values.
  Values start = inner_->estimate();
  std::copy(runawayStart_.begin(), runawayStart_.end(), start.data(0));
  for (int s = beforeSize; s < start.size(); ++s) {
    const int i = u.initial.slot(start.key(s));
    if (i >= 0) std::copy(u.initial.data(i), u.initial.data(i) + kValueStride, start.data(s));
  }
  innerIsam2_->resetEstimate(start);
  // A runaway's estimate before may itself be far from converged; a contested arrival's
  // was not (the relinearization at it is enough, and an optimize() per undo cost
  // manhattan + 1000 local 4× the solve time).
  if (settle) inner_->optimize();
}

}  // namespace loopd
