#include "robust/risam_backend.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <unordered_set>

namespace loopd {

RisamBackend::RisamBackend(std::unique_ptr<Backend> inner, RisamOptions options)
    : DecoratorBackend(std::move(inner), "RisamBackend"), options_(options) {}

double RisamBackend::nextMu(double mu) const {
  return std::min(1.0, mu + 1.2 * (mu - options_.muInit + 0.1));
}

std::shared_ptr<GraduatedFactor> RisamBackend::wrap(const FactorPtr& f, double mu,
                                                    FactorId internal) const {
  const double c = options_.shape > 0.0 ? options_.shape
                                        : std::sqrt(chi2Quantile(f->dim(), 0.95));
  auto w = GraduatedFactor::make(f, mu, c);
  w->setId(internal);
  return w;
}

UpdateResult RisamBackend::update(const BackendUpdate& u) {
  std::unordered_set<FactorId> removing(u.removals.begin(), u.removals.end());
  BackendUpdate first;
  first.initial = u.initial;
  FactorId nextInternal = nextInternal_;
  auto newInternal = [&] { return kInternalIdBit | nextInternal++; };

  for (FactorId id : u.removals) {
    auto it = graduated_.find(id);
    first.removals.push_back(it == graduated_.end() ? id : it->second.internalId);
  }
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
    g.wrapper = wrap(f, options_.muInit, g.internalId);
    first.factors.push_back(g.wrapper);
    active.push_back(g);
    activeIds.push_back(f->id());
    inActive.insert(f->id());
  }
  if (options_.graduateNeighbours && !active.empty()) {
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
          if (inActive.count(id) || removing.count(id)) continue;
          auto g = graduated_.find(id);
          if (g == graduated_.end()) continue;
          inActive.insert(id);
          first.removals.push_back(g->second.internalId);
          Graduated n;
          n.original = g->second.original;
          n.internalId = newInternal();
          n.wrapper = wrap(n.original, options_.muInit, n.internalId);
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
  commitOriginals(u, removing);
  for (FactorId id : u.removals) graduated_.erase(id);
  for (size_t a = 0; a < active.size(); ++a) {
    const bool isNew = graduated_.find(activeIds[a]) == graduated_.end();
    graduated_[activeIds[a]] = active[a];
    if (isNew)
      for (int k = 0; k < active[a].original->size(); ++k)
        byKey_[active[a].original->key(k)].push_back(activeIds[a]);
  }
  if (!removing.empty())
    for (auto& [key, ids] : byKey_)
      ids.erase(std::remove_if(ids.begin(), ids.end(),
                               [&](FactorId id) { return !graduated_.count(id); }),
                ids.end());

  // Graduate the active set: each step re-adds its factors at the next μ.
  if (!active.empty()) {
    double mu = options_.muInit;
    int extra = options_.extraIterations;
    while (mu < 1.0 || extra-- > 0) {
      mu = nextMu(mu);
      BackendUpdate step;
      for (FactorId id : activeIds) {
        Graduated& g = graduated_[id];
        step.removals.push_back(g.internalId);
        g.internalId = kInternalIdBit | nextInternal_++;
        g.wrapper = wrap(g.original, mu, g.internalId);
        step.factors.push_back(g.wrapper);
      }
      const UpdateResult r = inner_->update(step);
      result.seconds += r.seconds;
      result.relinearized += r.relinearized;
      ++lastInnerUpdates_;
    }
  }
  return result;
}

std::vector<std::pair<FactorId, double>> RisamBackend::decisions() const {
  std::vector<std::pair<FactorId, double>> out;
  out.reserve(graduated_.size());
  const Values& x = inner_->estimate();
  for (const auto& f : originals_.factors()) {
    auto it = graduated_.find(f->id());
    if (it != graduated_.end()) out.emplace_back(f->id(), it->second.wrapper->weightAt(x));
  }
  return out;
}

std::vector<FactorId> RisamBackend::rejected() const {
  std::vector<FactorId> out;
  const Values& x = inner_->estimate();
  for (const auto& f : originals_.factors())
    if (graduated_.count(f->id()) &&
        !(f->chi2(x) <= chi2Quantile(f->dim(), options_.rejectChi2Probability)))
      out.push_back(f->id());
  return out;
}

}  // namespace loopd
