#pragma once
// The server's engine driven in-process for unit tests (no LCM): wire factors and batches
// built in a line, messages posted and stepped, everything it publishes decoded and kept.
#include <gtest/gtest.h>

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "client/factor_publisher.h"
#include "loopd/command_t.hpp"
#include "loopd/covariance_t.hpp"
#include "loopd/error_t.hpp"
#include "loopd/estimate_t.hpp"
#include "loopd/status_t.hpp"
#include "server/engine.h"
#include "tests/server/wire_encode.h"

namespace loopd::test {

/// Robot ra's pose a to robot rb's pose b, measured z, information diag(100, 100, 1000).
inline loopd::factor_t between2(std::int64_t id, int ra, std::int64_t a, int rb, std::int64_t b,
                                client::Pose2 z,
                                std::int8_t role = loopd::factor_t::ROLE_ODOMETRY) {
  loopd::factor_t f{};
  f.id = id;
  f.type = loopd::factor_t::BETWEEN_SE2;
  f.role = role;
  f.keys = {client::wireKey(client::KeyRef::pose(ra, a)),
            client::wireKey(client::KeyRef::pose(rb, b))};
  f.num_keys = 2;
  f.measurement = {z.x, z.y, z.theta};
  f.num_measurement = 3;
  f.noise_kind = loopd::factor_t::NOISE_INFORMATION;
  f.noise = {100, 0, 0, 100, 0, 1000};
  f.num_noise = 6;
  f.robust = "";
  f.robust_param = 0;
  return f;
}

inline loopd::factor_batch_t batch(const std::string& sender, std::int64_t seq,
                                   std::vector<loopd::factor_t> fs,
                                   std::vector<std::int64_t> removals = {}) {
  loopd::factor_batch_t b{};
  b.sender = sender;
  b.sequence = seq;
  b.factors = std::move(fs);
  b.num_factors = static_cast<std::int16_t>(b.factors.size());
  b.remove_ids = std::move(removals);
  b.num_remove_ids = static_cast<std::int16_t>(b.remove_ids.size());
  return b;
}

/// What the engine published on T_ERROR, T_STATUS, T_ESTIMATE and T_COVARIANCE.
struct Captured {
  std::vector<loopd::error_t> errors;
  std::vector<loopd::status_t> statuses;
  std::vector<loopd::estimate_t> estimates;
  std::vector<loopd::covariance_t> covariances;
};

struct EngineHarness {
  Captured out;
  server::Publisher pub;
  server::Engine engine;

  /// publishEvery 0 (no periodic publishing), the given solver and hold bound.
  static server::EngineOptions options(const std::string& solver, double holdSeconds = 30) {
    server::EngineOptions o;
    o.solver = solver;
    o.holdSeconds = holdSeconds;
    o.publishEvery = 0;
    return o;
  }
  explicit EngineHarness(const std::string& solver = "lm", double holdSeconds = 30,
                         server::Journal* journal = nullptr)
      : EngineHarness(options(solver, holdSeconds), journal) {}
  EngineHarness(const server::EngineOptions& o, server::Journal* journal)
      : pub(server::Channels::withPrefix("T_"),
            [this](const std::string& ch, const std::vector<uint8_t>& b) { capture(ch, b); }),
        engine(o, pub, journal) {}

  void send(const loopd::factor_batch_t& b) { sendRaw(encode(b)); }
  void sendRaw(std::vector<uint8_t> bytes) {
    engine.post({"T_FACTORS", std::move(bytes)});
    engine.step();
  }
  void command(std::int8_t c, const std::string& arg = "", std::vector<loopd::key_t> keys = {},
               std::int64_t requestId = 7) {
    loopd::command_t m{};
    m.sender = "test";
    m.request_id = requestId;
    m.command = c;
    m.argument = arg;
    m.keys = std::move(keys);
    m.num_keys = static_cast<std::int16_t>(m.keys.size());
    engine.post({"T_COMMAND", encode(m)});
    engine.step();
  }
  /// Pose variables in the backend (anchors included).
  int poses() const {
    int n = 0;
    for (Key k : engine.backend().estimate().keys()) n += keyKind(k) == KeyKind::Pose;
    return n;
  }

 private:
  void capture(const std::string& ch, const std::vector<uint8_t>& b) {
    const int n = static_cast<int>(b.size());
    auto decodeInto = [&](auto& list) {
      list.emplace_back();
      EXPECT_EQ(list.back().decode(b.data(), 0, n), n) << ch << " decodes to its end";
    };
    if (ch == "T_ERROR") decodeInto(out.errors);
    if (ch == "T_STATUS") decodeInto(out.statuses);
    if (ch == "T_ESTIMATE") decodeInto(out.estimates);
    if (ch == "T_COVARIANCE") decodeInto(out.covariances);
  }
};

}  // namespace loopd::test
