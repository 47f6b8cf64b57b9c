#include "robust/mh_backend.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <unordered_set>

#include "robust/robust_factors.h"
#include "solvers/backend/update_validation.h"
#include "solvers/problem/initial_guess.h"

namespace loopd {

namespace {

void appendMoved(std::vector<Key>& into, const std::vector<Key>& moved) {
  into.insert(into.end(), moved.begin(), moved.end());
}

/// How many of `sorted` (ascending score) survive: the best always, then those within `gap` of
/// it, at most `k`.
template <class Scored>
size_t survivors(const std::vector<Scored>& sorted, int k, double gap) {
  const double limit = sorted.front().score + gap;
  size_t keep = 1;
  while (keep < sorted.size() && keep < static_cast<size_t>(k) && sorted[keep].score <= limit)
    ++keep;
  return keep;
}

}  // namespace

MhBackend::MhBackend(BackendOptions options, MhOptions mh)
    : options_(std::move(options)), mh_(std::move(mh)) {
  if (options_.maxHypotheses > 0) mh_.maxHypotheses = options_.maxHypotheses;
  if (mh_.maxHypotheses < 1) throw std::invalid_argument("mh: max hypotheses must be at least 1");
  Hypothesis root;
  root.tree = std::make_unique<Isam2Backend>(options_, mh_.isam);
  live_.push_back(std::move(root));
}

double MhBackend::nullPenalty(const Layer& layer) const {
  double base = chi2Quantile(layer.dim, mh_.nullProbability);
  const auto tail = certainTail_.find(layer.dim);
  if (tail != certainTail_.end()) base = std::max(base, tail->second);
  return base - 2.0 * std::log(layer.nullWeight);
}

void MhBackend::refreshCertainTail() {
  // What "consistent" means in this data: χ² of the loop closures the front-end was sure of,
  // at the best estimate, per residual dimension.
  std::unordered_map<int, std::vector<double>> byDim;
  const Values& x = estimate();
  for (const auto& f : best().tree->graph().factors()) {
    if (!f || !isUncertain(f->role())) continue;
    const auto it = ids_.find(f->id());
    if (it == ids_.end() || it->second >= 0) continue;  // an alternative, not a certain one
    byDim[f->dim()].push_back(f->chi2(x));
  }
  certainTail_.clear();
  for (auto& [dim, chi2] : byDim) {
    if (static_cast<int>(chi2.size()) < mh_.minTailSamples) continue;
    const size_t k = std::min(chi2.size() - 1, static_cast<size_t>(mh_.tailQuantile * chi2.size()));
    std::nth_element(chi2.begin(), chi2.begin() + k, chi2.end());
    certainTail_[dim] = chi2[k];
  }
}

void MhBackend::validate(const BackendUpdate& u, const Values& initial) const {
  // The plain part and every alternative must pass as one ordinary update would.
  BackendUpdate flat;
  flat.factors = u.factors;
  flat.initial = u.initial;
  flat.removals = u.removals;
  for (FactorId id : u.removals) {
    const auto it = ids_.find(id);
    if (it != ids_.end() && it->second >= 0)
      throw std::invalid_argument("factor " + std::to_string(id) +
                                  " is an alternative of an ambiguous measurement: it cannot be "
                                  "removed on its own");
  }
  // Keys an alternative may use: existing ones and those the plain factors bring.
  std::unordered_set<Key> plainKeys;
  for (const auto& f : u.factors)
    if (f)
      for (int k = 0; k < f->size(); ++k) plainKeys.insert(f->key(k));
  std::unordered_set<FactorId> newMeasurements;
  for (const AmbiguousFactor& a : u.ambiguous) {
    const std::string what = "ambiguous measurement " + std::to_string(a.id);
    if (layerIndex_.count(a.id) || !newMeasurements.insert(a.id).second)
      throw std::invalid_argument(what + ": duplicate id");
    if (a.alternatives.empty()) throw std::invalid_argument(what + " has no alternatives");
    if (!(a.nullWeight > 0.0) || !std::isfinite(a.nullWeight))
      throw std::invalid_argument(what + ": null weight must be positive and finite");
    if (a.alternatives.size() == 1 && !a.nullHypothesis)
      throw std::invalid_argument(what + " has one alternative and no null: send a factor");
    const int dim = a.alternatives.front() ? a.alternatives.front()->dim() : 0;
    for (const auto& f : a.alternatives) {
      if (!f) throw std::invalid_argument(what + " has a null alternative");
      if (f->dim() != dim)
        throw std::invalid_argument(what + ": alternatives of different dimensions");
      for (int k = 0; k < f->size(); ++k) {
        if (!estimate().contains(f->key(k)) && !plainKeys.count(f->key(k)))
          throw std::invalid_argument(what + " refers to " + keyToString(f->key(k)) +
                                      ", which neither exists nor comes with this update's "
                                      "factors");
      }
      flat.factors.push_back(f);
    }
  }
  validateUpdate(flat, estimate(), ids_, initial);
}

UpdateResult MhBackend::update(const BackendUpdate& u) {
  const auto t0 = std::chrono::steady_clock::now();
  Values initial = u.initial;
  predictMissingValues(u.factors, estimate(), initial);
  validate(u, initial);

  const Isam2Backend* bestBefore = best().tree.get();
  for (Hypothesis& h : live_) h.moved.clear();
  UpdateResult result;
  for (const auto& f : u.factors) ids_.emplace(f->id(), -1);
  for (FactorId id : u.removals) ids_.erase(id);
  // While several hypotheses live, every new loop closure scores in each of them: that is how
  // later data decide between hypotheses. Scored before it is added (the exact innovation),
  // the closures over variables that exist once the rest is in go in a second inner update.
  BackendUpdate first, second;
  first.initial = initial;
  first.removals = u.removals;
  if (live_.size() > 1)
    splitScored(u.factors, first.factors, second.factors);
  else
    first.factors = u.factors;
  auto apply = [&](const BackendUpdate& part) {
    if (part.factors.empty() && part.initial.empty() && part.removals.empty()) return;
    for (Hypothesis& h : live_) {
      const UpdateResult r = h.tree->update(part);
      appendMoved(h.moved, r.moved);
      result.relinearized = std::max(result.relinearized, r.relinearized);
    }
  };
  apply(first);
  if (!second.factors.empty()) {
    for (Hypothesis& h : live_)
      for (const auto& f : second.factors) h.score += predictedIncrease(h, *f);
    apply(second);
    prune();
  }
  for (const AmbiguousFactor& a : u.ambiguous) {
    Layer layer;
    layer.id = a.id;
    layer.alternatives = a.alternatives;
    layer.null = a.nullHypothesis;
    layer.nullWeight = a.nullWeight;
    layer.dim = a.alternatives.front()->dim();
    const int l = static_cast<int>(layers_.size());
    layers_.push_back(std::move(layer));
    layerIndex_.emplace(a.id, l);
    for (const auto& f : a.alternatives) ids_.emplace(f->id(), l);
    branch(l);
  }
  if (live_.size() == 1) live_.front().score = 0.0;  // scores only rank live hypotheses
  ++updates_;
  liveSum_ += static_cast<long>(live_.size());
  // Sampled (it walks every live tree): the most the hypotheses held together.
  if (live_.size() > 1 && updates_ % 16 == 0) {
    const Storage s = cliqueStorage();
    if (s.sharedBytes > peakStorage_.sharedBytes) peakStorage_ = s;
  }

  if (best().tree.get() != bestBefore) {
    result.moved = estimate().keys();  // another hypothesis leads: everything may differ
  } else {
    result.moved = best().moved;
    std::sort(result.moved.begin(), result.moved.end());
    result.moved.erase(std::unique(result.moved.begin(), result.moved.end()), result.moved.end());
  }
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return result;
}

double MhBackend::predictedIncrease(Hypothesis& h, const Factor& f) {
  const Values& x = h.tree->estimate();
  const int d = f.dim();
  std::array<const double*, kMaxFactorKeys> ptr{};
  std::array<JacobianBlock, kMaxFactorKeys> blocks{};
  std::array<double*, kMaxFactorKeys> jac{};
  std::vector<Key> keys;
  std::array<int, kMaxFactorKeys + 1> offset{};
  for (int k = 0; k < f.size(); ++k) {
    const int s = x.slot(f.key(k));
    ptr[k] = x.data(s);
    jac[k] = blocks[k].data();
    keys.push_back(f.key(k));
    offset[k + 1] = offset[k] + varDim(x.type(s));
  }
  Eigen::Matrix<double, kMaxResidualDim, 1> r;
  f.evaluate(ptr.data(), r.data(), jac.data());
  Eigen::MatrixXd J(d, offset[f.size()]);
  for (int k = 0; k < f.size(); ++k) {
    const int n = offset[k + 1] - offset[k];
    J.middleCols(offset[k], n) = Eigen::Map<const Eigen::MatrixXd>(blocks[k].data(), d, n);
  }
  const Eigen::MatrixXd sigma = h.tree->marginalCovariance(keys);
  // Δ = rᵀS⁻¹r, S = I + JΣJᵀ: the exact increase of the minimum for a linear problem.
  Eigen::MatrixXd S = J * sigma * J.transpose();
  S.diagonal().array() += 1.0;  // whitened measurement noise
  const Eigen::VectorXd rd = r.head(d);
  Eigen::LLT<Eigen::MatrixXd> llt(S);
  const double increase = llt.info() == Eigen::Success ? rd.dot(llt.solve(rd)) : -1.0;
  // Unusable numerics (NaN, indefinite S) make the alternative implausible, never a NaN score.
  return increase >= 0.0 && std::isfinite(increase) ? increase
                                                    : std::numeric_limits<double>::infinity();
}

void MhBackend::branch(int l) {
  const Layer& layer = layers_[l];
  if (layer.null) refreshCertainTail();
  const double gate = chi2Quantile(layer.dim, mh_.gateProbability);
  std::vector<Child> children;
  for (int p = 0; p < static_cast<int>(live_.size()); ++p) {
    Hypothesis& parent = live_[p];
    const size_t first = children.size();
    double lowest = std::numeric_limits<double>::infinity();
    int lowestAt = 0;
    for (int a = 0; a < static_cast<int>(layer.alternatives.size()); ++a) {
      const double increase = predictedIncrease(parent, *layer.alternatives[a]);
      if (increase < lowest) {
        lowest = increase;
        lowestAt = a;
      }
      if (increase <= gate)
        children.push_back({p, a, parent.score + increase});
      else
        ++predictedAway_;
    }
    if (layer.null) children.push_back({p, -1, parent.score + nullPenalty(layer)});
    // Without a null, one alternative is true: keep the least implausible.
    if (children.size() == first) children.push_back({p, lowestAt, parent.score + lowest});
  }
  std::stable_sort(children.begin(), children.end(),
                   [](const Child& a, const Child& b) { return a.score < b.score; });
  const size_t keep = survivors(children, mh_.maxHypotheses, pruneGap());
  predictedAway_ += static_cast<long>(children.size() - keep);
  children.resize(keep);

  // Build the survivors: copies first, the parent's own tree goes to its last child.
  std::vector<int> remaining(live_.size(), 0);
  for (const Child& c : children) ++remaining[c.parent];
  std::vector<Hypothesis> next;
  next.reserve(children.size());
  for (const Child& c : children) {
    Hypothesis& parent = live_[c.parent];
    Hypothesis child;
    if (--remaining[c.parent] > 0) {
      child.tree = std::make_unique<Isam2Backend>(*parent.tree);
      ++branchesBuilt_;
    } else {
      child.tree = std::move(parent.tree);
    }
    child.choices = parent.choices;
    child.choices.push_back(c.choice);
    child.moved = parent.moved;
    child.score = c.score;
    if (c.choice >= 0) {
      BackendUpdate add;
      add.factors.push_back(layer.alternatives[c.choice]);
      appendMoved(child.moved, child.tree->update(add).moved);
    }
    next.push_back(std::move(child));
  }
  live_ = std::move(next);
}

void MhBackend::splitScored(const std::vector<FactorPtr>& factors, std::vector<FactorPtr>& first,
                            std::vector<FactorPtr>& scored) const {
  std::unordered_set<Key> reached;  // variables the unscored part constrains
  for (const auto& f : factors)
    if (!isUncertain(f->role()))
      for (int k = 0; k < f->size(); ++k) reached.insert(f->key(k));
  const Values& x = estimate();
  for (const auto& f : factors) {
    bool scorable = isUncertain(f->role());
    for (int k = 0; k < f->size() && scorable; ++k)
      scorable = x.contains(f->key(k)) || reached.count(f->key(k));
    (scorable ? scored : first).push_back(f);
  }
}

MhBackend::Storage MhBackend::cliqueStorage() const {
  Storage s;
  std::unordered_set<const double*> seen;
  for (const Hypothesis& h : live_) {
    s.sharedBytes += h.tree->cliqueStorageBytes(&seen);
    s.unsharedBytes += h.tree->cliqueStorageBytes();
  }
  return s;
}

void MhBackend::rescore() {
  refreshCertainTail();
  for (Hypothesis& h : live_) {
    double penalty = 0.0;
    for (size_t l = 0; l < h.choices.size(); ++l)
      if (h.choices[l] < 0) penalty += nullPenalty(layers_[l]);
    h.score = h.tree->chi2() + penalty;
  }
}

void MhBackend::prune() {
  std::stable_sort(live_.begin(), live_.end(),
                   [](const Hypothesis& a, const Hypothesis& b) { return a.score < b.score; });
  live_.resize(survivors(live_, mh_.maxHypotheses, pruneGap()));
}

void MhBackend::optimize() {
  for (Hypothesis& h : live_) h.tree->optimize();
  // At the optimum χ² itself ranks the hypotheses (the running scores are predictions).
  if (live_.size() > 1) {
    rescore();
    prune();
  }
}

Eigen::MatrixXd MhBackend::marginalCovariance(const std::vector<Key>& keys) {
  return live_.front().tree->marginalCovariance(keys);
}

std::vector<Eigen::MatrixXd> MhBackend::marginals(const std::vector<Key>& keys) {
  return live_.front().tree->marginals(keys);
}

std::vector<std::pair<FactorId, double>> MhBackend::decisions() const {
  std::vector<std::pair<FactorId, double>> out;
  for (size_t l = 0; l < layers_.size(); ++l) {
    const int chosen = best().choices[l];
    for (int a = 0; a < static_cast<int>(layers_[l].alternatives.size()); ++a)
      out.emplace_back(layers_[l].alternatives[a]->id(), a == chosen ? 1.0 : 0.0);
  }
  return out;
}

std::vector<FactorId> MhBackend::rejected() const {
  std::vector<FactorId> out;
  for (const auto& [id, weight] : decisions())
    if (weight == 0.0) out.push_back(id);
  return out;
}

std::optional<int> MhBackend::chosenAlternative(FactorId id) const {
  const auto it = layerIndex_.find(id);
  if (it == layerIndex_.end()) return std::nullopt;
  return best().choices[it->second];
}

std::vector<HypothesisSummary> MhBackend::hypotheses(int count) const {
  std::vector<HypothesisSummary> out;
  for (int i = 0; i < static_cast<int>(live_.size()) && i < count; ++i)
    out.push_back({live_[i].score, live_[i].choices, &live_[i].tree->estimate()});
  return out;
}

}  // namespace loopd
