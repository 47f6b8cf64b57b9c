#include "server/engine.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <set>
#include <unordered_set>

#include "loopd/covariance_t.hpp"
#include "loopd/error_t.hpp"
#include "loopd/estimate_t.hpp"
#include "loopd/status_t.hpp"
#include "robust/ambiguous_choice.h"
#include "robust/backend_registry.h"
#include "robust/mh_backend.h"
#include "server/anchored_between_factor.h"
#include "server/wire.h"
#include "solvers/factors/landmark_factors.h"
#include "solvers/factors/prior_factors.h"
#include "solvers/io/estimate_writer.h"
#include "solvers/problem/initial_guess.h"

namespace loopd::server {

using E = loopd::error_t;
using W = loopd::factor_t;
using Clock = std::chrono::steady_clock;

namespace {

Key anchorKey(std::uint32_t robot) { return makeKey(robot, KeyKind::Anchor, 0); }

FactorRole roleOf(int role) {
  switch (role) {
    case W::ROLE_PRIOR:
      return FactorRole::Prior;
    case W::ROLE_ODOMETRY:
      return FactorRole::Odometry;
    case W::ROLE_LANDMARK:
      return FactorRole::Landmark;
    default:
      return FactorRole::LoopClosure;
  }
}

SE3 se3From(const std::vector<double>& m) { return SE3::fromTranslationQuaternion(m.data()); }

// A validated wire factor as a solver factor on its own keys (intra-robot form).
std::shared_ptr<Factor> buildFactor(const W& f) {
  const Eigen::MatrixXd info = informationOf(f);
  const Key a = toKey(f.keys[0]);
  const Key b = f.num_keys > 1 ? toKey(f.keys[1]) : 0;
  const auto& m = f.measurement;
  const FactorRole role = roleOf(f.role);
  std::shared_ptr<Factor> out;
  switch (f.type) {
    case W::PRIOR_SE2:
      out = std::make_shared<PriorFactorSE2>(a, SE2(m[0], m[1], m[2]), Eigen::Matrix3d(info));
      break;
    case W::PRIOR_SE3:
      out = std::make_shared<PriorFactorSE3>(a, se3From(m), Mat6(info));
      break;
    case W::PRIOR_POINT2:
      out = std::make_shared<PriorFactorPoint2>(a, Vec2(m[0], m[1]), Eigen::Matrix2d(info));
      break;
    case W::PRIOR_POINT3:
      out = std::make_shared<PriorFactorPoint3>(a, Vec3(m[0], m[1], m[2]), Mat3(info));
      break;
    case W::BETWEEN_SE2:
      out = std::make_shared<BetweenFactorSE2>(a, b, SE2(m[0], m[1], m[2]), Eigen::Matrix3d(info),
                                               role);
      break;
    case W::BETWEEN_SE3:
      out = std::make_shared<BetweenFactorSE3>(a, b, se3From(m), Mat6(info), role);
      break;
    case W::POSE_POINT2:
      out = std::make_shared<PosePointFactor2>(a, b, Vec2(m[0], m[1]), Eigen::Matrix2d(info), role);
      break;
    case W::POSE_POINT3:
      out = std::make_shared<PosePointFactor3>(a, b, Vec3(m[0], m[1], m[2]), Mat3(info), role);
      break;
    case W::BEARING_RANGE2:
      out = std::make_shared<BearingRangeFactor2>(a, b, Vec2(m[0], m[1]), Eigen::Matrix2d(info),
                                                  role);
      break;
    default:
      throw std::invalid_argument("unknown factor type");
  }
  out->setRole(role);
  return out;
}

bool isInterRobot(const W& f) {
  return (f.type == W::BETWEEN_SE2 || f.type == W::BETWEEN_SE3) &&
         f.keys[0].robot != f.keys[1].robot;
}

// An inter-robot between factor (`built` = its intra-robot form) evaluated through the robots'
// anchors: keys A_r, x_r, A_s, x_s. The anchors must exist (joinRobots).
std::shared_ptr<Factor> anchoredFactor(const W& wf, const Factor& built) {
  const Key xr = toKey(wf.keys[0]), xs = toKey(wf.keys[1]);
  const Key ar = anchorKey(keyRobot(xr)), as = anchorKey(keyRobot(xs));
  const Eigen::MatrixXd info = informationOf(wf);
  if (wf.type == W::BETWEEN_SE2) {
    const auto& bf = static_cast<const BetweenFactorSE2&>(built);
    return std::make_shared<AnchoredBetweenFactorSE2>(
        ar, xr, as, xs, bf.measured(), Eigen::Matrix3d(info), FactorRole::LoopClosure);
  }
  const auto& bf = static_cast<const BetweenFactorSE3&>(built);
  return std::make_shared<AnchoredBetweenFactorSE3>(ar, xr, as, xs, bf.measured(), Mat6(info),
                                                    FactorRole::LoopClosure);
}

// The robots an anchored (inter-robot) factor joins; commit() records those as interEdges_.
bool isAnchored(const Factor& f) { return f.size() == 4; }

std::string fingerprintName(std::int64_t hash) {
  struct T {
    std::int64_t h;
    const char* n;
  };
  const T known[] = {{loopd::command_t::getHash(), "command_t"},
                     {loopd::estimate_t::getHash(), "estimate_t"},
                     {loopd::covariance_t::getHash(), "covariance_t"},
                     {loopd::status_t::getHash(), "status_t"},
                     {loopd::error_t::getHash(), "error_t"},
                     {loopd::factor_batch_t::getHash(), "factor_batch_t"}};
  for (const auto& t : known)
    if (t.h == hash) return t.n;
  return "";
}

std::int64_t readHash(const std::uint8_t* p) {
  std::uint64_t h = 0;
  for (int i = 0; i < 8; ++i) h = (h << 8) | p[i];
  return static_cast<std::int64_t>(h);
}

// Pose value helpers over Values slots.
SE2 se2Of(const Values& v, Key k) { return v.se2(v.slot(k)); }
SE3 se3Of(const Values& v, Key k) { return v.se3(v.slot(k)); }

// The whole graph into a new backend (mh: plain factors, optimize, then the groups).
void feedWhole(Backend& next, BackendUpdate all) {
  if (!next.handlesAmbiguous()) {
    flattenAmbiguous(all);
    if (!all.factors.empty()) next.update(all);
    return;
  }
  // The hypotheses branch on the optimum of the rest of the graph (as when the groups arrived
  // one by one), not on an estimate another variant left (flattened decoys drag it).
  BackendUpdate groups;
  groups.ambiguous = std::move(all.ambiguous);
  all.ambiguous.clear();
  if (!all.factors.empty()) {
    next.update(all);
    next.optimize();
  }
  if (!groups.ambiguous.empty()) next.update(groups);
}

}  // namespace

Engine::Engine(EngineOptions options, Publisher& publisher, Journal* journal)
    : opt_(std::move(options)), pub_(publisher), journal_(journal) {
  backend_ = makeSolver(opt_.solver);
  lastInput_ = lastStatus_ = Clock::now();
}

Engine::~Engine() = default;

BackendOptions Engine::backendOptions() const {
  BackendOptions bo;
  bo.maxHypotheses = opt_.maxHypotheses;
  return bo;
}

EngineCounters Engine::counters() const {
  std::lock_guard<std::mutex> l(countersMu_);
  return counters_;
}

void Engine::post(Inbound m) {
  if (static_cast<int>(m.bytes.size()) > opt_.maxMessageBytes) {
    pub_.error("", 0, 0, -1, E::DECODE_FAILED,
               "message of " + std::to_string(m.bytes.size()) + " bytes exceeds the " +
                   std::to_string(opt_.maxMessageBytes) + "-byte limit (dropped before decoding)",
               m.channel);
    std::lock_guard<std::mutex> l(countersMu_);
    ++counters_.decodeFailed;
    return;
  }
  {
    std::lock_guard<std::mutex> l(qmu_);
    queue_.push_back(std::make_shared<const Inbound>(std::move(m)));
  }
  qcv_.notify_one();
}

int Engine::queueDepth() const {
  std::lock_guard<std::mutex> l(qmu_);
  return static_cast<int>(queue_.size());
}

// --- GraphView --------------------------------------------------------------------------

const Values* Engine::holder(Key k) const {
  if (backend_->estimate().contains(k)) return &backend_->estimate();
  if (stagedValues_.contains(k)) return &stagedValues_;
  return nullptr;
}

std::optional<VarType> Engine::varType(Key k) const {
  const Values* v = holder(k);
  if (!v) return std::nullopt;
  return v->type(v->slot(k));
}

std::optional<VarType> Engine::robotPoseType(std::uint32_t robot) const {
  auto it = robots_.find(robot);
  if (it == robots_.end()) return std::nullopt;
  return it->second.poseType;
}

bool Engine::idUsed(const std::string& s, std::int64_t id) const { return sessions_.idUsed(s, id); }
bool Engine::idLive(const std::string& s, std::int64_t id) const { return sessions_.idLive(s, id); }

std::map<std::uint32_t, std::uint32_t> Engine::frameGroups(const loopd::factor_batch_t& b) const {
  // From the certain inter-robot factors themselves (not robots_' parents, which regroup()
  // updates only after a round), so the answer depends on the order of batches alone, not on
  // how they were coalesced into rounds: a journal replay decides exactly as the live run.
  std::map<FactorId, std::pair<std::uint32_t, std::uint32_t>> edges = interEdges_;
  for (const Staged& s : staged_) {
    for (FactorId r : s.update.removals) edges.erase(r);
    for (const auto& f : s.update.factors)
      if (isAnchored(*f)) edges[f->id()] = {keyRobot(f->key(1)), keyRobot(f->key(3))};
  }
  for (std::int64_t rid : b.remove_ids)
    if (const auto fid = sessions_.liveId(b.sender, rid)) edges.erase(*fid);
  std::map<std::uint32_t, std::uint32_t> parent;
  auto find = [&](std::uint32_t r) {
    if (!parent.count(r)) parent[r] = r;
    while (parent[r] != r) r = parent[r] = parent[parent[r]];
    return r;
  };
  auto join = [&](std::uint32_t r, std::uint32_t s) {
    const std::uint32_t a = find(r), c = find(s);
    if (a != c) parent[std::max(a, c)] = std::min(a, c);
  };
  for (const auto& [id, e] : edges) join(e.first, e.second);
  for (const auto& f : b.factors)
    if (isInterRobot(f))
      join(static_cast<std::uint32_t>(f.keys[0].robot),
           static_cast<std::uint32_t>(f.keys[1].robot));
  std::map<std::uint32_t, std::uint32_t> out;
  for (const auto& [r, p] : parent) out[r] = find(r);
  return out;
}

std::uint32_t Engine::root(std::uint32_t r) const {
  for (int guard = 0; guard < 1 << 20; ++guard) {
    auto it = robots_.find(r);
    if (it == robots_.end() || it->second.parent == r) return r;
    r = it->second.parent;
  }
  return r;
}

bool Engine::robotJoined(std::uint32_t robot) const {
  auto it = robots_.find(robot);
  return it != robots_.end() && it->second.anchored;
}

// --- the loop ---------------------------------------------------------------------------

bool Engine::step() {
  std::deque<std::shared_ptr<const Inbound>> batch;
  {
    std::lock_guard<std::mutex> l(qmu_);
    batch.swap(queue_);
  }
  if (batch.empty()) return false;
  lastInput_ = Clock::now();
  for (auto& m : batch) {
    if (m->channel == pub_.channels().command) {
      flush();
      handleCommand(*m);
    } else {
      handleFactors(m, false);
    }
  }
  retryHolds();
  const std::int64_t seq = updateSeq_;
  flush();
  if (updateSeq_ == seq)
    publishStatus(0, false);  // nothing applied: still tell (held, refused, ...)
  return true;
}

void Engine::idle() {
  expireHolds(false);
  const auto now = Clock::now();
  if (dirty_ && std::chrono::duration<double>(now - lastInput_).count() >= opt_.idleSeconds &&
      queueDepth() == 0) {
    const Values before = backend_->estimate();
    const auto t0 = Clock::now();
    try {
      backend_->optimize();
    } catch (const std::exception& e) {
      spdlog::error("optimize() failed: {}", e.what());
    }
    recoverIfDiverged("an idle optimize", &before);
    const double sec = std::chrono::duration<double>(Clock::now() - t0).count();
    dirty_ = false;
    std::vector<Key> moved;
    const Values& after = backend_->estimate();
    for (int s = 0; s < after.size(); ++s) {
      const int o = before.slot(after.key(s));
      bool m = o < 0;
      for (int i = 0; !m && i < kValueStride; ++i)
        m = std::abs(after.data(s)[i] - before.data(o)[i]) > 1e-9;
      if (m) moved.push_back(after.key(s));
    }
    spdlog::debug("idle optimize: {:.1f} ms, {} variables moved, chi2 {:.9g}", sec * 1e3,
                  moved.size(), backend_->chi2());
    afterUpdate(moved, sec, true);
  }
  if (std::chrono::duration<double>(Clock::now() - lastStatus_).count() >= opt_.heartbeatSeconds)
    publishStatus(0, false);
}

void Engine::run(const std::atomic<bool>& stop) {
  while (!stop.load()) {
    {
      std::unique_lock<std::mutex> l(qmu_);
      qcv_.wait_for(l, std::chrono::milliseconds(50),
                    [&] { return !queue_.empty() || stop.load(); });
    }
    step();
    idle();
  }
  // Finish what arrived, then leave the journal flushed.
  while (step()) {
  }
  if (journal_) journal_->flush();
}

std::int64_t Engine::replay(const std::string& path, bool rejournal, long* validBytes) {
  replaying_ = !rejournal;
  std::int64_t n = 0;
  n = readJournal(
      path,
      [&](const std::string& channel, const void* data, int size) {
        if (channel != pub_.channels().factors) return;  // journals hold only batches
        auto m = std::make_shared<Inbound>();
        m->channel = channel;
        m->bytes.assign(static_cast<const std::uint8_t*>(data),
                        static_cast<const std::uint8_t*>(data) + size);
        handleFactors(m, !rejournal);
        if (staged_.size() >= 64) flush();
      },
      validBytes);
  retryHolds();
  flush();
  replaying_ = false;
  // The resumed graph's optimum, and a complete decision listing.
  dirty_ = true;
  lastInput_ = Clock::now() - std::chrono::hours(1);
  idle();
  publishStatus(0, true);
  return n;
}

// --- batches ----------------------------------------------------------------------------

void Engine::reject(const loopd::factor_batch_t& b, const std::vector<Issue>& issues,
                    const std::string& channel) {
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
  const std::int64_t hash = readHash(bytes.data());
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
  // (unless the front-end gave values, or earlier batches of this sender are missing).
  std::map<std::uint32_t, Key> lowestNew;
  std::set<std::uint32_t> robotsWithGuess;
  for (int s = 0; s < guess.size(); ++s)
    if (keyKind(guess.key(s)) == KeyKind::Pose) robotsWithGuess.insert(keyRobot(guess.key(s)));
  for (const auto& f : b.factors)
    for (int i = 0; i < f.num_keys; ++i) {
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

  // Solver factors; inter-robot ones are built once anchors are known.
  std::vector<std::shared_ptr<Factor>> built(b.factors.size());
  std::vector<FactorPtr> intra;
  for (size_t i = 0; i < b.factors.size(); ++i) {
    built[i] = buildFactor(b.factors[i]);
    if (!isInterRobot(b.factors[i])) intra.push_back(built[i]);
  }
  predictMissingValues(intra, knownVals, guess);
  for (Key k : keys)
    if (!knownVals.contains(k) && !guess.contains(k)) waiting.push_back(k);
  for (Key k : altKeys)
    if (!knownVals.contains(k) && !guess.contains(k)) waiting.push_back(k);
  if (!waiting.empty()) return StageResult::Hold;

  Staged st;
  st.d = d;
  st.robotsBefore = robots_;
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
  // The batch's factors.
  Values batchValues = knownVals;  // known ∪ guess, for anchor initialisation
  for (int s = 0; s < guess.size(); ++s) batchValues.insertFrom(guess, s);
  for (size_t i = 0; i < b.factors.size(); ++i) {
    const W& wf = b.factors[i];
    FactorPtr f = built[i];
    if (isInterRobot(wf)) {
      const Key xr = toKey(wf.keys[0]), xs = toKey(wf.keys[1]);
      joinRobots(keyRobot(xr), keyRobot(xs), xr, xs, *built[i], batchValues, st);
      f = anchoredFactor(wf, *built[i]);
    }
    const FactorId id = newFactorId();
    std::const_pointer_cast<Factor>(f)->setId(id);
    if (isUncertain(f->role()))
      std::const_pointer_cast<Factor>(f)->setRobustRequest({wf.robust, wf.robust_param});
    u.factors.push_back(f);
    st.owners.push_back({b.sender, wf.id, isUncertain(f->role())});
    sessions_.addId(b.sender, wf.id, id);
    st.addedIds.emplace_back(wf.id, id);
  }
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
      if (isInterRobot(wf)) f = anchoredFactor(wf, *f);
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
    else
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

FactorPtr Engine::priorAt(Key k, const Values& from, int slot, double information) {
  std::shared_ptr<Factor> f;
  if (from.type(slot) == VarType::SE3)
    f = std::make_shared<PriorFactorSE3>(k, from.se3(slot), Mat6::Identity() * information);
  else
    f = std::make_shared<PriorFactorSE2>(k, from.se2(slot),
                                         Eigen::Matrix3d::Identity() * information);
  f->setId(newFactorId());
  return f;
}

void Engine::joinRobots(std::uint32_t r, std::uint32_t s, Key xr, Key xs, const Factor& between,
                        const Values& vals, Staged& st) {
  RobotInfo& R = robots_.at(r);
  RobotInfo& S = robots_.at(s);
  BackendUpdate& u = st.update;
  const bool se3 = R.poseType == VarType::SE3;
  auto addFactor = [&](FactorPtr f) {
    u.factors.push_back(std::move(f));
    st.owners.push_back({"", -1, false});
  };
  auto anchorValue = [&](Key a, Values& into) {
    const Values* h = u.initial.contains(a) ? &u.initial : holder(a);
    into.insertFrom(*h, h->slot(a));
  };
  auto insertAnchor = [&](Key a, const SE2& v2, const SE3& v3, double info) -> FactorId {
    Values one;
    if (se3)
      one.insert(a, v3);
    else
      one.insert(a, v2);
    u.initial.insertFrom(one, 0);
    stagedValues_.insertFrom(one, 0);
    if (info <= 0.0) return FactorId{0};
    FactorPtr p = priorAt(a, one, 0, info);
    const FactorId id = p->id();
    addFactor(std::move(p));
    return id;
  };
  if (!R.anchored && !S.anchored) {
    R.anchorPrior = insertAnchor(anchorKey(r), SE2(), SE3(), opt_.priorInformation);
    R.anchored = true;
    R.parent = r;
    spdlog::info("robot {} anchors a common frame", r);
  }
  if (R.anchored != S.anchored) {
    // The newcomer's anchor, from the factor: A_s = A_r·x_r·Z·x_s⁻¹ (or the reverse).
    const bool newIsS = !S.anchored;
    const std::uint32_t n = newIsS ? s : r, o = newIsS ? r : s;
    Values av;
    anchorValue(anchorKey(o), av);
    SE2 a2;
    SE3 a3;
    if (se3) {
      const SE3 Z = static_cast<const BetweenFactorSE3&>(between).measured();
      const SE3 Ao = av.se3(0);
      a3 = newIsS ? Ao * se3Of(vals, xr) * Z * se3Of(vals, xs).inverse()
                  : Ao * se3Of(vals, xs) * Z.inverse() * se3Of(vals, xr).inverse();
    } else {
      const SE2 Z = static_cast<const BetweenFactorSE2&>(between).measured();
      const SE2 Ao = av.se2(0);
      a2 = newIsS ? Ao * se2Of(vals, xr) * Z * se2Of(vals, xs).inverse()
                  : Ao * se2Of(vals, xs) * Z.inverse() * se2Of(vals, xr).inverse();
    }
    RobotInfo& N = robots_.at(n);
    N.anchorPrior = insertAnchor(anchorKey(n), a2, a3, 0.0);  // the factor determines it
    N.anchored = true;
    N.parent = root(o);
    spdlog::info("robot {} joins robot {}'s frame", n, root(o));
    return;
  }
  const std::uint32_t rr = root(r), rs = root(s);
  if (rr == rs) return;
  // Two anchored groups: s's group root loses its strong prior (a negligible one keeps it
  // well posed) and the group follows the factor.
  RobotInfo& RS = robots_.at(rs);
  if (RS.anchorPrior != 0) u.removals.push_back(RS.anchorPrior);
  RS.anchorPrior = 0;
  RS.parent = rr;
  spdlog::info("robot group of {} merges into robot {}'s frame", rs, rr);
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
}

void Engine::commit(Staged& s) {
  for (FactorId r : s.update.removals) {
    if (interEdges_.erase(r)) regroupNeeded_ = true;
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
    if (isAnchored(*f)) interEdges_[f->id()] = {keyRobot(f->key(1)), keyRobot(f->key(3))};
    if (s.owners[i].id >= 0) {
      owners_[f->id()] = s.owners[i];
      if (s.owners[i].uncertain) ++loopClosures_;
    }
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
  // Journal first: what is accepted survives a crash during the update.
  for (auto& s : staged_) {
    if (s.d.replayed || !journal_) continue;
    if (!journal_->append(s.d.raw->channel, s.d.raw->bytes.data(),
                          static_cast<int>(s.d.raw->bytes.size()), nowUtime()))
      spdlog::error("journal {}: write failed", journal_->path());
    else {
      std::lock_guard<std::mutex> l(countersMu_);
      ++counters_.journaled;
    }
  }
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
  if (ok) {
    for (auto& s : round) commit(s);
  } else {
    for (auto it = round.rbegin(); it != round.rend(); ++it) undo(*it);
    std::set<Key> movedSet;
    for (auto& s : round) {
      std::vector<Key> waiting;
      if (stage(s.d, waiting) != StageResult::Staged) {
        pub_.error(s.d.batch->sender, s.d.batch->sequence, 0, -1, E::INTERNAL,
                   "batch could not be initialised on retry; not applied", s.d.raw->channel);
        continue;
      }
      Staged one = std::move(staged_.back());
      staged_.clear();
      stagedValues_ = Values();
      try {
        for (Key k : applyUpdate(one.update, one.groupRemovals)) movedSet.insert(k);
        commit(one);
      } catch (const std::exception& e) {
        undo(one);
        spdlog::error("sender '{}' seq {}: backend refused the batch: {}", s.d.batch->sender,
                      s.d.batch->sequence, e.what());
        pub_.error(
            s.d.batch->sender, s.d.batch->sequence, 0, -1, E::INTERNAL,
            std::string("the solver refused the batch (not applied; graph intact): ") + e.what(),
            s.d.raw->channel);
        std::lock_guard<std::mutex> l(countersMu_);
        ++counters_.internalErrors;
      }
    }
    moved.assign(movedSet.begin(), movedSet.end());
  }
  if (regroupNeeded_) regroup(moved);
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

// --- publishing -------------------------------------------------------------------------

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
  if (!full.empty())
    for (int s = 0; s < est.size(); ++s) {
      const Key k = est.key(s);
      if (full.count(keyRobot(k)) &&
          (keyKind(k) == KeyKind::Pose || keyKind(k) == KeyKind::Landmark))
        keysOf[keyRobot(k)].push_back(k);
    }
  for (auto& [r, keys] : keysOf) {
    if (onlyRobot >= 0 && static_cast<int>(r) != onlyRobot) continue;
    auto rit = robots_.find(r);
    RobotEstimate e;
    e.robot = static_cast<std::int32_t>(r);
    e.hypothesis = hypothesis;
    e.fullSnapshot = full.count(r) > 0 && !moved ? true : full.count(r) > 0;
    e.se3 = rit != robots_.end() && rit->second.poseType == VarType::SE3;
    const bool anchored =
        rit != robots_.end() && rit->second.anchored && est.contains(anchorKey(r));
    e.commonFrame = anchored;
    e.frameRobot = static_cast<std::int32_t>(anchored ? root(r) : r);
    std::sort(keys.begin(), keys.end());
    keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
    SE2 A2;
    SE3 A3;
    if (anchored) {
      if (e.se3)
        A3 = se3Of(est, anchorKey(r));
      else
        A2 = se2Of(est, anchorKey(r));
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
    const std::uint32_t r = keyRobot(keys[i]);
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

// --- commands ---------------------------------------------------------------------------

void Engine::commandError(const loopd::command_t& c, std::int8_t code, const std::string& reason,
                          const std::string& channel) {
  spdlog::warn("command {} from '{}' (request {}): {}", static_cast<int>(c.command), c.sender,
               c.request_id, reason);
  pub_.error(c.sender, 0, c.request_id, -1, code, reason, channel);
}

void Engine::feedRebuilt(Backend& next, BackendUpdate all) {
  feedWhole(next, std::move(all));
  // Callers swap `next` in only if this returns: a diverged rebuild leaves the old backend.
  if (ranAway(next.estimate()))
    throw std::runtime_error("the rebuilt solver diverged (NaN, infinite or absurd estimate)");
}

std::unique_ptr<PerFactorRobustBackend> Engine::makeSolver(const std::string& name) const {
  return std::make_unique<PerFactorRobustBackend>(makeBackend(name, backendOptions()));
}

void Engine::rebuildBackend(const std::string& solver) {
  std::unique_ptr<PerFactorRobustBackend> next = makeSolver(solver);
  BackendUpdate all;
  for (const auto& [id, f] : live_) all.factors.push_back(f);
  for (const auto& [id, g] : groups_) all.ambiguous.push_back(g.factor);  // in arrival order
  all.initial = backend_->estimate();
  feedRebuilt(*next, std::move(all));
  backend_ = std::move(next);
  lastDecisions_.clear();
  lastGroupDecisions_.clear();
  dirty_ = true;
}

void Engine::resetAll() {
  backend_ = makeSolver(backend_->name());
  sessions_.clear();
  robots_.clear();
  live_.clear();
  owners_.clear();
  lastDecisions_.clear();
  groups_.clear();
  lastGroupDecisions_.clear();
  loopClosures_ = 0;
  interEdges_.clear();
  staged_.clear();
  stagedValues_ = Values();
  holds_.clear();
  dirty_ = false;
}

void Engine::handleCommand(const Inbound& m) {
  loopd::command_t c{};
  int used = -1;
  if (m.bytes.size() >= 8 && readHash(m.bytes.data()) != loopd::command_t::getHash()) {
    const std::string name = fingerprintName(readHash(m.bytes.data()));
    pub_.error("", 0, 0, -1, E::WRONG_FINGERPRINT,
               "fingerprint does not match command_t" +
                   (name.empty() ? std::string() : " (it is a " + name + ")"),
               m.channel);
    return;
  }
  try {
    used = c.decode(m.bytes.data(), 0, static_cast<int>(m.bytes.size()));
  } catch (const std::exception&) {
    used = -1;
  }
  if (used < 0 || used != static_cast<int>(m.bytes.size())) {
    pub_.error("", 0, 0, -1, E::DECODE_FAILED, "command_t does not decode", m.channel);
    return;
  }
  spdlog::info("command {} from '{}' (request {}) '{}'", static_cast<int>(c.command), c.sender,
               c.request_id, c.argument);
  using C = loopd::command_t;
  try {
    switch (c.command) {
      case C::RESET:
        resetAll();
        ++updateSeq_;
        publishStatus(c.request_id, true);
        return;
      case C::SWITCH_SOLVER: {
        if (!isBackendName(c.argument)) {
          commandError(c, E::COMMAND_FAILED, "unknown solver '" + c.argument + "'", m.channel);
          return;
        }
        rebuildBackend(c.argument);
        afterUpdate(backend_->estimate().keys(), 0.0, true);
        publishStatus(c.request_id, true);
        return;
      }
      case C::REQUEST_COVARIANCE: {
        std::vector<Key> keys;
        for (const auto& k : c.keys) {
          std::string why;
          const Key key = toKey(k);
          if (k.robot < 0 || k.index < 0 || (k.kind != 0 && k.kind != 1) ||
              !backend_->estimate().contains(key)) {
            commandError(c, E::UNKNOWN_KEY, "key " + wireKeyName(k) + " is not in the graph",
                         m.channel);
            return;
          }
          keys.push_back(key);
        }
        if (keys.empty()) {
          commandError(c, E::COMMAND_FAILED, "REQUEST_COVARIANCE without keys", m.channel);
          return;
        }
        const bool joint = c.argument.empty() || c.argument == "joint";
        if (!joint && c.argument != "marginals") {
          commandError(c, E::COMMAND_FAILED, "argument must be \"\", \"joint\" or \"marginals\"",
                       m.channel);
          return;
        }
        std::vector<int> dims;
        int D = 0;
        for (Key k : keys) {
          dims.push_back(varDim(backend_->estimate().type(backend_->estimate().slot(k))));
          D += dims.back();
        }
        if (joint && D > loopd::covariance_t::MAX_JOINT_DIM) {
          commandError(c, E::LIMIT_EXCEEDED, "joint dimension " + std::to_string(D) + " exceeds 72",
                       m.channel);
          return;
        }
        const size_t per = joint ? keys.size() : static_cast<size_t>(loopd::covariance_t::MAX_KEYS);
        const size_t chunks = (keys.size() + per - 1) / per;
        for (size_t ch = 0; ch < chunks; ++ch) {
          loopd::covariance_t out{};
          out.update_seq = updateSeq_;
          out.request_id = c.request_id;
          out.chunk_index = static_cast<std::int32_t>(ch);
          out.chunk_count = static_cast<std::int32_t>(chunks);
          out.joint = joint;
          const size_t b = ch * per, e = std::min(keys.size(), b + per);
          if (joint) {
            const Eigen::MatrixXd S = commonFrameCovariance(keys);
            for (int i = 0; i < S.rows(); ++i)
              for (int j = 0; j < S.cols(); ++j) out.values.push_back(S(i, j));
          }
          for (size_t i = b; i < e; ++i) {
            out.keys.push_back(toWireKey(keys[i]));
            out.dims.push_back(static_cast<std::int8_t>(dims[i]));
            if (!joint) {
              const Eigen::MatrixXd S = commonFrameCovariance({keys[i]});
              for (int r = 0; r < S.rows(); ++r)
                for (int q = 0; q < S.cols(); ++q) out.values.push_back(S(r, q));
            }
          }
          pub_.covariance(out);
        }
        return;
      }
      case C::REQUEST_ESTIMATE: {
        int robot = -1;
        if (!c.argument.empty()) {
          try {
            robot = std::stoi(c.argument);
          } catch (const std::exception&) {
            commandError(c, E::COMMAND_FAILED, "argument must be a robot id", m.channel);
            return;
          }
        }
        publishEstimates(nullptr, c.request_id, robot);
        return;
      }
      case C::SAVE_SNAPSHOT: {
        io::Dataset ds;
        ds.path = c.argument;
        const Values& est = backend_->estimate();
        std::vector<Key> keys = est.keys();
        std::sort(keys.begin(), keys.end());
        for (Key k : keys) {
          const int s = est.slot(k);
          io::Vertex v;
          v.id = static_cast<std::int64_t>(keyIndex(k));
          std::vector<double> common;
          if (keyKind(k) == KeyKind::Pose) {
            if (!commonFramePose(k, common)) continue;
            v.type = est.type(s) == VarType::SE3 ? io::VertexType::SE3 : io::VertexType::SE2;
            std::copy(common.begin(), common.end(), v.value.begin());
            ds.is3d |= v.type == io::VertexType::SE3;
            ds.poses.push_back(v);
          } else if (keyKind(k) == KeyKind::Landmark) {
            v.type =
                est.type(s) == VarType::Point3 ? io::VertexType::Point3 : io::VertexType::Point2;
            for (int i = 0; i < varDim(est.type(s)); ++i)
              v.value[static_cast<size_t>(i)] = est.data(s)[i];
            ds.landmarks.push_back(v);
          }
        }
        try {
          io::writeG2oVertices(c.argument, ds);
        } catch (const std::exception& e) {
          commandError(c, E::COMMAND_FAILED, std::string("cannot write snapshot: ") + e.what(),
                       m.channel);
          return;
        }
        publishStatus(c.request_id, false);
        return;
      }
      case C::OPTIMIZE: {
        dirty_ = true;
        lastInput_ = Clock::now() - std::chrono::hours(1);
        idle();
        publishStatus(c.request_id, false);
        return;
      }
      case C::REQUEST_STATUS:
        publishStatus(c.request_id, true);
        return;
      case C::REQUEST_HYPOTHESES: {
        // Full snapshots of hypotheses rank 0..n−1 (estimate_t.hypothesis = rank), then a
        // status with the top min(n, MAX_HYPOTHESES) of them. Without mh: rank 0 only.
        int n = loopd::status_t::MAX_HYPOTHESES;
        if (!c.argument.empty()) {
          size_t used = 0;
          try {
            n = std::stoi(c.argument, &used);
          } catch (const std::exception&) {
            used = 0;
          }
          if (used != c.argument.size() || n < 1) {
            commandError(
                c, E::COMMAND_FAILED,
                "argument must be \"\" or a number of hypotheses >= 1, not '" + c.argument + "'",
                m.channel);
            return;
          }
        }
        if (const auto* mh = dynamic_cast<const MhBackend*>(&backend_->solver())) {
          const auto hyps = mh->hypotheses(n);
          for (size_t r = 0; r < hyps.size(); ++r)
            publishEstimates(nullptr, c.request_id, -1, hyps[r].estimate, static_cast<int>(r));
        } else {
          publishEstimates(nullptr, c.request_id, -1);
        }
        publishStatus(c.request_id, false, n);
        return;
      }
      default:
        commandError(c, E::INVALID_FIELD, "unknown command " + std::to_string(c.command),
                     m.channel);
        return;
    }
  } catch (const std::exception& e) {
    commandError(c, E::COMMAND_FAILED, e.what(), m.channel);
  }
}

void Engine::regroup(std::vector<Key>& moved) {
  // Inter-robot factors were removed: recompute the groups of joined robots from the live ones;
  // a group left without a root prior gets one (at its current value) on its lowest robot.
  regroupNeeded_ = false;
  std::map<std::uint32_t, std::uint32_t> parent;
  std::function<std::uint32_t(std::uint32_t)> find = [&](std::uint32_t r) {
    while (parent[r] != r) r = parent[r] = parent[parent[r]];
    return r;
  };
  for (auto& [r, info] : robots_)
    if (info.anchored) parent[r] = r;
  for (const auto& [id, e] : interEdges_) {
    const std::uint32_t a = find(e.first), b = find(e.second);
    if (a != b) parent[std::max(a, b)] = std::min(a, b);
  }
  std::map<std::uint32_t, bool> hasRootPrior;
  for (auto& [r, p] : parent) hasRootPrior[find(r)] |= robots_.at(r).anchorPrior != 0;
  BackendUpdate u;
  for (auto& [r, p] : parent) {
    const std::uint32_t g = find(r);
    robots_.at(r).parent = g;
    if (g == r && !hasRootPrior[g]) {
      const Values& est = backend_->estimate();
      FactorPtr prior = priorAt(anchorKey(r), est, est.slot(anchorKey(r)), opt_.priorInformation);
      robots_.at(r).anchorPrior = prior->id();
      u.factors.push_back(prior);
      spdlog::info("robot {} roots a group again (inter-robot factors removed)", r);
    }
  }
  if (u.factors.empty()) return;
  try {
    for (Key k : backend_->update(u).moved) moved.push_back(k);
    for (const auto& f : u.factors) live_[f->id()] = f;
  } catch (const std::exception& e) {
    spdlog::error("re-anchoring failed: {}", e.what());
  }
}

bool Engine::commonFramePose(Key k, std::vector<double>& out) const {
  const Values& est = backend_->estimate();
  const int s = est.slot(k);
  if (s < 0) return false;
  const std::uint32_t r = keyRobot(k);
  const bool anchored = robotJoined(r) && est.contains(anchorKey(r));
  if (est.type(s) == VarType::SE2) {
    const SE2 x = anchored ? se2Of(est, anchorKey(r)) * est.se2(s) : est.se2(s);
    out = {x.x, x.y, x.theta};
  } else if (est.type(s) == VarType::SE3) {
    const SE3 x = anchored ? se3Of(est, anchorKey(r)) * est.se3(s) : est.se3(s);
    out.assign(7, 0.0);
    x.toTranslationQuaternion(out.data());
  } else {
    return false;
  }
  return true;
}

}  // namespace loopd::server
