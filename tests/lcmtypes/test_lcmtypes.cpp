// Tests of the loopd wire API (lcmtypes/*.lcm, generated at build time): round trips of every
// type with realistic content, distinct fingerprints, worst-case message sizes against the
// documented limits, clean failure on truncated or corrupted bytes, the generated Python
// agreeing with C++, and one real publish/subscribe through memq://.

#include <gtest/gtest.h>
#include <lcm/lcm-cpp.hpp>

#include <algorithm>
#include <climits>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <limits>
#include <random>
#include <set>
#include <stdexcept>
#include <string>
#include <tuple>
#include <vector>

#include <unistd.h>

#include "loopd/ambiguous_factor_t.hpp"
#include "loopd/command_t.hpp"
#include "loopd/covariance_t.hpp"
#include "loopd/error_t.hpp"
#include "loopd/estimate_t.hpp"
#include "loopd/factor_batch_t.hpp"
#include "loopd/factor_t.hpp"
#include "loopd/hypothesis_choice_t.hpp"
#include "loopd/hypothesis_t.hpp"
#include "loopd/initial_value_t.hpp"
#include "loopd/key_t.hpp"
#include "loopd/loop_decision_t.hpp"
#include "loopd/sender_gap_t.hpp"
#include "loopd/status_t.hpp"

namespace {

using Bytes = std::vector<uint8_t>;

// An LCM message travels in one UDP datagram (no LCM fragmentation) when
// channel + '\0' + payload <= 65499 bytes (LCM_SHORT_MESSAGE_MAX_SIZE on Linux, 1.3.1).
// Channels are at most 63 characters, so every payload must stay <= 65435 bytes.
constexpr int kOneDatagramPayload = 65499 - 64;
constexpr double kPi = 3.14159265358979323846;
constexpr int kHardLimit = 200 * 1024;  // udpm drops larger messages at the default rmem

// ---------------------------------------------------------------------------------------
// Encoding helpers

template <class T>
Bytes encode(const T& msg) {
  const int size = msg.getEncodedSize();
  EXPECT_GT(size, 0);
  Bytes buf(static_cast<size_t>(size));
  const int written = msg.encode(buf.data(), 0, size);
  EXPECT_EQ(written, size) << T::getTypeName();
  return buf;
}

template <class T>
T decode(const Bytes& buf) {
  T out;
  const int read = out.decode(buf.data(), 0, static_cast<int>(buf.size()));
  EXPECT_EQ(read, static_cast<int>(buf.size())) << T::getTypeName();
  return out;
}

template <class V>
int16_t n16(const V& v) {
  return static_cast<int16_t>(v.size());
}

// ---------------------------------------------------------------------------------------
// Realistic content builders (these also show how a client fills the types).

loopd::key_t key(int32_t robot, int8_t kind, int64_t index) {
  loopd::key_t k{};
  k.robot = robot;
  k.kind = kind;
  k.index = index;
  return k;
}
loopd::key_t pose(int32_t robot, int64_t index) { return key(robot, loopd::key_t::POSE, index); }
loopd::key_t landmark(int32_t robot, int64_t index) {
  return key(robot, loopd::key_t::LANDMARK, index);
}

// Unit quaternion (qx, qy, qz, qw) of a rotation by `angle` about the (normalised) axis.
std::vector<double> quat(double ax, double ay, double az, double angle) {
  const double n = std::sqrt(ax * ax + ay * ay + az * az);
  const double s = std::sin(angle / 2) / n;
  return {ax * s, ay * s, az * s, std::cos(angle / 2)};
}

// Upper triangle, row-major (g2o order), of an n x n symmetric positive definite matrix:
// the covariance with standard deviations `sigmas` and correlation `rho` between neighbouring
// entries, or (information) its diagonal inverse 1/sigma^2 with a weak, diagonally dominated
// coupling -rho/(10 sigma_r sigma_c) between neighbours.
std::vector<double> upper_triangle(const std::vector<double>& sigmas, double rho,
                                   bool information) {
  const size_t n = sigmas.size();
  std::vector<double> out;
  for (size_t r = 0; r < n; ++r) {
    for (size_t c = r; c < n; ++c) {
      const double s = sigmas[r] * sigmas[c];
      if (r == c)
        out.push_back(information ? 1.0 / s : s);
      else if (c == r + 1)
        out.push_back(information ? -rho / (10.0 * s) : rho * s);
      else
        out.push_back(0.0);
    }
  }
  EXPECT_EQ(out.size(), n * (n + 1) / 2);
  return out;
}

loopd::factor_t factor(int64_t id, int8_t type, int8_t role, std::vector<loopd::key_t> keys,
                       std::vector<double> measurement, std::vector<double> noise,
                       std::string robust = "", double robust_param = 0.0,
                       int8_t noise_kind = loopd::factor_t::NOISE_INFORMATION) {
  loopd::factor_t f{};
  f.id = id;
  f.type = type;
  f.role = role;
  f.keys = std::move(keys);
  f.num_keys = n16(f.keys);
  f.measurement = std::move(measurement);
  f.num_measurement = n16(f.measurement);
  f.noise_kind = noise_kind;
  f.noise = std::move(noise);
  f.num_noise = n16(f.noise);
  f.robust = std::move(robust);
  f.robust_param = robust_param;
  return f;
}

std::vector<double> se3(double x, double y, double z, const std::vector<double>& q) {
  return {x, y, z, q[0], q[1], q[2], q[3]};
}

const std::vector<double> kSe3Sigmas = {0.05, 0.05, 0.08, 0.01, 0.01, 0.02};
const std::vector<double> kSe2Sigmas = {0.1, 0.05, 0.02};

loopd::factor_t se3_loop_closure() {
  return factor(1042, loopd::factor_t::BETWEEN_SE3, loopd::factor_t::ROLE_LOOP_CLOSURE,
                {pose(0, 117), pose(1, 3)}, se3(0.42, -1.73, 0.05, quat(0.1, -0.2, 1.0, 0.31)),
                upper_triangle(kSe3Sigmas, 0.2, true), "dcs", 1.0);
}

loopd::initial_value_t initial(loopd::key_t k, int8_t type, std::vector<double> v) {
  loopd::initial_value_t iv{};
  iv.key = k;
  iv.type = type;
  iv.value = std::move(v);
  iv.num_value = n16(iv.value);
  return iv;
}

loopd::ambiguous_factor_t ambiguous_association() {
  // One bearing-range sighting that could be one of three landmarks, or none of them.
  loopd::ambiguous_factor_t a{};
  a.id = 5001;
  a.mode = loopd::ambiguous_factor_t::MULTI_ASSOCIATION;
  for (int64_t lm : {12, 13, 40}) {
    a.alternatives.push_back(factor(0, loopd::factor_t::BEARING_RANGE2,
                                    loopd::factor_t::ROLE_LANDMARK, {pose(2, 880), landmark(2, lm)},
                                    {0.3927, 14.2}, upper_triangle({0.01, 0.25}, 0.0, true), "mm"));
  }
  a.num_alternatives = n16(a.alternatives);
  a.null_hypothesis = true;
  a.null_weight = 0.5;
  return a;
}

// A 3D robot's batch: prior, odometry, a robust inter-robot loop closure, a landmark sighting,
// an ambiguous loop closure (two candidate measurements + null), initial values, removals.
loopd::factor_batch_t batch_3d() {
  loopd::factor_batch_t b{};
  b.utime = 1700000000123456;
  b.sender = "robot1/vio";
  b.sequence = 42;
  b.factors.push_back(factor(1, loopd::factor_t::PRIOR_SE3, loopd::factor_t::ROLE_PRIOR,
                             {pose(1, 0)}, se3(0, 0, 0, {0, 0, 0, 1}),
                             upper_triangle({1e-3, 1e-3, 1e-3, 1e-4, 1e-4, 1e-4}, 0.0, true)));
  b.factors.push_back(factor(2, loopd::factor_t::BETWEEN_SE3, loopd::factor_t::ROLE_ODOMETRY,
                             {pose(1, 0), pose(1, 1)}, se3(1.02, 0.01, -0.003, quat(0, 0, 1, 0.05)),
                             upper_triangle(kSe3Sigmas, 0.0, true), "none"));
  b.factors.push_back(se3_loop_closure());
  b.factors.push_back(factor(4, loopd::factor_t::POSE_POINT3, loopd::factor_t::ROLE_LANDMARK,
                             {pose(1, 1), landmark(1, 7)}, {3.5, -0.4, 1.25},
                             upper_triangle({0.2, 0.2, 0.3}, 0.1, false), "", 0.0,
                             loopd::factor_t::NOISE_COVARIANCE));
  b.num_factors = n16(b.factors);

  loopd::ambiguous_factor_t a{};
  a.id = 5;
  a.mode = loopd::ambiguous_factor_t::MULTI_MEASUREMENT;
  for (double yaw : {0.1, 3.0}) {
    a.alternatives.push_back(factor(0, loopd::factor_t::BETWEEN_SE3,
                                    loopd::factor_t::ROLE_LOOP_CLOSURE, {pose(1, 1), pose(0, 3)},
                                    se3(0.2, 0.1, 0.0, quat(0, 0, 1, yaw)),
                                    upper_triangle(kSe3Sigmas, 0.0, true)));
  }
  a.num_alternatives = n16(a.alternatives);
  a.null_hypothesis = true;
  a.null_weight = 0.0;
  b.ambiguous.push_back(a);
  b.num_ambiguous = n16(b.ambiguous);

  b.initial_values.push_back(
      initial(pose(1, 1), loopd::initial_value_t::SE3, se3(1.0, 0.0, 0.0, quat(0, 0, 1, 0.05))));
  b.initial_values.push_back(
      initial(landmark(1, 7), loopd::initial_value_t::POINT3, {4.5, -0.3, 1.2}));
  b.num_initial_values = n16(b.initial_values);
  b.remove_ids = {17, 23};
  b.num_remove_ids = n16(b.remove_ids);
  return b;
}

// A 2D robot's batch exercising the remaining factor types.
loopd::factor_batch_t batch_2d() {
  loopd::factor_batch_t b{};
  b.utime = 1700000000223456;
  b.sender = "robot2";
  b.sequence = 1;
  const auto info2 = upper_triangle(kSe2Sigmas, 0.0, true);
  b.factors.push_back(factor(1, loopd::factor_t::PRIOR_SE2, loopd::factor_t::ROLE_PRIOR,
                             {pose(2, 0)}, {0, 0, 0}, upper_triangle({1e-3, 1e-3, 1e-4}, 0, true)));
  b.factors.push_back(factor(2, loopd::factor_t::BETWEEN_SE2, loopd::factor_t::ROLE_ODOMETRY,
                             {pose(2, 0), pose(2, 1)}, {1.0, 0.0, -0.0175}, info2));
  b.factors.push_back(factor(3, loopd::factor_t::BETWEEN_SE2, loopd::factor_t::ROLE_LOOP_CLOSURE,
                             {pose(2, 1), pose(2, 0)}, {-0.98, 0.02, 0.0175}, info2, "sc", 1.0));
  b.factors.push_back(factor(4, loopd::factor_t::POSE_POINT2, loopd::factor_t::ROLE_LANDMARK,
                             {pose(2, 1), landmark(2, 12)}, {5.0, 1.5},
                             upper_triangle({0.1, 0.1}, 0, true)));
  b.factors.push_back(factor(5, loopd::factor_t::BEARING_RANGE2, loopd::factor_t::ROLE_LANDMARK,
                             {pose(2, 1), landmark(2, 13)}, {-0.7854, 8.1},
                             upper_triangle({0.01, 0.25}, 0, true), "huber", 1.345));
  b.factors.push_back(factor(6, loopd::factor_t::PRIOR_POINT2, loopd::factor_t::ROLE_PRIOR,
                             {landmark(2, 12)}, {6.0, 1.4}, upper_triangle({1.0, 1.0}, 0, false),
                             "", 0.0, loopd::factor_t::NOISE_COVARIANCE));
  b.factors.push_back(factor(7, loopd::factor_t::PRIOR_POINT3, loopd::factor_t::ROLE_PRIOR,
                             {landmark(2, 99)}, {1.0, 2.0, 3.0},
                             upper_triangle({1, 1, 1}, 0, true)));
  b.num_factors = n16(b.factors);
  b.ambiguous.push_back(ambiguous_association());
  b.num_ambiguous = n16(b.ambiguous);
  b.initial_values.push_back(initial(pose(2, 1), loopd::initial_value_t::SE2, {1.0, 0.0, -0.0175}));
  b.initial_values.push_back(initial(landmark(2, 12), loopd::initial_value_t::POINT2, {6.0, 1.5}));
  b.num_initial_values = n16(b.initial_values);
  b.num_remove_ids = 0;
  return b;
}

loopd::command_t covariance_request() {
  loopd::command_t c{};
  c.utime = 1700000001000000;
  c.sender = "planner";
  c.request_id = 77;
  c.command = loopd::command_t::REQUEST_COVARIANCE;
  c.argument = "joint";
  c.keys = {pose(0, 117), pose(1, 3), landmark(1, 7)};
  c.num_keys = n16(c.keys);
  return c;
}

loopd::estimate_t estimate_se3(int n_poses, int n_landmarks) {
  loopd::estimate_t e{};
  e.utime = 1700000002000000;
  e.update_seq = 314;
  e.request_id = 0;
  e.robot = 1;
  e.frame_robot = 0;
  e.common_frame = true;
  e.full_snapshot = false;
  e.hypothesis = 0;
  e.chunk_index = 0;
  e.chunk_count = 1;
  e.pose_type = loopd::estimate_t::SE3;
  e.pose_dim = 7;
  for (int i = 0; i < n_poses; ++i) {
    e.pose_indices.push_back(1000 + i);
    const double t = 0.1 * i;
    e.poses.push_back(se3(5 * std::cos(t), 5 * std::sin(t), 0.01 * i, quat(0, 0, 1, t + kPi / 2)));
  }
  e.num_poses = n16(e.pose_indices);
  e.landmark_dim = 3;
  for (int i = 0; i < n_landmarks; ++i) {
    e.landmark_indices.push_back(i * 3 + 1);
    e.landmarks.push_back({7.0 * std::cos(i), 7.0 * std::sin(i), 1.5});
  }
  e.num_landmarks = n16(e.landmark_indices);
  return e;
}

// Dense covariance over keys with the given tangent dims: joint (D x D) or diagonal blocks.
loopd::covariance_t covariance(const std::vector<std::pair<loopd::key_t, int8_t>>& keys,
                               bool joint) {
  loopd::covariance_t c{};
  c.utime = 1700000002000100;
  c.update_seq = 314;
  c.request_id = joint ? 77 : 0;
  c.chunk_index = 0;
  c.chunk_count = 1;
  c.joint = joint;
  int total = 0;
  for (const auto& [k, d] : keys) {
    c.keys.push_back(k);
    c.dims.push_back(d);
    total += d;
  }
  c.num_keys = n16(c.keys);
  auto cov = [](int r, int col) {
    return r == col ? 0.01 * (1 + r) : 0.001 / (1 + std::abs(r - col));
  };
  if (joint) {
    for (int r = 0; r < total; ++r)
      for (int col = 0; col < total; ++col) c.values.push_back(cov(r, col));
  } else {
    for (int8_t d : c.dims)
      for (int r = 0; r < d; ++r)
        for (int col = 0; col < d; ++col) c.values.push_back(cov(r, col));
  }
  c.num_values = n16(c.values);
  return c;
}

loopd::loop_decision_t decision(std::string sender, int64_t id, bool accepted, double weight) {
  loopd::loop_decision_t d{};
  d.sender = std::move(sender);
  d.factor_id = id;
  d.ambiguous = false;
  d.alternative = 0;
  d.accepted = accepted;
  d.weight = weight;
  return d;
}

loopd::hypothesis_choice_t choice(std::string sender, int64_t id, int32_t alternative) {
  loopd::hypothesis_choice_t c{};
  c.sender = std::move(sender);
  c.ambiguous_id = id;
  c.alternative = alternative;
  return c;
}

loopd::hypothesis_t hypothesis(int32_t rank, double score,
                               std::vector<loopd::hypothesis_choice_t> choices) {
  loopd::hypothesis_t h{};
  h.rank = rank;
  h.score = score;
  h.choices = std::move(choices);
  h.num_choices = n16(h.choices);
  return h;
}

loopd::sender_gap_t gap(std::string sender, int64_t last, int64_t highest, int64_t missing) {
  loopd::sender_gap_t g{};
  g.sender = std::move(sender);
  g.last_contiguous = last;
  g.highest = highest;
  g.missing = missing;
  return g;
}

loopd::status_t status() {
  loopd::status_t s{};
  s.utime = 1700000002000200;
  s.update_seq = 314;
  s.request_id = 0;
  s.solver = "mh";
  s.converged = false;
  s.robots = 3;
  s.robots_in_common_frame = 2;
  s.poses = 10000;
  s.landmarks = 40;
  s.factors = 10700;
  s.loop_closures = 688;
  s.loop_closures_rejected = 12;
  s.ambiguous = 3;
  s.last_update_ms = 2.7;
  s.mean_update_ms = 1.9;
  s.chi2 = 6112.4;
  s.queue_depth = 2;
  s.batches_accepted = 9998;
  s.batches_rejected = 3;
  s.batches_duplicate = 17;
  s.batches_held = 1;
  s.batches_expired = 0;
  s.sender_gaps = {gap("robot2", 40, 45, 2)};
  s.num_sender_gaps = n16(s.sender_gaps);
  s.decisions_full = false;
  s.decisions_chunk_index = 0;
  s.decisions_chunk_count = 1;
  s.decisions = {decision("robot1/vio", 1042, true, 0.93),
                 decision("robot1/vio", 1050, false, 0.0)};
  loopd::loop_decision_t amb = decision("robot2", 5001, true, 1.0);
  amb.ambiguous = true;
  amb.alternative = 2;
  s.decisions.push_back(amb);
  s.num_decisions = n16(s.decisions);
  s.live_hypotheses = 3;
  s.undecided_ambiguous = 2;
  s.hypotheses = {hypothesis(0, 6112.4, {choice("robot1/vio", 5, 0), choice("robot2", 5002, -1)}),
                  hypothesis(1, 6140.0, {choice("robot1/vio", 5, 1), choice("robot2", 5002, -1)}),
                  hypothesis(2, 6190.5, {choice("robot1/vio", 5, -1), choice("robot2", 5002, 0)})};
  s.num_hypotheses = n16(s.hypotheses);
  return s;
}

loopd::error_t error_msg() {
  loopd::error_t e{};
  e.utime = 1700000002000300;
  e.sender = "robot1/vio";
  e.sequence = 43;
  e.request_id = 0;
  e.factor_id = 1043;
  e.code = loopd::error_t::NOT_POSITIVE_DEFINITE;
  e.reason =
      "factor 1043 (BETWEEN_SE3): information matrix not positive definite "
      "(smallest eigenvalue -2.5e-03)";
  e.channel = "LOOPD_FACTORS";
  return e;
}

// One realistic sample per type, for the typed tests.
template <class T>
T sample();
template <>
loopd::key_t sample() {
  return pose(3, 1234567890123);
}
template <>
loopd::factor_t sample() {
  return se3_loop_closure();
}
template <>
loopd::ambiguous_factor_t sample() {
  return ambiguous_association();
}
template <>
loopd::initial_value_t sample() {
  return initial(pose(1, 118), loopd::initial_value_t::SE3,
                 se3(12.5, -3.25, 0.4, quat(1, 2, 3, 0.7)));
}
template <>
loopd::factor_batch_t sample() {
  return batch_3d();
}
template <>
loopd::command_t sample() {
  return covariance_request();
}
template <>
loopd::estimate_t sample() {
  return estimate_se3(60, 5);
}
template <>
loopd::covariance_t sample() {
  return covariance({{pose(0, 117), 6}, {pose(1, 3), 6}, {landmark(1, 7), 3}}, true);
}
template <>
loopd::loop_decision_t sample() {
  return decision("robot1/vio", 1042, true, 0.93);
}
template <>
loopd::hypothesis_choice_t sample() {
  return choice("robot1/vio", 5, 1);
}
template <>
loopd::hypothesis_t sample() {
  return hypothesis(0, 6112.4, {choice("robot1/vio", 5, 0), choice("robot2", 5002, -1)});
}
template <>
loopd::sender_gap_t sample() {
  return gap("robot2", 40, 45, 2);
}
template <>
loopd::status_t sample() {
  return status();
}
template <>
loopd::error_t sample() {
  return error_msg();
}

using AllTypes = ::testing::Types<loopd::key_t, loopd::factor_t, loopd::ambiguous_factor_t,
                                  loopd::initial_value_t, loopd::factor_batch_t, loopd::command_t,
                                  loopd::estimate_t, loopd::covariance_t, loopd::loop_decision_t,
                                  loopd::hypothesis_choice_t, loopd::hypothesis_t,
                                  loopd::sender_gap_t, loopd::status_t, loopd::error_t>;
using AllTypesTuple =
    std::tuple<loopd::key_t, loopd::factor_t, loopd::ambiguous_factor_t, loopd::initial_value_t,
               loopd::factor_batch_t, loopd::command_t, loopd::estimate_t, loopd::covariance_t,
               loopd::loop_decision_t, loopd::hypothesis_choice_t, loopd::hypothesis_t,
               loopd::sender_gap_t, loopd::status_t, loopd::error_t>;

struct TypeNames {
  template <class T>
  static std::string GetName(int) {
    return T::getTypeName();
  }
};

template <class T>
class EveryType : public ::testing::Test {};
TYPED_TEST_SUITE(EveryType, AllTypes, TypeNames);

// ---------------------------------------------------------------------------------------
// Round trips

TYPED_TEST(EveryType, RoundTripIsByteExact) {
  const TypeParam original = sample<TypeParam>();
  const Bytes bytes = encode(original);
  const TypeParam copy = decode<TypeParam>(bytes);
  EXPECT_EQ(encode(copy), bytes);
  // The first 8 bytes are the fingerprint, big-endian.
  uint64_t fp = 0;
  for (int i = 0; i < 8; ++i) fp = (fp << 8) | bytes[static_cast<size_t>(i)];
  EXPECT_EQ(static_cast<int64_t>(fp), TypeParam::getHash());
}

TYPED_TEST(EveryType, EveryTruncationFailsCleanly) {
  const Bytes bytes = encode(sample<TypeParam>());
  for (size_t len = 0; len < bytes.size(); ++len) {
    TypeParam out;
    int rc = 0;
    EXPECT_NO_THROW(rc = out.decode(bytes.data(), 0, static_cast<int>(len))) << "length " << len;
    EXPECT_LT(rc, 0) << TypeParam::getTypeName() << " decoded from " << len << " of "
                     << bytes.size() << " bytes";
  }
}

TEST(RoundTrip, FactorBatchFieldsSurvive) {
  const loopd::factor_batch_t b = decode<loopd::factor_batch_t>(encode(batch_3d()));
  EXPECT_EQ(b.sender, "robot1/vio");
  EXPECT_EQ(b.sequence, 42);
  ASSERT_EQ(b.num_factors, 4);
  ASSERT_EQ(b.factors.size(), 4u);
  const loopd::factor_t& lc = b.factors[2];
  EXPECT_EQ(lc.id, 1042);
  EXPECT_EQ(lc.type, loopd::factor_t::BETWEEN_SE3);
  EXPECT_EQ(lc.role, loopd::factor_t::ROLE_LOOP_CLOSURE);
  ASSERT_EQ(lc.num_keys, 2);
  EXPECT_EQ(lc.keys[0].robot, 0);
  EXPECT_EQ(lc.keys[0].kind, loopd::key_t::POSE);
  EXPECT_EQ(lc.keys[0].index, 117);
  EXPECT_EQ(lc.keys[1].robot, 1);
  ASSERT_EQ(lc.num_measurement, 7);
  const std::vector<double> q = quat(0.1, -0.2, 1.0, 0.31);
  EXPECT_EQ(lc.measurement[6], q[3]);  // qw last
  EXPECT_EQ(lc.num_noise, 21);
  EXPECT_EQ(lc.robust, "dcs");
  EXPECT_EQ(lc.robust_param, 1.0);
  EXPECT_EQ(b.factors[3].noise_kind, loopd::factor_t::NOISE_COVARIANCE);
  ASSERT_EQ(b.num_ambiguous, 1);
  EXPECT_EQ(b.ambiguous[0].mode, loopd::ambiguous_factor_t::MULTI_MEASUREMENT);
  EXPECT_EQ(b.ambiguous[0].num_alternatives, 2);
  EXPECT_TRUE(b.ambiguous[0].null_hypothesis);
  ASSERT_EQ(b.num_initial_values, 2);
  EXPECT_EQ(b.initial_values[1].key.kind, loopd::key_t::LANDMARK);
  EXPECT_EQ(b.initial_values[1].type, loopd::initial_value_t::POINT3);
  ASSERT_EQ(b.num_remove_ids, 2);
  EXPECT_EQ(b.remove_ids[1], 23);
}

TEST(RoundTrip, EveryFactorTypeWithItsDimensions) {
  // The table of lcmtypes/README.md: keys, measurement size and noise entries per type.
  struct Row {
    int8_t type;
    int keys;
    int measurement;
    int dim;
  };
  const std::vector<Row> table = {
      {loopd::factor_t::PRIOR_SE2, 1, 3, 3},      {loopd::factor_t::PRIOR_SE3, 1, 7, 6},
      {loopd::factor_t::PRIOR_POINT2, 1, 2, 2},   {loopd::factor_t::PRIOR_POINT3, 1, 3, 3},
      {loopd::factor_t::BETWEEN_SE2, 2, 3, 3},    {loopd::factor_t::BETWEEN_SE3, 2, 7, 6},
      {loopd::factor_t::POSE_POINT2, 2, 2, 2},    {loopd::factor_t::POSE_POINT3, 2, 3, 3},
      {loopd::factor_t::BEARING_RANGE2, 2, 2, 2},
  };
  std::set<int8_t> seen;
  for (const auto& batch : {batch_2d(), batch_3d()}) {
    const loopd::factor_batch_t b = decode<loopd::factor_batch_t>(encode(batch));
    std::vector<loopd::factor_t> all = b.factors;
    for (const auto& a : b.ambiguous)
      all.insert(all.end(), a.alternatives.begin(), a.alternatives.end());
    for (const auto& f : all) {
      const auto row =
          std::find_if(table.begin(), table.end(), [&](const Row& r) { return r.type == f.type; });
      ASSERT_NE(row, table.end()) << int{f.type};
      EXPECT_EQ(f.num_keys, row->keys);
      EXPECT_EQ(f.num_measurement, row->measurement);
      EXPECT_EQ(f.num_noise, row->dim * (row->dim + 1) / 2);
      seen.insert(f.type);
    }
  }
  EXPECT_EQ(seen.size(), table.size()) << "a factor type is not exercised";
}

TEST(RoundTrip, NonFiniteNumbersArriveIntactForTheServerToReject) {
  loopd::factor_t f = se3_loop_closure();
  f.measurement[0] = std::numeric_limits<double>::quiet_NaN();
  f.measurement[1] = std::numeric_limits<double>::infinity();
  f.noise[0] = -std::numeric_limits<double>::infinity();
  const loopd::factor_t g = decode<loopd::factor_t>(encode(f));
  EXPECT_TRUE(std::isnan(g.measurement[0]));
  EXPECT_TRUE(std::isinf(g.measurement[1]) && g.measurement[1] > 0);
  EXPECT_TRUE(std::isinf(g.noise[0]) && g.noise[0] < 0);
}

TEST(RoundTrip, EstimateAndCovarianceLayouts) {
  const loopd::estimate_t e = decode<loopd::estimate_t>(encode(estimate_se3(10, 3)));
  ASSERT_EQ(e.num_poses, 10);
  ASSERT_EQ(e.poses.size(), 10u);
  ASSERT_EQ(e.poses[4].size(), 7u);
  EXPECT_EQ(e.pose_indices[4], 1004);
  const auto q = quat(0, 0, 1, 0.4 + kPi / 2);
  EXPECT_EQ(e.poses[4][5], q[2]);
  EXPECT_EQ(e.poses[4][6], q[3]);
  ASSERT_EQ(e.num_landmarks, 3);
  EXPECT_EQ(e.landmarks[2].size(), 3u);

  const loopd::covariance_t joint =
      decode<loopd::covariance_t>(encode(covariance({{pose(0, 1), 6}, {pose(0, 2), 6}}, true)));
  EXPECT_EQ(joint.num_values, 144);
  const loopd::covariance_t blocks = decode<loopd::covariance_t>(
      encode(covariance({{pose(0, 1), 3}, {pose(1, 9), 3}, {landmark(0, 4), 2}}, false)));
  EXPECT_FALSE(blocks.joint);
  EXPECT_EQ(blocks.num_values, 9 + 9 + 4);
}

// ---------------------------------------------------------------------------------------
// Fingerprints

template <class... T>
std::vector<std::pair<std::string, int64_t>> all_hashes(std::tuple<T...>*) {
  return {{T::getTypeName(), T::getHash()}...};
}

TEST(Fingerprints, AllDistinct) {
  const auto hashes = all_hashes(static_cast<AllTypesTuple*>(nullptr));
  EXPECT_EQ(hashes.size(), 14u);
  std::set<int64_t> distinct;
  for (const auto& [name, h] : hashes) {
    EXPECT_TRUE(distinct.insert(h).second) << name << " shares its fingerprint";
  }
}

template <class A, class... T>
void expect_rejected_by_all_others(const Bytes& bytes, std::tuple<T...>*) {
  auto check = [&](auto tag) {
    using B = decltype(tag);
    if constexpr (!std::is_same_v<A, B>) {
      B out;
      int rc = 0;
      EXPECT_NO_THROW(rc = out.decode(bytes.data(), 0, static_cast<int>(bytes.size())));
      EXPECT_LT(rc, 0) << A::getTypeName() << " decoded as " << B::getTypeName();
    }
  };
  (check(T{}), ...);
}

TYPED_TEST(EveryType, OtherTypesRefuseItsBytes) {
  expect_rejected_by_all_others<TypeParam>(encode(sample<TypeParam>()),
                                           static_cast<AllTypesTuple*>(nullptr));
}

// ---------------------------------------------------------------------------------------
// Worst-case sizes: every message stays under one LCM datagram, far below 200 KB.

std::string chars(int n) { return std::string(static_cast<size_t>(n), 'w'); }

void expect_fits(int size, const char* what) {
  EXPECT_LE(size, kOneDatagramPayload) << what << " needs LCM fragmentation";
  EXPECT_LT(size, kHardLimit) << what;
  std::cout << "[ size     ] worst-case " << what << ": " << size << " bytes\n";
}

loopd::factor_t worst_factor() {
  loopd::factor_t f = se3_loop_closure();
  f.id = std::numeric_limits<int64_t>::max();
  f.robust = chars(loopd::factor_t::MAX_ROBUST_LENGTH);
  return f;
}

TEST(Limits, WorstCaseFactorBatch) {
  // Largest item: an SE(3) factor with the longest robust name, or the same as the single
  // alternative of an ambiguous measurement (group overhead on top). Try both extremes.
  loopd::factor_batch_t plain{};
  plain.utime = 1;
  plain.sender = chars(loopd::factor_batch_t::MAX_SENDER_LENGTH);
  plain.sequence = 1;
  plain.factors.assign(loopd::factor_batch_t::MAX_ITEMS, worst_factor());
  plain.num_factors = n16(plain.factors);
  expect_fits(plain.getEncodedSize(), "factor_batch_t (SE3 factors)");
  EXPECT_EQ(decode<loopd::factor_batch_t>(encode(plain)).num_factors,
            loopd::factor_batch_t::MAX_ITEMS);

  loopd::factor_batch_t amb = plain;
  amb.factors.clear();
  amb.num_factors = 0;
  loopd::ambiguous_factor_t group{};
  group.id = 1;
  group.mode = loopd::ambiguous_factor_t::MULTI_MEASUREMENT;
  group.alternatives = {worst_factor()};
  group.num_alternatives = 1;
  group.null_hypothesis = true;
  group.null_weight = 1.0;
  amb.ambiguous.assign(loopd::factor_batch_t::MAX_ITEMS, group);
  amb.num_ambiguous = n16(amb.ambiguous);
  expect_fits(amb.getEncodedSize(), "factor_batch_t (1-alternative ambiguous)");
  EXPECT_EQ(decode<loopd::factor_batch_t>(encode(amb)).num_ambiguous,
            loopd::factor_batch_t::MAX_ITEMS);

  // Any mix of items is bounded by the largest item, so these two bound every valid batch;
  // a full group of MAX_ALTERNATIVES counts as that many items.
  EXPECT_LE(group.num_alternatives, loopd::ambiguous_factor_t::MAX_ALTERNATIVES);
}

TEST(Limits, WorstCaseEstimateChunk) {
  // SE(3) poses (8 + 56 bytes) are the largest entries; landmarks are at most 8 + 24.
  loopd::estimate_t e = estimate_se3(loopd::estimate_t::MAX_CHUNK_ENTRIES, 0);
  e.update_seq = e.request_id = std::numeric_limits<int64_t>::max();
  expect_fits(e.getEncodedSize(), "estimate_t (1000 SE3 poses)");
  const loopd::estimate_t back = decode<loopd::estimate_t>(encode(e));
  EXPECT_EQ(back.num_poses, loopd::estimate_t::MAX_CHUNK_ENTRIES);

  loopd::estimate_t mixed = estimate_se3(loopd::estimate_t::MAX_CHUNK_ENTRIES / 2,
                                         loopd::estimate_t::MAX_CHUNK_ENTRIES / 2);
  EXPECT_LT(mixed.getEncodedSize(), e.getEncodedSize());
}

TEST(Limits, WorstCaseCovariance) {
  std::vector<std::pair<loopd::key_t, int8_t>> blocks;
  for (int i = 0; i < loopd::covariance_t::MAX_KEYS; ++i) blocks.push_back({pose(i, 1 << 30), 6});
  const loopd::covariance_t b = covariance(blocks, false);
  EXPECT_EQ(b.num_values, loopd::covariance_t::MAX_VALUES);
  expect_fits(b.getEncodedSize(), "covariance_t (144 SE3 marginals)");

  std::vector<std::pair<loopd::key_t, int8_t>> joint;
  for (int i = 0; i < loopd::covariance_t::MAX_JOINT_DIM / 6; ++i) joint.push_back({pose(0, i), 6});
  const loopd::covariance_t j = covariance(joint, true);
  EXPECT_EQ(j.num_values, loopd::covariance_t::MAX_VALUES);
  expect_fits(j.getEncodedSize(), "covariance_t (joint 72x72)");
}

TEST(Limits, WorstCaseStatus) {
  loopd::status_t s = status();
  const std::string sender = chars(loopd::factor_batch_t::MAX_SENDER_LENGTH);
  s.solver = chars(32);
  s.sender_gaps.assign(loopd::status_t::MAX_SENDER_GAPS, gap(sender, 1, 2, 1));
  s.num_sender_gaps = n16(s.sender_gaps);
  s.decisions.assign(loopd::status_t::MAX_DECISIONS, decision(sender, 1, true, 0.5));
  s.num_decisions = n16(s.decisions);
  s.hypotheses.assign(loopd::status_t::MAX_HYPOTHESES,
                      hypothesis(0, 1.0,
                                 std::vector<loopd::hypothesis_choice_t>(
                                     loopd::hypothesis_t::MAX_CHOICES, choice(sender, 1, 0))));
  s.num_hypotheses = n16(s.hypotheses);
  expect_fits(s.getEncodedSize(), "status_t");
}

TEST(Limits, WorstCaseCommandAndError) {
  loopd::command_t c = covariance_request();
  c.sender = chars(loopd::factor_batch_t::MAX_SENDER_LENGTH);
  c.argument = chars(loopd::command_t::MAX_ARGUMENT_LENGTH);
  c.keys.assign(loopd::command_t::MAX_KEYS, pose(1, 1));
  c.num_keys = n16(c.keys);
  expect_fits(c.getEncodedSize(), "command_t");

  loopd::error_t e = error_msg();
  e.sender = chars(loopd::factor_batch_t::MAX_SENDER_LENGTH);
  e.reason = chars(loopd::error_t::MAX_REASON_LENGTH);
  e.channel = chars(63);
  expect_fits(e.getEncodedSize(), "error_t");
}

// ---------------------------------------------------------------------------------------
// Untrusted bytes. All counts are int16, so no decode can allocate more than a few MB. The
// headers are hardened at generation (lcmtypes/CMakeLists.txt): lcm-gen 1.3.1 alone reads 2 GB
// past the buffer for a string length of INT32_MIN and throws std::length_error for negative
// counts or string lengths <= 0. Hardened, every such input makes decode() return -1.

template <class T>
int try_decode(const Bytes& bytes, bool* threw) {
  T out;
  *threw = false;
  try {
    return out.decode(bytes.data(), 0, static_cast<int>(bytes.size()));
  } catch (const std::exception&) {
    *threw = true;
    return -1;
  }
}

void put_be(Bytes& b, size_t at, uint32_t v, int bytes) {
  for (int i = 0; i < bytes; ++i) {
    b[at + static_cast<size_t>(i)] = static_cast<uint8_t>(v >> (8 * (bytes - 1 - i)));
  }
}

TEST(UntrustedBytes, CorruptedCountsAndLengthsFailCleanly) {
  const loopd::factor_batch_t batch = batch_3d();
  const Bytes good = encode(batch);
  // Layout: fingerprint 8, utime 8, sender (int32 length incl. NUL, bytes, NUL), sequence 8,
  // then num_factors (int16) and the first factor_t: id 8, type 1, role 1, num_keys (int16).
  const size_t sender_len_at = 16;
  const size_t num_factors_at = 16 + 4 + batch.sender.size() + 1 + 8;
  const size_t num_keys_at = num_factors_at + 2 + 8 + 1 + 1;
  ASSERT_EQ((good[num_factors_at] << 8) | good[num_factors_at + 1], batch.num_factors);
  ASSERT_EQ((good[num_keys_at] << 8) | good[num_keys_at + 1], batch.factors[0].num_keys);
  for (size_t at : {num_factors_at, num_keys_at}) {
    for (int bad : {-1, -32768, 32767, 1000}) {
      Bytes b = good;
      put_be(b, at, static_cast<uint32_t>(bad), 2);
      bool threw = false;
      EXPECT_LT(try_decode<loopd::factor_batch_t>(b, &threw), 0) << "count " << bad << " at " << at;
      EXPECT_FALSE(threw) << "count " << bad << " at " << at;
    }
  }
  for (int64_t bad : {int64_t{0}, int64_t{-7}, int64_t{INT32_MIN}, int64_t{1} << 30}) {
    Bytes b = good;
    put_be(b, sender_len_at, static_cast<uint32_t>(bad), 4);
    bool threw = false;
    EXPECT_LT(try_decode<loopd::factor_batch_t>(b, &threw), 0) << "sender length " << bad;
    EXPECT_FALSE(threw) << "sender length " << bad;
  }
}

// Random byte mutations (fingerprint kept, so the body is parsed) and truncations of a sample
// of every type: decode returns the full length or < 0, never throws, never reads out of
// bounds (run under LOOPD_SANITIZE to check the last part).
TYPED_TEST(EveryType, RandomMutationsFailCleanly) {
  const Bytes good = encode(sample<TypeParam>());
  if (good.size() <= 8) GTEST_SKIP();
  std::mt19937 rng(1234);
  std::uniform_int_distribution<size_t> pos(8, good.size() - 1);
  std::uniform_int_distribution<int> byte(0, 255), flips(1, 8), special(0, 5);
  const uint32_t nasty[] = {0x80000000u, 0xffffffffu, 0u, 0x7fffffffu, 0x8000u, 0xffffu};
  int decoded = 0, failed = 0, threw = 0;
  for (int trial = 0; trial < 5000; ++trial) {
    Bytes b = good;
    for (int k = flips(rng); k > 0; --k) b[pos(rng)] = static_cast<uint8_t>(byte(rng));
    if (trial % 4 == 1 && b.size() > 12)
      put_be(b, std::min(pos(rng), b.size() - 4), nasty[special(rng)], 4);
    if (trial % 3 == 0) b.resize(pos(rng));
    bool t = false;
    const int rc = try_decode<TypeParam>(b, &t);
    if (t)
      ++threw;
    else if (rc < 0)
      ++failed;
    else {
      ++decoded;
      EXPECT_LE(rc, static_cast<int>(b.size()));
    }
  }
  EXPECT_EQ(threw, 0) << TypeParam::getTypeName();
  EXPECT_EQ(decoded + failed + threw, 5000);
}

// ---------------------------------------------------------------------------------------
// The generated Python agrees with C++ byte for byte (fingerprints included).

template <class... T>
void write_samples(const std::filesystem::path& dir, std::tuple<T...>*) {
  auto write = [&](auto tag) {
    using M = decltype(tag);
    const Bytes bytes = encode(sample<M>());
    std::ofstream out(dir / (std::string(M::getTypeName()) + ".bin"), std::ios::binary);
    out.write(reinterpret_cast<const char*>(bytes.data()),
              static_cast<std::streamsize>(bytes.size()));
  };
  (write(T{}), ...);
}

TEST(Python, DecodesAndReencodesEverySampleIdentically) {
  const std::string python = LOOPD_PYTHON3;
  if (python.empty()) GTEST_SKIP() << "python3 not found";
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / ("loopd_lcmtypes_py_" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  write_samples(dir, static_cast<AllTypesTuple*>(nullptr));
  {
    std::ofstream script(dir / "check.py");
    script << "import os, sys\n"
              "sys.path.insert(0, sys.argv[1])\n"
              "import loopd\n"
              "d, n, bad = sys.argv[2], 0, 0\n"
              "for name in sorted(os.listdir(d)):\n"
              "    if not name.endswith('.bin'):\n"
              "        continue\n"
              "    data = open(os.path.join(d, name), 'rb').read()\n"
              "    cls = getattr(loopd, name[:-4])\n"
              "    msg = cls.decode(data)\n"
              "    n += 1\n"
              "    if msg.encode() != data:\n"
              "        print('python re-encoding differs:', name)\n"
              "        bad += 1\n"
              "print('python checked', n, 'types')\n"
              "sys.exit(1 if bad or n != 14 else 0)\n";
  }
  const std::string cmd = "'" + python + "' '" + (dir / "check.py").string() + "' '" +
                          LOOPD_LCMTYPES_PYTHON_DIR + "' '" + dir.string() + "'";
  const int rc = std::system(cmd.c_str());
  std::filesystem::remove_all(dir);
  EXPECT_EQ(rc, 0) << cmd;
}

// ---------------------------------------------------------------------------------------
// A real publish/subscribe through LCM's in-process provider.

// Handlers are plain functions (subscribeFunction): LCM 1.3.1's member-function subscribe
// trips a GCC UBSan vptr false positive inside lcm-cpp-impl.hpp under LOOPD_SANITIZE.
struct Received {
  std::vector<loopd::factor_batch_t> batches;
  std::vector<loopd::estimate_t> estimates;
  std::vector<std::pair<std::string, Bytes>> raw;
};

void on_batch(const lcm::ReceiveBuffer*, const std::string&, const loopd::factor_batch_t* msg,
              Received* rx) {
  rx->batches.push_back(*msg);
}
void on_estimate(const lcm::ReceiveBuffer*, const std::string&, const loopd::estimate_t* msg,
                 Received* rx) {
  rx->estimates.push_back(*msg);
}
void on_raw(const lcm::ReceiveBuffer* rbuf, const std::string& channel, Received* rx) {
  const auto* p = static_cast<const uint8_t*>(rbuf->data);
  rx->raw.emplace_back(channel, Bytes(p, p + rbuf->data_size));
}

TEST(Lcm, PublishSubscribeOverMemq) {
  lcm::LCM lc("memq://");
  ASSERT_TRUE(lc.good());
  Received rx;
  lcm::Subscription* s1 = lc.subscribeFunction("LOOPD_FACTORS", &on_batch, &rx);
  lcm::Subscription* s2 = lc.subscribeFunction("LOOPD_ESTIMATE", &on_estimate, &rx);
  lcm::Subscription* s3 = lc.subscribeFunction("LOOPD_.*", &on_raw, &rx);
  ASSERT_NE(s1, nullptr);
  ASSERT_NE(s2, nullptr);
  ASSERT_NE(s3, nullptr);
  s1->setQueueCapacity(0);
  s2->setQueueCapacity(0);
  s3->setQueueCapacity(0);

  const loopd::factor_batch_t batch = batch_2d();
  const loopd::estimate_t est = estimate_se3(loopd::estimate_t::MAX_CHUNK_ENTRIES, 0);
  ASSERT_EQ(lc.publish("LOOPD_FACTORS", &batch), 0);
  ASSERT_EQ(lc.publish("LOOPD_ESTIMATE", &est), 0);
  // A batch on the estimate channel: the typed subscriber must skip it (wrong fingerprint).
  ASSERT_EQ(lc.publish("LOOPD_ESTIMATE", &batch), 0);

  for (int i = 0; i < 50 && rx.raw.size() < 3; ++i) ASSERT_GE(lc.handleTimeout(100), 0);
  ASSERT_EQ(rx.raw.size(), 3u);
  ASSERT_EQ(rx.batches.size(), 1u);
  EXPECT_EQ(encode(rx.batches[0]), encode(batch));
  ASSERT_EQ(rx.estimates.size(), 1u);
  EXPECT_EQ(rx.estimates[0].num_poses, loopd::estimate_t::MAX_CHUNK_ENTRIES);
  EXPECT_EQ(encode(rx.estimates[0]), encode(est));
  // The raw subscriber sees the misdirected batch and can name it by its fingerprint.
  EXPECT_EQ(rx.raw[2].first, "LOOPD_ESTIMATE");
  loopd::factor_batch_t misdirected{};
  EXPECT_GT(
      misdirected.decode(rx.raw[2].second.data(), 0, static_cast<int>(rx.raw[2].second.size())), 0);

  lc.unsubscribe(s1);
  lc.unsubscribe(s2);
  lc.unsubscribe(s3);
}

}  // namespace
