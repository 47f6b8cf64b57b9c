// The engine's construction, its GraphView (what the validator asks of the graph), the
// loop (step, idle, run) and journal replay.
#include "server/engine.h"

#include <spdlog/spdlog.h>

#include <algorithm>

#include "loopd/error_t.hpp"
#include "server/frame_groups.h"
#include "server/wire_factors.h"
#include "solvers/backend/moved_keys.h"

namespace loopd::server {

using E = loopd::error_t;
using Clock = std::chrono::steady_clock;

Engine::Engine(EngineOptions options, Publisher& publisher, Journal* journal)
    : opt_(std::move(options)), pub_(publisher), journal_(journal) {
  backend_ = makeSolver(opt_.solver);
  lastInput_ = lastStatus_ = Clock::now();
  // update_seq never goes back, across restarts and resumes too: it starts at the start time
  // in µs (an update takes longer than one) and counts up from there.
  updateSeq_ = nowUtime();
}

Engine::~Engine() = default;

BackendOptions Engine::backendOptions() const {
  BackendOptions bo;
  bo.maxHypotheses = opt_.maxHypotheses;
  // The server's values are the odometry's predictions and, after a SWITCH_SOLVER or a
  // rebuild, the converged estimate: a batch solver's linear initialization would replace
  // them with one that skips every closure with a per-factor robust request (and then
  // rejects them all).
  bo.linearInitialization = false;
  // Long optimize() work that can be given up (risam's GNC look at a pause) yields to input
  // and to a stop.
  bo.interrupt = [this] { return queueDepth() > 0 || stopping(); };
  // A look that has given way too often (RisamOptions::looksGivenUpAtMost) runs to its end
  // while input waits in the queue, and still yields to a stop.
  bo.stopping = [this] { return stopping(); };
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

std::map<FactorId, InterEdge> Engine::currentInterEdges(const Staged* building) const {
  std::map<FactorId, InterEdge> edges = interEdges_;
  auto apply = [&](const Staged& s) {
    for (FactorId r : s.update.removals) edges.erase(r);
    for (const auto& f : s.update.factors)
      if (isAnchored(*f)) edges[f->id()] = interEdgeOf(*f);
  };
  for (const Staged& s : staged_) apply(s);
  if (building) apply(*building);
  return edges;
}

OwnerTies Engine::ownerTiesAt(const Staged* building) const {
  // The staged rounds' ties, added and removed, over the committed counts.
  std::map<Key, int> delta;
  std::map<FactorId, Key> stagedTies;
  auto apply = [&](const Staged& s) {
    for (FactorId r : s.update.removals) {
      Key l = 0;
      if (const auto t = stagedTies.find(r); t != stagedTies.end())
        l = t->second;
      else if (const auto f = live_.find(r); f != live_.end())
        l = ownerTiedLandmark(*f->second);
      if (l != 0) --delta[l];
    }
    for (const auto& f : s.update.factors)
      if (const Key l = ownerTiedLandmark(*f)) {
        ++delta[l];
        stagedTies[f->id()] = l;
      }
  };
  for (const Staged& s : staged_) apply(s);
  if (building) apply(*building);
  return [this, delta = std::move(delta)](Key l) {
    const auto c = ownerTies_.find(l);
    const auto d = delta.find(l);
    return (c == ownerTies_.end() ? 0 : c->second) + (d == delta.end() ? 0 : d->second) > 0;
  };
}

std::map<std::uint32_t, std::uint32_t> Engine::frameGroups(const loopd::factor_batch_t& b) const {
  // From the certain inter-robot factors themselves (not robots_' parents, which regroup()
  // updates only after a round), so the answer depends on the order of batches alone, not on
  // how they were coalesced into rounds: a journal replay decides exactly as the live run.
  // The batch's own sightings are not counted (whether they join is decided when staged), nor
  // its closures that would be kept back until enough agree (engine_closures.cpp).
  std::map<FactorId, InterEdge> edges = currentInterEdges(nullptr);
  for (std::int64_t rid : b.remove_ids)
    if (const auto fid = sessions_.liveId(b.sender, rid)) edges.erase(*fid);
  std::vector<std::pair<std::uint32_t, std::uint32_t>> joins;
  for (const auto& f : b.factors)
    if (isInterRobot(f) && joinsAtOnce(f))
      joins.emplace_back(static_cast<std::uint32_t>(f.keys[0].robot),
                         static_cast<std::uint32_t>(f.keys[1].robot));
  return frameGroupsOf(edges, ownerTiesAt(nullptr), joins);
}

std::uint32_t Engine::landmarkFrame(std::uint32_t robot) const {
  const auto a = adopted_.find(robot);
  return a == adopted_.end() ? robot : a->second;
}

std::map<std::uint32_t, std::uint32_t> Engine::adoptionsOf(const loopd::factor_batch_t& b) const {
  std::map<std::uint32_t, std::uint32_t> out;
  for (const auto& f : b.factors) {
    if (!isSighting(f)) continue;  // (a prior has one key)
    const auto ns = static_cast<std::uint32_t>(f.keys[1].robot);
    if (isLandmarkNamespace(ns) && !adopted_.count(ns))
      out.emplace(ns, static_cast<std::uint32_t>(f.keys[0].robot));
  }
  return out;
}

bool Engine::isCrossFrameSighting(const loopd::factor_t& f,
                                  const std::map<std::uint32_t, std::uint32_t>& adoptions) const {
  // A namespace has no poses, so only a cross-robot sighting can be one (of its adopter's
  // frame or not).
  if (!isCrossRobotSighting(f)) return false;
  const auto robot = static_cast<std::uint32_t>(f.keys[1].robot);
  const auto a = adoptions.find(robot);
  return static_cast<std::uint32_t>(f.keys[0].robot) !=
         (a == adoptions.end() ? landmarkFrame(robot) : a->second);
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
  std::map<std::uint32_t, int> posesStaged;  // new poses of each robot in the staged round
  for (auto& m : batch) {
    if (m->channel == pub_.channels().command) {
      flush();
      posesStaged.clear();
      handleCommand(*m);
      continue;
    }
    const size_t before = staged_.size();
    handleFactors(m, false);
    if (staged_.size() == before) continue;
    bool full = false;
    const Values& added = staged_.back().update.initial;
    for (int i = 0; i < added.size(); ++i)
      if (keyKind(added.key(i)) == KeyKind::Pose)
        full |= ++posesStaged[keyRobot(added.key(i))] >= opt_.posesPerUpdate;
    if (full && opt_.posesPerUpdate > 0) {
      retryHolds();
      flush();
      posesStaged.clear();
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
    dirty_ = pauseGoesOn();
    const std::vector<Key> moved = movedKeys(before, backend_->estimate(), 1e-9);
    spdlog::debug("idle optimize: {:.1f} ms, {} variables moved, chi2 {:.9g}", sec * 1e3,
                  moved.size(), backend_->chi2());
    afterUpdate(moved, sec, true);
  }
  if (std::chrono::duration<double>(Clock::now() - lastStatus_).count() >= opt_.heartbeatSeconds)
    publishStatus(0, false);
}

bool Engine::pauseGoesOn() {
  if (pauseOf_ != lastInput_) {
    pauseOf_ = lastInput_;
    idleRound_ = 0;
  }
  // Input that arrived meanwhile may have made the backend give work up (interrupt: risam's
  // GNC look); the graph is then not settled, and the next pause optimizes again even if the
  // input was only a command. An optimize() that spent its budget still descending goes on
  // at the next idle(), up to idleRounds per pause: a quiet server shows the optimum, not
  // where 100 iterations reached (dcs on sphere2500 in two robots: 255 rejected, 203 given
  // 377 iterations).
  const bool budgetSpent = backend_->summary().budgetSpent;
  const bool resume = budgetSpent && ++idleRound_ < opt_.idleRounds;
  if (resume)
    spdlog::debug("idle optimize: stopped on its iteration budget; round {} follows",
                  idleRound_ + 1);
  else if (budgetSpent)
    spdlog::warn("idle optimize: still descending after {} rounds; resumed at the next input",
                 idleRound_);
  if (queueDepth() > 0 || resume) return true;
  // Settled: the joins are checked again on the settled maps. At a round's own check its new
  // poses, composed from odometry, can bend the maps so that one revisit's true closures
  // split into small agreeing sets (sphere2500 at full speed, three robots).
  if (joinChecks_.empty()) return false;
  std::vector<Key> rejoined;
  checkJoins(rejoined, true);
  return !rejoined.empty() && ++idleRound_ < opt_.idleRounds;  // a move counts as a round
}

void Engine::run(const std::atomic<bool>& stop) {
  stop_ = &stop;
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
  stop_ = nullptr;
  if (journal_) journal_->flush();
}

std::int64_t Engine::replay(const std::string& path, bool rejournal, long* validBytes) {
  replaying_ = !rejournal;
  struct Done {  // a journal that turns out damaged throws: the engine is left live
    bool& replaying;
    ~Done() { replaying = false; }
  } done{replaying_};
  const std::int64_t n = readJournal(
      path,
      [&](const std::string& channel, const void* data, int size) {
        const auto* bytes = static_cast<const std::uint8_t*>(data);
        if (channel == pub_.channels().factors) {  // an applied batch
          auto m = std::make_shared<Inbound>();
          m->channel = channel;
          m->bytes.assign(bytes, bytes + size);
          handleFactors(m, !rejournal);
          if (staged_.size() >= 64) flush();
        } else if (channel == pub_.channels().command) {  // a RESET
          loopd::command_t c{};
          if (c.decode(data, 0, size) != size || c.command != loopd::command_t::RESET) return;
          flush();
          if (rejournal && journal_) journal_->appendRecord(channel, data, size, nowUtime());
          resetAll();
          ++updateSeq_;
        } else if (channel == pub_.channels().error) {  // a number consumed, not applied
          E e{};
          if (e.decode(data, 0, size) != size || e.sender.empty() || e.sequence < 1) return;
          if (!sessions_.receive(e.sender, e.sequence)) return;
          if (rejournal && journal_)
            journal_->appendConsumed(channel, e.sender, e.sequence, e.code, e.reason, nowUtime());
          std::lock_guard<std::mutex> l(countersMu_);
          ++(e.code == E::HELD_EXPIRED ? counters_.expired : counters_.rejected);
        }
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

}  // namespace loopd::server
