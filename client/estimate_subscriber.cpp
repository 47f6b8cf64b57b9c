#include "client/estimate_subscriber.h"
#include "lcmtypes/lcm_url.h"

#include <lcm/lcm-cpp.hpp>

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

void EstimateSubscriber::handleEstimate(const loopd::estimate_t& m) {
  if (m.hypothesis != 0) return;
  RobotEstimate copy;
  bool changed = false;
  {
    std::lock_guard<std::mutex> l(mu_);
    ++estimates_;
    auto fill = [&](RobotEstimate& t) {
      t.robot = m.robot;
      t.frameRobot = m.frame_robot;
      t.commonFrame = m.common_frame;
      t.se3 = m.pose_type == loopd::estimate_t::SE3;
      t.updateSeq = m.update_seq;
      for (int i = 0; i < m.num_poses; ++i)
        t.poses[m.pose_indices[static_cast<size_t>(i)]] = m.poses[static_cast<size_t>(i)];
      for (int i = 0; i < m.num_landmarks; ++i)
        t.landmarks[m.landmark_indices[static_cast<size_t>(i)]] =
            m.landmarks[static_cast<size_t>(i)];
    };
    if (!m.full_snapshot) {
      fill(robots_[m.robot]);
      changed = true;
    } else {
      Pending& p = snapshots_[m.robot];
      if (p.updateSeq != m.update_seq || p.requestId != m.request_id || m.chunk_index == 0) {
        p = Pending{};
        p.updateSeq = m.update_seq;
        p.requestId = m.request_id;
        p.count = m.chunk_count;
      }
      fill(p.table);
      if (++p.received >= p.count) {
        // A complete snapshot replaces the table, unless deltas of a later update arrived.
        RobotEstimate& cur = robots_[m.robot];
        if (cur.updateSeq <= p.updateSeq)
          cur = p.table;
        else
          for (const auto& [i, v] : p.table.poses) cur.poses.emplace(i, v);
        snapshots_.erase(m.robot);
        changed = true;
      }
    }
    if (changed) copy = robots_[m.robot];
  }
  if (changed && onEstimate_) onEstimate_(copy, m);
}

void EstimateSubscriber::covarianceMsg(const lcm::ReceiveBuffer*, const std::string&,
                                       const loopd::covariance_t* m, EstimateSubscriber* self) {
  {
    std::lock_guard<std::mutex> l(self->mu_);
    if (m->request_id == 0 && !m->joint) {
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
  {
    std::lock_guard<std::mutex> l(self->mu_);
    self->status_ = *m;
  }
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
std::vector<loopd::error_t> EstimateSubscriber::errors() const {
  std::lock_guard<std::mutex> l(mu_);
  return errors_;
}

}  // namespace loopd::client
