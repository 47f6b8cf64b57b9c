#pragma once
// Encodes and sends what the server publishes: estimates (chunked per estimate_t limits),
// covariances, status (decisions chunked), errors. The sink is the LCM thread's publish (or a
// test's capture); it must be safe to call from the engine thread.
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "loopd/covariance_t.hpp"
#include "loopd/error_t.hpp"
#include "loopd/estimate_t.hpp"
#include "loopd/status_t.hpp"

namespace loopd::server {

struct Channels {
  std::string factors, command, estimate, covariance, status, error;
  static Channels withPrefix(const std::string& prefix);
};

using Sink =
    std::function<void(const std::string& channel, const std::vector<std::uint8_t>& bytes)>;

/// One robot's poses/landmarks to publish (already in the frame to publish in).
struct RobotEstimate {
  std::int32_t robot = 0, frameRobot = 0;
  std::int32_t hypothesis = 0;  // rank of the hypothesis this estimate belongs to (0 = best)
  bool commonFrame = false, fullSnapshot = false, se3 = false, landmarks3d = false;
  std::vector<std::int64_t> poseIndices;
  std::vector<std::vector<double>> poses;  // 3 or 7 numbers each
  std::vector<std::int64_t> landmarkIndices;
  std::vector<std::vector<double>> landmarks;  // 2 or 3 numbers each
};

class Publisher {
 public:
  Publisher(Channels channels, Sink sink) : ch_(std::move(channels)), sink_(std::move(sink)) {}
  const Channels& channels() const { return ch_; }

  /// Splits into chunks of at most MAX_CHUNK_ENTRIES entries (poses first, then landmarks).
  void estimate(const RobotEstimate& e, std::int64_t updateSeq, std::int64_t requestId);
  void covariance(loopd::covariance_t& msg);
  /// Splits the decisions over chunks of MAX_DECISIONS (every other field repeated).
  void status(loopd::status_t msg, const std::vector<loopd::loop_decision_t>& decisions);
  void error(const std::string& sender, std::int64_t sequence, std::int64_t requestId,
             std::int64_t factorId, std::int8_t code, const std::string& reason,
             const std::string& channel);

  template <class T>
  void send(const std::string& channel, const T& msg) {
    std::vector<std::uint8_t> buf(static_cast<size_t>(msg.getEncodedSize()));
    msg.encode(buf.data(), 0, static_cast<int>(buf.size()));
    sink_(channel, buf);
  }

 private:
  Channels ch_;
  Sink sink_;
};

std::int64_t nowUtime();

}  // namespace loopd::server
