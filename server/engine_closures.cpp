// Inter-robot loop closures under a solver that judges loop closures (engine.h): kept back
// while their robots' frames are not joined, until enough of a pair's agree on the transform
// between the frames (closure_agreement.h). Each closure alone fixes that transform, so joining
// on the first one, as a trusted closure does, let a wrong one decide it: mm with two robots on
// intel + 100 random wrong closures then rejected the true closures that disagreed with it
// (204 rejected, 14 m off; one robot exact).
#include <spdlog/spdlog.h>

#include <algorithm>
#include <optional>
#include <set>

#include "server/closure_agreement.h"
#include "server/engine.h"
#include "server/own_map_relaxation.h"
#include "server/wire_factors.h"
#include "solvers/factors/between_factor_se2.h"
#include "solvers/factors/between_factor_se3.h"

namespace loopd::server {

namespace {
// The closure the server would apply for wire factor wf (its robust request included).
std::shared_ptr<Factor> requested(const loopd::factor_t& wf) {
  std::shared_ptr<Factor> f = buildFactor(wf);
  f->setRobustRequest({wf.robust, wf.robust_param});
  return f;
}
}  // namespace

bool Engine::keepsBack(const Factor& f) const {
  return !joinsAtOnce(f) && !shareFrame(keyRobot(f.key(0)), keyRobot(f.key(1)));
}

bool Engine::joinsAtOnce(const Factor& f) const {
  return opt_.joinAgreement <= 1 || !backend_->mayDownWeight(f);
}

bool Engine::joinsAtOnce(const loopd::factor_t& wf) const {
  return opt_.joinAgreement <= 1 || joinsAtOnce(*requested(wf));
}

bool Engine::shareFrame(std::uint32_t r, std::uint32_t s) const {
  return robots_.at(r).anchored && robots_.at(s).anchored && root(r) == root(s);
}

void Engine::frameOffset(const Factor& z, SE2& m2, SE3& m3) const {
  const Key xr = z.key(0), xs = z.key(1);
  if (const auto* b = dynamic_cast<const BetweenFactorSE2*>(&z))
    m2 = se2Of(*holder(xr), xr) * b->measured() * se2Of(*holder(xs), xs).inverse();
  else
    m3 = se3Of(*holder(xr), xr) * static_cast<const BetweenFactorSE3&>(z).measured() *
         se3Of(*holder(xs), xs).inverse();
}

void Engine::stageInterRobotClosures(const std::vector<KeptBack>& closures, Staged& st) {
  std::set<RobotPair> arrived;
  for (const KeptBack& c : closures) {
    const RobotPair pair = std::minmax(keyRobot(c.factor->key(0)), keyRobot(c.factor->key(1)));
    std::vector<KeptBack>& list = pendingClosures_[pair];
    if (list.empty())
      spdlog::info(
          "loop closures between robots {} and {} are kept back until {} of them agree on the "
          "transform between their frames (one alone, right or wrong, would fix it)",
          pair.first, pair.second, opt_.joinAgreement);
    list.push_back(c);
    arrived.insert(pair);
  }
  std::optional<std::set<FactorId>> rejected;  // read once, only if some pair is tested
  for (const RobotPair& pair : arrived) {
    const auto it = pendingClosures_.find(pair);
    if (static_cast<int>(it->second.size()) < opt_.joinAgreement ||
        shareFrame(pair.first, pair.second))
      continue;
    std::vector<FactorPtr> factors;
    for (const KeptBack& c : it->second) factors.push_back(c.factor);
    if (!rejected) rejected = rejectedFactors();
    const std::vector<size_t> agree = agreeingPairClosures(pairMaps(pair, &st, *rejected), factors);
    if (static_cast<int>(agree.size()) < opt_.joinAgreement) continue;
    const Factor& z = *it->second[agree.front()].factor;
    SE2 m2;
    SE3 m3;
    frameOffset(z, m2, m3);
    spdlog::info(
        "robots {} and {}: {} of their {} kept-back loop closures agree; joining their "
        "frames",
        pair.first, pair.second, agree.size(), it->second.size());
    const std::int64_t placed = joinRobots(keyRobot(z.key(0)), keyRobot(z.key(1)), m2, m3, st);
    if (placed < 0) continue;  // cannot happen: the pair does not share a frame
    JoinCheck check;
    check.placed = static_cast<std::uint32_t>(placed);
    for (size_t a : agree) check.joiners.insert(it->second[a].factor->id());
    st.joinsMade.emplace_back(pair, std::move(check));
  }
  releaseJoinedClosures(st);
}

std::set<FactorId> Engine::rejectedFactors() const {
  const std::vector<FactorId> ids = backend_->rejected();
  return std::set<FactorId>(ids.begin(), ids.end());
}

Engine::PairMaps Engine::pairMaps(const RobotPair& pair, const Staged* building,
                                  const std::set<FactorId>& rejected) const {
  auto inPair = [&](Key k) {
    return keyKind(k) == KeyKind::Pose && (keyRobot(k) == pair.first || keyRobot(k) == pair.second);
  };
  // The two robots' odometry and own loop closures (committed but those the solver rejects,
  // staged, `building`'s) and poses, each in its frame.
  PairMaps maps;
  auto withinOneRobot = [&](const FactorPtr& f) {
    return f->size() == 2 && inPair(f->key(0)) && keyKind(f->key(1)) == KeyKind::Pose &&
           keyRobot(f->key(1)) == keyRobot(f->key(0));
  };
  auto take = [&](const FactorPtr& f) {
    if (!withinOneRobot(f)) return;
    if (f->role() == FactorRole::Odometry)
      maps.odometry.push_back(f);
    else if (f->role() == FactorRole::LoopClosure)
      maps.ownClosures.push_back(f);
  };
  for (const auto& [id, f] : live_) {
    if (!rejected.count(id))
      take(f);
    else if (f->role() == FactorRole::LoopClosure && withinOneRobot(f))
      maps.rejectedOwnClosures.push_back(f);
  }
  for (const Staged& s : staged_)
    for (const FactorPtr& f : s.update.factors) take(f);
  if (building)
    for (const FactorPtr& f : building->update.factors) take(f);
  for (const Values* v : {&backend_->estimate(), static_cast<const Values*>(&stagedValues_)})
    for (int s = 0; s < v->size(); ++s)
      if (inPair(v->key(s))) maps.poses.insertFrom(*v, s);
  maps.closureScale = ownClosureNoiseScale(maps.ownClosures, maps.odometry, maps.poses);
  return maps;
}

Engine::PairMaps Engine::relaxedPairMaps(PairMaps maps) {
  std::vector<FactorPtr> own = maps.odometry;
  own.insert(own.end(), maps.ownClosures.begin(), maps.ownClosures.end());
  relaxOwnMaps(own, maps.poses, kRelaxIterations);
  const std::vector<FactorPtr> back = closuresThatFit(maps.rejectedOwnClosures, maps.poses);
  if (!back.empty()) {
    own.insert(own.end(), back.begin(), back.end());
    maps.ownClosures.insert(maps.ownClosures.end(), back.begin(), back.end());
    relaxOwnMaps(own, maps.poses, kRelaxIterations);
  }
  maps.closureScale = ownClosureNoiseScale(maps.ownClosures, maps.odometry, maps.poses);
  return maps;
}

std::vector<size_t> Engine::agreeingPairClosures(const PairMaps& maps,
                                                 const std::vector<FactorPtr>& closures) const {
  return agreeingClosures(closures, maps.odometry, maps.poses, opt_.joinProbability,
                          maps.closureScale);
}

void Engine::releaseJoinedClosures(Staged& st) {
  for (auto it = pendingClosures_.begin(); it != pendingClosures_.end();) {
    const auto [a, b] = it->first;
    if (!shareFrame(a, b)) {
      ++it;
      continue;
    }
    for (const KeptBack& c : it->second) {
      st.update.factors.push_back(anchoredFactor(*c.factor));
      st.owners.push_back(c.owner);
      st.pairClosures.push_back(c.factor);
    }
    spdlog::debug("robots {} and {} share a frame: their {} kept-back loop closures go in", a, b,
                  it->second.size());
    it = pendingClosures_.erase(it);
  }
}

}  // namespace loopd::server
