// command_t through the engine: solver switch, covariance and status requests, snapshots,
// removals, optimize, reset; and rebuilding the Backend from the graph it holds.
#include "server/engine.h"

#include <spdlog/spdlog.h>

#include <algorithm>

#include "loopd/covariance_t.hpp"
#include "loopd/error_t.hpp"
#include "robust/backend_registry.h"
#include "robust/mh_backend.h"
#include "server/fingerprint.h"
#include "server/wire.h"
#include "server/wire_factors.h"
#include "solvers/io/estimate_writer.h"

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

}  // namespace

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
  if (m.bytes.size() >= 8 && readFingerprint(m.bytes.data()) != loopd::command_t::getHash()) {
    const std::string name = fingerprintName(readFingerprint(m.bytes.data()));
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

}  // namespace loopd::server
