#include "server/publisher.h"

#include <algorithm>
#include <chrono>

namespace loopd::server {

Channels Channels::withPrefix(const std::string& p) {
  return {p + "FACTORS",    p + "COMMAND", p + "ESTIMATE",
          p + "COVARIANCE", p + "STATUS",  p + "ERROR"};
}

std::int64_t nowUtime() {
  return std::chrono::duration_cast<std::chrono::microseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

void Publisher::estimate(const RobotEstimate& e, std::int64_t updateSeq, std::int64_t requestId) {
  const size_t maxEntries = static_cast<size_t>(loopd::estimate_t::MAX_CHUNK_ENTRIES);
  const size_t total = e.poseIndices.size() + e.landmarkIndices.size();
  const size_t chunks = std::max<size_t>(1, (total + maxEntries - 1) / maxEntries);
  const std::int16_t pdim = e.se3 ? 7 : 3;
  const std::int16_t ldim = e.landmarks3d ? 3 : 2;
  size_t next = 0;
  const std::int64_t utime = nowUtime();
  for (size_t c = 0; c < chunks; ++c) {
    loopd::estimate_t m{};
    m.utime = utime;
    m.update_seq = updateSeq;
    m.request_id = requestId;
    m.robot = e.robot;
    m.frame_robot = e.frameRobot;
    m.common_frame = e.commonFrame;
    m.full_snapshot = e.fullSnapshot;
    m.hypothesis = e.hypothesis;
    m.chunk_index = static_cast<std::int32_t>(c);
    m.chunk_count = static_cast<std::int32_t>(chunks);
    m.pose_type = e.se3 ? loopd::estimate_t::SE3 : loopd::estimate_t::SE2;
    m.pose_dim = pdim;
    m.landmark_dim = ldim;
    const size_t end = std::min(total, next + maxEntries);
    for (; next < end; ++next) {
      if (next < e.poseIndices.size()) {
        m.pose_indices.push_back(e.poseIndices[next]);
        m.poses.push_back(e.poses[next]);
      } else {
        const size_t l = next - e.poseIndices.size();
        m.landmark_indices.push_back(e.landmarkIndices[l]);
        m.landmarks.push_back(e.landmarks[l]);
      }
    }
    m.num_poses = static_cast<std::int16_t>(m.pose_indices.size());
    m.num_landmarks = static_cast<std::int16_t>(m.landmark_indices.size());
    send(ch_.estimate, m);
  }
}

void Publisher::covariance(loopd::covariance_t& m) {
  m.utime = nowUtime();
  m.num_keys = static_cast<std::int16_t>(m.keys.size());
  m.num_values = static_cast<std::int16_t>(m.values.size());
  send(ch_.covariance, m);
}

void Publisher::status(loopd::status_t m, const std::vector<loopd::loop_decision_t>& decisions) {
  const size_t per = static_cast<size_t>(loopd::status_t::MAX_DECISIONS);
  const size_t chunks = std::max<size_t>(1, (decisions.size() + per - 1) / per);
  m.utime = nowUtime();
  m.num_sender_gaps = static_cast<std::int16_t>(m.sender_gaps.size());
  m.num_hypotheses = static_cast<std::int16_t>(m.hypotheses.size());
  for (size_t c = 0; c < chunks; ++c) {
    m.decisions_chunk_index = static_cast<std::int32_t>(c);
    m.decisions_chunk_count = static_cast<std::int32_t>(chunks);
    const size_t b = c * per, e = std::min(decisions.size(), b + per);
    m.decisions.assign(decisions.begin() + static_cast<long>(b),
                       decisions.begin() + static_cast<long>(e));
    m.num_decisions = static_cast<std::int16_t>(m.decisions.size());
    send(ch_.status, m);
  }
}

void Publisher::error(const std::string& sender, std::int64_t sequence, std::int64_t requestId,
                      std::int64_t factorId, std::int8_t code, const std::string& reason,
                      const std::string& channel) {
  loopd::error_t m{};
  m.utime = nowUtime();
  m.sender = sender.substr(0, 63);
  m.sequence = sequence;
  m.request_id = requestId;
  m.factor_id = factorId;
  m.code = code;
  m.reason = reason.substr(0, static_cast<size_t>(loopd::error_t::MAX_REASON_LENGTH));
  m.channel = channel;
  send(ch_.error, m);
}

}  // namespace loopd::server
