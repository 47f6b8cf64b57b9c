#pragma once
// Two robots walking in their own frames, for the engine's inter-robot closure tests: robot 0
// starts at the world's origin, robot 1 at T1; each walks poses 0..9 (odometry sent at
// construction) and robot 1 sends closures to robot 0's poses, true or wrong.
#include <cmath>
#include <string>
#include <vector>

#include "tests/server/engine_harness.h"

namespace loopd::test {

inline const Eigen::Matrix3d kInfo = Eigen::Vector3d(100, 100, 1000).asDiagonal();

inline client::Pose2 pose2(const SE2& x) { return {x.x, x.y, x.theta}; }

struct TwoWalkers {
  EngineHarness h;
  client::FactorPublisher r0, r1;
  SE2 T1{3, 4, 0.7};
  explicit TwoWalkers(const server::EngineOptions& o)
      : h(o, nullptr),
        r0([this](const std::string&, const std::vector<std::uint8_t>& b) { h.sendRaw(b); }, "r0",
           "T_FACTORS"),
        r1([this](const std::string&, const std::vector<std::uint8_t>& b) { h.sendRaw(b); }, "r1",
           "T_FACTORS") {
    for (int i = 0; i < 9; ++i) {
      r0.odometry(0, i, i + 1, pose2(robot0(i).between(robot0(i + 1))), kInfo);
      r0.flush();
      r1.odometry(1, i, i + 1, pose2(own1(i).between(own1(i + 1))), kInfo);
      r1.flush();
    }
  }
  explicit TwoWalkers(const std::string& solver) : TwoWalkers(EngineHarness::options(solver)) {}
  static SE2 robot0(int i) { return SE2(i * 1.0, 0.0, 0.05 * i); }
  static SE2 own1(int j) { return SE2(0.8 * j, 0.1 * j, -0.1 * j); }
  SE2 robot1(int j) const { return T1 * own1(j); }
  // Robot 0's pose i to robot 1's pose j as measured (or as `wrong` says), sent by robot 1.
  std::int64_t close(int i, int j, const std::string& robust = "") {
    const std::int64_t id = r1.loopClosure(client::KeyRef::pose(0, i), client::KeyRef::pose(1, j),
                                           pose2(robot0(i).between(robot1(j))), kInfo, robust);
    r1.flush();
    return id;
  }
  // The same as if robot 1's frame lay at `frame`: closures made so agree with each other, and
  // for frame ≠ T1 they are a group of mutually consistent wrong ones.
  std::int64_t closeAsIf(const SE2& frame, int i, int j) {
    const std::int64_t id = r1.loopClosure(client::KeyRef::pose(0, i), client::KeyRef::pose(1, j),
                                           pose2(robot0(i).between(frame * own1(j))), kInfo);
    r1.flush();
    return id;
  }
  std::int64_t closeWrongly(int i, int j) {
    const std::int64_t id = r1.loopClosure(client::KeyRef::pose(0, i), client::KeyRef::pose(1, j),
                                           {-2.0, 5.0, 2.5}, kInfo);
    r1.flush();
    return id;
  }
  int anchoredFactors() const {
    int n = 0;
    for (const auto& f : h.engine.backend().graph().factors()) n += f->size() == 4;
    return n;
  }
  bool joined() const { return h.engine.robotJoined(0) && h.engine.robotJoined(1); }
  // Robot 1's poses as published, against the world.
  void expectWorld(double tol) const {
    for (int j = 0; j <= 9; ++j) {
      std::vector<double> x;
      ASSERT_TRUE(h.engine.commonFramePose(poseKey(static_cast<std::uint64_t>(j), 1), x));
      const SE2 truth = robot1(j);
      EXPECT_NEAR(x[0], truth.x, tol) << j;
      EXPECT_NEAR(x[1], truth.y, tol) << j;
      EXPECT_NEAR(std::remainder(x[2] - truth.theta, 2 * M_PI), 0.0, tol) << j;
    }
  }
  std::string firstError() const { return h.out.errors.empty() ? "" : h.out.errors.front().reason; }
};

}  // namespace loopd::test
