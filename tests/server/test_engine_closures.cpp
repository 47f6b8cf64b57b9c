// Inter-robot loop closures under a solver that judges loop closures (server/engine_closures.cpp):
// kept back until enough of a pair's agree on the transform between the robots' frames. Before,
// the first one joined the frames, right or wrong.
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "loopd/ambiguous_factor_t.hpp"
#include "tests/server/two_walkers.h"

namespace loopd {
namespace {

using client::FactorPublisher;
using client::KeyRef;
using test::EngineHarness;
using test::kInfo;
using test::pose2;
using test::TwoWalkers;

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
