// What the engine publishes after an update or on request: estimates (in the common frame),
// covariances, the status with its per-factor decisions and live hypotheses.
#include "server/engine.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <set>

#include "loopd/covariance_t.hpp"
#include "loopd/estimate_t.hpp"
#include "loopd/status_t.hpp"
#include "robust/ambiguous_choice.h"
#include "robust/mh_backend.h"
#include "server/wire.h"
#include "server/wire_factors.h"
#include "solvers/factors/anchored_between_factor.h"

namespace loopd::server {

using Clock = std::chrono::steady_clock;

void Engine::afterUpdate(const std::vector<Key>& moved, double seconds, bool optimizeRun) {
  ++updateSeq_;
  {
    std::lock_guard<std::mutex> l(countersMu_);
    ++counters_.updates;
  }
  if (!optimizeRun) {
    lastUpdateMs_ = seconds * 1e3;
    sumUpdateMs_ += lastUpdateMs_;
  }
  ++updatesSinceSnapshot_;
  if (opt_.publishEvery > 0 && updatesSinceSnapshot_ >= opt_.publishEvery) {
    updatesSinceSnapshot_ = 0;
    publishEstimates(nullptr, 0, -1);
  } else {
    publishEstimates(&moved, 0, -1);
  }
  if (queueDepth() == 0) publishLatestCovariances();
  publishStatus(0, false);
}

void Engine::publishEstimates(const std::vector<Key>* moved, std::int64_t requestId, int onlyRobot,
                              const Values* values, int hypothesis) {
  const Values& est = values ? *values : backend_->estimate();
  // Which robots to publish fully (snapshot, or their anchor moved) and which keys otherwise.
  std::map<std::uint32_t, std::vector<Key>> keysOf;
  std::set<std::uint32_t> full;
  if (!moved) {
    for (const auto& [r, info] : robots_) full.insert(r);
  } else {
    for (Key k : *moved) {
      if (keyKind(k) == KeyKind::Anchor)
        full.insert(keyRobot(k));
      else if (keyKind(k) == KeyKind::Pose || keyKind(k) == KeyKind::Landmark)
        keysOf[keyRobot(k)].push_back(k);
    }
  }
  // A landmark namespace moves with the robot whose frame it lives in.
  for (const auto& [ns, r] : adopted_)
    if (full.count(r)) full.insert(ns);
  if (!full.empty())
    for (int s = 0; s < est.size(); ++s) {
      const Key k = est.key(s);
      if (full.count(keyRobot(k)) &&
          (keyKind(k) == KeyKind::Pose || keyKind(k) == KeyKind::Landmark))
        keysOf[keyRobot(k)].push_back(k);
    }
  for (auto& [r, keys] : keysOf) {
    if (onlyRobot >= 0 && static_cast<int>(r) != onlyRobot) continue;
    const std::uint32_t fr = landmarkFrame(r);  // r, or the robot a namespace lives with
    auto rit = robots_.find(fr);
    RobotEstimate e;
    e.robot = static_cast<std::int32_t>(r);
    e.hypothesis = hypothesis;
    e.fullSnapshot = full.count(r) > 0 && !moved ? true : full.count(r) > 0;
    e.se3 = rit != robots_.end() && rit->second.poseType == VarType::SE3;
    const bool anchored =
        rit != robots_.end() && rit->second.anchored && est.contains(anchorKey(fr));
    e.commonFrame = anchored;
    e.frameRobot = static_cast<std::int32_t>(anchored ? root(fr) : fr);
    std::sort(keys.begin(), keys.end());
    keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
    SE2 A2;
    SE3 A3;
    if (anchored) {
      if (e.se3)
        A3 = se3Of(est, anchorKey(fr));
      else
        A2 = se2Of(est, anchorKey(fr));
    }
    for (Key k : keys) {
      const int s = est.slot(k);
      if (s < 0) continue;
      switch (est.type(s)) {
        case VarType::SE2: {
          const SE2 x = anchored ? A2 * est.se2(s) : est.se2(s);
          e.poseIndices.push_back(static_cast<std::int64_t>(keyIndex(k)));
          e.poses.push_back({x.x, x.y, x.theta});
          break;
        }
        case VarType::SE3: {
          const SE3 x = anchored ? A3 * est.se3(s) : est.se3(s);
          std::vector<double> v(7);
          x.toTranslationQuaternion(v.data());
          e.poseIndices.push_back(static_cast<std::int64_t>(keyIndex(k)));
          e.poses.push_back(v);
          break;
        }
        case VarType::Point2: {
          const Vec2 p = anchored ? A2.transform(est.point2(s)) : est.point2(s);
          e.landmarkIndices.push_back(static_cast<std::int64_t>(keyIndex(k)));
          e.landmarks.push_back({p.x(), p.y()});
          break;
        }
        case VarType::Point3: {
          const Vec3 p = anchored ? A3.transform(est.point3(s)) : est.point3(s);
          e.landmarkIndices.push_back(static_cast<std::int64_t>(keyIndex(k)));
          e.landmarks.push_back({p.x(), p.y(), p.z()});
          e.landmarks3d = true;
          break;
        }
        default:
          break;
      }
    }
    pub_.estimate(e, updateSeq_, requestId);
  }
}

Eigen::MatrixXd Engine::commonFrameCovariance(const std::vector<Key>& keys) {
  // Σ of A_r ⊕ x_r: J·Σ(x, A)·Jᵀ with ∂/∂x = I, ∂/∂A = Ad(x⁻¹) (poses), R_A·[I, …] (points).
  const Values& est = backend_->estimate();
  std::vector<Key> vars = keys;
  std::vector<int> anchorCol(keys.size(), -1);
  for (size_t i = 0; i < keys.size(); ++i) {
    const std::uint32_t r = frameOf(keys[i]);
    if (!robotJoined(r) || !est.contains(anchorKey(r))) continue;
    auto it = std::find(vars.begin(), vars.end(), anchorKey(r));
    if (it == vars.end()) {
      vars.push_back(anchorKey(r));
      it = vars.end() - 1;
    }
    anchorCol[i] = static_cast<int>(it - vars.begin());
  }
  std::vector<int> off(vars.size() + 1, 0);
  for (size_t i = 0; i < vars.size(); ++i)
    off[i + 1] = off[i] + varDim(est.type(est.slot(vars[i])));
  const Eigen::MatrixXd S = backend_->marginalCovariance(vars);
  if (vars.size() == keys.size()) return S;
  const int D = off[keys.size()];
  Eigen::MatrixXd J = Eigen::MatrixXd::Zero(D, off.back());
  for (size_t i = 0; i < keys.size(); ++i) {
    const int s = est.slot(keys[i]);
    const int d = varDim(est.type(s));
    J.block(off[i], off[i], d, d).setIdentity();
    if (anchorCol[i] < 0) continue;
    const int ac = off[static_cast<size_t>(anchorCol[i])];
    const int as = est.slot(vars[static_cast<size_t>(anchorCol[i])]);
    switch (est.type(s)) {
      case VarType::SE2:
        J.block(off[i], ac, 3, 3) = adjointSE2(est.se2(s).inverse());
        break;
      case VarType::SE3:
        J.block(off[i], ac, 6, 6) = est.se3(s).inverse().adjoint();
        break;
      case VarType::Point2: {
        const Mat2 R = est.se2(as).R();
        const Vec2 p = est.point2(s);
        J.block(off[i], off[i], 2, 2) = R;
        J.block(off[i], ac, 2, 2) = R;
        J.block(off[i], ac + 2, 2, 1) = R * Vec2(-p.y(), p.x());
        break;
      }
      case VarType::Point3: {
        const Mat3 R = est.se3(as).R;
        J.block(off[i], off[i], 3, 3) = R;
        J.block(off[i], ac, 3, 3) = R;
        J.block(off[i], ac + 3, 3, 3) = -R * hat(est.point3(s));
        break;
      }
      default:
        break;
    }
  }
  return J * S * J.transpose();
}

void Engine::publishLatestCovariances() {
  if (robots_.empty()) return;
  loopd::covariance_t m{};
  m.update_seq = updateSeq_;
  m.request_id = 0;
  m.chunk_index = 0;
  m.chunk_count = 1;
  m.joint = false;
  try {
    for (const auto& [r, info] : robots_) {
      if (info.latestIndex < 0) continue;
      const Key k = makeKey(r, KeyKind::Pose, static_cast<std::uint64_t>(info.latestIndex));
      if (!backend_->estimate().contains(k)) continue;
      const Eigen::MatrixXd c = commonFrameCovariance({k});
      m.keys.push_back(toWireKey(k));
      m.dims.push_back(static_cast<std::int8_t>(c.rows()));
      for (int i = 0; i < c.rows(); ++i)
        for (int j = 0; j < c.cols(); ++j) m.values.push_back(c(i, j));
      if (static_cast<int>(m.keys.size()) >= loopd::covariance_t::MAX_KEYS) break;
    }
  } catch (const std::exception& e) {
    spdlog::warn("latest-pose covariances failed: {}", e.what());
    return;
  }
  if (!m.keys.empty()) pub_.covariance(m);
}

std::vector<loopd::loop_decision_t> Engine::decisionList(bool full) {
  std::vector<loopd::loop_decision_t> out;
  std::unordered_map<FactorId, double> now;
  for (const auto& [id, w] : backend_->decisions()) now[id] = w;
  // Uncertain factors the solver does not judge are trusted (weight 1).
  for (const auto& [fid, o] : owners_) {
    if (!o.uncertain) continue;
    auto it = now.find(fid);
    const double w = it == now.end() ? 1.0 : it->second;
    auto old = lastDecisions_.find(fid);
    const bool changed = old == lastDecisions_.end() || std::abs(old->second - w) > 1e-3;
    if (full || changed) {
      loopd::loop_decision_t d{};
      d.sender = o.sender;
      d.factor_id = o.id;
      d.ambiguous = false;
      d.alternative = 0;
      d.accepted = w >= 0.5;
      d.weight = w;
      out.push_back(d);
    }
    if (changed) lastDecisions_[fid] = w;
  }
  // Ambiguous groups: the best hypothesis's choice (other variants: the alternative their
  // decisions favour). weight: mh, the share of live hypotheses making that choice (1 =
  // settled); others, the chosen alternative's decision weight (0 for none).
  if (!groups_.empty()) {
    std::vector<AmbiguousFactor> ms;
    ms.reserve(groups_.size());
    for (const auto& [gid, g] : groups_) ms.push_back(g.factor);
    const std::vector<int> chosen = chosenAlternatives(*backend_, ms);
    std::vector<double> share(ms.size(), 1.0);
    if (const auto* mh = dynamic_cast<const MhBackend*>(&backend_->solver())) {
      const auto hyps = mh->hypotheses(mh->liveHypotheses());
      for (size_t l = 0; l < ms.size(); ++l) {
        int agree = 0, n = 0;
        for (const auto& h : hyps)
          if (l < h.choices.size()) {
            ++n;
            agree += h.choices[l] == chosen[l];
          }
        share[l] = n > 0 ? static_cast<double>(agree) / n : 1.0;
      }
    } else {
      std::unordered_map<FactorId, double> w;
      for (const auto& [id, x] : backend_->decisions()) w[id] = x;
      for (size_t l = 0; l < ms.size(); ++l) {
        if (chosen[l] < 0) {
          share[l] = 0.0;
          continue;
        }
        const auto it = w.find(ms[l].alternatives[static_cast<size_t>(chosen[l])]->id());
        share[l] = it == w.end() ? 1.0 : it->second;
      }
    }
    size_t l = 0;
    for (const auto& [gid, g] : groups_) {
      const std::pair<int, double> d{chosen[l], share[l]};
      ++l;
      auto old = lastGroupDecisions_.find(gid);
      const bool changed = old == lastGroupDecisions_.end() || old->second.first != d.first ||
                           std::abs(old->second.second - d.second) > 1e-3;
      if (full || changed) {
        loopd::loop_decision_t x{};
        x.sender = g.sender;
        x.factor_id = g.id;
        x.ambiguous = true;
        x.alternative = d.first;
        x.accepted = d.first >= 0;
        x.weight = d.second;
        out.push_back(x);
      }
      if (changed) lastGroupDecisions_[gid] = d;
    }
  }
  std::sort(out.begin(), out.end(), [](const auto& a, const auto& b) {
    return a.sender != b.sender ? a.sender < b.sender : a.factor_id < b.factor_id;
  });
  return out;
}

void Engine::publishStatus(std::int64_t requestId, bool fullDecisions, int hypotheses) {
  lastStatus_ = Clock::now();
  loopd::status_t s{};
  s.update_seq = updateSeq_;
  s.request_id = requestId;
  s.solver = backend_->name();
  s.converged = !dirty_;
  s.robots = static_cast<std::int32_t>(robots_.size());
  for (const auto& [r, info] : robots_) s.robots_in_common_frame += info.anchored ? 1 : 0;
  const Values& est = backend_->estimate();
  for (Key k : est.keys()) {
    if (keyKind(k) == KeyKind::Pose)
      ++s.poses;
    else if (keyKind(k) == KeyKind::Landmark)
      ++s.landmarks;
  }
  s.factors = static_cast<std::int64_t>(live_.size());
  s.loop_closures = loopClosures_;
  for (FactorId id : backend_->rejected()) {
    const auto it = owners_.find(id);  // the sender's own loop closures (not alternatives)
    s.loop_closures_rejected += it != owners_.end() && it->second.uncertain ? 1 : 0;
  }
  s.ambiguous = static_cast<std::int64_t>(groups_.size());
  s.last_update_ms = lastUpdateMs_;
  const EngineCounters c = counters();
  s.mean_update_ms = c.updates > 0 ? sumUpdateMs_ / static_cast<double>(c.updates) : 0.0;
  try {
    s.chi2 = backend_->graph().empty() ? 0.0 : backend_->chi2();
  } catch (const std::exception&) {
    s.chi2 = -1.0;
  }
  s.queue_depth = queueDepth();
  s.batches_accepted = c.accepted;
  s.batches_rejected = c.rejected;
  s.batches_duplicate = c.duplicate;
  s.batches_held = static_cast<std::int64_t>(holds_.size());
  s.batches_expired = c.expired;
  for (const auto& g : sessions_.gaps()) {
    if (static_cast<int>(s.sender_gaps.size()) >= loopd::status_t::MAX_SENDER_GAPS) break;
    loopd::sender_gap_t w{};
    w.sender = g.sender;
    w.last_contiguous = g.lastContiguous;
    w.highest = g.highest;
    w.missing = g.missing;
    s.sender_gaps.push_back(w);
  }
  s.decisions_full = fullDecisions;
  s.live_hypotheses = 1;
  s.undecided_ambiguous = 0;
  if (const auto* mh = dynamic_cast<const MhBackend*>(&backend_->solver())) {
    s.live_hypotheses = mh->liveHypotheses();
    const auto hyps = mh->hypotheses(mh->liveHypotheses());
    // Layers are the groups in arrival order (= ascending internal id, as fed to the backend).
    std::vector<const Group*> layer;
    for (const auto& [gid, g] : groups_) layer.push_back(&g);
    std::vector<size_t> undecided;  // layers the live hypotheses disagree on
    for (size_t l = 0; l < layer.size(); ++l) {
      bool differ = false;
      for (const auto& h : hyps)
        differ |= l >= h.choices.size() || h.choices[l] != hyps.front().choices[l];
      if (differ) undecided.push_back(l);
    }
    s.undecided_ambiguous = static_cast<std::int32_t>(undecided.size());
    const int top = std::min<int>(hypotheses < 0 ? loopd::status_t::MAX_HYPOTHESES : hypotheses,
                                  loopd::status_t::MAX_HYPOTHESES);
    for (int r = 0; r < top && r < static_cast<int>(hyps.size()); ++r) {
      loopd::hypothesis_t h{};
      h.rank = r;
      h.score = hyps[static_cast<size_t>(r)].score;
      for (auto it = undecided.rbegin(); it != undecided.rend(); ++it) {  // newest first
        if (static_cast<int>(h.choices.size()) >= loopd::hypothesis_t::MAX_CHOICES) break;
        const auto& c = hyps[static_cast<size_t>(r)].choices;
        loopd::hypothesis_choice_t x{};
        x.sender = layer[*it]->sender;
        x.ambiguous_id = layer[*it]->id;
        x.alternative = *it < c.size() ? c[*it] : -1;
        h.choices.push_back(x);
      }
      h.num_choices = static_cast<std::int16_t>(h.choices.size());
      s.hypotheses.push_back(h);
    }
  }
  pub_.status(s, decisionList(fullDecisions));
}

}  // namespace loopd::server
