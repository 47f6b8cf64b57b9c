// Factor batches through the engine: decoded, de-duplicated, validated and staged; held while
// they refer to poses not introduced yet; committed (journal, sessions, groups) and applied
// as one Backend update per round, or undone whole.
#include "server/engine.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <set>
#include <unordered_set>

#include "loopd/error_t.hpp"
#include "server/fingerprint.h"
#include "server/wire.h"
#include "server/wire_factors.h"
#include "solvers/factors/between_factor_se2.h"
#include "solvers/factors/between_factor_se3.h"
#include "solvers/problem/initial_guess.h"

namespace loopd::server {

using E = loopd::error_t;
using W = loopd::factor_t;
using Clock = std::chrono::steady_clock;

namespace {

// The journal's record of a batch number consumed without being applied (refused, expired),
// so that a resume knows it (no gap, a resend is a duplicate). A batch without a usable
// identity is refused without consuming a number (handleFactors): no record.
void journalConsumed(Journal* journal, bool replaying, const Publisher& pub,
                     const loopd::factor_batch_t& b, std::int8_t code, const std::string& reason) {
  if (!journal || replaying || b.sender.empty() || b.sender.size() > 63 || b.sequence < 1) return;
  if (!journal->appendConsumed(pub.channels().error, b.sender, b.sequence, code, reason,
                               nowUtime()))
    spdlog::error("journal {}: write failed", journal->path());
}

}  // namespace

void Engine::reject(const loopd::factor_batch_t& b, const std::vector<Issue>& issues,
                    const std::string& channel) {
  // Its number is consumed: journaled (before the errors report it) so that a resume knows.
  if (!issues.empty())
    journalConsumed(journal_, replaying_, pub_, b, issues.front().code, issues.front().reason);
  for (const auto& i : issues) {
    spdlog::warn("refused {}", describe(b, i));
    pub_.error(b.sender, b.sequence, 0, i.factorId, i.code, i.reason, channel);
  }
  std::lock_guard<std::mutex> l(countersMu_);
  ++counters_.rejected;
}

void Engine::handleFactors(std::shared_ptr<const Inbound> m, bool replayed) {
  const auto& bytes = m->bytes;
  auto decodeError = [&](std::int8_t code, const std::string& why) {
    spdlog::warn("{}: {}", m->channel, why);
    pub_.error("", 0, 0, -1, code, why, m->channel);
    std::lock_guard<std::mutex> l(countersMu_);
    ++counters_.decodeFailed;
    ++counters_.rejected;
  };
  if (static_cast<int>(bytes.size()) > opt_.maxMessageBytes) {
    decodeError(E::DECODE_FAILED,
                "message of " + std::to_string(bytes.size()) + " bytes exceeds the limit");
    return;
  }
  if (bytes.size() < 8) {
    decodeError(E::DECODE_FAILED,
                "message of " + std::to_string(bytes.size()) + " bytes is too short");
    return;
  }
  const std::int64_t hash = readFingerprint(bytes.data());
  if (hash != loopd::factor_batch_t::getHash()) {
    const std::string name = fingerprintName(hash);
    decodeError(E::WRONG_FINGERPRINT,
                "fingerprint does not match factor_batch_t" +
                    (name.empty() ? std::string(" (unknown type)") : " (it is a " + name + ")"));
    return;
  }
  auto b = std::make_shared<loopd::factor_batch_t>();
  int used = -1;
  try {
    used = b->decode(bytes.data(), 0, static_cast<int>(bytes.size()));
  } catch (const std::exception& e) {
    used = -1;
  }
  if (used < 0 || used != static_cast<int>(bytes.size())) {
    decodeError(E::DECODE_FAILED, used < 0
                                      ? "factor_batch_t does not decode (truncated or corrupt)"
                                      : "factor_batch_t followed by " +
                                            std::to_string(static_cast<int>(bytes.size()) - used) +
                                            " trailing bytes");
    return;
  }
  // Static checks of sender/sequence first: a batch without a usable identity is refused
  // without consuming a sequence number.
  std::vector<Issue> issues = validator_.check(*b);
  const bool identityOk = !b->sender.empty() && b->sender.size() <= 63 && b->sequence >= 1;
  if (identityOk && !sessions_.receive(b->sender, b->sequence)) {
    spdlog::debug("duplicate batch {} seq {} ignored", b->sender, b->sequence);
    std::lock_guard<std::mutex> l(countersMu_);
    ++counters_.duplicate;
    return;
  }
  if (issues.empty()) issues = validator_.checkContext(*b, *this);
  if (!issues.empty()) {
    reject(*b, issues, m->channel);
    return;
  }
  Decoded d{b, m, replayed};
  std::vector<Key> waiting;
  const StageResult r = stage(d, waiting);
  if (r == StageResult::Hold) {
    holds_.push_back({d, Clock::now(), waiting});
    spdlog::debug("holding {} seq {}: waiting for {}", b->sender, b->sequence,
                  keyToString(waiting.front()));
    if (static_cast<int>(holds_.size()) > opt_.holdMaxBatches) expireHolds(false);
  }
}

Engine::StageResult Engine::stage(const Decoded& d, std::vector<Key>& waiting) {
  const loopd::factor_batch_t& b = *d.batch;
  // Keys the batch refers to, and what is known of them.
  std::vector<Key> keys;
  for (const auto& f : b.factors)
    for (const auto& k : f.keys) keys.push_back(toKey(k));
  std::sort(keys.begin(), keys.end());
  keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
  // Keys of ambiguous alternatives: they must exist (or come with the batch's factors); they
  // never introduce or initialise a variable.
  std::vector<Key> altKeys;
  for (const auto& a : b.ambiguous)
    for (const auto& f : a.alternatives)
      for (const auto& k : f.keys) altKeys.push_back(toKey(k));
  std::sort(altKeys.begin(), altKeys.end());
  altKeys.erase(std::unique(altKeys.begin(), altKeys.end()), altKeys.end());
  Values knownVals, guess;
  for (Key k : keys)
    if (const Values* h = holder(k)) knownVals.insertFrom(*h, h->slot(k));
  for (Key k : altKeys)
    if (const Values* h = holder(k); h && !knownVals.contains(k))
      knownVals.insertFrom(*h, h->slot(k));
  for (const auto& v : b.initial_values) {
    const Key k = toKey(v.key);
    if (known(k) || guess.contains(k) || !std::binary_search(keys.begin(), keys.end(), k)) continue;
    switch (v.type) {
      case loopd::initial_value_t::SE2:
        guess.insert(k, SE2(v.value[0], v.value[1], v.value[2]));
        break;
      case loopd::initial_value_t::SE3:
        guess.insert(k, se3From(v.value));
        break;
      case loopd::initial_value_t::POINT2:
        guess.insertPoint2(k, Vec2(v.value[0], v.value[1]));
        break;
      default:
        guess.insertPoint3(k, Vec3(v.value[0], v.value[1], v.value[2]));
        break;
    }
  }
  // A robot never seen starts at the origin of its own frame: its lowest pose in the batch
  // (unless the front-end gave values, or earlier batches of this sender are missing). Only its
  // own factors introduce it: a closure from another robot to a pose of a robot not yet heard
  // from waits for that robot (else that pose became its origin, and its own first batches,
  // held behind it, expired).
  std::map<std::uint32_t, Key> lowestNew;
  std::set<std::uint32_t> robotsWithGuess;
  for (int s = 0; s < guess.size(); ++s)
    if (keyKind(guess.key(s)) == KeyKind::Pose) robotsWithGuess.insert(keyRobot(guess.key(s)));
  for (const auto& f : b.factors)
    for (int i = 0; i < f.num_keys && !isInterRobot(f); ++i) {
      const Key k = toKey(f.keys[static_cast<size_t>(i)]);
      if (keyKind(k) != KeyKind::Pose || robots_.count(keyRobot(k)) ||
          robotsWithGuess.count(keyRobot(k)))
        continue;
      auto it = lowestNew.find(keyRobot(k));
      if (it == lowestNew.end() || k < it->second) lowestNew[keyRobot(k)] = k;
    }
  std::map<std::uint32_t, VarType> newRobotType;
  for (const auto& f : b.factors)
    for (int i = 0; i < f.num_keys; ++i)
      if (slotIsPose(f.type, i))
        newRobotType.emplace(static_cast<std::uint32_t>(f.keys[static_cast<size_t>(i)].robot),
                             slotVarType(f.type, i));
  if (!lowestNew.empty() && !sessions_.hasGapBelow(b.sender, b.sequence))
    for (const auto& [robot, k] : lowestNew) {
      if (newRobotType[robot] == VarType::SE3)
        guess.insert(k, SE3());
      else
        guess.insert(k, SE2());
    }

  // Solver factors; inter-robot ones are built once anchors are known. A landmark namespace's
  // first sighting adopts the sighting robot's frame for it (engine.h).
  const std::map<std::uint32_t, std::uint32_t> adoptions = adoptionsOf(b);
  std::vector<std::shared_ptr<Factor>> built(b.factors.size());
  std::vector<FactorPtr> intra;
  for (size_t i = 0; i < b.factors.size(); ++i) {
    built[i] = buildFactor(b.factors[i]);
    // Inter-robot factors relate two frames: they do not predict values in one.
    if (!isInterRobot(b.factors[i]) && !isCrossFrameSighting(b.factors[i], adoptions))
      intra.push_back(built[i]);
  }
  predictMissingValues(intra, knownVals, guess);
  // A landmark of robot s that robot r ≠ s sights first does not hold the batch (and every
  // later one of r's behind it): the sighting is kept back until the frames are joined, and
  // then places the landmark through the anchors (stageSightings).
  const std::set<Key> leftToSightings = landmarksLeftToSightings(b, knownVals, guess, adoptions);
  for (Key k : keys)
    if (!knownVals.contains(k) && !guess.contains(k) && !leftToSightings.count(k))
      waiting.push_back(k);
  for (Key k : altKeys)
    if (!knownVals.contains(k) && !guess.contains(k)) waiting.push_back(k);
  if (!waiting.empty()) return StageResult::Hold;

  Staged st;
  st.d = d;
  st.robotsBefore = robots_;
  st.pendingBefore = pending_;
  st.closuresBefore = pendingClosures_;
  st.adoptedBefore = adopted_;
  for (const auto& [ns, r] : adoptions) {
    adopted_.emplace(ns, r);
    spdlog::info(
        "landmark namespace {}: its landmarks live in robot {}'s frame (the first to sight one)",
        ns, r);
  }
  BackendUpdate& u = st.update;
  for (int s = 0; s < guess.size(); ++s) {
    u.initial.insertFrom(guess, s);
    stagedValues_.insertFrom(guess, s);
  }
  auto addServerFactor = [&](FactorPtr f) {
    u.factors.push_back(std::move(f));
    st.owners.push_back({"", -1, false});
  };
  // New robots: record them; their first pose gets the frame-fixing prior.
  for (int s = 0; s < guess.size(); ++s) {
    const Key k = guess.key(s);
    if (keyKind(k) != KeyKind::Pose) continue;
    const std::uint32_t r = keyRobot(k);
    auto it = robots_.find(r);
    if (it == robots_.end()) {
      RobotInfo info;
      info.poseType = guess.type(s);
      info.firstPose = k;
      info.parent = r;
      it = robots_.emplace(r, info).first;
      bool hasPrior = false;
      for (const auto& f : b.factors)
        hasPrior |= (f.type == W::PRIOR_SE2 || f.type == W::PRIOR_SE3) &&
                    static_cast<std::uint32_t>(f.keys[0].robot) == r;
      // The robot's first pose: the lowest new one of this batch.
      Key first = k;
      for (int t = 0; t < guess.size(); ++t)
        if (keyKind(guess.key(t)) == KeyKind::Pose && keyRobot(guess.key(t)) == r)
          first = std::min(first, guess.key(t));
      it->second.firstPose = first;
      if (!hasPrior)
        addServerFactor(priorAt(first, guess, guess.slot(first), opt_.priorInformation));
    }
    it->second.latestIndex =
        std::max<std::int64_t>(it->second.latestIndex, static_cast<std::int64_t>(keyIndex(k)));
  }
  // The batch's factors (the batch's guesses are staged: holder() finds them).
  std::vector<std::pair<FactorPtr, Owner>> sightings;  // cross-robot ones
  std::vector<KeptBack> keptClosures;                  // inter-robot ones, frames not joined
  for (size_t i = 0; i < b.factors.size(); ++i) {
    const W& wf = b.factors[i];
    std::shared_ptr<Factor> f = built[i];
    const bool uncertain = isUncertain(f->role());  // inter-robot ones: loop closures (validator)
    const FactorId id = newFactorId();
    f->setId(id);
    if (uncertain) f->setRobustRequest({wf.robust, wf.robust_param});
    sessions_.addId(b.sender, wf.id, id);
    st.addedIds.emplace_back(wf.id, id);
    const Owner owner{b.sender, wf.id, uncertain};
    if (isInterRobot(wf)) {
      if (keepsBack(*f)) {
        keptClosures.push_back({f, owner});
        continue;
      }
      if (!joinsAtOnce(*f)) st.pairClosures.push_back(f);  // judged, between joined frames
      SE2 m2;
      SE3 m3;
      frameOffset(*f, m2, m3);
      joinRobots(keyRobot(f->key(0)), keyRobot(f->key(1)), m2, m3, st);
      f = anchoredFactor(*f);
    }
    if (isCrossFrameSighting(wf, {})) {
      sightings.emplace_back(f, owner);
      continue;
    }
    u.factors.push_back(f);
    st.owners.push_back(owner);
  }
  stageInterRobotClosures(keptClosures, st);
  stageSightings(sightings, st);
  mergeGroupsJoinedByLandmarks(st);
  releaseJoinedClosures(st);  // sightings or landmarks may have joined a pair's frames
  // Ambiguous groups: each alternative is built like a factor_t and gets an internal id of
  // its own; the group's internal id is what the sender's id maps to. An inter-robot
  // alternative goes through the anchors of its robots, which certain inter-robot factors
  // joined before (checkContext refused the batch otherwise); it never joins robots itself.
  for (const auto& wa : b.ambiguous) {
    Group g;
    g.sender = b.sender;
    g.id = wa.id;
    g.factor.id = newFactorId();
    g.factor.nullHypothesis = wa.null_hypothesis;
    g.factor.nullWeight = wa.null_hypothesis && wa.null_weight > 0.0 ? wa.null_weight : 1.0;
    for (const auto& wf : wa.alternatives) {
      std::shared_ptr<Factor> f = buildFactor(wf);
      if (isInterRobot(wf))
        f = anchoredFactor(*f);
      else if (isCrossFrameSighting(wf, {}))
        f = anchoredFactor(*f, frameOf(f->key(1)));
      f->setId(newFactorId());
      f->setRobustRequest({wf.robust, wf.robust_param});  // applies once flattened
      g.factor.alternatives.push_back(std::move(f));
    }
    u.ambiguous.push_back(g.factor);
    sessions_.addId(b.sender, wa.id, g.factor.id);
    st.addedIds.emplace_back(wa.id, g.factor.id);
    st.groups.push_back(std::move(g));
  }
  for (std::int64_t rid : b.remove_ids) {
    const FactorId fid = sessions_.removeId(b.sender, rid);
    if (isGroupId(fid))
      st.groupRemovals.push_back(fid);
    else if (!dropKeptBack(fid))
      u.removals.push_back(fid);
    st.removedIds.emplace_back(rid, fid);
  }
  // Server-owned factors got ids after the sender's: give them theirs now.
  for (size_t i = 0; i < u.factors.size(); ++i)
    if (st.owners[i].id < 0 && u.factors[i]->id() == 0)
      std::const_pointer_cast<Factor>(u.factors[i])->setId(newFactorId());
  staged_.push_back(std::move(st));
  return StageResult::Staged;
}

bool Engine::isGroupId(FactorId id) const {
  if (groups_.count(id)) return true;
  for (const Staged& s : staged_)
    for (const Group& g : s.groups)
      if (g.factor.id == id) return true;
  return false;
}

void Engine::retryHolds() {
  bool progress = !holds_.empty();
  while (progress) {
    progress = false;
    for (auto it = holds_.begin(); it != holds_.end();) {
      std::vector<Key> waiting;
      // Context may have changed while it waited (ids, types): re-check.
      std::vector<Issue> issues = validator_.checkContext(*it->d.batch, *this);
      if (!issues.empty()) {
        reject(*it->d.batch, issues, it->d.raw->channel);
        it = holds_.erase(it);
        continue;
      }
      if (stage(it->d, waiting) == StageResult::Staged) {
        it = holds_.erase(it);
        progress = true;
      } else {
        it->waiting = waiting;
        ++it;
      }
    }
  }
}

void Engine::expireHolds(bool all) {
  const auto now = Clock::now();
  while (!holds_.empty()) {
    Held& h = holds_.front();
    const bool tooMany = static_cast<int>(holds_.size()) > opt_.holdMaxBatches;
    const bool tooOld = std::chrono::duration<double>(now - h.since).count() > opt_.holdSeconds;
    if (!all && !tooMany && !tooOld) break;
    std::string keys;
    for (size_t i = 0; i < h.waiting.size() && i < 8; ++i)
      keys += (i ? ", " : "") + keyToString(h.waiting[i]);
    const auto& b = *h.d.batch;
    const std::string reason = "held " + num(std::chrono::duration<double>(now - h.since).count()) +
                               " s waiting for " + keys + (tooMany ? " (hold queue full)" : "") +
                               ": dropped";
    spdlog::warn("sender '{}' seq {}: {}", b.sender, b.sequence, reason);
    journalConsumed(journal_, replaying_, pub_, b, E::HELD_EXPIRED, reason);
    pub_.error(b.sender, b.sequence, 0, -1, E::HELD_EXPIRED, reason, h.d.raw->channel);
    holds_.pop_front();
    std::lock_guard<std::mutex> l(countersMu_);
    ++counters_.expired;
  }
}

void Engine::undo(Staged& s) {
  const std::string& sender = s.d.batch->sender;
  for (auto it = s.removedIds.rbegin(); it != s.removedIds.rend(); ++it)
    sessions_.undoRemove(sender, it->first, it->second);
  for (const auto& [id, fid] : s.addedIds) sessions_.undoAdd(sender, id);
  robots_ = s.robotsBefore;
  pending_ = s.pendingBefore;
  pendingClosures_ = s.closuresBefore;
  adopted_ = s.adoptedBefore;
}

void Engine::commit(Staged& s) {
  for (FactorId r : s.update.removals) {
    if (interEdges_.erase(r)) regroupNeeded_ = true;
    if (const auto f = live_.find(r); f != live_.end())
      if (const Key l = ownerTiedLandmark(*f->second); l != 0 && --ownerTies_[l] <= 0) {
        ownerTies_.erase(l);
        // Other robots' sightings of it may have been all that joined their frames to its owner's.
        const auto owner = robots_.find(frameOf(l));
        if (owner != robots_.end() && owner->second.anchored) regroupNeeded_ = true;
      }
    live_.erase(r);
    auto it = owners_.find(r);
    if (it != owners_.end()) {
      if (it->second.uncertain) --loopClosures_;
      owners_.erase(it);
    }
    lastDecisions_.erase(r);
  }
  for (size_t i = 0; i < s.update.factors.size(); ++i) {
    const FactorPtr& f = s.update.factors[i];
    live_[f->id()] = f;
    if (isAnchored(*f)) interEdges_[f->id()] = interEdgeOf(*f);
    if (const Key l = ownerTiedLandmark(*f)) ++ownerTies_[l];
    if (s.owners[i].id >= 0) {
      owners_[f->id()] = s.owners[i];
      if (s.owners[i].uncertain) ++loopClosures_;
    }
  }
  for (auto& [pair, check] : s.joinsMade) joinChecks_[pair] = std::move(check);
  for (const FactorPtr& f : s.pairClosures) {
    const RobotPair pair = std::minmax(keyRobot(f->key(0)), keyRobot(f->key(1)));
    auto it = joinChecks_.find(pair);
    // Joined through other robots: checked from its first closure, if a placement it could
    // move still rests on a checked join.
    if (it == joinChecks_.end() && !settledJoins_.count(pair) && weakerPlacement(pair) >= 0) {
      JoinCheck check;
      check.throughOthers = true;
      it = joinChecks_.emplace(pair, std::move(check)).first;
    }
    if (it != joinChecks_.end()) it->second.closures.push_back(f);
  }
  for (const Group& g : s.groups) groups_[g.factor.id] = g;
  for (FactorId r : s.groupRemovals) {
    groups_.erase(r);
    lastGroupDecisions_.erase(r);
  }
  std::lock_guard<std::mutex> l(countersMu_);
  ++counters_.accepted;
}

void Engine::flush() {
  if (staged_.empty()) return;
  // One update for the round; factors and groups removed within the round cancel out.
  BackendUpdate all;
  std::vector<FactorId> groupRemovals;
  std::unordered_set<FactorId> added, cancelled;
  for (auto& s : staged_) {
    for (const auto& f : s.update.factors) added.insert(f->id());
    for (const auto& a : s.update.ambiguous) added.insert(a.id);
  }
  for (auto& s : staged_) {
    for (FactorId r : s.update.removals)
      if (added.count(r)) cancelled.insert(r);
    for (FactorId r : s.groupRemovals)
      if (added.count(r)) cancelled.insert(r);
  }
  for (auto& s : staged_) {
    for (const auto& f : s.update.factors)
      if (!cancelled.count(f->id())) all.factors.push_back(f);
    for (const auto& a : s.update.ambiguous)
      if (!cancelled.count(a.id)) all.ambiguous.push_back(a);
    for (int i = 0; i < s.update.initial.size(); ++i) all.initial.insertFrom(s.update.initial, i);
    for (FactorId r : s.update.removals)
      if (!cancelled.count(r)) all.removals.push_back(r);
    for (FactorId r : s.groupRemovals)
      if (!cancelled.count(r)) groupRemovals.push_back(r);
  }
  const auto t0 = Clock::now();
  std::vector<Key> moved;
  bool ok = true;
  try {
    moved = applyUpdate(all, groupRemovals);
  } catch (const std::exception& e) {
    ok = false;
    spdlog::error("update of {} batches failed ({}); applying them one by one", staged_.size(),
                  e.what());
  }
  std::vector<Staged> round;
  round.swap(staged_);
  stagedValues_ = Values();
  // Journaled once applied, before anything reports it (afterUpdate): the journal holds only
  // what was applied, and what was reported survives a kill -9. A batch being applied when
  // the server died is in no status: its front-end's resend applies it.
  auto journalApplied = [&](const Staged& s) {
    if (s.d.replayed || !journal_) return;
    if (!journal_->append(s.d.raw->channel, s.d.raw->bytes.data(),
                          static_cast<int>(s.d.raw->bytes.size()), nowUtime())) {
      spdlog::error("journal {}: write failed", journal_->path());
      return;
    }
    std::lock_guard<std::mutex> l(countersMu_);
    ++counters_.journaled;
  };
  // Refused by the backend (INTERNAL): its number is consumed like any refused batch's.
  auto refuse = [&](const Staged& s, const std::string& reason) {
    journalConsumed(journal_, replaying_, pub_, *s.d.batch, E::INTERNAL, reason);
    pub_.error(s.d.batch->sender, s.d.batch->sequence, 0, -1, E::INTERNAL, reason,
               s.d.raw->channel);
    std::lock_guard<std::mutex> l(countersMu_);
    ++counters_.internalErrors;
    ++counters_.rejected;
  };
  if (ok) {
    for (auto& s : round) {
      journalApplied(s);
      commit(s);
    }
  } else {
    for (auto it = round.rbegin(); it != round.rend(); ++it) undo(*it);
    std::set<Key> movedSet;
    for (auto& s : round) {
      std::vector<Key> waiting;
      if (stage(s.d, waiting) != StageResult::Staged) {
        refuse(s, "batch could not be initialised on retry; not applied");
        continue;
      }
      Staged one = std::move(staged_.back());
      staged_.clear();
      stagedValues_ = Values();
      try {
        for (Key k : applyUpdate(one.update, one.groupRemovals)) movedSet.insert(k);
        journalApplied(one);
        commit(one);
      } catch (const std::exception& e) {
        undo(one);
        spdlog::error("sender '{}' seq {}: backend refused the batch: {}", s.d.batch->sender,
                      s.d.batch->sequence, e.what());
        refuse(s, std::string("the solver refused the batch (not applied; graph intact): ") +
                      e.what());
      }
    }
    moved.assign(movedSet.begin(), movedSet.end());
  }
  if (regroupNeeded_) regroup(moved);
  checkJoins(moved);
  const double sec = std::chrono::duration<double>(Clock::now() - t0).count();
  dirty_ = true;
  if (!replaying_)
    afterUpdate(moved, sec, false);
  else {
    ++updateSeq_;
    std::lock_guard<std::mutex> l(countersMu_);
    ++counters_.updates;
  }
}

std::vector<Key> Engine::applyUpdate(BackendUpdate u, const std::vector<FactorId>& groupRemovals) {
  std::vector<Key> moved;
  const std::vector<Key> newKeys = u.initial.keys();
  if (!groupRemovals.empty() && backend_->handlesAmbiguous()) {
    // mh cannot drop a layer of its hypothesis tree: a new backend gets the graph without it
    // (cost: a rebuild of everything).
    const std::unordered_set<FactorId> gone(groupRemovals.begin(), groupRemovals.end());
    const std::unordered_set<FactorId> removed(u.removals.begin(), u.removals.end());
    std::unique_ptr<PerFactorRobustBackend> next = makeSolver(backend_->name());
    BackendUpdate full;
    for (const auto& [id, f] : live_)
      if (!removed.count(id)) full.factors.push_back(f);
    full.factors.insert(full.factors.end(), u.factors.begin(), u.factors.end());
    for (const auto& [id, g] : groups_)
      if (!gone.count(id)) full.ambiguous.push_back(g.factor);
    full.ambiguous.insert(full.ambiguous.end(), u.ambiguous.begin(), u.ambiguous.end());
    full.initial = backend_->estimate();
    for (int i = 0; i < u.initial.size(); ++i)
      if (!full.initial.contains(u.initial.key(i))) full.initial.insertFrom(u.initial, i);
    feedRebuilt(*next, std::move(full));
    backend_ = std::move(next);
    lastDecisions_.clear();
    lastGroupDecisions_.clear();
    return backend_->estimate().keys();
  }
  for (FactorId r : groupRemovals) {  // flattened: the alternatives are ordinary factors
    const auto it = groups_.find(r);
    if (it == groups_.end()) throw std::logic_error("removal of an unknown ambiguous group");
    for (const auto& f : it->second.factor.alternatives) u.removals.push_back(f->id());
  }
  if (!backend_->handlesAmbiguous()) flattenAmbiguous(u);
  if (!u.factors.empty() || !u.removals.empty() || !u.ambiguous.empty()) {
    moved = backend_->update(u).moved;
    if (recoverIfDiverged("an update", nullptr))
      throw std::runtime_error("the solver diverged on it (NaN, infinite or absurd estimate)");
  }
  moved.insert(moved.end(), newKeys.begin(), newKeys.end());
  return moved;
}

}  // namespace loopd::server
