#include "client/estimate_subscriber.h"
#include "lcmtypes/lcm_url.h"

#include <lcm/lcm-cpp.hpp>

#include <algorithm>
#include <cstdlib>

namespace loopd::client {

std::string receiveUrl(const std::string& url) { return lcmReceiveUrl(url); }

EstimateSubscriber::EstimateSubscriber(lcm::LCM& lcm, const std::string& p) : lcm_(lcm) {
  auto keep = [&](lcm::Subscription* s) {
    if (s) {
      s->setQueueCapacity(0);
      subscriptions_.push_back(s);
    }
  };
  keep(lcm_.subscribeFunction(p + "ESTIMATE", &EstimateSubscriber::estimateMsg, this));
  keep(lcm_.subscribeFunction(p + "COVARIANCE", &EstimateSubscriber::covarianceMsg, this));
  keep(lcm_.subscribeFunction(p + "STATUS", &EstimateSubscriber::statusMsg, this));
  keep(lcm_.subscribeFunction(p + "ERROR", &EstimateSubscriber::errorMsg, this));
}

EstimateSubscriber::~EstimateSubscriber() {
  for (void* s : subscriptions_) lcm_.unsubscribe(static_cast<lcm::Subscription*>(s));
}

void EstimateSubscriber::estimateMsg(const lcm::ReceiveBuffer*, const std::string&,
                                     const loopd::estimate_t* m, EstimateSubscriber* self) {
  self->handleEstimate(*m);
}

namespace {

/// Copies an estimate chunk's header and values into a table (values by index: later win).
void fillTable(RobotEstimate& t, const loopd::estimate_t& m) {
  t.robot = m.robot;
  t.frameRobot = m.frame_robot;
  t.commonFrame = m.common_frame;
  t.se3 = m.pose_type == loopd::estimate_t::SE3;
  t.updateSeq = m.update_seq;
  for (int i = 0; i < m.num_poses; ++i)
    t.poses[m.pose_indices[static_cast<size_t>(i)]] = m.poses[static_cast<size_t>(i)];
  for (int i = 0; i < m.num_landmarks; ++i)
    t.landmarks[m.landmark_indices[static_cast<size_t>(i)]] = m.landmarks[static_cast<size_t>(i)];
}

}  // namespace

void EstimateSubscriber::handleEstimate(const loopd::estimate_t& m) {
  if (m.hypothesis != 0) return;
  RobotEstimate copy;
  {
    std::lock_guard<std::mutex> l(mu_);
    ++estimates_;
    if (m.update_seq < forgottenBelow_) return;  // a late message of a forgotten graph
    if (m.full_snapshot) {
      if (!applySnapshotChunk(m)) return;
    } else {
      fillTable(robots_[m.robot], m);
    }
    newestTableSeq_ = std::max(newestTableSeq_, m.update_seq);
    const auto it = robots_.find(m.robot);
    copy = it != robots_.end() ? it->second : RobotEstimate{};
    copy.robot = m.robot;
  }
  if (onEstimate_) onEstimate_(copy, m);
}

/// Adds a chunk to the robot's snapshot being assembled; true once the snapshot is complete
/// and applied to the table.
bool EstimateSubscriber::applySnapshotChunk(const loopd::estimate_t& m) {
  Pending& p = snapshots_[m.robot];
  if (p.updateSeq != m.update_seq || p.requestId != m.request_id || m.chunk_index == 0) {
    p = Pending{};
    p.updateSeq = m.update_seq;
    p.requestId = m.request_id;
    p.count = m.chunk_count;
  }
  fillTable(p.table, m);
  if (++p.received < p.count) return false;
  // A complete snapshot replaces the table, unless deltas of a later update arrived.
  RobotEstimate& cur = robots_[m.robot];
  if (cur.updateSeq <= p.updateSeq) {
    cur = std::move(p.table);
  } else {
    for (const auto& [i, v] : p.table.poses) cur.poses.emplace(i, v);
    for (const auto& [i, v] : p.table.landmarks) cur.landmarks.emplace(i, v);
  }
  // A snapshot listing nothing: the robot has no variables left.
  if (cur.poses.empty() && cur.landmarks.empty()) robots_.erase(m.robot);
  snapshots_.erase(m.robot);
  return true;
}

bool EstimateSubscriber::tablesExceed(const loopd::status_t& s) const {
  std::int64_t robotsWithPoses = 0, poses = 0, landmarks = 0;
  for (const auto& [r, t] : robots_) {
    robotsWithPoses += t.poses.empty() ? 0 : 1;  // status_t.robots counts robots with poses
    poses += static_cast<std::int64_t>(t.poses.size());
    landmarks += static_cast<std::int64_t>(t.landmarks.size());
  }
  return robotsWithPoses > s.robots || poses > s.poses || landmarks > s.landmarks;
}

void EstimateSubscriber::forgetTables(std::int64_t updateSeq) {
  robots_.clear();
  snapshots_.clear();
  covariances_.clear();
  forgottenBelow_ = updateSeq;
  ++forgets_;
}

void EstimateSubscriber::covarianceMsg(const lcm::ReceiveBuffer*, const std::string&,
                                       const loopd::covariance_t* m, EstimateSubscriber* self) {
  {
    std::lock_guard<std::mutex> l(self->mu_);
    if (m->request_id == 0 && !m->joint && m->update_seq >= self->forgottenBelow_) {
      size_t off = 0;
      for (int i = 0; i < m->num_keys; ++i) {
        const size_t d = static_cast<size_t>(m->dims[static_cast<size_t>(i)]);
        if (off + d * d > m->values.size()) break;
        const auto& k = m->keys[static_cast<size_t>(i)];
        self->covariances_[k.robot] = {
            k.index, std::vector<double>(m->values.begin() + static_cast<long>(off),
                                         m->values.begin() + static_cast<long>(off + d * d))};
        off += d * d;
      }
    }
  }
  if (self->onCovariance_) self->onCovariance_(*m);
}

void EstimateSubscriber::statusMsg(const lcm::ReceiveBuffer*, const std::string&,
                                   const loopd::status_t* m, EstimateSubscriber* self) {
  bool forgot = false;
  {
    std::lock_guard<std::mutex> l(self->mu_);
    self->status_ = *m;
    // An older status (reordered) may count fewer variables than newer deltas brought.
    if (m->update_seq >= self->newestTableSeq_ && self->tablesExceed(*m)) {
      self->forgetTables(m->update_seq);
      forgot = true;
    }
  }
  if (forgot && self->onForget_) self->onForget_(m->update_seq);
  if (self->onStatus_) self->onStatus_(*m);
}

void EstimateSubscriber::errorMsg(const lcm::ReceiveBuffer*, const std::string&,
                                  const loopd::error_t* m, EstimateSubscriber* self) {
  {
    std::lock_guard<std::mutex> l(self->mu_);
    ++self->errorCount_;
    if (self->errors_.size() < 10000) self->errors_.push_back(*m);
  }
  if (self->onError_) self->onError_(*m);
}

std::vector<std::int32_t> EstimateSubscriber::robots() const {
  std::lock_guard<std::mutex> l(mu_);
  std::vector<std::int32_t> out;
  for (const auto& [r, t] : robots_) out.push_back(r);
  return out;
}
RobotEstimate EstimateSubscriber::robot(std::int32_t id) const {
  std::lock_guard<std::mutex> l(mu_);
  auto it = robots_.find(id);
  return it == robots_.end() ? RobotEstimate{} : it->second;
}
std::map<std::int32_t, RobotEstimate> EstimateSubscriber::all() const {
  std::lock_guard<std::mutex> l(mu_);
  return robots_;
}
std::map<std::int32_t, std::pair<std::int64_t, std::vector<double>>>
EstimateSubscriber::latestCovariances() const {
  std::lock_guard<std::mutex> l(mu_);
  return covariances_;
}
loopd::status_t EstimateSubscriber::lastStatus() const {
  std::lock_guard<std::mutex> l(mu_);
  return status_;
}
std::int64_t EstimateSubscriber::estimatesReceived() const {
  std::lock_guard<std::mutex> l(mu_);
  return estimates_;
}
std::int64_t EstimateSubscriber::errorsReceived() const {
  std::lock_guard<std::mutex> l(mu_);
  return errorCount_;
}
std::int64_t EstimateSubscriber::forgets() const {
  std::lock_guard<std::mutex> l(mu_);
  return forgets_;
}
std::vector<loopd::error_t> EstimateSubscriber::errors() const {
  std::lock_guard<std::mutex> l(mu_);
  return errors_;
}

}  // namespace loopd::client
