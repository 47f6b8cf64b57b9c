// Unit tests of the server's parts without LCM: the validator, the session table, the anchored
// factors' Jacobians, and the engine driven directly (messages in, captured messages out).
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <fstream>
#include <limits>
#include <random>
#include <set>
#include <thread>

#include "client/factor_publisher.h"
#include "loopd/command_t.hpp"
#include "loopd/error_t.hpp"
#include "loopd/estimate_t.hpp"
#include "loopd/status_t.hpp"
#include "robust/backend_registry.h"
#include "robust/decorator_backend.h"
#include "server/batch_validator.h"
#include "server/engine.h"
#include "server/server_config.h"
#include "server/session_table.h"
#include "solvers/incremental/isam2.h"
#include "tests/server/engine_harness.h"
#include "tests/server/wire_encode.h"

using namespace loopd;
using namespace loopd::server;
using client::KeyRef;
using client::Pose2;

namespace {

// --- helpers ------------------------------------------------------------------------------

using test::batch;
using test::between2;
using EngineFixture = test::EngineHarness;
using test::encode;

// A chain of odometry for robot r from index `from` to `to`, one batch per pose.
void chain(EngineFixture& f, const std::string& sender, int r, int from, int to, std::int64_t& seq,
           std::int64_t& id) {
  for (int i = from; i < to; ++i)
    f.send(batch(sender, ++seq, {between2(id++, r, i, r, i + 1, {1, 0, 0.1})}));
}

// --- validator ----------------------------------------------------------------------------

TEST(FactorBatchValidator, AcceptsWellFormedBatch) {
  FactorBatchValidator v;
  EXPECT_TRUE(v.check(batch("a", 1, {between2(0, 0, 0, 0, 1, {1, 0, 0})})).empty());
}

TEST(FactorBatchValidator, ReportsEachProblemWithItsCode) {
  FactorBatchValidator v;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  struct Case {
    std::function<void(factor_t&)> mutate;
    int8_t code;
  };
  const std::vector<Case> cases = {
      {[&](factor_t& f) { f.measurement[1] = nan; }, loopd::error_t::NON_FINITE},
      {[&](factor_t& f) { f.noise[0] = std::numeric_limits<double>::infinity(); },
       loopd::error_t::NON_FINITE},
      {[&](factor_t& f) { f.noise = {1, 0, 0, -1, 0, 1}; }, loopd::error_t::NOT_POSITIVE_DEFINITE},
      {[&](factor_t& f) { f.noise = {1, 2, 0, 1, 0, 1}; }, loopd::error_t::NOT_POSITIVE_DEFINITE},
      // Positive definite but beyond kMaxInformation: 1e300 passed and a closure disagreeing
      // with the odometry then made χ² inf and the graph unsolvable (every later batch INTERNAL).
      {[&](factor_t& f) { f.noise = {1e300, 0, 0, 1e300, 0, 1e300}; },
       loopd::error_t::LIMIT_EXCEEDED},
      {[&](factor_t& f) {
         f.noise_kind = factor_t::NOISE_COVARIANCE;
         f.noise = {1e-20, 0, 0, 1, 0, 1};
       },
       loopd::error_t::LIMIT_EXCEEDED},
      {[&](factor_t& f) {
         f.noise.pop_back();
         f.num_noise = 5;
       },
       loopd::error_t::WRONG_DIMENSION},
      {[&](factor_t& f) {
         f.measurement.pop_back();
         f.num_measurement = 2;
       },
       loopd::error_t::WRONG_DIMENSION},
      {[&](factor_t& f) {
         f.keys.pop_back();
         f.num_keys = 1;
       },
       loopd::error_t::WRONG_DIMENSION},
      {[&](factor_t& f) { f.keys[1].kind = loopd::key_t::LANDMARK; },
       loopd::error_t::WRONG_KEY_KIND},
      {[&](factor_t& f) { f.keys[1].kind = 5; }, loopd::error_t::INVALID_FIELD},
      {[&](factor_t& f) { f.type = 42; }, loopd::error_t::INVALID_FIELD},
      {[&](factor_t& f) { f.role = factor_t::ROLE_PRIOR; }, loopd::error_t::INVALID_FIELD},
      {[&](factor_t& f) { f.robust = "bogus"; }, loopd::error_t::INVALID_FIELD},
      {[&](factor_t& f) { f.robust = "dcs"; },
       loopd::error_t::INVALID_FIELD},  // odometry is trusted
      {[&](factor_t& f) { f.robust_param = -1; }, loopd::error_t::INVALID_FIELD},
      {[&](factor_t& f) { f.noise_kind = 0; }, loopd::error_t::INVALID_FIELD},
      {[&](factor_t& f) { f.id = -3; }, loopd::error_t::INVALID_FIELD},
      {[&](factor_t& f) { f.keys[1].robot = 3; },
       loopd::error_t::INVALID_FIELD},  // odometry across robots
  };
  for (size_t i = 0; i < cases.size(); ++i) {
    factor_t f = between2(5, 0, 0, 0, 1, {1, 0, 0});
    cases[i].mutate(f);
    const auto issues = v.check(batch("a", 1, {f}));
    ASSERT_FALSE(issues.empty()) << "case " << i;
    bool found = false;
    for (const auto& is : issues) found |= is.code == cases[i].code;
    EXPECT_TRUE(found) << "case " << i << ": " << issues[0].reason;
  }
}

TEST(FactorBatchValidator, BatchLevelChecks) {
  FactorBatchValidator v;
  EXPECT_EQ(v.check(batch("", 1, {})).at(0).code, loopd::error_t::INVALID_FIELD);
  EXPECT_EQ(v.check(batch(std::string(64, 'x'), 1, {})).at(0).code, loopd::error_t::LIMIT_EXCEEDED);
  EXPECT_EQ(v.check(batch("a", 0, {})).at(0).code, loopd::error_t::INVALID_FIELD);
  auto dup =
      batch("a", 1, {between2(3, 0, 0, 0, 1, {1, 0, 0}), between2(3, 0, 1, 0, 2, {1, 0, 0})});
  EXPECT_EQ(v.check(dup).at(0).code, loopd::error_t::DUPLICATE_FACTOR_ID);
  std::vector<factor_t> many;
  for (int i = 0; i < 201; ++i) many.push_back(between2(i, 0, i, 0, i + 1, {1, 0, 0}));
  EXPECT_EQ(v.check(batch("a", 1, many)).at(0).code, loopd::error_t::LIMIT_EXCEEDED);
  factor_batch_t se3 = batch("a", 1, {});
  initial_value_t iv{};
  iv.key = client::wireKey(KeyRef::pose(0, 1));
  iv.type = initial_value_t::SE3;
  iv.value = {0, 0, 0, 0, 0, 0, 2};  // not a unit quaternion
  iv.num_value = 7;
  se3.initial_values = {iv};
  se3.num_initial_values = 1;
  EXPECT_EQ(v.check(se3).at(0).code, loopd::error_t::INVALID_FIELD);
  iv.type = initial_value_t::POINT2;
  se3.initial_values = {iv};
  EXPECT_FALSE(v.check(se3).empty());
}

// --- sessions -----------------------------------------------------------------------------

TEST(SessionTable, DuplicatesAndGaps) {
  SessionTable t;
  EXPECT_TRUE(t.receive("a", 1));
  EXPECT_FALSE(t.receive("a", 1));
  EXPECT_TRUE(t.receive("a", 2));
  EXPECT_TRUE(t.receive("a", 5));
  EXPECT_TRUE(t.receive("b", 1));
  EXPECT_TRUE(t.hasGapBelow("a", 5));
  EXPECT_FALSE(t.hasGapBelow("a", 3));
  auto g = t.gaps();
  ASSERT_EQ(g.size(), 1u);
  EXPECT_EQ(g[0].sender, "a");
  EXPECT_EQ(g[0].lastContiguous, 2);
  EXPECT_EQ(g[0].highest, 5);
  EXPECT_EQ(g[0].missing, 2);
  EXPECT_TRUE(t.receive("a", 4));
  EXPECT_TRUE(t.receive("a", 3));  // a late batch filling the gap
  EXPECT_FALSE(t.receive("a", 4));
  EXPECT_TRUE(t.gaps().empty());
  EXPECT_FALSE(t.hasGapBelow("a", 6));
}

TEST(SessionTable, IdsAreNeverReused) {
  SessionTable t;
  t.addId("a", 10, 100);
  EXPECT_TRUE(t.idLive("a", 10));
  EXPECT_FALSE(t.idLive("b", 10));
  EXPECT_EQ(t.removeId("a", 10), 100u);
  EXPECT_FALSE(t.idLive("a", 10));
  EXPECT_TRUE(t.idUsed("a", 10));
  t.undoRemove("a", 10, 100);
  EXPECT_TRUE(t.idLive("a", 10));
  t.undoAdd("a", 10);
  EXPECT_FALSE(t.idUsed("a", 10));
}

// --- engine -------------------------------------------------------------------------------

TEST(Engine, AppliesBatchesAndIgnoresDuplicates) {
  EngineFixture f;
  std::int64_t seq = 0, id = 0;
  chain(f, "r0", 0, 0, 5, seq, id);
  EXPECT_EQ(f.poses(), 6);
  f.send(batch("r0", 3, {between2(99, 0, 5, 0, 6, {1, 0, 0})}));  // duplicate sequence: ignored
  EXPECT_EQ(f.poses(), 6);
  const auto c = f.engine.counters();
  EXPECT_EQ(c.accepted, 5);
  EXPECT_EQ(c.duplicate, 1);
  EXPECT_TRUE(f.out.errors.empty());
  // The first pose is the robot's origin (identity), the others composed from odometry.
  std::vector<double> x;
  ASSERT_TRUE(f.engine.commonFramePose(poseKey(0, 0), x));
  EXPECT_NEAR(x[0], 0, 1e-6);
  ASSERT_TRUE(f.engine.commonFramePose(poseKey(1, 0), x));
  EXPECT_NEAR(x[0], 1, 1e-6);
  EXPECT_FALSE(f.out.statuses.empty());
  EXPECT_FALSE(f.out.covariances.empty());
}

TEST(Engine, RejectsWholeBatchAndKeepsGraph) {
  EngineFixture f;
  std::int64_t seq = 0, id = 0;
  chain(f, "r0", 0, 0, 3, seq, id);
  factor_t bad = between2(50, 0, 3, 0, 4, {1, 0, 0});
  bad.noise = {1, 0, 0, -5, 0, 1};
  f.send(batch("r0", ++seq, {between2(49, 0, 3, 0, 4, {1, 0, 0}), bad}));
  EXPECT_EQ(f.poses(), 4);  // nothing of the batch applied
  ASSERT_EQ(f.out.errors.size(), 1u);
  EXPECT_EQ(f.out.errors[0].code, loopd::error_t::NOT_POSITIVE_DEFINITE);
  EXPECT_EQ(f.out.errors[0].sender, "r0");
  EXPECT_EQ(f.out.errors[0].sequence, seq);
  EXPECT_EQ(f.out.errors[0].factor_id, 50);
  // Reused id and unknown removal.
  f.send(batch("r0", ++seq, {between2(0, 0, 3, 0, 4, {1, 0, 0})}));
  EXPECT_EQ(f.out.errors.back().code, loopd::error_t::DUPLICATE_FACTOR_ID);
  factor_batch_t rm = batch("r0", ++seq, {});
  rm.remove_ids = {12345};
  rm.num_remove_ids = 1;
  f.send(rm);
  EXPECT_EQ(f.out.errors.back().code, loopd::error_t::UNKNOWN_FACTOR_ID);
  // Wrong type for a known variable: an SE3 factor on an SE2 pose.
  factor_t se3{};
  se3 = between2(60, 0, 2, 0, 3, {0, 0, 0}, factor_t::ROLE_LOOP_CLOSURE);
  se3.type = factor_t::BETWEEN_SE3;
  se3.measurement = {0, 0, 0, 0, 0, 0, 1};
  se3.num_measurement = 7;
  se3.noise.assign(21, 0.0);
  for (int i : {0, 6, 11, 15, 18, 20}) se3.noise[static_cast<size_t>(i)] = 1;
  se3.num_noise = 21;
  f.send(batch("r0", ++seq, {se3}));
  EXPECT_EQ(f.out.errors.back().code, loopd::error_t::WRONG_DIMENSION);
  EXPECT_EQ(f.poses(), 4);
  EXPECT_EQ(f.engine.counters().rejected, 4);
}

TEST(Engine, HoldsOutOfOrderBatchesUntilThePoseArrives) {
  EngineFixture f;
  std::int64_t id = 0;
  f.send(batch("r0", 1, {between2(id++, 0, 0, 0, 1, {1, 0, 0})}));
  // Sequence 3 (pose 2→3) arrives before 2 (pose 1→2): held, then applied.
  f.send(batch("r0", 3, {between2(11, 0, 2, 0, 3, {1, 0, 0})}));
  EXPECT_EQ(f.poses(), 2);
  EXPECT_EQ(f.out.statuses.back().batches_held, 1);
  ASSERT_EQ(f.out.statuses.back().num_sender_gaps, 1);
  EXPECT_EQ(f.out.statuses.back().sender_gaps[0].missing, 1);
  f.send(batch("r0", 2, {between2(10, 0, 1, 0, 2, {1, 0, 0})}));
  EXPECT_EQ(f.poses(), 4);
  EXPECT_EQ(f.out.statuses.back().batches_held, 0);
  EXPECT_EQ(f.out.statuses.back().num_sender_gaps, 0);
  EXPECT_TRUE(f.out.errors.empty());
}

TEST(Engine, ExpiresHeldBatches) {
  EngineFixture f("lm", 0.05);
  f.send(batch("r0", 1, {between2(0, 0, 0, 0, 1, {1, 0, 0})}));
  f.send(batch("r0", 3, {between2(5, 0, 7, 0, 8, {1, 0, 0})}));
  std::this_thread::sleep_for(std::chrono::milliseconds(100));
  f.engine.idle();
  ASSERT_EQ(f.out.errors.size(), 1u);
  EXPECT_EQ(f.out.errors[0].code, loopd::error_t::HELD_EXPIRED);
  EXPECT_EQ(f.engine.counters().expired, 1);
}

TEST(Engine, RemovalsAndCommands) {
  EngineFixture f;
  std::int64_t seq = 0, id = 0;
  chain(f, "r0", 0, 0, 6, seq, id);
  f.send(batch("r0", ++seq, {between2(100, 0, 6, 0, 0, {0, 0, 0}, factor_t::ROLE_LOOP_CLOSURE)}));
  const double withLoop = f.engine.backend().chi2();
  factor_batch_t rm = batch("r0", ++seq, {});
  rm.remove_ids = {100};
  rm.num_remove_ids = 1;
  f.send(rm);
  EXPECT_LT(f.engine.backend().chi2(), withLoop);
  EXPECT_TRUE(f.out.errors.empty());
  f.send(rm);  // same sequence: duplicate, no error
  rm.sequence = ++seq;
  f.send(rm);  // removed already
  EXPECT_EQ(f.out.errors.back().code, loopd::error_t::UNKNOWN_FACTOR_ID);

  f.command(command_t::REQUEST_COVARIANCE, "joint",
            {client::wireKey(KeyRef::pose(0, 1)), client::wireKey(KeyRef::pose(0, 2))});
  f.command(command_t::REQUEST_COVARIANCE, "", {client::wireKey(KeyRef::pose(0, 99))});
  EXPECT_EQ(f.out.errors.back().code, loopd::error_t::UNKNOWN_KEY);
  EXPECT_EQ(f.out.errors.back().request_id, 7);
  f.command(command_t::SWITCH_SOLVER, "nope");
  EXPECT_EQ(f.out.errors.back().code, loopd::error_t::COMMAND_FAILED);
  f.command(command_t::SWITCH_SOLVER, "gn");
  EXPECT_EQ(f.engine.backend().name(), "gn");
  EXPECT_EQ(f.poses(), 7);
  const auto est = f.out.estimates.size();
  f.command(command_t::REQUEST_ESTIMATE);
  ASSERT_GT(f.out.estimates.size(), est);
  EXPECT_TRUE(f.out.estimates.back().full_snapshot);
  EXPECT_EQ(f.out.estimates.back().request_id, 7);
  EXPECT_EQ(f.out.estimates.back().num_poses, 7);
  const std::string snap = ::testing::TempDir() + "/snap.g2o";
  f.command(command_t::SAVE_SNAPSHOT, snap);
  std::ifstream in(snap);
  std::string first;
  std::getline(in, first);
  EXPECT_EQ(first.rfind("VERTEX_SE2 0 ", 0), 0u) << first;
  f.command(command_t::SAVE_SNAPSHOT, "/nonexistent/dir/x.g2o");
  EXPECT_EQ(f.out.errors.back().code, loopd::error_t::COMMAND_FAILED);
  f.command(command_t::RESET);
  EXPECT_EQ(f.poses(), 0);
  // After RESET sequences restart.
  f.send(batch("r0", 1, {between2(0, 0, 0, 0, 1, {1, 0, 0})}));
  EXPECT_EQ(f.poses(), 2);
}

// "isam2" whose estimate turns NaN once its chi2 passes 1e30: a stand-in for a variant that
// runs away on absurd input (the shipped ones keep this test's estimate finite).
// When it runs away: once chi2 passes 1e30, at every optimize(), or at every update.
enum class Runaway { HugeChi2, Optimize, Always };

class RunawayBackend : public DecoratorBackend {
 public:
  RunawayBackend(Runaway when, std::string name)
      : DecoratorBackend(std::make_unique<Isam2Backend>(), "RunawayBackend"),
        when_(when),
        name_(std::move(name)) {}
  // The registered name: the engine rebuilds a diverged solver by name.
  std::string name() const override { return name_; }
  UpdateResult update(const BackendUpdate& u) override {
    const UpdateResult r = inner_->update(u);
    commitOriginals(u, {u.removals.begin(), u.removals.end()});
    if (when_ == Runaway::Always || !(inner_->chi2() < 1e30)) runAway();
    return r;
  }
  void optimize() override {
    inner_->optimize();
    if (when_ == Runaway::Optimize) runAway();
  }
  const Values& estimate() const override { return nan_.empty() ? inner_->estimate() : nan_; }

 private:
  void runAway() {
    nan_ = inner_->estimate();
    for (int s = 0; s < nan_.size(); ++s)
      std::fill_n(nan_.data(s), kValueStride, std::numeric_limits<double>::quiet_NaN());
  }
  Runaway when_;
  std::string name_;
  Values nan_;
};

void registerRunawayBackends() {
  static const bool registered = [] {
    for (const auto& [name, when] :
         {std::pair{"runaway", Runaway::HugeChi2}, std::pair{"runaway-optimize", Runaway::Optimize},
          std::pair{"runaway-always", Runaway::Always}})
      registerBackend({name, "test: a NaN estimate", true},
                      [when = when, name = std::string(name)](const BackendOptions&) {
                        return std::make_unique<RunawayBackend>(when, name);
                      });
    return true;
  }();
  ASSERT_TRUE(registered);
}

// An odometry of 1e200 m passes validation (finite) and the solver runs away on it. The round
// is refused with an error, the solver is rebuilt from the graph before it, nothing non-finite
// is published, and later batches apply.
TEST(Engine, RefusesARoundThatMakesTheSolverDiverge) {
  registerRunawayBackends();
  EngineFixture f("runaway");
  std::int64_t seq = 0, id = 0;
  chain(f, "r0", 0, 0, 4, seq, id);
  const size_t published = f.out.estimates.size();
  f.send(batch("r0", ++seq,
               {between2(id++, 0, 4, 0, 5, {1e200, 0, 0}),
                between2(id++, 0, 5, 0, 0, {0, 0, 0}, factor_t::ROLE_LOOP_CLOSURE)}));
  ASSERT_FALSE(f.out.errors.empty());
  EXPECT_EQ(f.out.errors.back().code, loopd::error_t::INTERNAL);
  EXPECT_EQ(f.out.errors.back().sequence, seq);
  EXPECT_NE(f.out.errors.back().reason.find("diverged"), std::string::npos)
      << f.out.errors.back().reason;
  EXPECT_EQ(f.poses(), 5);
  EXPECT_TRUE(f.engine.backend().estimate().allFinite());
  EXPECT_GE(f.engine.counters().divergences, 1);
  // The next pose, from pose 4 as if the refused batch had never come.
  f.send(batch("r0", ++seq, {between2(id++, 0, 4, 0, 5, {1, 0, 0.1})}));
  EXPECT_EQ(f.poses(), 6);
  EXPECT_TRUE(f.engine.backend().estimate().allFinite());
  EXPECT_LT(f.engine.backend().chi2(), 1e-9);  // odometry only: every factor exact
  for (size_t e = published; e < f.out.estimates.size(); ++e)
    for (const auto& pose : f.out.estimates[e].poses)
      for (double v : pose) EXPECT_TRUE(std::isfinite(v));
}

// "isam2" whose optimize() stands for a long piece of work that can be given up (risam's GNC
// look): it waits until BackendOptions::interrupt says so, at most 20 s, and records what it
// saw.
struct Yielding {
  static inline std::atomic<int> optimizes{0}, interrupted{0};
  static inline std::atomic<bool> hadInterrupt{false};
  // BackendOptions::stopping when the interrupt last said yes: a stop, not waiting input.
  static inline std::atomic<bool> stoppingWhenInterrupted{false};
  static inline std::atomic<bool> waits{true};  // false: optimize() returns at once
};
class YieldingBackend : public DecoratorBackend {
 public:
  explicit YieldingBackend(const BackendOptions& o)
      : DecoratorBackend(std::make_unique<Isam2Backend>(), "YieldingBackend"),
        interrupt_(o.interrupt),
        stopping_(o.stopping) {
    Yielding::hadInterrupt = static_cast<bool>(interrupt_) && static_cast<bool>(stopping_);
  }
  std::string name() const override { return "yielding"; }
  UpdateResult update(const BackendUpdate& u) override {
    const UpdateResult r = inner_->update(u);
    commitOriginals(u, {u.removals.begin(), u.removals.end()});
    return r;
  }
  void optimize() override {
    ++Yielding::optimizes;
    if (!Yielding::waits) return;
    const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(20);
    while (std::chrono::steady_clock::now() < until) {
      if (interrupt_ && interrupt_()) {
        Yielding::stoppingWhenInterrupted = stopping_ && stopping_();
        ++Yielding::interrupted;
        return;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
  }

 private:
  std::function<bool()> interrupt_, stopping_;
};

// An engine on "yielding" (registered on first use) that optimizes at every pause.
struct YieldingEngine {
  static EngineOptions options() {
    static const bool registered = [] {
      registerBackend({"yielding", "test: optimize() waits for the interrupt", true},
                      [](const BackendOptions& o) { return std::make_unique<YieldingBackend>(o); });
      return true;
    }();
    (void)registered;
    EngineOptions o = EngineFixture::options("yielding", 30);
    o.idleSeconds = 0;
    return o;
  }
  Publisher pub{Channels::withPrefix("T_"), [](const std::string&, const std::vector<uint8_t>&) {}};
  Engine engine{options(), pub, nullptr};
};

// The idle optimize gives way: a message that arrives while it runs, or a stop, ends work
// that asks BackendOptions::interrupt (risam's GNC look at a pause) at once, instead of
// holding the input back until it is done; BackendOptions::stopping (asked by a look that has
// given way too often) tells the stop apart from the input.
TEST(Engine, AnIdleOptimizeGivesWayToInputAndToAStop) {
  YieldingEngine y;
  Engine& engine = y.engine;
  ASSERT_TRUE(Yielding::hadInterrupt);
  std::int64_t seq = 0, id = 0;
  auto send = [&](int from) {
    engine.post({"T_FACTORS",
                 encode(batch("r0", ++seq, {between2(id++, 0, from, 0, from + 1, {1, 0, 0.1})}))});
  };
  send(0);
  ASSERT_TRUE(engine.step());
  // Input while the idle optimize runs.
  const int optimizesBefore = Yielding::optimizes;
  const auto t0 = std::chrono::steady_clock::now();
  std::thread poster([&] {
    while (Yielding::optimizes == optimizesBefore) std::this_thread::yield();
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    send(1);
  });
  engine.idle();
  poster.join();
  const double waited =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  EXPECT_EQ(Yielding::interrupted, 1);
  EXPECT_FALSE(Yielding::stoppingWhenInterrupted);  // waiting input is not a stop
  EXPECT_LT(waited, 10.0);
  EXPECT_EQ(engine.queueDepth(), 1);
  ASSERT_TRUE(engine.step());  // the waiting pose goes in
  EXPECT_EQ(engine.backend().estimate().size(), 3);
  // A stop while run()'s idle optimize runs.
  std::atomic<bool> stop{false};
  const int interruptedBefore = Yielding::interrupted;
  std::thread stopper([&] {
    while (Yielding::optimizes == optimizesBefore + 1) std::this_thread::yield();
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    stop = true;
  });
  const auto t1 = std::chrono::steady_clock::now();
  engine.run(stop);
  stopper.join();
  EXPECT_EQ(Yielding::interrupted, interruptedBefore + 1);
  EXPECT_TRUE(Yielding::stoppingWhenInterrupted);
  EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count(), 10.0);
}

// An idle optimize given up for a command (no factors, so nothing else marks the graph
// unsettled) runs again at the next pause: the look it gave up is not lost until new factors
// come.
TEST(Engine, AnIdleOptimizeGivenUpForACommandRunsAgainAtTheNextPause) {
  YieldingEngine y;
  Engine& engine = y.engine;
  engine.post({"T_FACTORS", encode(batch("r0", 1, {between2(0, 0, 0, 0, 1, {1, 0, 0.1})}))});
  ASSERT_TRUE(engine.step());
  const int optimizesBefore = Yielding::optimizes, interruptedBefore = Yielding::interrupted;
  std::thread poster([&] {
    while (Yielding::optimizes == optimizesBefore) std::this_thread::yield();
    command_t c{};
    c.sender = "test";
    c.command = command_t::REQUEST_ESTIMATE;
    engine.post({"T_COMMAND", encode(c)});
  });
  engine.idle();
  poster.join();
  EXPECT_EQ(Yielding::interrupted, interruptedBefore + 1);
  ASSERT_TRUE(engine.step());  // the command
  Yielding::waits = false;
  engine.idle();
  EXPECT_EQ(Yielding::optimizes, optimizesBefore + 2) << "the given-up optimize did not run again";
  engine.idle();
  EXPECT_EQ(Yielding::optimizes, optimizesBefore + 2) << "settled: no optimize without input";
  Yielding::waits = true;
}

// A solver that runs away need not pass through NaN (riSAM on parking-garage went from 1e3 to
// 1e188 m, all finite): an estimate beyond kRunawayMagnitude is treated as diverged too. Plain
// isam2 put a pose 1e13 m out (finite, chi2 0) where it was published before.
TEST(Engine, RefusesARoundThatLeavesAnAbsurdButFiniteEstimate) {
  EngineFixture f("isam2");
  std::int64_t seq = 0, id = 0;
  chain(f, "r0", 0, 0, 4, seq, id);
  const size_t published = f.out.estimates.size();
  f.send(batch("r0", ++seq, {between2(id++, 0, 4, 0, 5, {1e13, 0, 0})}));
  ASSERT_FALSE(f.out.errors.empty());
  EXPECT_EQ(f.out.errors.back().code, loopd::error_t::INTERNAL);
  EXPECT_NE(f.out.errors.back().reason.find("diverged"), std::string::npos)
      << f.out.errors.back().reason;
  EXPECT_EQ(f.poses(), 5);
  EXPECT_FALSE(ranAway(f.engine.backend().estimate()));
  EXPECT_GE(f.engine.counters().divergences, 1);
  f.send(batch("r0", ++seq, {between2(id++, 0, 4, 0, 5, {1, 0, 0.1})}));
  EXPECT_EQ(f.poses(), 6);
  for (size_t e = published; e < f.out.estimates.size(); ++e)
    for (const auto& pose : f.out.estimates[e].poses)
      for (double v : pose) EXPECT_LE(std::abs(v), kRunawayMagnitude);
}

// An idle optimize that runs away is rolled back to the estimate before it; nothing
// non-finite is published and updates go on.
TEST(Engine, RollsBackAnIdleOptimizeThatDiverges) {
  registerRunawayBackends();
  EngineFixture f("runaway-optimize", 30);
  std::int64_t seq = 0, id = 0;
  chain(f, "r0", 0, 0, 4, seq, id);
  std::vector<double> before;
  ASSERT_TRUE(f.engine.commonFramePose(poseKey(4, 0), before));
  const size_t published = f.out.estimates.size();
  f.command(command_t::OPTIMIZE);
  EXPECT_EQ(f.engine.counters().divergences, 1);
  EXPECT_TRUE(f.engine.backend().estimate().allFinite());
  std::vector<double> after;
  ASSERT_TRUE(f.engine.commonFramePose(poseKey(4, 0), after));
  ASSERT_EQ(after.size(), before.size());
  for (size_t i = 0; i < after.size(); ++i) EXPECT_NEAR(after[i], before[i], 1e-9);
  chain(f, "r0", 0, 4, 6, seq, id);
  EXPECT_EQ(f.poses(), 7);
  EXPECT_TRUE(f.engine.backend().estimate().allFinite());
  for (size_t e = published; e < f.out.estimates.size(); ++e)
    for (const auto& pose : f.out.estimates[e].poses)
      for (double v : pose) EXPECT_TRUE(std::isfinite(v));
}

// SWITCH_SOLVER to a variant that diverges on the graph fails; the old solver stays.
TEST(Engine, KeepsTheSolverWhenASwitchDiverges) {
  registerRunawayBackends();
  EngineFixture f("isam2");
  std::int64_t seq = 0, id = 0;
  chain(f, "r0", 0, 0, 4, seq, id);
  f.command(command_t::SWITCH_SOLVER, "runaway-always");
  ASSERT_FALSE(f.out.errors.empty());
  EXPECT_EQ(f.out.errors.back().code, loopd::error_t::COMMAND_FAILED);
  EXPECT_NE(f.out.errors.back().reason.find("diverged"), std::string::npos)
      << f.out.errors.back().reason;
  EXPECT_EQ(f.engine.backend().name(), "isam2");
  EXPECT_TRUE(f.engine.backend().estimate().allFinite());
  chain(f, "r0", 0, 4, 5, seq, id);
  EXPECT_EQ(f.poses(), 6);
}

// A 20-pose walk whose every pose also sees the one two steps back (true closures), then one
// wrong closure from the last pose to the first with the given per-factor `robust`.
void rigidWalkWithWrongClosure(EngineFixture& f, const std::string& robust) {
  std::int64_t seq = 0, id = 0;
  const Pose2 two{1 + std::cos(0.1), std::sin(0.1), 0.2};  // {1, 0, 0.1} twice
  for (int i = 0; i < 20; ++i) {
    std::vector<factor_t> fs = {between2(id++, 0, i, 0, i + 1, {1, 0, 0.1})};
    if (i >= 1) fs.push_back(between2(id++, 0, i - 1, 0, i + 1, two, factor_t::ROLE_LOOP_CLOSURE));
    f.send(batch("r0", ++seq, fs));
  }
  factor_t wrong = between2(1000, 0, 20, 0, 0, {3, -2, 1.0}, factor_t::ROLE_LOOP_CLOSURE);
  wrong.robust = robust;
  f.send(batch("r0", ++seq, {wrong}));
}

TEST(Engine, PerFactorRobustRequestsApplyUnderAnySolver) {
  // isam2 alone takes the wrong closure; asked for "dcs" on it, the server rejects it.
  EngineFixture plain("isam2");
  rigidWalkWithWrongClosure(plain, "");
  EXPECT_TRUE(plain.engine.backend().rejected().empty());
  EngineFixture asked("isam2");
  rigidWalkWithWrongClosure(asked, "dcs");
  EXPECT_TRUE(asked.out.errors.empty()) << asked.out.errors[0].reason;
  EXPECT_EQ(asked.engine.backend().rejected().size(), 1u);
  EXPECT_LT(asked.engine.backend().chi2(), plain.engine.backend().chi2());
  // It survives a solver switch (the request travels with the factor).
  asked.command(command_t::SWITCH_SOLVER, "gn");
  EXPECT_EQ(asked.engine.backend().name(), "gn");
  EXPECT_EQ(asked.engine.backend().rejected().size(), 1u);
  // dcs as the solver rejects it too; "none" forces it in.
  EngineFixture robust("dcs");
  rigidWalkWithWrongClosure(robust, "");
  EXPECT_EQ(robust.engine.backend().rejected().size(), 1u);
  EngineFixture forced("dcs");
  rigidWalkWithWrongClosure(forced, "none");
  const Backend& b = forced.engine.backend();
  FactorId wrong = 0;
  for (const auto& x : b.graph().factors())
    if (x->size() == 2 && x->key(0) == poseKey(20) && x->key(1) == poseKey(0)) wrong = x->id();
  ASSERT_NE(wrong, 0u);
  const auto rejected = b.rejected();
  EXPECT_EQ(std::count(rejected.begin(), rejected.end(), wrong), 0);  // the true ones give way
  EXPECT_GT(b.chi2(), robust.engine.backend().chi2());
}

// Per-factor requests on true closures survive every solver switch: "sc" (its switch is the
// per-factor layer's own variable, which a rebuild gave the new solver twice: "already
// exists") and "dcs" under a batch solver (its linear initialization skipped the wrapped
// closures and replaced the converged estimate with the odometry's: every closure rejected).
TEST(Engine, SwitchingSolversKeepsTrueClosuresWithPerFactorRequests) {
  for (const char* robust : {"sc", "dcs"}) {
    SCOPED_TRACE(robust);
    EngineFixture f("isam2");
    std::int64_t seq = 0, id = 0;
    const Pose2 two{1 + std::cos(0.1), std::sin(0.1), 0.2};  // {1, 0, 0.1} twice
    for (int i = 0; i < 20; ++i) {
      std::vector<factor_t> fs = {between2(id++, 0, i, 0, i + 1, {1, 0.02, 0.1})};
      if (i >= 1) {
        fs.push_back(between2(id++, 0, i - 1, 0, i + 1, two, factor_t::ROLE_LOOP_CLOSURE));
        fs.back().robust = robust;
      }
      f.send(batch("r0", ++seq, fs));
    }
    f.command(command_t::OPTIMIZE);
    const double chi2 = f.engine.backend().chi2();
    for (const char* solver : {"lm", "gn", "dogleg", "isam2", "mh", "lm"}) {
      f.command(command_t::SWITCH_SOLVER, solver);
      f.command(command_t::OPTIMIZE);
      EXPECT_TRUE(f.out.errors.empty()) << solver << ": " << f.out.errors.front().reason;
      f.out.errors.clear();
      EXPECT_EQ(f.engine.backend().name(), solver);
      EXPECT_TRUE(f.engine.backend().rejected().empty()) << solver;
      EXPECT_NEAR(f.engine.backend().chi2(), chi2, 1e-6 * (1 + chi2)) << solver;
    }
  }
}

TEST(Engine, WholeGraphSchemesPerFactorOnlyAsTheSolver) {
  EngineFixture f("isam2");
  rigidWalkWithWrongClosure(f, "risam");
  ASSERT_EQ(f.out.errors.size(), 1u);
  EXPECT_EQ(f.out.errors[0].code, loopd::error_t::INVALID_FIELD);
  EXPECT_NE(std::string(f.out.errors[0].reason).find("whole-graph scheme"), std::string::npos);
  EXPECT_EQ(f.engine.backend().graph().size(),
            40u);  // the walk and its prior: nothing of the batch
  EngineFixture r("risam");
  rigidWalkWithWrongClosure(r, "risam");
  EXPECT_TRUE(r.out.errors.empty());
  EXPECT_EQ(r.engine.backend().rejected().size(), 1u);
}

TEST(Engine, TwoRobotsJoinInOneFrame) {
  EngineFixture f("isam2");
  std::int64_t s0 = 0, s1 = 0, id0 = 0, id1 = 0;
  chain(f, "a", 0, 0, 4, s0, id0);
  chain(f, "b", 1, 10, 14, s1, id1);
  EXPECT_FALSE(f.engine.robotJoined(0));
  EXPECT_FALSE(f.engine.robotJoined(1));
  // Robot 1's pose 10 is robot 0's pose 2 moved by (5, 0, 0).
  f.send(batch("b", ++s1, {between2(id1++, 0, 2, 1, 10, {5, 0, 0}, factor_t::ROLE_LOOP_CLOSURE)}));
  EXPECT_TRUE(f.engine.robotJoined(0));
  EXPECT_TRUE(f.engine.robotJoined(1));
  std::vector<double> a, b;
  ASSERT_TRUE(f.engine.commonFramePose(poseKey(2, 0), a));
  ASSERT_TRUE(f.engine.commonFramePose(poseKey(10, 1), b));
  const SE2 rel = SE2(a[0], a[1], a[2]).between(SE2(b[0], b[1], b[2]));
  EXPECT_NEAR(rel.x, 5, 1e-6);
  EXPECT_NEAR(rel.y, 0, 1e-6);
  EXPECT_NEAR(rel.theta, 0, 1e-6);
  EXPECT_NEAR(f.engine.backend().chi2(), 0.0, 1e-6);
  const auto& st = f.out.statuses.back();
  EXPECT_EQ(st.robots, 2);
  EXPECT_EQ(st.robots_in_common_frame, 2);
  // The last estimates say common frame, robot 0's frame.
  bool saw = false;
  for (const auto& e : f.out.estimates)
    if (e.robot == 1 && e.common_frame) {
      saw = true;
      EXPECT_EQ(e.frame_robot, 0);
    }
  EXPECT_TRUE(saw);
  // Removing the only inter-robot factor re-roots robot 1 (the graph stays solvable).
  factor_batch_t rm = batch("b", ++s1, {});
  rm.remove_ids = {id1 - 1};
  rm.num_remove_ids = 1;
  f.send(rm);
  EXPECT_TRUE(f.out.errors.empty());
  chain(f, "b", 1, 14, 16, s1, id1);
  EXPECT_TRUE(f.out.errors.empty());
}

// A closure from robot 1 to a pose of robot 0, which has not been heard from yet, waits for
// robot 0's own batches (before: it made that pose robot 0's origin, and robot 0's first
// batches, whose poses then had no value, were held until they expired).
TEST(Engine, AClosureToARobotNotYetHeardFromWaitsForIt) {
  EngineFixture f("isam2");
  std::int64_t s0 = 0, s1 = 0, id0 = 0, id1 = 100;
  chain(f, "b", 1, 10, 14, s1, id1);
  f.send(batch("b", ++s1, {between2(id1++, 0, 20, 1, 12, {5, 0, 0}, factor_t::ROLE_LOOP_CLOSURE)}));
  EXPECT_EQ(f.out.statuses.back().batches_held, 1);
  EXPECT_EQ(f.out.statuses.back().robots, 1);
  chain(f, "a", 0, 0, 21, s0, id0);
  EXPECT_TRUE(f.out.errors.empty()) << f.out.errors.front().reason;
  EXPECT_EQ(f.out.statuses.back().batches_held, 0);
  EXPECT_EQ(f.out.statuses.back().robots_in_common_frame, 2);
  // Robot 0's poses are all there, in the frame of its own first pose.
  const Values& x = f.engine.backend().estimate();
  for (int i = 0; i <= 20; ++i) EXPECT_TRUE(x.contains(poseKey(i, 0))) << i;
  const int origin = x.slot(poseKey(0, 0));
  ASSERT_GE(origin, 0);
  EXPECT_NEAR(x.se2(origin).x, 0.0, 1e-6);
  EXPECT_NEAR(x.se2(origin).y, 0.0, 1e-6);
}

TEST(Engine, MalformedBytesAreReported) {
  EngineFixture f;
  f.sendRaw({1, 2, 3});
  EXPECT_EQ(f.out.errors.back().code, loopd::error_t::DECODE_FAILED);
  status_t s{};
  s.solver = "x";
  f.sendRaw(encode(s));
  EXPECT_EQ(f.out.errors.back().code, loopd::error_t::WRONG_FINGERPRINT);
  EXPECT_NE(f.out.errors.back().reason.find("status_t"), std::string::npos);
  auto good = encode(batch("r0", 1, {between2(0, 0, 0, 0, 1, {1, 0, 0})}));
  good.resize(good.size() - 3);
  f.sendRaw(good);
  EXPECT_EQ(f.out.errors.back().code, loopd::error_t::DECODE_FAILED);
  f.sendRaw(std::vector<uint8_t>(300 * 1024, 0));
  EXPECT_EQ(f.out.errors.back().code, loopd::error_t::DECODE_FAILED);
  EXPECT_EQ(f.poses(), 0);
}

TEST(ServerConfig, FlagsFileAndDefaults) {
  const std::string path = ::testing::TempDir() + "/loopd.conf";
  std::ofstream(path) << "# comment\nsolver = lm\npublish-every = 7\nchannel-prefix = X_\n";
  ServerConfig c = parseServerConfig({"--config", path, "--publish-every", "9"});
  EXPECT_EQ(c.solver, "lm");
  EXPECT_EQ(c.publishEvery, 9);
  EXPECT_EQ(c.channelPrefix, "X_");
  EXPECT_EQ(parseServerConfig({}).solver, defaultSolver());
  EXPECT_THROW(parseServerConfig({"--solver", "nope"}), std::invalid_argument);
  EXPECT_THROW(parseServerConfig({"--bogus", "1"}), std::invalid_argument);
  // Rounds: at most 100 new poses of one robot per update unless told (0: no bound).
  EXPECT_EQ(parseServerConfig({}).posesPerUpdate, 100);
  EXPECT_EQ(parseServerConfig({"--poses-per-update", "0"}).posesPerUpdate, 0);
  EXPECT_EQ(parseServerConfig({"--poses-per-update", "25"}).posesPerUpdate, 25);
  EXPECT_THROW(parseServerConfig({"--poses-per-update", "-1"}), std::invalid_argument);
  EXPECT_THROW(parseServerConfig({"--poses-per-update", "2.5"}), std::invalid_argument);
  // Frames join once two inter-robot closures agree unless told (1: the first joins them).
  EXPECT_EQ(parseServerConfig({}).joinAgreement, 2);
  EXPECT_EQ(parseServerConfig({"--join-agreement", "1"}).joinAgreement, 1);
  EXPECT_EQ(parseServerConfig({"--join-agreement", "5"}).joinAgreement, 5);
  for (const char* bad : {"0", "-1", "1001", "2.5"})
    EXPECT_THROW(parseServerConfig({"--join-agreement", bad}), std::invalid_argument) << bad;
  // Landmark namespaces: a comma-separated list of robot ids.
  EXPECT_TRUE(parseServerConfig({}).landmarkNamespaces.empty());
  EXPECT_EQ(parseServerConfig({"--landmark-namespace", "100"}).landmarkNamespaces,
            (std::set<std::uint32_t>{100}));
  EXPECT_EQ(parseServerConfig({"--landmark-namespace=7,100,2147483647"}).landmarkNamespaces,
            (std::set<std::uint32_t>{7, 100, 2147483647u}));
  for (const char* bad : {"", "-1", "1,", ",1", "1,,2", "x", "2147483648", "1.5"})
    EXPECT_THROW(parseServerConfig({"--landmark-namespace", bad}), std::invalid_argument) << bad;
  EXPECT_EQ(effectiveLcmUrl("udpm://239.255.76.67:7667?ttl=0"),
            "udpm://239.255.76.67:7667?ttl=0&recv_buf_size=4194304");
  EXPECT_EQ(effectiveLcmUrl("memq://"), "memq://");
}

}  // namespace
