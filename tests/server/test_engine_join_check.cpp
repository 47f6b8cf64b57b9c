// Joins made at agreeing inter-robot closures, checked again as the pair's closures grow
// (server/engine_join_check.cpp). A group of mutually consistent wrong closures that arrives
// first joins the two frames where it puts them; before, the frames stayed there and the true
// closures that followed were judged against it.
#include <gtest/gtest.h>

#include <set>

#include "tests/server/two_walkers.h"

namespace loopd {
namespace {

using test::TwoWalkers;

// Robot 0's poses at which the rejected closures end (each is robot 1's closure to robot 0).
std::set<std::uint64_t> rejectedAtRobot0(const TwoWalkers& t) {
  const auto rejected = t.h.engine.backend().rejected();
  const std::set<FactorId> ids(rejected.begin(), rejected.end());
  std::set<std::uint64_t> poses;
  for (const auto& f : t.h.engine.backend().graph().factors())
    if (ids.count(f->id()) && f->size() == 4) poses.insert(keyIndex(f->key(1)));
  return poses;
}

TEST(EngineJoinCheck, AFrameJoinedAtAWrongGroupMovesWhereMoreClosuresAgree) {
  for (const char* solver : {"dcs", "mm", "sc", "risam", "gnc-tls"}) {
    SCOPED_TRACE(solver);
    TwoWalkers t(solver);
    const SE2 wrongFrame(-6.0, 2.0, 2.0);
    t.closeAsIf(wrongFrame, 2, 1);
    t.closeAsIf(wrongFrame, 3, 2);
    ASSERT_TRUE(t.joined()) << "the wrong pair agrees with itself";
    for (int i = 4; i <= 9; ++i) t.close(i, i - 1);
    EXPECT_TRUE(t.h.out.errors.empty()) << t.firstError();
    EXPECT_EQ(t.h.engine.counters().rejoins, 1);
    t.h.command(command_t::OPTIMIZE);
    t.expectWorld(1e-4);  // dcs leaves the rejected closures a small weight
    EXPECT_EQ(rejectedAtRobot0(t), (std::set<std::uint64_t>{2, 3}));
  }
}

// Four wrong closures after the two true ones that joined the frames are not more than twice
// as many: the join stays, and the solver judges them. (risam is left out: its GNC takes the
// larger consistent set itself.)
TEST(EngineJoinCheck, ATrueJoinStaysWhenASmallerWrongGroupFollows) {
  for (const char* solver : {"dcs", "mm", "sc"}) {
    SCOPED_TRACE(solver);
    TwoWalkers t(solver);
    t.close(2, 1);
    t.close(3, 2);
    ASSERT_TRUE(t.joined());
    const SE2 wrongFrame(-6.0, 2.0, 2.0);
    for (int i = 5; i <= 8; ++i) t.closeAsIf(wrongFrame, i, i - 1);  // 4: not over twice 2
    EXPECT_EQ(t.h.engine.counters().rejoins, 0);
    t.h.command(command_t::OPTIMIZE);
    t.expectWorld(1e-4);
    EXPECT_EQ(rejectedAtRobot0(t), (std::set<std::uint64_t>{5, 6, 7, 8}));
  }
}

}  // namespace
}  // namespace loopd
