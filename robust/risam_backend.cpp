// riSAM arrivals (risam_backend.h): new uncertain factors wrapped in the SIG kernel, the
// neighbours they share variables with, the μ schedule cut short once the arrival is absorbed;
// and the per-factor decisions and rejections.
#include "robust/risam_backend.h"

#include <algorithm>
#include <stdexcept>
#include <unordered_set>

#include "robust/risam_sig_factor.h"
#include "solvers/incremental/isam2.h"

namespace loopd {

RisamBackend::RisamBackend(std::unique_ptr<Backend> inner, RisamOptions options)
    : DecoratorBackend(std::move(inner), "RisamBackend"),
      options_(options),
      innerIsam2_(dynamic_cast<Isam2Backend*>(inner_.get())) {}

BackendUpdate RisamBackend::regraduate(const std::vector<FactorId>& ids, double mu) {
  BackendUpdate step;
  for (FactorId id : ids) {
    Graduated& g = graduated_[id];
    if (g.parked)
      unpark(id);
    else
      step.removals.push_back(g.internalId);
    g.internalId = kInternalIdBit | nextInternal_++;
    g.wrapper = wrap(g.original, mu, g.internalId);
    g.mu = mu;
    g.decided = false;
    step.factors.push_back(g.wrapper);
  }
  return step;
}

FactorPtr RisamBackend::wrap(const FactorPtr& f, double mu, FactorId internal) const {
  const Values* at = options_.weightAtEstimate ? &inner_->estimate() : nullptr;
  return makeRisamSig(f, mu, sigShape(f->dim()), at, internal);
}

UpdateResult RisamBackend::updateArrival(const BackendUpdate& u) {
  restoreGraduated();  // after optimize(): every closure back to its SIG kernel at μ = 1
  size_t incoming = 0;
  for (const FactorPtr& f : u.factors)
    if (f && isUncertain(f->role())) ++incoming;
  if (incoming > 0 && graduated_.size() + incoming >
                          static_cast<size_t>((1.0 + options_.gateRefreshGrowth) * gateAtCount_)) {
    refreshGate();  // the shape the new factors are graduated with
    regraduateIfTightened();
  }
  std::unordered_set<FactorId> removing(u.removals.begin(), u.removals.end());
  // Far-out factors leave the inner backend with this update; parked ones that fit the
  // current estimate come back at μ = 1, where their SIG weight would have recovered had they
  // stayed in.
  std::vector<FactorId> parking, unparking;
  std::unordered_set<FactorId> leaving, unparkingSet;
  for (FactorId id : toPark_)
    if (!removing.count(id) && !leaving.count(id) && shouldPark(id)) {
      parking.push_back(id);
      leaving.insert(id);
    }
  for (FactorId id : parked_) {
    const Factor& f = *graduated_.at(id).original;
    if (!removing.count(id) && f.chi2(inner_->estimate()) <= tailChi2(f.dim())) {
      unparking.push_back(id);
      unparkingSet.insert(id);
    }
  }
  BackendUpdate first;
  first.initial = u.initial;
  FactorId nextInternal = nextInternal_;
  auto newInternal = [&] { return kInternalIdBit | nextInternal++; };

  // Consistent arrivals skip the graduation: every new uncertain factor already fits the
  // current estimate (new variables at their initial values) within the inlier test.
  bool consistent = options_.skipConsistent && incoming > 0;
  if (consistent) {
    const Values& x = inner_->estimate();
    for (const FactorPtr& f : u.factors) {
      if (!f || !isUncertain(f->role())) continue;
      Values local;
      for (int k = 0; k < f->size() && consistent; ++k) {
        const Key key = f->key(k);
        const int su = u.initial.slot(key);
        const int sx = su < 0 ? x.slot(key) : -1;
        if (su >= 0)
          local.insertFrom(u.initial, su);
        else if (sx >= 0)
          local.insertFrom(x, sx);
        else
          consistent = false;
      }
      if (!consistent || !(f->chi2(local) <= options_.consistentFraction * rejectChi2(f->dim())))
        consistent = false;
      if (!consistent) break;
    }
  }
  for (FactorId id : u.removals) {
    auto it = graduated_.find(id);
    if (it == graduated_.end())
      first.removals.push_back(id);
    else if (!it->second.parked)
      first.removals.push_back(it->second.internalId);
  }
  for (FactorId id : parking) first.removals.push_back(graduated_[id].internalId);
  // The active set: new uncertain factors, plus existing ones sharing a variable with them.
  std::vector<Graduated> active;
  std::vector<FactorId> activeIds;  // original ids, parallel to active
  std::unordered_set<FactorId> inActive;
  for (const FactorPtr& f : u.factors) {
    if (!f) throw std::invalid_argument("risam: null factor in update");
    if (f->id() & kInternalIdBit)
      throw std::invalid_argument("risam: factor id " + std::to_string(f->id()) +
                                  " uses the top bit (reserved for internal factors)");
    if (!isUncertain(f->role())) {
      first.factors.push_back(f);
      continue;
    }
    Graduated g;
    g.original = f;
    g.internalId = newInternal();
    g.mu = consistent ? 1.0 : options_.muInit;
    g.wrapper = wrap(f, g.mu, g.internalId);
    first.factors.push_back(g.wrapper);
    active.push_back(g);
    activeIds.push_back(f->id());
    inActive.insert(f->id());
  }
  std::vector<Graduated> returning;  // unparking, committed with the update
  for (FactorId id : unparking) {
    Graduated g = graduated_[id];
    g.parked = false;
    g.internalId = newInternal();
    g.mu = 1.0;
    g.wrapper = wrap(g.original, g.mu, g.internalId);
    first.factors.push_back(g.wrapper);
    returning.push_back(g);
  }
  // Existing uncertain factors sharing a variable with the new ones (riSAM resets them to
  // μ_init with the arrival). With lazyNeighbours they are only reset if the arrival is not
  // absorbed at its own convex step or that step pushed one of them out (below).
  std::vector<FactorId> neighbours;
  std::vector<double> neighbourChi2;       // before the update, at the estimate
  std::vector<FactorId> parkedNeighbours;  // join the graduation like the others, if it runs
  if (options_.graduateNeighbours && !active.empty() && !consistent) {
    const size_t numNew = active.size();
    for (size_t a = 0; a < numNew; ++a) {
      const Factor& f = *active[a].original;
      for (int kk = 0; kk < f.size() * (2 * options_.neighbourWindow + 1); ++kk) {
        const int k = kk / (2 * options_.neighbourWindow + 1);
        const long d = kk % (2 * options_.neighbourWindow + 1) - options_.neighbourWindow;
        const Key key = f.key(k);
        if (d < 0 && keyIndex(key) < static_cast<std::uint64_t>(-d)) continue;
        const Key near = makeKey(keyRobot(key), keyKind(key), keyIndex(key) + d);
        auto it = byKey_.find(near);
        if (it == byKey_.end()) continue;
        for (FactorId id : it->second) {
          if (inActive.count(id) || removing.count(id) || leaving.count(id)) continue;
          auto g = graduated_.find(id);
          if (g == graduated_.end()) continue;
          if (g->second.parked && (!options_.lazyNeighbours || unparkingSet.count(id))) continue;
          inActive.insert(id);
          if (g->second.parked) {
            parkedNeighbours.push_back(id);
            continue;
          }
          if (options_.lazyNeighbours) {
            neighbours.push_back(id);
            neighbourChi2.push_back(g->second.original->chi2(inner_->estimate()));
            continue;
          }
          first.removals.push_back(g->second.internalId);
          Graduated n;
          n.original = g->second.original;
          n.internalId = newInternal();
          n.mu = options_.muInit;
          n.wrapper = wrap(n.original, n.mu, n.internalId);
          first.factors.push_back(n.wrapper);
          active.push_back(n);
          activeIds.push_back(id);
        }
      }
    }
  }

  UpdateResult result = inner_->update(first);  // throws, state unchanged, if invalid
  lastInnerUpdates_ = 1;

  // Commit the bookkeeping.
  nextInternal_ = nextInternal;
  if (!refeeding_) commitOriginals(u, removing);
  for (FactorId id : u.removals) graduated_.erase(id);
  parked_.erase(std::remove_if(parked_.begin(), parked_.end(),
                               [&](FactorId id) { return removing.count(id) > 0; }),
                parked_.end());
  for (Graduated& g : returning) {
    const FactorId id = g.original->id();
    graduated_[id] = g;
    parked_.erase(std::find(parked_.begin(), parked_.end(), id));
  }
  for (FactorId id : parking) park(id);
  toPark_.clear();
  for (size_t a = 0; a < active.size(); ++a) {
    const bool isNew = graduated_.find(activeIds[a]) == graduated_.end();
    graduated_[activeIds[a]] = active[a];
    if (isNew)
      for (int k = 0; k < active[a].original->size(); ++k) {
        const Key key = active[a].original->key(k);
        byKey_[key].push_back(activeIds[a]);
        framesJoined_ = framesJoined_ || keyKind(key) == KeyKind::Anchor;
      }
  }
  if (!removing.empty())
    for (auto& [key, ids] : byKey_)
      ids.erase(std::remove_if(ids.begin(), ids.end(),
                               [&](FactorId id) { return !graduated_.count(id); }),
                ids.end());
  if (active.empty() || consistent) return result;

  // One inner update; `graduating`: a step of the schedule (weights about to move), which
  // relinearizes whatever the inner iSAM2's relinearizeSkip says.
  auto step = [&](const BackendUpdate& s, bool graduating) {
    if (graduating && innerIsam2_ && options_.relinearizeGraduation)
      innerIsam2_->relinearizeNextUpdate();
    const double before = graduating && tight_ ? inner_->estimate().largestMagnitude() : 0.0;
    const UpdateResult r = inner_->update(s);
    // Tightened, the kernel's weights are steep in χ², and one Gauss–Newton step per μ can
    // overshoot (parking-garage local 1000: 334 m → 1e300 m over four arrivals); a step that
    // doubles the map's extent is followed by the inner backend's own optimize().
    if (graduating && tight_ && inner_->estimate().largestMagnitude() > 2.0 * before)
      inner_->optimize();
    result.seconds += r.seconds;
    result.relinearized += r.relinearized;
    ++lastInnerUpdates_;
  };
  // Absorbed: every active factor fits the current estimate well inside its test (and no
  // neighbour left out of the convex step was pushed out by it), so the rest of the schedule
  // could only confirm it; go straight to μ = 1 — in place where that changes the SIG weight
  // at the estimate by at most promoteTolerance (the cached linearization is then close
  // enough; the next relinearization uses μ = 1), else by re-adding.
  auto absorbedNow = [&](bool checkNeighbours) {
    if (!options_.acceptAbsorbed) return false;
    const Values& x = inner_->estimate();
    for (FactorId id : activeIds) {
      const Factor& f = *graduated_[id].original;
      if (!(f.chi2(x) <= options_.absorbedFraction * tailChi2(f.dim()))) return false;
    }
    if (checkNeighbours)
      for (size_t n = 0; n < neighbours.size(); ++n) {
        const Factor& f = *graduated_[neighbours[n]].original;
        const double thr = rejectChi2(f.dim());
        if (f.chi2(x) > thr && neighbourChi2[n] <= thr) return false;
      }
    return true;
  };
  auto promote = [&]() {
    const Values& x = inner_->estimate();
    std::vector<FactorId> readd;
    for (FactorId id : activeIds) {
      Graduated& g = graduated_[id];
      const double c2 = g.original->chi2(x);
      const SigShape shape = sigShape(g.original->dim());
      const double w0 = shape.weight(c2, g.mu), w1 = shape.weight(c2, 1.0);
      if (tight_ || std::abs(w1 - w0) <= options_.promoteTolerance * w0) {
        static_cast<const RisamSigFactor&>(*g.wrapper).setMu(1.0);
        g.mu = 1.0;
      } else {
        readd.push_back(id);
      }
    }
    if (!readd.empty()) step(regraduate(readd, 1.0), false);
  };
  if (absorbedNow(true)) {
    ++absorbedUpdates_;
    promote();
    return result;
  }
  // Not absorbed: the neighbours join the active set at μ_init (one more convex step), then
  // the schedule, cut short once everything is absorbed.
  neighbours.insert(neighbours.end(), parkedNeighbours.begin(), parkedNeighbours.end());
  if (!neighbours.empty()) {
    step(regraduate(neighbours, options_.muInit), true);
    activeIds.insert(activeIds.end(), neighbours.begin(), neighbours.end());
  }
  double mu = options_.muInit;
  int extra = options_.extraIterations;
  while (mu < 1.0 || extra-- > 0) {
    mu = nextMu(mu);
    step(regraduate(activeIds, mu), true);
    if (mu < 1.0 && absorbedNow(false)) {
      promote();
      return result;
    }
  }
  markFarOut(activeIds);
  return result;
}

std::vector<std::pair<FactorId, double>> RisamBackend::decisions() const {
  std::vector<std::pair<FactorId, double>> out;
  out.reserve(graduated_.size());
  const Values& x = inner_->estimate();
  for (const auto& f : originals_.factors()) {
    auto it = graduated_.find(f->id());
    if (it != graduated_.end())
      out.emplace_back(f->id(), it->second.decided
                                    ? it->second.mu
                                    : sigShape(f->dim()).weight(f->chi2(x), it->second.mu));
  }
  return out;
}

std::vector<FactorId> RisamBackend::rejected() const {
  std::vector<FactorId> out;
  const Values& x = inner_->estimate();
  for (const auto& f : originals_.factors())
    if (graduated_.count(f->id()) && !(f->chi2(x) <= rejectChi2(f->dim()))) out.push_back(f->id());
  return out;
}

}  // namespace loopd
