// Inter-robot loop closures under a solver that judges loop closures (server/engine_closures.cpp):
// kept back until enough of a pair's agree on the transform between the robots' frames. Before,
// the first one joined the frames, right or wrong.
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "loopd/ambiguous_factor_t.hpp"
#include "tests/server/engine_harness.h"

namespace loopd {
namespace {

using client::FactorPublisher;
using client::KeyRef;
using test::EngineHarness;

const Eigen::Matrix3d kInfo = Eigen::Vector3d(100, 100, 1000).asDiagonal();

client::Pose2 pose2(const SE2& x) { return {x.x, x.y, x.theta}; }

// Robot 0 starts at the world's origin, robot 1 at T1; each walks poses 0..9 in its own frame.
struct TwoWalkers {
  EngineHarness h;
  FactorPublisher r0, r1;
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
    const std::int64_t id = r1.loopClosure(KeyRef::pose(0, i), KeyRef::pose(1, j),
                                           pose2(robot0(i).between(robot1(j))), kInfo, robust);
    r1.flush();
    return id;
  }
  std::int64_t closeWrongly(int i, int j) {
    const std::int64_t id =
        r1.loopClosure(KeyRef::pose(0, i), KeyRef::pose(1, j), {-2.0, 5.0, 2.5}, kInfo);
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

TEST(EngineClosures, TheFirstClosureWaitsAndASecondThatAgreesJoinsTheFrames) {
  for (const char* solver : {"risam", "mm", "gnc-tls"}) {
    SCOPED_TRACE(solver);
    TwoWalkers t(solver);
    t.close(2, 1);
    EXPECT_TRUE(t.h.out.errors.empty()) << t.firstError();
    EXPECT_FALSE(t.h.engine.robotJoined(1));
    EXPECT_EQ(t.anchoredFactors(), 0);
    t.close(3, 2);
    EXPECT_TRUE(t.joined());
    EXPECT_EQ(t.anchoredFactors(), 2);
    EXPECT_LT(t.h.engine.backend().chi2(), 1e-9);
    t.expectWorld(1e-6);
    t.close(5, 6);  // later ones go straight in
    EXPECT_EQ(t.anchoredFactors(), 3);
  }
}

TEST(EngineClosures, AWrongFirstClosureNoLongerDecidesTheFrames) {
  for (const char* solver : {"risam", "mm", "gnc-tls"}) {
    SCOPED_TRACE(solver);
    TwoWalkers t(solver);
    t.closeWrongly(6, 3);
    t.close(2, 1);
    EXPECT_FALSE(t.joined()) << "the two disagree";
    t.close(4, 4);
    ASSERT_TRUE(t.joined());
    EXPECT_EQ(t.anchoredFactors(), 3);  // the wrong one goes in too, for the solver to judge
    t.h.command(command_t::OPTIMIZE);
    t.expectWorld(1e-6);
    const auto rejected = t.h.engine.backend().rejected();
    ASSERT_EQ(rejected.size(), 1u);
    const Factor* f = nullptr;
    for (const auto& g : t.h.engine.backend().graph().factors())
      if (g->id() == rejected[0]) f = g.get();
    ASSERT_NE(f, nullptr);
    EXPECT_EQ(f->size(), 4);
    EXPECT_EQ(keyIndex(f->key(1)), 6u) << "robot 0's pose 6: the wrong closure";
  }
}

TEST(EngineClosures, TrustedClosuresAndPlainSolversJoinOnTheFirst) {
  TwoWalkers trusted("risam");
  trusted.close(2, 1, "none");
  EXPECT_TRUE(trusted.joined());
  EXPECT_EQ(trusted.anchoredFactors(), 1);
  trusted.expectWorld(1e-6);
  TwoWalkers plain("isam2");
  plain.close(2, 1);
  EXPECT_TRUE(plain.joined());
  server::EngineOptions o = EngineHarness::options("risam");
  o.joinAgreement = 1;
  TwoWalkers first(o);
  first.close(2, 1);
  EXPECT_TRUE(first.joined());
}

TEST(EngineClosures, AClosureThatJoinsTheFramesReleasesTheWaitingOnes) {
  TwoWalkers t("risam");
  t.close(2, 1);
  t.closeWrongly(7, 7);
  EXPECT_EQ(t.anchoredFactors(), 0);
  t.close(5, 5, "none");
  EXPECT_TRUE(t.h.out.errors.empty()) << t.firstError();
  EXPECT_TRUE(t.joined());
  EXPECT_EQ(t.anchoredFactors(), 3);
  t.h.command(command_t::OPTIMIZE);
  t.expectWorld(1e-6);
  EXPECT_EQ(t.h.engine.backend().rejected().size(), 1u);
}

TEST(EngineClosures, AClosureRemovedWhileItWaitsDoesNotCount) {
  TwoWalkers t("risam");
  const std::int64_t first = t.close(2, 1);
  t.r1.remove(first);
  t.r1.flush();
  EXPECT_TRUE(t.h.out.errors.empty()) << t.firstError();
  t.close(3, 2);
  EXPECT_FALSE(t.joined()) << "one closure left";
  t.close(4, 3);
  EXPECT_TRUE(t.joined());
  EXPECT_EQ(t.anchoredFactors(), 2);
}

// An ambiguous inter-robot alternative needs its robots' frames joined by a certain factor: a
// closure of the same batch that would be kept back does not count (before, the validator
// counted it, and the alternative reached the solver on anchors that did not exist).
TEST(EngineClosures, AnAmbiguousAlternativeDoesNotCountAClosureKeptBack) {
  TwoWalkers t("risam");
  auto sendWithGroup = [&](const std::string& robust) {
    t.r1.loopClosure(KeyRef::pose(0, 2), KeyRef::pose(1, 1),
                     pose2(t.robot0(2).between(t.robot1(1))), kInfo, robust);
    t.r1.ambiguous(loopd::ambiguous_factor_t::MULTI_ASSOCIATION,
                   {client::loopClosureFactor(KeyRef::pose(0, 4), KeyRef::pose(1, 3),
                                              pose2(t.robot0(4).between(t.robot1(3))), kInfo)},
                   true);
    t.r1.flush();
  };
  sendWithGroup("");
  ASSERT_EQ(t.h.out.errors.size(), 1u);
  EXPECT_EQ(t.h.out.errors[0].code, loopd::error_t::INVALID_FIELD);
  EXPECT_NE(t.firstError().find("send a certain inter-robot loop closure"), std::string::npos);
  EXPECT_FALSE(t.joined());
  EXPECT_EQ(t.anchoredFactors(), 0);
  sendWithGroup("none");  // trusted: it joins the frames, and the group goes in with it
  EXPECT_EQ(t.h.out.errors.size(), 1u);
  EXPECT_TRUE(t.joined());
  EXPECT_EQ(t.anchoredFactors(), 2);
}

TEST(EngineClosures, AJoinAgreementOfThreeWaitsForTheThird) {
  server::EngineOptions o = EngineHarness::options("risam");
  o.joinAgreement = 3;
  TwoWalkers t(o);
  t.close(2, 1);
  t.close(3, 2);
  EXPECT_FALSE(t.joined());
  t.close(4, 3);
  EXPECT_TRUE(t.joined());
  EXPECT_EQ(t.anchoredFactors(), 3);
}

}  // namespace
}  // namespace loopd
