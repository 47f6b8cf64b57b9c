#include "client/factor_publisher.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <lcm/lcm-cpp.hpp>
#include <stdexcept>

namespace loopd::client {

using F = loopd::factor_t;

std::vector<double> upperTriangle(const double* m, int d) {
  std::vector<double> out;
  for (int i = 0; i < d; ++i)
    for (int j = i; j < d; ++j) out.push_back(m[j * d + i]);
  return out;
}

loopd::key_t wireKey(KeyRef k) {
  loopd::key_t w{};
  w.robot = k.robot;
  w.kind = k.landmark ? loopd::key_t::LANDMARK : loopd::key_t::POSE;
  w.index = k.index;
  return w;
}

namespace {
std::vector<double> pose3(const Pose3& z) {
  const Eigen::Quaterniond q = z.q.normalized();
  return {z.t.x(), z.t.y(), z.t.z(), q.x(), q.y(), q.z(), q.w()};
}
}  // namespace

FactorPublisher::FactorPublisher(lcm::LCM& lcm, std::string sender, std::string channel)
    : FactorPublisher(
          [&lcm](const std::string& ch, const std::vector<std::uint8_t>& b) {
            lcm.publish(ch, b.data(), static_cast<unsigned>(b.size()));
          },
          std::move(sender), std::move(channel)) {}

FactorPublisher::FactorPublisher(BatchSink sink, std::string sender, std::string channel)
    : sink_(std::move(sink)), sender_(std::move(sender)), channel_(std::move(channel)) {
  if (sender_.empty() || sender_.size() > 63)
    throw std::invalid_argument("sender must have 1..63 characters");
}

std::int64_t FactorPublisher::takeId(std::int64_t id) {
  if (id < 0) id = nextId_;
  nextId_ = std::max(nextId_, id + 1);
  return id;
}

void FactorPublisher::added(int items) {
  items_ += items;
  if (items_ >= loopd::factor_batch_t::MAX_ITEMS) flush();
}

namespace {
// A factor_t with id 0 and no robust kernel (the alternatives of ambiguous measurements).
loopd::factor_t plain(std::int8_t type, std::int8_t role, std::vector<KeyRef> keys,
                      std::vector<double> measurement, const double* info, int dim) {
  loopd::factor_t f{};
  f.id = 0;
  f.type = type;
  f.role = role;
  for (const auto& k : keys) f.keys.push_back(wireKey(k));
  f.num_keys = static_cast<std::int16_t>(f.keys.size());
  f.measurement = std::move(measurement);
  f.num_measurement = static_cast<std::int16_t>(f.measurement.size());
  f.noise_kind = F::NOISE_INFORMATION;
  f.noise = upperTriangle(info, dim);
  f.num_noise = static_cast<std::int16_t>(f.noise.size());
  f.robust = "";
  f.robust_param = 0.0;
  return f;
}
}  // namespace

loopd::factor_t FactorPublisher::make(std::int8_t type, std::int8_t role, std::vector<KeyRef> keys,
                                      std::vector<double> measurement, const double* info, int dim,
                                      std::int64_t id, const std::string& robust,
                                      double robustParam) {
  loopd::factor_t f = plain(type, role, std::move(keys), std::move(measurement), info, dim);
  f.id = id;
  f.robust = robust;
  f.robust_param = robustParam;
  return f;
}

std::int64_t FactorPublisher::factor(loopd::factor_t f) {
  // Room for it (a full batch is flushed first).
  if (items_ + 1 > loopd::factor_batch_t::MAX_ITEMS) flush();
  f.id = takeId(f.id);
  batch_.factors.push_back(f);
  added(1);
  return f.id;
}

std::int64_t FactorPublisher::odometry(std::int32_t robot, std::int64_t from, std::int64_t to,
                                       const Pose2& z, const Eigen::Matrix3d& info,
                                       std::int64_t id) {
  return factor(make(F::BETWEEN_SE2, F::ROLE_ODOMETRY,
                     {KeyRef::pose(robot, from), KeyRef::pose(robot, to)}, {z.x, z.y, z.theta},
                     info.data(), 3, id));
}
std::int64_t FactorPublisher::odometry(std::int32_t robot, std::int64_t from, std::int64_t to,
                                       const Pose3& z, const Eigen::Matrix<double, 6, 6>& info,
                                       std::int64_t id) {
  return factor(make(F::BETWEEN_SE3, F::ROLE_ODOMETRY,
                     {KeyRef::pose(robot, from), KeyRef::pose(robot, to)}, pose3(z), info.data(), 6,
                     id));
}
std::int64_t FactorPublisher::loopClosure(KeyRef a, KeyRef b, const Pose2& z,
                                          const Eigen::Matrix3d& info, const std::string& robust,
                                          double param, std::int64_t id) {
  return factor(make(F::BETWEEN_SE2, F::ROLE_LOOP_CLOSURE, {a, b}, {z.x, z.y, z.theta}, info.data(),
                     3, id, robust, param));
}
std::int64_t FactorPublisher::loopClosure(KeyRef a, KeyRef b, const Pose3& z,
                                          const Eigen::Matrix<double, 6, 6>& info,
                                          const std::string& robust, double param,
                                          std::int64_t id) {
  return factor(make(F::BETWEEN_SE3, F::ROLE_LOOP_CLOSURE, {a, b}, pose3(z), info.data(), 6, id,
                     robust, param));
}
std::int64_t FactorPublisher::landmark(KeyRef pose, KeyRef point, const Eigen::Vector2d& z,
                                       const Eigen::Matrix2d& info, std::int64_t id) {
  return factor(
      make(F::POSE_POINT2, F::ROLE_LANDMARK, {pose, point}, {z.x(), z.y()}, info.data(), 2, id));
}
std::int64_t FactorPublisher::landmark(KeyRef pose, KeyRef point, const Eigen::Vector3d& z,
                                       const Eigen::Matrix3d& info, std::int64_t id) {
  return factor(make(F::POSE_POINT3, F::ROLE_LANDMARK, {pose, point}, {z.x(), z.y(), z.z()},
                     info.data(), 3, id));
}
std::int64_t FactorPublisher::bearingRange(KeyRef pose, KeyRef point, double bearing, double range,
                                           const Eigen::Matrix2d& info, std::int64_t id) {
  return factor(make(F::BEARING_RANGE2, F::ROLE_LANDMARK, {pose, point}, {bearing, range},
                     info.data(), 2, id));
}
std::int64_t FactorPublisher::prior(KeyRef pose, const Pose2& z, const Eigen::Matrix3d& info,
                                    std::int64_t id) {
  return factor(make(F::PRIOR_SE2, F::ROLE_PRIOR, {pose}, {z.x, z.y, z.theta}, info.data(), 3, id));
}
std::int64_t FactorPublisher::prior(KeyRef pose, const Pose3& z,
                                    const Eigen::Matrix<double, 6, 6>& info, std::int64_t id) {
  return factor(make(F::PRIOR_SE3, F::ROLE_PRIOR, {pose}, pose3(z), info.data(), 6, id));
}

bool sameKeys(const loopd::factor_t& a, const loopd::factor_t& b) {
  if (a.keys.size() != b.keys.size()) return false;
  for (size_t i = 0; i < a.keys.size(); ++i)
    if (a.keys[i].robot != b.keys[i].robot || a.keys[i].kind != b.keys[i].kind ||
        a.keys[i].index != b.keys[i].index)
      return false;
  return true;
}

namespace {

// The server's rules for an ambiguous group that need no graph (lcmtypes/README.md).
void checkAmbiguous(std::int8_t mode, const std::vector<loopd::factor_t>& alts, bool null,
                    double nullWeight) {
  using A = loopd::ambiguous_factor_t;
  auto fail = [](const std::string& why) { throw std::invalid_argument("ambiguous: " + why); };
  if (mode != A::MULTI_MEASUREMENT && mode != A::MULTI_ASSOCIATION) fail("unknown mode");
  const size_t k = alts.size();
  if (k > static_cast<size_t>(A::MAX_ALTERNATIVES)) fail("more than 16 alternatives");
  if (k < (null ? 1u : 2u)) fail("needs 2 alternatives, or 1 with a null hypothesis");
  if (!std::isfinite(nullWeight) || nullWeight < 0.0) fail("null weight must be finite and >= 0");
  for (size_t i = 0; i < k; ++i) {
    const auto& f = alts[i];
    if (f.role != F::ROLE_LOOP_CLOSURE && f.role != F::ROLE_LANDMARK)
      fail("alternatives must be loop closures or landmark sightings");
    if (f.type != alts[0].type || f.role != alts[0].role)
      fail("all alternatives must have one type and role");
    if (i == 0) continue;
    if (mode == A::MULTI_MEASUREMENT && !sameKeys(f, alts[0]))
      fail("MULTI_MEASUREMENT alternatives must have the same keys");
    if (mode == A::MULTI_ASSOCIATION) {
      if (f.measurement != alts[0].measurement || f.noise_kind != alts[0].noise_kind ||
          f.noise != alts[0].noise)
        fail("MULTI_ASSOCIATION alternatives must have the same measurement and noise");
      for (size_t j = 0; j < i; ++j)
        if (sameKeys(f, alts[j])) fail("MULTI_ASSOCIATION alternatives must differ in their keys");
    }
  }
}
}  // namespace

loopd::factor_t loopClosureFactor(KeyRef a, KeyRef b, const Pose2& z, const Eigen::Matrix3d& info) {
  return plain(F::BETWEEN_SE2, F::ROLE_LOOP_CLOSURE, {a, b}, {z.x, z.y, z.theta}, info.data(), 3);
}
loopd::factor_t loopClosureFactor(KeyRef a, KeyRef b, const Pose3& z,
                                  const Eigen::Matrix<double, 6, 6>& info) {
  return plain(F::BETWEEN_SE3, F::ROLE_LOOP_CLOSURE, {a, b}, pose3(z), info.data(), 6);
}
loopd::factor_t landmarkFactor(KeyRef pose, KeyRef point, const Eigen::Vector2d& z,
                               const Eigen::Matrix2d& info) {
  return plain(F::POSE_POINT2, F::ROLE_LANDMARK, {pose, point}, {z.x(), z.y()}, info.data(), 2);
}
loopd::factor_t landmarkFactor(KeyRef pose, KeyRef point, const Eigen::Vector3d& z,
                               const Eigen::Matrix3d& info) {
  return plain(F::POSE_POINT3, F::ROLE_LANDMARK, {pose, point}, {z.x(), z.y(), z.z()}, info.data(),
               3);
}
loopd::factor_t bearingRangeFactor(KeyRef pose, KeyRef point, double bearing, double range,
                                   const Eigen::Matrix2d& info) {
  return plain(F::BEARING_RANGE2, F::ROLE_LANDMARK, {pose, point}, {bearing, range}, info.data(),
               2);
}

std::int64_t FactorPublisher::ambiguous(std::int8_t mode,
                                        const std::vector<loopd::factor_t>& alternatives,
                                        bool nullHypothesis, double nullWeight, std::int64_t id) {
  checkAmbiguous(mode, alternatives, nullHypothesis, nullWeight);
  const int n = static_cast<int>(alternatives.size());
  if (items_ + n > loopd::factor_batch_t::MAX_ITEMS) flush();
  loopd::ambiguous_factor_t a{};
  a.id = takeId(id);
  a.mode = mode;
  a.alternatives = alternatives;
  for (auto& f : a.alternatives) f.id = 0;
  a.num_alternatives = static_cast<std::int16_t>(n);
  a.null_hypothesis = nullHypothesis;
  a.null_weight = nullWeight;
  batch_.ambiguous.push_back(a);
  added(n);
  return a.id;
}

void FactorPublisher::initialValue(KeyRef k, const Pose2& x) {
  addInitial(k, loopd::initial_value_t::SE2, {x.x, x.y, x.theta});
}
void FactorPublisher::initialValue(KeyRef k, const Pose3& x) {
  addInitial(k, loopd::initial_value_t::SE3, pose3(x));
}
void FactorPublisher::initialValue(KeyRef k, const Eigen::Vector2d& p) {
  addInitial(k, loopd::initial_value_t::POINT2, {p.x(), p.y()});
}
void FactorPublisher::initialValue(KeyRef k, const Eigen::Vector3d& p) {
  addInitial(k, loopd::initial_value_t::POINT3, {p.x(), p.y(), p.z()});
}

void FactorPublisher::addInitial(KeyRef k, std::int8_t type, std::vector<double> value) {
  loopd::initial_value_t v{};
  v.key = wireKey(k);
  v.type = type;
  v.value = std::move(value);
  v.num_value = static_cast<std::int16_t>(v.value.size());
  batch_.initial_values.push_back(v);
  added(1);
}

void FactorPublisher::remove(std::int64_t id) {
  // Added in the batch still pending: it is taken out of it instead (the server refuses a
  // batch that removes what it adds: the id is not known to it yet).
  auto& fs = batch_.factors;
  auto& gs = batch_.ambiguous;
  const auto f = std::find_if(fs.begin(), fs.end(), [&](const auto& x) { return x.id == id; });
  const auto g = std::find_if(gs.begin(), gs.end(), [&](const auto& x) { return x.id == id; });
  if (f != fs.end() || g != gs.end()) {
    if (f != fs.end()) fs.erase(f);
    if (g != gs.end()) gs.erase(g);
    --items_;
    return;
  }
  batch_.remove_ids.push_back(id);
  added(1);
}

std::int64_t FactorPublisher::flush() {
  if (items_ == 0) return 0;
  batch_.utime = std::chrono::duration_cast<std::chrono::microseconds>(
                     std::chrono::system_clock::now().time_since_epoch())
                     .count();
  batch_.sender = sender_;
  batch_.sequence = ++sequence_;
  batch_.num_factors = static_cast<std::int16_t>(batch_.factors.size());
  batch_.num_ambiguous = static_cast<std::int16_t>(batch_.ambiguous.size());
  batch_.num_initial_values = static_cast<std::int16_t>(batch_.initial_values.size());
  batch_.num_remove_ids = static_cast<std::int16_t>(batch_.remove_ids.size());
  last_.resize(static_cast<size_t>(batch_.getEncodedSize()));
  batch_.encode(last_.data(), 0, static_cast<int>(last_.size()));
  sink_(channel_, last_);
  ++published_;
  batch_ = loopd::factor_batch_t{};
  items_ = 0;
  return sequence_;
}

bool FactorPublisher::resendLast() {
  if (last_.empty()) return false;
  sink_(channel_, last_);
  return true;
}

}  // namespace loopd::client
