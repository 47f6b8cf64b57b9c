// command_t through the engine: solver switch, covariance and status requests, snapshots,
// removals, optimize, reset; and rebuilding the Backend from the graph it holds.
#include "server/engine.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <charconv>
#include <limits>
#include <unordered_set>

#include "loopd/covariance_t.hpp"
#include "loopd/error_t.hpp"
#include "robust/backend_registry.h"
#include "robust/mh_backend.h"
#include "server/fingerprint.h"
#include "server/wire.h"
#include "server/wire_factors.h"

namespace loopd::server {

using E = loopd::error_t;
using Clock = std::chrono::steady_clock;

namespace {

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

// A command argument for logs and reasons: at most 80 characters of it.
std::string clipped(const std::string& s) {
  if (s.size() <= 80) return s;
  return s.substr(0, 80) + "... (" + std::to_string(s.size()) + " characters)";
}

// A decimal number of digits only (no sign, spaces or other characters), 0 … max.
bool parseDecimal(const std::string& s, std::int64_t max, std::int64_t& out) {
  if (s.empty() || s.front() < '0' || s.front() > '9') return false;
  std::int64_t v = 0;
  const auto r = std::from_chars(s.data(), s.data() + s.size(), v);
  if (r.ec != std::errc() || r.ptr != s.data() + s.size() || v > max) return false;
  out = v;
  return true;
}

}  // namespace

void Engine::commandError(const loopd::command_t& c, std::int8_t code, const std::string& reason,
                          const std::string& channel) {
  spdlog::warn("command {} from '{}' (request {}): {}", static_cast<int>(c.command), c.sender,
               c.request_id, reason);
  pub_.error(c.sender, 0, c.request_id, -1, code, reason, channel);
}

void Engine::feedRebuilt(Backend& next, BackendUpdate all) {
  // Only the graph's own variables: a solver's inner ones (the switch of a closure sent with
  // robust "sc") are the new solver's to add, and given as values too they "already exist".
  std::unordered_set<Key> used;
  auto use = [&](const FactorPtr& f) {
    for (int k = 0; k < f->size(); ++k) used.insert(f->key(k));
  };
  for (const auto& f : all.factors) use(f);
  for (const auto& a : all.ambiguous)
    for (const auto& f : a.alternatives) use(f);
  Values initial;
  for (int s = 0; s < all.initial.size(); ++s)
    if (used.count(all.initial.key(s))) initial.insertFrom(all.initial, s);
  all.initial = std::move(initial);
  feedWhole(next, std::move(all));
  // Callers swap `next` in only if this returns: a diverged rebuild leaves the old backend.
  if (ranAway(next.estimate()))
    throw std::runtime_error("the rebuilt solver diverged (NaN, infinite or absurd estimate)");
}

std::unique_ptr<PerFactorRobustBackend> Engine::makeSolver(const std::string& name) const {
  return std::make_unique<PerFactorRobustBackend>(makeBackend(name, backendOptions()));
}

void Engine::rebuildBackend(const std::string& solver, const Values* start) {
  std::unique_ptr<PerFactorRobustBackend> next = makeSolver(solver);
  BackendUpdate all;
  for (const auto& [id, f] : live_) all.factors.push_back(f);
  for (const auto& [id, g] : groups_) all.ambiguous.push_back(g.factor);  // in arrival order
  all.initial = start ? *start : backend_->estimate();
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
  ownerTies_.clear();
  adopted_.clear();
  pending_.clear();
  pendingClosures_.clear();
  joinChecks_.clear();
  settledJoins_.clear();
  staged_.clear();
  stagedValues_ = Values();
  holds_.clear();
  dirty_ = false;
}

void Engine::handleCommand(const Inbound& m) {
  loopd::command_t c{};
  int used = -1;
  if (m.bytes.size() >= 8 && readFingerprint(m.bytes.data()) != loopd::command_t::getHash()) {
    const std::string name = fingerprintName(readFingerprint(m.bytes.data()));
    const std::string why =
        "fingerprint does not match command_t" +
        (name.empty() ? std::string(" (unknown type)") : " (it is a " + name + ")");
    spdlog::warn("{}: {}", m.channel, why);
    pub_.error("", 0, 0, -1, E::WRONG_FINGERPRINT, why, m.channel);
    return;
  }
  try {
    used = c.decode(m.bytes.data(), 0, static_cast<int>(m.bytes.size()));
  } catch (const std::exception&) {
    used = -1;
  }
  if (used < 0 || used != static_cast<int>(m.bytes.size())) {
    const std::string why = used < 0 ? "command_t does not decode (truncated or corrupt)"
                                     : "command_t followed by " +
                                           std::to_string(static_cast<int>(m.bytes.size()) - used) +
                                           " trailing bytes";
    spdlog::warn("{}: {}", m.channel, why);
    pub_.error("", 0, 0, -1, E::DECODE_FAILED, why, m.channel);
    return;
  }
  spdlog::info("command {} from '{}' (request {}) '{}'", static_cast<int>(c.command), c.sender,
               c.request_id, clipped(c.argument));
  using C = loopd::command_t;
  // Checks every command shares (lcmtypes/README.md, command_t): a command that fails one is
  // refused before anything runs (nothing journaled, changed or replied but the error).
  if (c.command < C::RESET || c.command > C::REQUEST_STATUS) {
    commandError(c, E::INVALID_FIELD, "unknown command " + std::to_string(c.command), m.channel);
    return;
  }
  if (c.request_id <= 0) {
    commandError(c, E::INVALID_FIELD, "request_id must be > 0, not " + std::to_string(c.request_id),
                 m.channel);
    return;
  }
  if (c.argument.size() > static_cast<size_t>(C::MAX_ARGUMENT_LENGTH)) {
    commandError(c, E::LIMIT_EXCEEDED,
                 "argument of " + std::to_string(c.argument.size()) + " characters exceeds " +
                     std::to_string(C::MAX_ARGUMENT_LENGTH),
                 m.channel);
    return;
  }
  if (c.keys.size() > static_cast<size_t>(C::MAX_KEYS)) {
    commandError(c, E::LIMIT_EXCEEDED,
                 std::to_string(c.keys.size()) + " keys exceed " + std::to_string(C::MAX_KEYS),
                 m.channel);
    return;
  }
  if (!c.keys.empty() && c.command != C::REQUEST_COVARIANCE) {
    commandError(c, E::COMMAND_FAILED, "keys are for REQUEST_COVARIANCE only", m.channel);
    return;
  }
  if (!c.argument.empty() &&
      (c.command == C::RESET || c.command == C::OPTIMIZE || c.command == C::REQUEST_STATUS)) {
    commandError(c, E::COMMAND_FAILED, "takes no argument, not '" + clipped(c.argument) + "'",
                 m.channel);
    return;
  }
  try {
    switch (c.command) {
      case C::RESET:
        // Journaled (before anything reports it) so that --resume forgets what it forgot.
        if (journal_ && !replaying_ &&
            !journal_->appendRecord(m.channel, m.bytes.data(), static_cast<int>(m.bytes.size()),
                                    nowUtime()))
          spdlog::error("journal {}: write failed", journal_->path());
        resetAll();
        ++updateSeq_;
        publishStatus(c.request_id, true);
        return;
      case C::SWITCH_SOLVER: {
        if (!isBackendName(c.argument)) {
          commandError(c, E::COMMAND_FAILED, "unknown solver '" + clipped(c.argument) + "'",
                       m.channel);
          return;
        }
        rebuildBackend(c.argument);
        afterUpdate(backend_->estimate().keys(), 0.0, true);
        publishStatus(c.request_id, true);
        return;
      }
      case C::REQUEST_COVARIANCE: {
        const bool joint = c.argument.empty() || c.argument == "joint";
        if (!joint && c.argument != "marginals") {
          commandError(c, E::COMMAND_FAILED,
                       "argument must be \"\", \"joint\" or \"marginals\", not '" +
                           clipped(c.argument) + "'",
                       m.channel);
          return;
        }
        if (c.keys.empty()) {
          commandError(c, E::COMMAND_FAILED, "REQUEST_COVARIANCE without keys", m.channel);
          return;
        }
        std::vector<Key> keys;
        for (const auto& k : c.keys) {
          // Out-of-range fields would alias another variable once packed into a Key.
          if (k.robot < 0 || static_cast<std::uint32_t>(k.robot) > kMaxRobotId || k.index < 0 ||
              static_cast<std::uint64_t>(k.index) > kMaxKeyIndex ||
              (k.kind != loopd::key_t::POSE && k.kind != loopd::key_t::LANDMARK) ||
              !backend_->estimate().contains(toKey(k))) {
            commandError(c, E::UNKNOWN_KEY, "key " + wireKeyName(k) + " is not in the graph",
                         m.channel);
            return;
          }
          keys.push_back(toKey(k));
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
          std::int64_t r = -1;
          if (!parseDecimal(c.argument, kMaxRobotId, r) ||
              !robots_.count(static_cast<std::uint32_t>(r))) {
            commandError(c, E::COMMAND_FAILED,
                         "argument must be \"\" or the decimal id of a robot in the graph, not '" +
                             clipped(c.argument) + "'",
                         m.channel);
            return;
          }
          robot = static_cast<int>(r);
        }
        publishEstimates(nullptr, c.request_id, robot);
        return;
      }
      case C::SAVE_SNAPSHOT: {
        if (c.argument.empty()) {
          commandError(c, E::COMMAND_FAILED, "argument must be a path", m.channel);
          return;
        }
        try {
          writeSnapshot(c.argument);
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
          std::int64_t v = 0;
          if (!parseDecimal(c.argument, std::numeric_limits<int>::max(), v) || v < 1) {
            commandError(c, E::COMMAND_FAILED,
                         "argument must be \"\" or a decimal number of hypotheses >= 1, not '" +
                             clipped(c.argument) + "'",
                         m.channel);
            return;
          }
          n = static_cast<int>(v);
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

}  // namespace loopd::server
