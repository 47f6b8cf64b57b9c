#pragma once
// loopd_client: publishing factors to a loopd server (lcmtypes/README.md is the contract).
// Typed calls queue items into the current factor_batch_t; flush() (or reaching MAX_ITEMS)
// publishes it with the sender's next sequence number. resendLast() republishes the last batch
// with the same number (the server applies it once).
#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "loopd/factor_batch_t.hpp"

namespace lcm {
class LCM;
}

namespace loopd::client {

/// A variable on the wire: (robot, pose/landmark, index).
struct KeyRef {
  std::int32_t robot = 0;
  bool landmark = false;
  std::int64_t index = 0;
  static KeyRef pose(std::int32_t robot, std::int64_t index) { return {robot, false, index}; }
  static KeyRef point(std::int32_t robot, std::int64_t index) { return {robot, true, index}; }
};

struct Pose2 {
  double x = 0, y = 0, theta = 0;
};
struct Pose3 {
  Eigen::Vector3d t = Eigen::Vector3d::Zero();
  Eigen::Quaterniond q = Eigen::Quaterniond::Identity();
};

/// Where encoded batches go: an LCM publish, a log file, a test's capture.
using BatchSink =
    std::function<void(const std::string& channel, const std::vector<std::uint8_t>& bytes)>;

class FactorPublisher {
 public:
  /// Publishes on `channel` through lcm. sender: stable name of this front-end.
  FactorPublisher(lcm::LCM& lcm, std::string sender, std::string channel = "LOOPD_FACTORS");
  FactorPublisher(BatchSink sink, std::string sender, std::string channel = "LOOPD_FACTORS");

  /// Factor ids are assigned 0, 1, 2, ... unless given (>= 0). Every call returns the id.
  std::int64_t odometry(std::int32_t robot, std::int64_t from, std::int64_t to, const Pose2& z,
                        const Eigen::Matrix3d& information, std::int64_t id = -1);
  std::int64_t odometry(std::int32_t robot, std::int64_t from, std::int64_t to, const Pose3& z,
                        const Eigen::Matrix<double, 6, 6>& information, std::int64_t id = -1);
  /// A loop closure (intra- or inter-robot): robust = "" (server default), "none", or a variant.
  std::int64_t loopClosure(KeyRef a, KeyRef b, const Pose2& z, const Eigen::Matrix3d& information,
                           const std::string& robust = "", double robustParam = 0.0,
                           std::int64_t id = -1);
  std::int64_t loopClosure(KeyRef a, KeyRef b, const Pose3& z,
                           const Eigen::Matrix<double, 6, 6>& information,
                           const std::string& robust = "", double robustParam = 0.0,
                           std::int64_t id = -1);
  /// Landmark position in the pose's body frame (2D or 3D).
  std::int64_t landmark(KeyRef pose, KeyRef point, const Eigen::Vector2d& z,
                        const Eigen::Matrix2d& information, std::int64_t id = -1);
  std::int64_t landmark(KeyRef pose, KeyRef point, const Eigen::Vector3d& z,
                        const Eigen::Matrix3d& information, std::int64_t id = -1);
  std::int64_t bearingRange(KeyRef pose, KeyRef point, double bearing, double range,
                            const Eigen::Matrix2d& information, std::int64_t id = -1);
  std::int64_t prior(KeyRef pose, const Pose2& z, const Eigen::Matrix3d& information,
                     std::int64_t id = -1);
  std::int64_t prior(KeyRef pose, const Pose3& z, const Eigen::Matrix<double, 6, 6>& information,
                     std::int64_t id = -1);
  /// k alternatives, at most one true (MULTI_MEASUREMENT: same keys, own measurements;
  /// MULTI_ASSOCIATION: same measurement and noise, own keys), built with loopClosureFactor /
  /// landmarkFactor / bearingRangeFactor; their ids are ignored. 2 <= k <= 16, or k >= 1 with
  /// a null hypothesis; nullWeight >= 0 (0 = the server's default, 1). Throws
  /// std::invalid_argument on anything the server would refuse without looking at its graph
  /// (except the factors' own numbers: NaN, non-positive-definite noise, ...).
  std::int64_t ambiguous(std::int8_t mode, const std::vector<loopd::factor_t>& alternatives,
                         bool nullHypothesis, double nullWeight = 0.0, std::int64_t id = -1);
  /// Any factor as built by hand; its id is assigned if negative.
  std::int64_t factor(loopd::factor_t f);
  void initialValue(KeyRef pose, const Pose2& x);
  void initialValue(KeyRef pose, const Pose3& x);
  void initialValue(KeyRef point, const Eigen::Vector2d& p);
  void initialValue(KeyRef point, const Eigen::Vector3d& p);
  /// Removes one of this sender's factors or ambiguous groups; one added in the pending batch
  /// is taken out of it instead.
  void remove(std::int64_t id);

  /// Publishes the pending batch (if any); returns its sequence, or 0 if nothing was pending.
  std::int64_t flush();
  /// Republishes the last published batch, same sequence. False if none yet.
  bool resendLast();

  int pendingItems() const { return items_; }
  std::int64_t lastSequence() const { return sequence_; }
  /// The next batch's sequence is `next` (restart after a server RESET: 1).
  void setNextSequence(std::int64_t next) { sequence_ = next - 1; }
  const std::string& sender() const { return sender_; }
  std::int64_t batchesPublished() const { return published_; }

 private:
  std::int64_t takeId(std::int64_t id);
  void added(int items);
  void addInitial(KeyRef k, std::int8_t type, std::vector<double> value);
  loopd::factor_t make(std::int8_t type, std::int8_t role, std::vector<KeyRef> keys,
                       std::vector<double> measurement, const double* info, int dim,
                       std::int64_t id, const std::string& robust = "", double robustParam = 0.0);

  BatchSink sink_;
  std::string sender_, channel_;
  loopd::factor_batch_t batch_{};
  std::vector<std::uint8_t> last_;
  std::int64_t sequence_ = 0, nextId_ = 0, published_ = 0;
  int items_ = 0;
};

/// Factors to pass to FactorPublisher::ambiguous (nothing is queued; id 0).
loopd::factor_t loopClosureFactor(KeyRef a, KeyRef b, const Pose2& z,
                                  const Eigen::Matrix3d& information);
loopd::factor_t loopClosureFactor(KeyRef a, KeyRef b, const Pose3& z,
                                  const Eigen::Matrix<double, 6, 6>& information);
loopd::factor_t landmarkFactor(KeyRef pose, KeyRef point, const Eigen::Vector2d& z,
                               const Eigen::Matrix2d& information);
loopd::factor_t landmarkFactor(KeyRef pose, KeyRef point, const Eigen::Vector3d& z,
                               const Eigen::Matrix3d& information);
loopd::factor_t bearingRangeFactor(KeyRef pose, KeyRef point, double bearing, double range,
                                   const Eigen::Matrix2d& information);

/// Encodes the upper triangle (row-major, g2o order) of a symmetric matrix.
std::vector<double> upperTriangle(const double* colMajor, int dim);
loopd::key_t wireKey(KeyRef k);
/// Same keys in the same order (what MULTI_MEASUREMENT alternatives share).
bool sameKeys(const loopd::factor_t& a, const loopd::factor_t& b);

}  // namespace loopd::client
