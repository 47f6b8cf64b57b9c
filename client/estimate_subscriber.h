#pragma once
// loopd_client: following a loopd server's output. Keeps the latest estimate of every robot
// (assembling chunked full snapshots, applying deltas), the latest covariances, status and
// errors, and calls back on updates. Handlers run inside lcm.handle*() on the caller's thread;
// the accessors are safe from any thread.
//
// No message says a variable is gone, so the subscriber checks its tables against each status:
// a status at least as new as every table that counts fewer robots, poses or landmarks than
// the tables hold (an empty graph after RESET, a server restarted without --resume) proves
// them stale, and the subscriber forgets every table (see onForget).
#include <cstdint>
#include <functional>
#include <map>
#include <mutex>
#include <string>
#include <vector>

#include "loopd/covariance_t.hpp"
#include "loopd/error_t.hpp"
#include "loopd/estimate_t.hpp"
#include "loopd/status_t.hpp"

namespace lcm {
class LCM;
class ReceiveBuffer;
}  // namespace lcm

namespace loopd::client {

struct RobotEstimate {
  std::int32_t robot = 0;
  std::int32_t frameRobot = 0;
  bool commonFrame = false;
  bool se3 = false;
  std::int64_t updateSeq = 0;
  std::map<std::int64_t, std::vector<double>> poses;      // index → x y θ | x y z qx qy qz qw
  std::map<std::int64_t, std::vector<double>> landmarks;  // index → x y [z]
};

/// An LCM URL with a 4 MB kernel receive buffer for udpm (full snapshots come in bursts of
/// ~64 KB chunks; the default ~200 KB buffer drops them). "" resolves to LCM's default URL.
std::string receiveUrl(const std::string& url);

class EstimateSubscriber {
 public:
  explicit EstimateSubscriber(lcm::LCM& lcm, const std::string& channelPrefix = "LOOPD_");
  ~EstimateSubscriber();

  std::vector<std::int32_t> robots() const;
  RobotEstimate robot(std::int32_t id) const;
  std::map<std::int32_t, RobotEstimate> all() const;
  /// Latest automatic covariance block of each robot's newest pose (row-major d×d).
  std::map<std::int32_t, std::pair<std::int64_t, std::vector<double>>> latestCovariances() const;
  /// Last status (default-constructed until one arrives) and counters.
  loopd::status_t lastStatus() const;
  std::int64_t estimatesReceived() const;
  std::int64_t errorsReceived() const;
  std::vector<loopd::error_t> errors() const;

  /// Times the tables were forgotten as stale (a RESET, a restart without --resume).
  std::int64_t forgets() const;

  /// Called after a robot's table changed (a delta chunk or a complete snapshot).
  void onEstimate(std::function<void(const RobotEstimate&, const loopd::estimate_t&)> cb) {
    onEstimate_ = std::move(cb);
  }
  void onCovariance(std::function<void(const loopd::covariance_t&)> cb) {
    onCovariance_ = std::move(cb);
  }
  void onStatus(std::function<void(const loopd::status_t&)> cb) { onStatus_ = std::move(cb); }
  void onError(std::function<void(const loopd::error_t&)> cb) { onError_ = std::move(cb); }
  /// Called (before onStatus) when a status proved every table stale and they were forgotten;
  /// the argument is that status's update_seq. Deltas rebuild the tables only partly: a
  /// follower that needs them whole asks for a full estimate (command_t.REQUEST_ESTIMATE).
  void onForget(std::function<void(std::int64_t)> cb) { onForget_ = std::move(cb); }

 private:
  static void estimateMsg(const lcm::ReceiveBuffer*, const std::string&, const loopd::estimate_t* m,
                          EstimateSubscriber* self);
  static void covarianceMsg(const lcm::ReceiveBuffer*, const std::string&,
                            const loopd::covariance_t* m, EstimateSubscriber* self);
  static void statusMsg(const lcm::ReceiveBuffer*, const std::string&, const loopd::status_t* m,
                        EstimateSubscriber* self);
  static void errorMsg(const lcm::ReceiveBuffer*, const std::string&, const loopd::error_t* m,
                       EstimateSubscriber* self);
  void handleEstimate(const loopd::estimate_t& m);
  bool applySnapshotChunk(const loopd::estimate_t& m);
  /// The tables hold a robot, pose or landmark the server at status `s` no longer has.
  bool tablesExceed(const loopd::status_t& s) const;
  void forgetTables(std::int64_t updateSeq);

  lcm::LCM& lcm_;
  mutable std::mutex mu_;
  std::map<std::int32_t, RobotEstimate> robots_;
  struct Pending {
    std::int64_t updateSeq = -1, requestId = 0;
    std::int32_t received = 0, count = 0;
    RobotEstimate table;
  };
  std::map<std::int32_t, Pending> snapshots_;
  std::map<std::int32_t, std::pair<std::int64_t, std::vector<double>>> covariances_;
  loopd::status_t status_{};
  std::vector<loopd::error_t> errors_;
  std::int64_t estimates_ = 0, errorCount_ = 0, forgets_ = 0;
  std::int64_t newestTableSeq_ = 0;  // highest update_seq applied to a table
  std::int64_t forgottenBelow_ = 0;  // estimates older than this belong to a forgotten graph
  std::function<void(const RobotEstimate&, const loopd::estimate_t&)> onEstimate_;
  std::function<void(const loopd::covariance_t&)> onCovariance_;
  std::function<void(const loopd::status_t&)> onStatus_;
  std::function<void(const loopd::error_t&)> onError_;
  std::function<void(std::int64_t)> onForget_;
  std::vector<void*> subscriptions_;
};

}  // namespace loopd::client
