// Ambiguous measurements (ambiguous_factor_t) through the server: validation, the engine with
// mh (status fields, REQUEST_HYPOTHESES, removal, SWITCH_SOLVER, journal resume), flattening
// for the other variants, inter-robot alternatives (through the anchors of robots already
// joined; refused as a first link), --max-hypotheses. The engine is driven directly (no LCM);
// the last tests run loopd over real LCM.
#include <gtest/gtest.h>
#include <lcm/lcm-cpp.hpp>

#include <cmath>
#include <cstdio>
#include <limits>

#include "client/estimate_subscriber.h"
#include "client/factor_publisher.h"
#include "loopd/command_t.hpp"
#include "loopd/error_t.hpp"
#include "loopd/estimate_t.hpp"
#include "loopd/status_t.hpp"
#include "server/batch_validator.h"
#include "server/engine.h"
#include "server/journal.h"
#include "server/server_config.h"
#include "solvers/io/dataset_reader.h"
#include "tests/server/engine_harness.h"
#include "tests/server/live_util.h"
#include "tests/server/wire_encode.h"

using namespace loopd;
using namespace loopd::server;
using client::KeyRef;
using client::Pose2;
using A = loopd::ambiguous_factor_t;

namespace {

const Eigen::Matrix3d kInfo = Eigen::Vector3d(100, 100, 1000).asDiagonal();

factor_t odo(std::int64_t id, int r, std::int64_t a, std::int64_t b, Pose2 z, double info = 100) {
  factor_t f = client::loopClosureFactor(KeyRef::pose(r, a), KeyRef::pose(r, b), z,
                                         Eigen::Vector3d(info, info, 10 * info).asDiagonal());
  f.id = id;
  f.role = factor_t::ROLE_ODOMETRY;
  return f;
}

factor_t closure(int r, std::int64_t a, std::int64_t b, Pose2 z, std::int64_t id = 0) {
  factor_t f = client::loopClosureFactor(KeyRef::pose(r, a), KeyRef::pose(r, b), z, kInfo);
  f.id = id;
  return f;
}

A group(std::int64_t id, std::int8_t mode, std::vector<factor_t> alts, bool null = false,
        double nullWeight = 0.0) {
  A a{};
  a.id = id;
  a.mode = mode;
  a.alternatives = std::move(alts);
  a.num_alternatives = static_cast<std::int16_t>(a.alternatives.size());
  a.null_hypothesis = null;
  a.null_weight = nullWeight;
  return a;
}

factor_batch_t batch(const std::string& sender, std::int64_t seq, std::vector<factor_t> fs,
                     std::vector<A> amb = {}, std::vector<std::int64_t> remove = {}) {
  factor_batch_t b = test::batch(sender, seq, std::move(fs), std::move(remove));
  b.ambiguous = std::move(amb);
  b.num_ambiguous = static_cast<std::int16_t>(b.ambiguous.size());
  return b;
}

using test::encode;

struct Fixture {
  std::vector<loopd::error_t> errors;
  std::vector<status_t> statuses;
  std::vector<estimate_t> estimates;
  Publisher pub;
  Engine engine;
  std::int64_t seq = 0, id = 0;
  Fixture(const std::string& solver, Journal* journal = nullptr, int maxHypotheses = 10)
      : pub(Channels::withPrefix("T_"),
            [this](const std::string& ch, const std::vector<uint8_t>& b) {
              const int n = static_cast<int>(b.size());
              if (ch == "T_ERROR") {
                loopd::error_t m;
                m.decode(b.data(), 0, n);
                errors.push_back(m);
              }
              if (ch == "T_STATUS") {
                status_t m{};
                const int used = m.decode(b.data(), 0, n);
                EXPECT_EQ(used, n) << "status decode";
                statuses.push_back(m);
              }
              if (ch == "T_ESTIMATE") {
                estimate_t m;
                m.decode(b.data(), 0, n);
                estimates.push_back(m);
              }
            }),
        engine(options(solver, maxHypotheses), pub, journal) {}
  static EngineOptions options(const std::string& solver, int k) {
    EngineOptions o;
    o.solver = solver;
    o.publishEvery = 0;
    o.maxHypotheses = k;
    return o;
  }
  void send(const factor_batch_t& b) {
    engine.post({"T_FACTORS", encode(b)});
    engine.step();
  }
  void command(int8_t c, const std::string& arg = "") {
    command_t m{};
    m.sender = "test";
    m.request_id = 7;
    m.command = c;
    m.argument = arg;
    engine.post({"T_COMMAND", encode(m)});
    engine.step();
  }
  /// A 4 m square driven once (16 steps, a quarter turn every 4): pose 16 is back at pose 0.
  /// `info`: odometry information of x, y (θ: 10×).
  void square(double info = 100, int steps = 16) {
    for (int i = 0; i < steps; ++i)
      send(batch("fe", ++seq,
                 {odo(id++, 0, i, i + 1, {1, 0, (i % 4 == 3) ? M_PI / 2 : 0.0}, info)}));
  }
  /// The reply to REQUEST_STATUS (a periodic status may follow it).
  /// The reply to REQUEST_STATUS (a periodic status may follow it), its decision chunks merged.
  status_t fullStatus() {
    const size_t from = statuses.size();
    command(command_t::REQUEST_STATUS);
    status_t out{};
    int chunks = 0;
    for (size_t i = from; i < statuses.size(); ++i) {
      const status_t& x = statuses[i];
      if (x.request_id != 7 || !x.decisions_full) continue;
      if (chunks == 0)
        out = x;
      else
        out.decisions.insert(out.decisions.end(), x.decisions.begin(), x.decisions.end());
      EXPECT_EQ(x.decisions_chunk_index, chunks);
      ++chunks;
    }
    if (chunks == 0)
      ADD_FAILURE() << "no reply to REQUEST_STATUS";
    else
      EXPECT_EQ(chunks, out.decisions_chunk_count);
    out.num_decisions = static_cast<std::int16_t>(std::min<size_t>(out.decisions.size(), 32767));
    return out;
  }
  const loop_decision_t* decision(const status_t& s, std::int64_t gid) const {
    for (const auto& d : s.decisions)
      if (d.ambiguous && d.factor_id == gid) return &d;
    return nullptr;
  }
  std::vector<double> pose(std::int64_t i) {
    std::vector<double> out;
    EXPECT_TRUE(
        engine.commonFramePose(makeKey(0, KeyKind::Pose, static_cast<std::uint64_t>(i)), out));
    return out;
  }
};

double maxDiff(Fixture& a, Fixture& b, int poses) {
  double d = 0;
  for (int i = 0; i <= poses; ++i) {
    const auto x = a.pose(i), y = b.pose(i);
    if (x.size() != 3 || y.size() != 3) return 1e9;
    d = std::max(
        {d, std::hypot(x[0] - y[0], x[1] - y[1]), std::abs(std::remainder(x[2] - y[2], 2 * M_PI))});
  }
  return d;
}

// SWITCH_SOLVER to isam2 and back to mh keeps every group and, per group id, its choice.
void expectSwitchRoundTripKeeps(Fixture& f,
                                const std::vector<std::pair<std::int64_t, int>>& choices) {
  f.command(command_t::SWITCH_SOLVER, "isam2");
  status_t s = f.fullStatus();
  EXPECT_EQ(s.solver, "isam2");
  EXPECT_EQ(s.ambiguous, static_cast<int>(choices.size()));
  f.command(command_t::SWITCH_SOLVER, "mh");
  f.command(command_t::OPTIMIZE);
  s = f.fullStatus();
  EXPECT_EQ(s.ambiguous, static_cast<int>(choices.size()));
  for (const auto& [id, alternative] : choices) {
    ASSERT_NE(f.decision(s, id), nullptr) << id;
    EXPECT_EQ(f.decision(s, id)->alternative, alternative) << id;
  }
}

// A journal replayed against the run that wrote it: each group's choice, chi2 and the poses
// (x, y of each, in the same order).
void expectResumedAsWritten(const Fixture& g, const status_t& s, const status_t& first,
                            std::initializer_list<std::int64_t> groups,
                            const std::vector<std::vector<double>>& resumed,
                            const std::vector<std::vector<double>>& written) {
  for (std::int64_t gid : groups) {
    ASSERT_NE(g.decision(s, gid), nullptr);
    EXPECT_EQ(g.decision(s, gid)->alternative, g.decision(first, gid)->alternative);
  }
  EXPECT_NEAR(s.chi2, first.chi2, 1e-6 * (1 + first.chi2));
  ASSERT_EQ(resumed.size(), written.size());
  for (size_t n = 0; n < resumed.size(); ++n) {
    ASSERT_EQ(resumed[n].size(), 3u);
    EXPECT_NEAR(resumed[n][0], written[n][0], 1e-6);
    EXPECT_NEAR(resumed[n][1], written[n][1], 1e-6);
  }
}

// --- validation ---------------------------------------------------------------------------

TEST(AmbiguousValidation, WellFormedGroupsPass) {
  FactorBatchValidator v;
  EXPECT_TRUE(v.check(batch("a", 1, {},
                            {group(1, A::MULTI_ASSOCIATION,
                                   {closure(0, 9, 0, {0, 0, 0}), closure(0, 9, 4, {0, 0, 0})})}))
                  .empty());
  EXPECT_TRUE(v.check(batch("a", 1, {},
                            {group(1, A::MULTI_MEASUREMENT,
                                   {closure(0, 9, 0, {0, 0, 0}), closure(0, 9, 0, {1, 0, 0})})}))
                  .empty());
  EXPECT_TRUE(
      v.check(batch("a", 1, {},
                    {group(1, A::MULTI_MEASUREMENT, {closure(0, 9, 0, {0, 0, 0})}, true, 2.5)}))
          .empty());
  // Inter-robot alternatives are well-formed; whether their robots share a frame is a
  // contextual check (AmbiguousInterRobot tests).
  factor_t inter = closure(0, 9, 4, {0, 0, 0});
  inter.keys[1].robot = 2;
  EXPECT_TRUE(v.check(batch("a", 1, {},
                            {group(1, A::MULTI_ASSOCIATION, {closure(0, 9, 0, {0, 0, 0}), inter})}))
                  .empty());
}

TEST(AmbiguousValidation, EachBadGroupGetsItsCode) {
  FactorBatchValidator v;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  struct Case {
    const char* what;
    std::function<void(A&)> mutate;
    int8_t code;
  };
  const std::vector<Case> cases = {
      {"mode 0", [](A& a) { a.mode = 0; }, loopd::error_t::INVALID_FIELD},
      {"one alternative, no null",
       [](A& a) {
         a.alternatives.resize(1);
         a.num_alternatives = 1;
       },
       loopd::error_t::INVALID_FIELD},
      {"no alternative, null",
       [](A& a) {
         a.alternatives.clear();
         a.num_alternatives = 0;
         a.null_hypothesis = true;
       },
       loopd::error_t::INVALID_FIELD},
      {"17 alternatives",
       [](A& a) {
         a.alternatives.clear();
         for (int i = 0; i < 17; ++i) a.alternatives.push_back(closure(0, 30, i, {0, 0, 0}));
         a.num_alternatives = 17;
       },
       loopd::error_t::LIMIT_EXCEEDED},
      {"null weight NaN",
       [&](A& a) {
         a.null_hypothesis = true;
         a.null_weight = nan;
       },
       loopd::error_t::NON_FINITE},
      {"null weight -1",
       [](A& a) {
         a.null_hypothesis = true;
         a.null_weight = -1;
       },
       loopd::error_t::INVALID_FIELD},
      {"NaN measurement", [&](A& a) { a.alternatives[1].measurement[0] = nan; },
       loopd::error_t::NON_FINITE},
      {"Inf noise",
       [](A& a) { a.alternatives[0].noise[0] = std::numeric_limits<double>::infinity(); },
       loopd::error_t::NON_FINITE},
      {"non-PD noise", [](A& a) { a.alternatives[1].noise = {1, 0, 0, -1, 0, 1}; },
       loopd::error_t::NOT_POSITIVE_DEFINITE},
      {"odometry role",
       [](A& a) {
         for (auto& f : a.alternatives) f.role = factor_t::ROLE_ODOMETRY;
       },
       loopd::error_t::INVALID_FIELD},
      {"landmark key kind", [](A& a) { a.alternatives[1].keys[1].kind = loopd::key_t::LANDMARK; },
       loopd::error_t::WRONG_KEY_KIND},
      {"mixed types",
       [](A& a) {
         a.alternatives[1] =
             client::loopClosureFactor(KeyRef::pose(0, 9), KeyRef::pose(0, 4), client::Pose3{},
                                       Eigen::Matrix<double, 6, 6>::Identity());
       },
       loopd::error_t::INVALID_FIELD},
      {"association, different measurement", [](A& a) { a.alternatives[1].measurement[0] = 0.5; },
       loopd::error_t::INVALID_FIELD},
      {"association, different noise", [](A& a) { a.alternatives[1].noise[0] = 7; },
       loopd::error_t::INVALID_FIELD},
      {"association, same keys twice",
       [](A& a) { a.alternatives[1].keys = a.alternatives[0].keys; },
       loopd::error_t::INVALID_FIELD},
      {"measurement mode, different keys", [](A& a) { a.mode = A::MULTI_MEASUREMENT; },
       loopd::error_t::INVALID_FIELD},
      {"negative id", [](A& a) { a.id = -4; }, loopd::error_t::INVALID_FIELD},
  };
  for (const auto& c : cases) {
    A a =
        group(3, A::MULTI_ASSOCIATION, {closure(0, 9, 0, {0, 0, 0}), closure(0, 9, 4, {0, 0, 0})});
    c.mutate(a);
    const auto issues = v.check(batch("a", 1, {}, {a}));
    ASSERT_FALSE(issues.empty()) << c.what;
    bool found = false;
    for (const auto& is : issues) found |= is.code == c.code;
    EXPECT_TRUE(found) << c.what << ": " << issues[0].reason;
  }
  // A group's id shares the factor id space.
  auto dup = batch(
      "a", 1, {odo(3, 0, 0, 1, {1, 0, 0})},
      {group(3, A::MULTI_ASSOCIATION, {closure(0, 9, 0, {0, 0, 0}), closure(0, 9, 4, {0, 0, 0})})});
  EXPECT_EQ(v.check(dup).at(0).code, loopd::error_t::DUPLICATE_FACTOR_ID);
  // Alternatives count as items.
  std::vector<factor_t> many;
  for (int i = 0; i < 190; ++i) many.push_back(odo(100 + i, 0, i, i + 1, {1, 0, 0}));
  std::vector<factor_t> alts;
  for (int i = 0; i < 11; ++i) alts.push_back(closure(0, 300, i, {0, 0, 0}));
  EXPECT_EQ(v.check(batch("a", 1, many, {group(1, A::MULTI_ASSOCIATION, alts)})).at(0).code,
            loopd::error_t::LIMIT_EXCEEDED);
}

TEST(AmbiguousValidation, BadBatchesGiveErrorsAndChangeNothing) {
  for (const std::string solver : {"mh", "isam2"}) {
    Fixture f(solver);
    f.square();
    const status_t before = f.fullStatus();
    const size_t errorsBefore = f.errors.size();
    const factor_t good = odo(500, 0, 16, 17, {1, 0, 0});
    // A valid factor with an invalid group: nothing of the batch is applied.
    A bad = group(501, A::MULTI_ASSOCIATION,
                  {closure(0, 16, 0, {0, 0, 0}), closure(0, 16, 4, {0.5, 0, 0})});
    f.send(batch("fe", ++f.seq, {good}, {bad}));
    // Wrong variable type: robot 0 has SE2 poses.
    A se3 =
        group(502, A::MULTI_MEASUREMENT,
              {client::loopClosureFactor(KeyRef::pose(0, 16), KeyRef::pose(0, 0), client::Pose3{},
                                         Eigen::Matrix<double, 6, 6>::Identity() * 10),
               client::loopClosureFactor(KeyRef::pose(0, 16), KeyRef::pose(0, 0), client::Pose3{},
                                         Eigen::Matrix<double, 6, 6>::Identity() * 20)});
    f.send(batch("fe", ++f.seq, {}, {se3}));
    // Removal of an id never used, and a duplicate of a used id.
    f.send(batch("fe", ++f.seq, {}, {}, {9999}));
    f.send(batch("fe", ++f.seq, {},
                 {group(2, A::MULTI_ASSOCIATION,
                        {closure(0, 16, 0, {0, 0, 0}), closure(0, 16, 4, {0, 0, 0})})}));
    ASSERT_GE(f.errors.size(), errorsBefore + 4) << solver;
    EXPECT_EQ(f.errors[errorsBefore].factor_id, 501);
    EXPECT_EQ(f.errors[errorsBefore].code, loopd::error_t::INVALID_FIELD);
    EXPECT_NE(f.errors[errorsBefore].reason.find("MULTI_ASSOCIATION"), std::string::npos)
        << f.errors[errorsBefore].reason;
    bool wrongDim = false, unknownId = false, dupId = false;
    for (size_t i = errorsBefore; i < f.errors.size(); ++i) {
      wrongDim |=
          f.errors[i].code == loopd::error_t::WRONG_DIMENSION && f.errors[i].factor_id == 502;
      unknownId |=
          f.errors[i].code == loopd::error_t::UNKNOWN_FACTOR_ID && f.errors[i].factor_id == 9999;
      dupId |=
          f.errors[i].code == loopd::error_t::DUPLICATE_FACTOR_ID && f.errors[i].factor_id == 2;
    }
    EXPECT_TRUE(wrongDim && unknownId && dupId) << solver;
    const status_t after = f.fullStatus();
    EXPECT_EQ(after.poses, before.poses) << solver;
    EXPECT_EQ(after.factors, before.factors) << solver;
    EXPECT_EQ(after.ambiguous, 0) << solver;
    EXPECT_EQ(after.batches_rejected, before.batches_rejected + 4) << solver;
    EXPECT_DOUBLE_EQ(after.chi2, before.chi2) << solver;
  }
}

TEST(AmbiguousEngine, GroupOverUnknownPoseIsHeldThenApplied) {
  Fixture f("mh");
  f.square(100, 12);
  // Pose 16 does not exist yet: the group waits for it.
  f.send(batch("lc", 1, {},
               {group(1, A::MULTI_ASSOCIATION,
                      {closure(0, 16, 0, {0, 0, 0}), closure(0, 16, 8, {0, 0, 0})}, true)}));
  EXPECT_EQ(f.statuses.back().batches_held, 1);
  EXPECT_EQ(f.statuses.back().ambiguous, 0);
  for (int i = 12; i < 16; ++i)
    f.send(batch("fe", ++f.seq, {odo(f.id++, 0, i, i + 1, {1, 0, (i % 4 == 3) ? M_PI / 2 : 0.0})}));
  const status_t s = f.fullStatus();
  EXPECT_EQ(s.batches_held, 0);
  EXPECT_EQ(s.ambiguous, 1);
  ASSERT_NE(f.decision(s, 1), nullptr);
  EXPECT_EQ(f.decision(s, 1)->alternative, 0);
  EXPECT_TRUE(f.errors.empty());
}

// --- mh through the engine ----------------------------------------------------------------

TEST(AmbiguousEngine, MhPicksTheTrueAlternativeAndEqualsTheOutlierFreeOptimum) {
  // Slightly wrong odometry, so the closure moves things.
  Fixture f("mh"), ref("isam2");
  for (Fixture* x : {&f, &ref})
    for (int i = 0; i < 16; ++i)
      x->send(
          batch("fe", ++x->seq,
                {odo(x->id++, 0, i, i + 1, {1.03, 0.01, (i % 4 == 3) ? M_PI / 2 + 0.02 : 0.0})}));
  // Back at the start: pose 0 (true), the opposite corner 8 or the next corner 4 (decoys), or none.
  f.send(batch("lc", 1, {},
               {group(40, A::MULTI_ASSOCIATION,
                      {closure(0, 16, 8, {0, 0, 0}), closure(0, 16, 0, {0, 0, 0}),
                       closure(0, 16, 4, {0, 0, 0})},
                      true)}));
  ref.send(batch("lc", 1, {closure(0, 16, 0, {0, 0, 0}, 40)}));
  f.command(command_t::OPTIMIZE);
  ref.command(command_t::OPTIMIZE);
  EXPECT_TRUE(f.errors.empty()) << f.errors[0].reason;
  const status_t s = f.fullStatus();
  EXPECT_EQ(s.solver, "mh");
  EXPECT_EQ(s.ambiguous, 1);
  EXPECT_EQ(s.factors, ref.fullStatus().factors - 1);  // the closure is a group here
  EXPECT_EQ(s.live_hypotheses, 1);
  EXPECT_EQ(s.undecided_ambiguous, 0);
  ASSERT_EQ(s.num_hypotheses, 1);
  EXPECT_EQ(s.hypotheses[0].rank, 0);
  EXPECT_EQ(s.hypotheses[0].num_choices, 0);  // nothing undecided
  const loop_decision_t* d = f.decision(s, 40);
  ASSERT_NE(d, nullptr);
  EXPECT_EQ(d->sender, "lc");
  EXPECT_EQ(d->alternative, 1);
  EXPECT_TRUE(d->accepted);
  EXPECT_DOUBLE_EQ(d->weight, 1.0);
  EXPECT_LT(maxDiff(f, ref, 16), 1e-6);
  EXPECT_NEAR(s.chi2, ref.statuses.back().chi2, 1e-6 * (1 + s.chi2));
  EXPECT_GT(s.chi2, 1e-3);  // the closure did pull
}

TEST(AmbiguousEngine, UndecidedHypothesesStatusRequestAndLaterData) {
  // Weak odometry: two candidate measurements 0.6 m apart both fit at first.
  Fixture f("mh");
  f.square(1.0);
  f.send(batch("lc", 1, {},
               {group(7, A::MULTI_MEASUREMENT,
                      {closure(0, 16, 0, {0, 0, 0}), closure(0, 16, 0, {0.6, 0, 0})})}));
  status_t s = f.statuses.back();
  EXPECT_EQ(s.live_hypotheses, 2);
  EXPECT_EQ(s.undecided_ambiguous, 1);
  ASSERT_EQ(s.num_hypotheses, 2);
  for (int r = 0; r < 2; ++r) {
    EXPECT_EQ(s.hypotheses[r].rank, r);
    ASSERT_EQ(s.hypotheses[r].num_choices, 1);
    EXPECT_EQ(s.hypotheses[r].choices[0].sender, "lc");
    EXPECT_EQ(s.hypotheses[r].choices[0].ambiguous_id, 7);
  }
  EXPECT_LE(s.hypotheses[0].score, s.hypotheses[1].score);
  EXPECT_NE(s.hypotheses[0].choices[0].alternative, s.hypotheses[1].choices[0].alternative);
  // The decision reports the best hypothesis's choice, weight = share of hypotheses agreeing.
  const status_t full = f.fullStatus();
  ASSERT_NE(f.decision(full, 7), nullptr);
  EXPECT_EQ(f.decision(full, 7)->alternative, s.hypotheses[0].choices[0].alternative);
  EXPECT_DOUBLE_EQ(f.decision(full, 7)->weight, 0.5);

  // REQUEST_HYPOTHESES: full snapshots of rank 0 and 1 with their request id, then a status.
  f.estimates.clear();
  f.command(command_t::REQUEST_HYPOTHESES, "3");
  std::map<int, std::map<std::int64_t, std::vector<double>>> byRank;
  for (const auto& e : f.estimates) {
    EXPECT_EQ(e.request_id, 7);
    EXPECT_TRUE(e.full_snapshot);
    for (int i = 0; i < e.num_poses; ++i) byRank[e.hypothesis][e.pose_indices[i]] = e.poses[i];
  }
  ASSERT_EQ(byRank.size(), 2u);
  ASSERT_EQ(byRank[0].size(), 17u);
  ASSERT_EQ(byRank[1].size(), 17u);
  // Pose 16 relative to pose 0 differs by the two measurements (0.6 m along x of pose 16).
  const double gap =
      std::hypot(byRank[0][16][0] - byRank[1][16][0], byRank[0][16][1] - byRank[1][16][1]);
  EXPECT_GT(gap, 0.3);
  const status_t* reply = nullptr;
  for (const auto& x : f.statuses)
    if (x.request_id == 7) reply = &x;
  ASSERT_NE(reply, nullptr);
  EXPECT_EQ(reply->num_hypotheses, 2);
  EXPECT_EQ(reply->live_hypotheses, 2);
  f.command(command_t::REQUEST_HYPOTHESES, "x");
  EXPECT_EQ(f.errors.back().code, loopd::error_t::COMMAND_FAILED);
  EXPECT_EQ(f.errors.back().request_id, 7);

  // A plain closure agreeing with the first measurement decides it.
  f.send(batch("lc", 2, {closure(0, 16, 0, {0, 0, 0}, 8)}));
  f.command(command_t::OPTIMIZE);
  s = f.fullStatus();
  EXPECT_EQ(s.live_hypotheses, 1);
  EXPECT_EQ(s.undecided_ambiguous, 0);
  ASSERT_NE(f.decision(s, 7), nullptr);
  EXPECT_EQ(f.decision(s, 7)->alternative, 0);
  EXPECT_DOUBLE_EQ(f.decision(s, 7)->weight, 1.0);
}

TEST(AmbiguousEngine, MaxHypothesesBoundsLiveHypotheses) {
  Fixture f("mh", nullptr, 1);
  f.square(1.0);
  f.send(batch("lc", 1, {},
               {group(7, A::MULTI_MEASUREMENT,
                      {closure(0, 16, 0, {0, 0, 0}), closure(0, 16, 0, {0.6, 0, 0})})}));
  EXPECT_EQ(f.statuses.back().live_hypotheses, 1);
  EXPECT_EQ(f.statuses.back().undecided_ambiguous, 0);
}

// --- other variants: flattened -------------------------------------------------------------

TEST(AmbiguousEngine, OtherSolversFlattenTheAlternatives) {
  Fixture plain("isam2"), robust("dcs");
  for (Fixture* x : {&plain, &robust}) {
    x->square();
    x->send(batch("lc", 1, {},
                  {group(40, A::MULTI_ASSOCIATION,
                         {closure(0, 16, 0, {0, 0, 0}), closure(0, 16, 8, {0, 0, 0})}, true)}));
    x->command(command_t::OPTIMIZE);
    EXPECT_TRUE(x->errors.empty());
    const status_t s = x->fullStatus();
    EXPECT_EQ(s.ambiguous, 1);
    EXPECT_EQ(s.factors, 17);  // 16 odometry + the first pose's prior: alternatives not counted
    EXPECT_EQ(s.live_hypotheses, 1);
    EXPECT_EQ(s.num_hypotheses, 0);
    ASSERT_NE(x->decision(s, 40), nullptr);
  }
  // Plain least squares takes both: the decoy drags the square (chi2 far above the optimum's 0).
  EXPECT_GT(plain.statuses.back().chi2, 10.0);
  // A robust kernel down-weights the decoy: alternative 0 is the one it keeps.
  const status_t s = robust.fullStatus();
  EXPECT_EQ(robust.decision(s, 40)->alternative, 0);
  EXPECT_TRUE(robust.decision(s, 40)->accepted);
  // Removing the group removes every alternative.
  for (Fixture* x : {&plain, &robust}) {
    x->send(batch("lc", 2, {}, {}, {40}));
    x->command(command_t::OPTIMIZE);
    const status_t t = x->fullStatus();
    EXPECT_EQ(t.ambiguous, 0);
    EXPECT_EQ(x->decision(t, 40), nullptr);
    EXPECT_LT(t.chi2, 1e-6);
    // The id stays used.
    x->send(batch("lc", 3, {}, {}, {40}));
    EXPECT_EQ(x->errors.back().code, loopd::error_t::UNKNOWN_FACTOR_ID);
  }
}

TEST(AmbiguousEngine, MhRemovalRebuildsWithoutTheGroup) {
  Fixture f("mh"), ref("mh");
  for (Fixture* x : {&f, &ref})
    for (int i = 0; i < 16; ++i)
      x->send(
          batch("fe", ++x->seq,
                {odo(x->id++, 0, i, i + 1, {1.03, 0.01, (i % 4 == 3) ? M_PI / 2 + 0.02 : 0.0})}));
  f.send(batch("lc", 1, {},
               {group(1, A::MULTI_ASSOCIATION,
                      {closure(0, 16, 0, {0, 0, 0}), closure(0, 16, 8, {0, 0, 0})})}));
  f.send(
      batch("lc", 2, {},
            {group(2, A::MULTI_MEASUREMENT,
                   {closure(0, 12, 0, {4, 0, M_PI / 2}), closure(0, 12, 0, {6, 0, M_PI / 2})})}));
  ref.send(
      batch("lc", 2, {},
            {group(2, A::MULTI_MEASUREMENT,
                   {closure(0, 12, 0, {4, 0, M_PI / 2}), closure(0, 12, 0, {6, 0, M_PI / 2})})}));
  f.send(batch("lc", 3, {}, {}, {1}));
  EXPECT_TRUE(f.errors.empty()) << f.errors[0].reason;
  f.command(command_t::OPTIMIZE);
  ref.command(command_t::OPTIMIZE);
  const status_t s = f.fullStatus();
  EXPECT_EQ(s.ambiguous, 1);
  EXPECT_EQ(f.decision(s, 1), nullptr);
  ASSERT_NE(f.decision(s, 2), nullptr);
  EXPECT_EQ(f.decision(s, 2)->alternative, 0);
  EXPECT_LT(maxDiff(f, ref, 16), 1e-6);
}

TEST(AmbiguousEngine, SwitchSolverKeepsTheGroups) {
  Fixture f("isam2");
  for (int i = 0; i < 16; ++i)
    f.send(batch("fe", ++f.seq,
                 {odo(f.id++, 0, i, i + 1, {1.03, 0.01, (i % 4 == 3) ? M_PI / 2 + 0.02 : 0.0})}));
  f.send(batch("lc", 1, {},
               {group(1, A::MULTI_ASSOCIATION,
                      {closure(0, 16, 8, {0, 0, 0}), closure(0, 16, 0, {0, 0, 0})}, true)}));
  const double flatChi2 = f.fullStatus().chi2;
  f.command(command_t::SWITCH_SOLVER, "mh");
  f.command(command_t::OPTIMIZE);
  status_t s = f.fullStatus();
  EXPECT_EQ(s.solver, "mh");
  EXPECT_EQ(s.ambiguous, 1);
  ASSERT_NE(f.decision(s, 1), nullptr);
  EXPECT_EQ(f.decision(s, 1)->alternative, 1);
  EXPECT_LT(s.chi2, flatChi2);  // the decoy no longer pulls
  // A group added under mh survives the way back.
  f.send(
      batch("lc", 2, {},
            {group(2, A::MULTI_MEASUREMENT,
                   {closure(0, 12, 0, {4, 0, M_PI / 2}), closure(0, 12, 0, {6, 0, M_PI / 2})})}));
  expectSwitchRoundTripKeeps(f, {{1, 1}, {2, 0}});
  EXPECT_TRUE(f.errors.empty());
}

TEST(AmbiguousEngine, JournalResumeReplaysTheGroups) {
  const std::string path =
      ::testing::TempDir() + "/" + std::to_string(getpid()) + "_amb_journal.lcmlog";
  std::remove(path.c_str());
  status_t first;
  std::vector<std::vector<double>> poses;
  {
    Journal j(path, false);
    Fixture f("mh", &j);
    for (int i = 0; i < 16; ++i)
      f.send(batch("fe", ++f.seq,
                   {odo(f.id++, 0, i, i + 1, {1.03, 0.01, (i % 4 == 3) ? M_PI / 2 + 0.02 : 0.0})}));
    f.send(batch("lc", 1, {},
                 {group(1, A::MULTI_ASSOCIATION,
                        {closure(0, 16, 8, {0, 0, 0}), closure(0, 16, 0, {0, 0, 0})}, true)}));
    f.send(
        batch("lc", 2, {},
              {group(2, A::MULTI_MEASUREMENT,
                     {closure(0, 12, 0, {4, 0, M_PI / 2}), closure(0, 12, 0, {6, 0, M_PI / 2})})}));
    f.send(batch("lc", 3, {},
                 {group(3, A::MULTI_ASSOCIATION,
                        {closure(0, 14, 2, {0, 0, 0}), closure(0, 14, 6, {0, 0, 0})}, true)}));
    f.send(batch("lc", 4, {}, {}, {3}));
    f.send(batch("lc", 5, {}, {group(-1, A::MULTI_ASSOCIATION, {})}));  // refused: not journaled
    f.command(command_t::OPTIMIZE);
    first = f.fullStatus();
    for (int i = 0; i <= 16; ++i) poses.push_back(f.pose(i));
    EXPECT_EQ(j.written(), 20);
  }
  Fixture g("mh");
  g.engine.replay(path, false, nullptr);
  const status_t s = g.fullStatus();
  EXPECT_EQ(s.ambiguous, 2);
  EXPECT_EQ(s.ambiguous, first.ambiguous);
  EXPECT_EQ(s.factors, first.factors);
  std::vector<std::vector<double>> resumed;
  for (int i = 0; i <= 16; ++i) resumed.push_back(g.pose(i));
  expectResumedAsWritten(g, s, first, {1, 2}, resumed, poses);
  EXPECT_EQ(g.decision(s, 1)->alternative, 1);
  // The ids are known after the resume: removal of the replayed removal's id is refused.
  g.send(batch("lc", 6, {}, {}, {3}));
  EXPECT_EQ(g.errors.back().code, loopd::error_t::UNKNOWN_FACTOR_ID);
  // Resuming the same journal on another solver flattens the same groups.
  Fixture h("isam2");
  h.engine.replay(path, false, nullptr);
  EXPECT_EQ(h.fullStatus().ambiguous, 2);
  EXPECT_TRUE(h.errors.empty());
  std::remove(path.c_str());
}

// --- inter-robot alternatives --------------------------------------------------------------

factor_t inter(int ra, std::int64_t a, int rb, std::int64_t b, Pose2 z, std::int64_t id = 0) {
  factor_t f = client::loopClosureFactor(KeyRef::pose(ra, a), KeyRef::pose(rb, b), z, kInfo);
  f.id = id;
  return f;
}

// A certain link between two robots: sent with robust "none", it joins their frames on its own
// under every solver (under a robust one a closure of default handling waits for a second that
// agrees, server/engine_closures.cpp).
factor_t trustedLink(factor_t f) {
  f.robust = "none";
  return f;
}

std::vector<double> robotPose(Fixture& f, int robot, std::int64_t i) {
  std::vector<double> out;
  EXPECT_TRUE(f.engine.commonFramePose(
      makeKey(static_cast<std::uint32_t>(robot), KeyKind::Pose, static_cast<std::uint64_t>(i)),
      out));
  return out;
}

/// Largest common-frame difference over robot 0's poses 0..16 and robot 1's poses 0..8.
double maxDiffTwoRobots(Fixture& a, Fixture& b) {
  double d = 0;
  for (int r = 0; r < 2; ++r)
    for (int i = 0; i <= (r == 0 ? 16 : 8); ++i) {
      const auto x = robotPose(a, r, i), y = robotPose(b, r, i);
      if (x.size() != 3 || y.size() != 3) return 1e9;
      d = std::max({d, std::hypot(x[0] - y[0], x[1] - y[1]),
                    std::abs(std::remainder(x[2] - y[2], 2 * M_PI))});
    }
  return d;
}

/// Robot 1 (sender "b") seen from robot 0 (sender "a"), in the common frame.
SE2 relative(Fixture& f, std::int64_t i0, std::int64_t i1) {
  const auto a = robotPose(f, 0, i0), b = robotPose(f, 1, i1);
  if (a.size() != 3 || b.size() != 3) return SE2(1e9, 1e9, 0);
  return SE2(a[0], a[1], a[2]).between(SE2(b[0], b[1], b[2]));
}

int anchoredFactors(const Fixture& f) {
  int n = 0;
  for (const auto& x : f.engine.backend().graph().factors())
    n += x && std::string(x->typeName()) == "AnchoredBetweenSE2";
  return n;
}

/// Robot 0 ("a") drives the 4 m square (poses 0..16); robot 1 ("b") drives 8 m along x, 2 m to
/// the left of robot 0's start (poses 0..8); both odometries slightly wrong. With `join`, "b"
/// then sends a certain inter-robot closure: robot 1's pose 0 is 2 m left of robot 0's pose 0.
void twoRobots(Fixture& x, bool join = true) {
  for (int i = 0; i < 16; ++i)
    x.send(batch("a", ++x.seq,
                 {odo(x.id++, 0, i, i + 1, {1.03, 0.01, (i % 4 == 3) ? M_PI / 2 + 0.02 : 0.0})}));
  for (int i = 0; i < 8; ++i)
    x.send(batch("b", i + 1, {odo(1000 + i, 1, i, i + 1, {0.97, -0.01, 0.01})}));
  if (join) x.send(batch("b", 9, {trustedLink(inter(0, 0, 1, 0, {0, 2, 0}, 2000))}));
}

/// Robot 0's pose 2 sees robot 1 2 m to its left: robot 1's pose 2 (true, alternative 1), its
/// pose 4 or pose 0, or robot 0's own pose 0 (decoys, one of them intra-robot), or none.
A interGroup(std::int64_t id) {
  return group(id, A::MULTI_ASSOCIATION,
               {inter(0, 2, 1, 4, {0, 2, 0}), inter(0, 2, 1, 2, {0, 2, 0}),
                closure(0, 2, 0, {0, 2, 0}), inter(0, 2, 1, 0, {0, 2, 0})},
               true);
}

TEST(AmbiguousInterRobot, MhPicksTheTrueInterRobotAlternative) {
  Fixture f("mh"), ref("isam2");
  for (Fixture* x : {&f, &ref}) twoRobots(*x);
  ASSERT_TRUE(f.engine.robotJoined(1));
  const int anchoredBefore = anchoredFactors(f);
  f.send(batch("lc", 1, {}, {interGroup(40)}));
  ref.send(batch("lc", 1, {inter(0, 2, 1, 2, {0, 2, 0}, 40)}));
  f.command(command_t::OPTIMIZE);
  ref.command(command_t::OPTIMIZE);
  ASSERT_TRUE(f.errors.empty()) << f.errors[0].reason;
  ASSERT_TRUE(ref.errors.empty()) << ref.errors[0].reason;
  const status_t s = f.fullStatus(), r = ref.fullStatus();
  EXPECT_EQ(s.solver, "mh");
  EXPECT_EQ(s.ambiguous, 1);
  EXPECT_EQ(s.robots_in_common_frame, 2);
  EXPECT_EQ(s.factors, r.factors - 1);  // the closure is a group here
  EXPECT_EQ(s.live_hypotheses, 1);
  EXPECT_EQ(s.undecided_ambiguous, 0);
  const loop_decision_t* d = f.decision(s, 40);
  ASSERT_NE(d, nullptr);
  EXPECT_EQ(d->sender, "lc");
  EXPECT_EQ(d->alternative, 1);
  EXPECT_TRUE(d->accepted);
  EXPECT_DOUBLE_EQ(d->weight, 1.0);
  // The best hypothesis holds the chosen alternative as an anchored factor, like the reference.
  EXPECT_EQ(anchoredFactors(f), anchoredBefore + 1);
  EXPECT_EQ(anchoredFactors(ref), anchoredBefore + 1);
  EXPECT_LT(maxDiffTwoRobots(f, ref), 1e-6);
  EXPECT_NEAR(s.chi2, r.chi2, 1e-6 * (1 + s.chi2));
  EXPECT_GT(s.chi2, 1e-3);  // the closure did pull
  const SE2 z = relative(f, 2, 2);
  EXPECT_NEAR(z.x, 0.0, 0.05);
  EXPECT_NEAR(z.y, 2.0, 0.05);

  // Removing the group (mh: a rebuild without it) gives the optimum without the closure.
  Fixture bare("isam2");
  twoRobots(bare);
  bare.command(command_t::OPTIMIZE);
  f.send(batch("lc", 2, {}, {}, {40}));
  f.command(command_t::OPTIMIZE);
  EXPECT_TRUE(f.errors.empty()) << f.errors[0].reason;
  const status_t t = f.fullStatus();
  EXPECT_EQ(t.ambiguous, 0);
  EXPECT_EQ(f.decision(t, 40), nullptr);
  EXPECT_EQ(anchoredFactors(f), anchoredBefore);
  EXPECT_LT(maxDiffTwoRobots(f, bare), 1e-6);
}

TEST(AmbiguousInterRobot, OtherSolversFlattenIntoAnchoredFactors) {
  Fixture plain("isam2"), robust("dcs");
  for (Fixture* x : {&plain, &robust}) {
    twoRobots(*x);
    const int anchoredBefore = anchoredFactors(*x);
    x->send(batch("lc", 1, {}, {interGroup(40)}));
    x->command(command_t::OPTIMIZE);
    ASSERT_TRUE(x->errors.empty()) << x->engine.backend().name() << ": " << x->errors[0].reason;
    const status_t s = x->fullStatus();
    EXPECT_EQ(s.ambiguous, 1);
    EXPECT_EQ(s.live_hypotheses, 1);
    EXPECT_EQ(s.num_hypotheses, 0);
    ASSERT_NE(x->decision(s, 40), nullptr);
    // The three inter-robot alternatives are ordinary anchored loop closures now.
    EXPECT_EQ(anchoredFactors(*x), anchoredBefore + 3);
  }
  // Plain least squares takes them all: the decoys drag both robots.
  EXPECT_GT(plain.fullStatus().chi2, 10.0);
  // A robust kernel keeps the true alternative, evaluated in the common frame.
  const status_t s = robust.fullStatus();
  EXPECT_EQ(robust.decision(s, 40)->alternative, 1);
  EXPECT_TRUE(robust.decision(s, 40)->accepted);
  const SE2 z = relative(robust, 2, 2);
  EXPECT_NEAR(z.x, 0.0, 0.1);
  EXPECT_NEAR(z.y, 2.0, 0.1);
  // Removing the group removes every alternative.
  for (Fixture* x : {&plain, &robust}) {
    const int anchoredWith = anchoredFactors(*x);
    x->send(batch("lc", 2, {}, {}, {40}));
    x->command(command_t::OPTIMIZE);
    EXPECT_TRUE(x->errors.empty());
    const status_t t = x->fullStatus();
    EXPECT_EQ(t.ambiguous, 0);
    EXPECT_EQ(anchoredFactors(*x), anchoredWith - 3);
  }
}

TEST(AmbiguousInterRobot, AlternativeAsFirstLinkIsRefusedWhole) {
  for (const std::string solver : {"mh", "isam2"}) {
    Fixture f(solver);
    twoRobots(f, /*join=*/false);
    const status_t before = f.fullStatus();
    EXPECT_EQ(before.robots, 2);
    EXPECT_EQ(before.robots_in_common_frame, 0);
    const size_t errorsBefore = f.errors.size();
    // A valid closure of robot 0 and the group: nothing of the batch is applied.
    f.send(batch("lc", 1, {closure(0, 16, 0, {0, 0, 0}, 50)}, {interGroup(40)}));
    ASSERT_EQ(f.errors.size(), errorsBefore + 1) << solver;
    const loopd::error_t& e = f.errors.back();
    EXPECT_EQ(e.sender, "lc");
    EXPECT_EQ(e.sequence, 1);
    EXPECT_EQ(e.factor_id, 40);
    EXPECT_EQ(e.code, loopd::error_t::INVALID_FIELD);
    EXPECT_EQ(e.channel, "T_FACTORS");
    EXPECT_NE(e.reason.find("joins robots 0 and 1"), std::string::npos) << e.reason;
    EXPECT_NE(e.reason.find("send a certain inter-robot loop closure"), std::string::npos)
        << e.reason;
    status_t after = f.fullStatus();
    EXPECT_EQ(after.poses, before.poses) << solver;
    EXPECT_EQ(after.factors, before.factors) << solver;
    EXPECT_EQ(after.loop_closures, before.loop_closures) << solver;
    EXPECT_EQ(after.ambiguous, 0) << solver;
    EXPECT_EQ(after.robots_in_common_frame, 0) << solver;
    EXPECT_EQ(after.batches_rejected, before.batches_rejected + 1) << solver;
    EXPECT_DOUBLE_EQ(after.chi2, before.chi2) << solver;
    EXPECT_FALSE(f.engine.robotJoined(0));
    EXPECT_FALSE(f.engine.robotJoined(1));

    // The server goes on: the certain link and the group in one batch are accepted (the
    // batch's own certain factor joins the robots first), and the ids were not consumed.
    f.send(batch("lc", 2, {inter(0, 0, 1, 0, {0, 2, 0}, 2000), closure(0, 16, 0, {0, 0, 0}, 50)},
                 {interGroup(40)}));
    f.command(command_t::OPTIMIZE);
    ASSERT_EQ(f.errors.size(), errorsBefore + 1) << solver << ": " << f.errors.back().reason;
    after = f.fullStatus();
    EXPECT_EQ(after.ambiguous, 1) << solver;
    EXPECT_EQ(after.robots_in_common_frame, 2) << solver;
    EXPECT_EQ(after.batches_accepted, before.batches_accepted + 1) << solver;
    ASSERT_NE(f.decision(after, 40), nullptr);
    if (solver == "mh") {
      EXPECT_EQ(f.decision(after, 40)->alternative, 1);
    }

    // Removing the only certain link in the batch that brings a group: refused again.
    f.send(batch(
        "lc", 3, {},
        {group(41, A::MULTI_MEASUREMENT,
               {inter(0, 6, 1, 4, {0, 0, -M_PI / 2}), inter(0, 6, 1, 4, {1.5, 0, -M_PI / 2})})},
        {2000}));
    ASSERT_EQ(f.errors.size(), errorsBefore + 2) << solver;
    EXPECT_EQ(f.errors.back().factor_id, 41);
    EXPECT_EQ(f.fullStatus().ambiguous, 1) << solver;
    EXPECT_EQ(f.fullStatus().batches_rejected, before.batches_rejected + 2) << solver;
    // A robot no certain factor ever joined.
    f.send(batch("lc", 4, {},
                 {group(42, A::MULTI_ASSOCIATION,
                        {inter(0, 6, 1, 4, {0, 0, 0}), inter(0, 6, 2, 4, {0, 0, 0})}, true)}));
    ASSERT_EQ(f.errors.size(), errorsBefore + 3) << solver;
    EXPECT_NE(f.errors.back().reason.find("alternative 1 joins robots 0 and 2"), std::string::npos)
        << f.errors.back().reason;
  }
}

TEST(AmbiguousInterRobot, JournalResumeSwitchSolverAndRemoval) {
  const std::string path =
      ::testing::TempDir() + "/" + std::to_string(getpid()) + "_amb_inter_journal.lcmlog";
  std::remove(path.c_str());
  status_t first;
  std::vector<std::vector<double>> poses;
  {
    Journal j(path, false);
    Fixture f("mh", &j);
    twoRobots(f);
    f.send(batch("lc", 1, {}, {interGroup(40)}));
    // Robot 1's pose 4 seen from robot 0's pose 6: 0 m (true) or 1.5 m ahead.
    f.send(batch(
        "lc", 2, {},
        {group(41, A::MULTI_MEASUREMENT,
               {inter(0, 6, 1, 4, {0, 0, -M_PI / 2}), inter(0, 6, 1, 4, {1.5, 0, -M_PI / 2})})}));
    f.send(batch("lc", 3, {},
                 {group(42, A::MULTI_ASSOCIATION,
                        {inter(0, 4, 1, 6, {0, 0, 0}), inter(0, 4, 1, 8, {0, 0, 0})}, true)}));
    f.send(batch("lc", 4, {}, {}, {42}));
    // Refused (robot 2 is in no common frame): not journaled.
    f.send(batch("lc", 5, {},
                 {group(43, A::MULTI_ASSOCIATION,
                        {inter(0, 6, 1, 4, {0, 0, 0}), inter(0, 6, 2, 4, {0, 0, 0})}, true)}));
    ASSERT_EQ(f.errors.size(), 1u);
    EXPECT_EQ(f.errors[0].factor_id, 43);
    f.command(command_t::OPTIMIZE);
    first = f.fullStatus();
    EXPECT_EQ(first.ambiguous, 2);
    ASSERT_NE(f.decision(first, 40), nullptr);
    ASSERT_NE(f.decision(first, 41), nullptr);
    EXPECT_EQ(f.decision(first, 40)->alternative, 1);
    EXPECT_EQ(f.decision(first, 41)->alternative, 0);
    for (int r = 0; r < 2; ++r)
      for (int i = 0; i <= (r == 0 ? 16 : 8); ++i) poses.push_back(robotPose(f, r, i));
    EXPECT_EQ(j.written(), 16 + 9 + 4);
  }
  // Resume: one round replays the certain link and the groups that need it.
  Fixture g("mh");
  g.engine.replay(path, false, nullptr);
  status_t s = g.fullStatus();
  EXPECT_TRUE(g.errors.empty()) << g.errors[0].reason;
  EXPECT_EQ(s.ambiguous, 2);
  EXPECT_EQ(s.factors, first.factors);
  EXPECT_EQ(s.robots_in_common_frame, 2);
  std::vector<std::vector<double>> resumed;
  for (int r = 0; r < 2; ++r)
    for (int i = 0; i <= (r == 0 ? 16 : 8); ++i) resumed.push_back(robotPose(g, r, i));
  expectResumedAsWritten(g, s, first, {40, 41}, resumed, poses);
  // Another solver on the same journal flattens the same groups.
  Fixture h("dcs");
  h.engine.replay(path, false, nullptr);
  EXPECT_TRUE(h.errors.empty()) << h.errors[0].reason;
  EXPECT_EQ(h.fullStatus().ambiguous, 2);

  // SWITCH_SOLVER both ways keeps the groups and their anchored alternatives.
  expectSwitchRoundTripKeeps(g, {{40, 1}, {41, 0}});
  // Removing a group after the resume, then one more under the (unchanged) link.
  g.send(batch("lc", 6, {}, {}, {41}));
  g.send(batch(
      "lc", 7, {},
      {group(44, A::MULTI_MEASUREMENT,
             {inter(0, 6, 1, 4, {1.5, 0, -M_PI / 2}), inter(0, 6, 1, 4, {0, 0, -M_PI / 2})})}));
  g.command(command_t::OPTIMIZE);
  EXPECT_TRUE(g.errors.empty()) << g.errors[0].reason;
  s = g.fullStatus();
  EXPECT_EQ(s.ambiguous, 2);
  EXPECT_EQ(g.decision(s, 41), nullptr);
  ASSERT_NE(g.decision(s, 44), nullptr);
  EXPECT_EQ(g.decision(s, 44)->alternative, 1);
  std::remove(path.c_str());
}
TEST(AmbiguousInterRobot, RemovingTheCertainLinkKeepsTheGroupSolvable) {
  for (const std::string solver : {"mh", "isam2"}) {
    Fixture f(solver);
    twoRobots(f);
    f.send(batch("lc", 1, {}, {interGroup(40)}));
    // The only certain link goes: each robot roots its own group again; the group stays,
    // evaluated through the anchors, and does not count as a link.
    f.send(batch("b", 10, {}, {}, {2000}));
    f.command(command_t::OPTIMIZE);
    ASSERT_TRUE(f.errors.empty()) << solver << ": " << f.errors[0].reason;
    status_t s = f.fullStatus();
    EXPECT_EQ(s.ambiguous, 1) << solver;
    EXPECT_TRUE(std::isfinite(s.chi2) && s.chi2 >= 0.0) << solver;
    ASSERT_NE(f.decision(s, 40), nullptr);
    f.send(batch(
        "lc", 2, {},
        {group(41, A::MULTI_MEASUREMENT,
               {inter(0, 6, 1, 4, {0, 0, -M_PI / 2}), inter(0, 6, 1, 4, {1.5, 0, -M_PI / 2})})}));
    ASSERT_EQ(f.errors.size(), 1u) << solver;
    EXPECT_EQ(f.errors.back().factor_id, 41);
    // A new certain link joins them again: the group is accepted.
    f.send(batch("b", 11, {inter(0, 0, 1, 0, {0, 2, 0}, 2001)}));
    f.send(batch(
        "lc", 3, {},
        {group(41, A::MULTI_MEASUREMENT,
               {inter(0, 6, 1, 4, {0, 0, -M_PI / 2}), inter(0, 6, 1, 4, {1.5, 0, -M_PI / 2})})}));
    f.command(command_t::OPTIMIZE);
    EXPECT_EQ(f.errors.size(), 1u) << solver << ": " << f.errors.back().reason;
    s = f.fullStatus();
    EXPECT_EQ(s.ambiguous, 2) << solver;
    EXPECT_TRUE(std::isfinite(s.chi2)) << solver;
    if (solver == "mh") {
      ASSERT_NE(f.decision(s, 41), nullptr);
      EXPECT_EQ(f.decision(s, 41)->alternative, 0);
      EXPECT_EQ(f.decision(s, 40)->alternative, 1);
    }
  }
}

factor_t between3(int ra, std::int64_t a, int rb, std::int64_t b, Eigen::Vector3d t,
                  std::int8_t role, std::int64_t id = 0) {
  client::Pose3 z;
  z.t = t;
  factor_t f = client::loopClosureFactor(KeyRef::pose(ra, a), KeyRef::pose(rb, b), z,
                                         Eigen::Matrix<double, 6, 6>::Identity() * 100);
  f.id = id;
  f.role = role;
  return f;
}

TEST(AmbiguousInterRobot, Se3AlternativesGoThroughTheAnchorsToo) {
  const std::int8_t lc = factor_t::ROLE_LOOP_CLOSURE, od = factor_t::ROLE_ODOMETRY;
  Fixture f("mh"), ref("isam2");
  for (Fixture* x : {&f, &ref}) {
    for (int i = 0; i < 6; ++i)
      x->send(batch("a", i + 1, {between3(0, i, 0, i + 1, {1.0, 0.01, 0}, od, i)}));
    for (int i = 0; i < 6; ++i)
      x->send(batch("b", i + 1, {between3(1, i, 1, i + 1, {1.03, 0, 0.01}, od, 100 + i)}));
    x->send(batch("b", 7, {between3(0, 0, 1, 0, {0, 2, 0}, lc, 200)}));
  }
  // Robot 1's pose 4 seen from robot 0's pose 4: 2 m to the left (true) or also 1.5 m ahead.
  f.send(
      batch("lc", 1, {},
            {group(40, A::MULTI_MEASUREMENT,
                   {between3(0, 4, 1, 4, {1.5, 2, 0}, lc), between3(0, 4, 1, 4, {0, 2, 0}, lc)})}));
  ref.send(batch("lc", 1, {between3(0, 4, 1, 4, {0, 2, 0}, lc, 40)}));
  f.command(command_t::OPTIMIZE);
  ref.command(command_t::OPTIMIZE);
  ASSERT_TRUE(f.errors.empty()) << f.errors[0].reason;
  const status_t s = f.fullStatus();
  ASSERT_NE(f.decision(s, 40), nullptr);
  EXPECT_EQ(f.decision(s, 40)->alternative, 1);
  double d = 0;
  for (int r = 0; r < 2; ++r)
    for (int i = 0; i <= 6; ++i) {
      const auto x = robotPose(f, r, i), y = robotPose(ref, r, i);
      ASSERT_EQ(x.size(), 7u);
      ASSERT_EQ(y.size(), 7u);
      double dq = 0, dqFlipped = 0;  // quaternions up to sign
      for (size_t k = 0; k < 3; ++k) d = std::max(d, std::abs(x[k] - y[k]));
      for (size_t k = 3; k < 7; ++k) {
        dq = std::max(dq, std::abs(x[k] - y[k]));
        dqFlipped = std::max(dqFlipped, std::abs(x[k] + y[k]));
      }
      d = std::max(d, std::min(dq, dqFlipped));
    }
  EXPECT_LT(d, 1e-6);
  const auto a = robotPose(f, 0, 4), b = robotPose(f, 1, 4);
  EXPECT_NEAR(b[0] - a[0], 0.0, 0.15);  // odometry drift shared out; the decoy is 1.5 m off
  EXPECT_NEAR(b[1] - a[1], 2.0, 0.15);
  EXPECT_NEAR(s.chi2, ref.fullStatus().chi2, 1e-6 * (1 + s.chi2));
}

// --- the same as loopd-solve --solver mh --incremental -------------------------------------

std::vector<int> jsonInts(const std::string& path, const std::string& field) {
  std::stringstream ss;
  ss << std::ifstream(path).rdbuf();
  const std::string t = ss.str();
  std::vector<int> out;
  auto p = t.find("\"" + field + "\"");
  if (p == std::string::npos) return out;
  p = t.find('[', p);
  const auto e = t.find(']', p);
  std::stringstream list(t.substr(p + 1, e - p - 1));
  std::string item;
  while (std::getline(list, item, ',')) out.push_back(std::stoi(item));
  return out;
}

factor_t wireEdge(const io::Edge& e, bool alternative) {
  factor_t f{};
  f.type = factor_t::BETWEEN_SE2;
  const bool consecutive = e.to == e.from + 1 || e.from == e.to + 1;
  f.role = consecutive && !alternative ? factor_t::ROLE_ODOMETRY : factor_t::ROLE_LOOP_CLOSURE;
  f.keys = {client::wireKey(KeyRef::pose(0, e.from)), client::wireKey(KeyRef::pose(0, e.to))};
  f.num_keys = 2;
  f.measurement = {e.measurement[0], e.measurement[1], e.measurement[2]};
  f.num_measurement = 3;
  f.noise_kind = factor_t::NOISE_INFORMATION;
  for (int i = 0; i < 3; ++i)
    for (int j = i; j < 3; ++j) f.noise.push_back(e.information(i, j));
  f.num_noise = 6;
  f.robust = "";
  return f;
}

TEST(AmbiguousEngine, MatchesLoopdSolveMhOnAnAmbiguousDataset) {
  using namespace loopd::testing_live;
  const std::string amb = tmp("intel_amb.g2o"), truth = tmp("intel_amb.json"),
                    est = tmp("intel_amb_est.g2o"), stats = tmp("intel_amb_stats.json");
  ASSERT_EQ(runTool({kBin + "/tools/loopd-outliers", kData + "/intel.g2o", "--ambiguous", "20",
                     "--null", "--out", amb, "--truth", truth},
                    tmp("outliers.log")),
            0);
  ASSERT_EQ(runTool({kSolve, amb, "--solver", "mh", "--incremental", "--stats", stats, "--out", est,
                     "--quiet"},
                    tmp("solve.log")),
            0);
  const std::vector<int> solveChosen = jsonInts(stats, "chosen");
  ASSERT_EQ(solveChosen.size(), 20u);

  // The file as a front-end would send it: one batch per pose, each edge and each group with
  // the pose that completes it (loopd-solve --incremental's schedule).
  const io::Dataset ds = io::readDataset(amb);
  std::vector<int> groupOf(ds.edges.size(), -1);
  for (size_t g = 0; g < ds.hypotheses.size(); ++g)
    for (int k = 0; k < ds.hypotheses[g].count; ++k)
      groupOf[ds.hypotheses[g].firstEdge + k] = static_cast<int>(g);
  std::map<std::int64_t, factor_batch_t> byPose;
  for (size_t i = 0; i < ds.edges.size(); ++i) {
    if (groupOf[i] >= 0) continue;
    factor_t f = wireEdge(ds.edges[i], false);
    f.id = static_cast<std::int64_t>(i);
    byPose[std::max(ds.edges[i].from, ds.edges[i].to)].factors.push_back(f);
  }
  for (size_t g = 0; g < ds.hypotheses.size(); ++g) {
    const auto& h = ds.hypotheses[g];
    std::vector<factor_t> alts;
    std::int64_t due = 0;
    for (int k = 0; k < h.count; ++k) {
      const io::Edge& e = ds.edges[static_cast<size_t>(h.firstEdge + k)];
      alts.push_back(wireEdge(e, true));
      due = std::max({due, e.from, e.to});
    }
    // Group ids after every edge index, in file order.
    byPose[due].ambiguous.push_back(
        group(100000 + static_cast<std::int64_t>(g), A::MULTI_ASSOCIATION, alts, h.null));
  }
  Fixture f("mh");
  bool first = true;
  for (auto& [pose, b] : byPose) {
    b.sender = "intel";
    b.sequence = ++f.seq;
    if (first) {  // the first pose where the file puts it
      initial_value_t iv{};
      iv.key = client::wireKey(KeyRef::pose(0, ds.poses[0].id));
      iv.type = initial_value_t::SE2;
      iv.value = {ds.poses[0].value[0], ds.poses[0].value[1], ds.poses[0].value[2]};
      iv.num_value = 3;
      b.initial_values = {iv};
      first = false;
    }
    b.num_factors = static_cast<std::int16_t>(b.factors.size());
    b.num_ambiguous = static_cast<std::int16_t>(b.ambiguous.size());
    b.num_initial_values = static_cast<std::int16_t>(b.initial_values.size());
    f.engine.post({"T_FACTORS", encode(b)});
    f.engine.step();
  }
  f.command(command_t::OPTIMIZE);
  ASSERT_TRUE(f.errors.empty()) << f.errors[0].reason;
  const status_t s = f.fullStatus();
  EXPECT_EQ(s.ambiguous, 20);
  std::vector<int> serverChosen;
  for (size_t g = 0; g < 20; ++g) {
    const loop_decision_t* d = f.decision(s, 100000 + static_cast<std::int64_t>(g));
    ASSERT_NE(d, nullptr);
    serverChosen.push_back(d->alternative);
  }
  EXPECT_EQ(serverChosen, solveChosen);
  EXPECT_EQ(serverChosen, jsonInts(truth, "true_choice"));
  const auto offline = readVertices(est);
  double dt = 0, dr = 0;
  for (const auto& [id, x] : offline) {
    const auto y = f.pose(id);
    ASSERT_EQ(y.size(), 3u);
    dt = std::max(dt, std::hypot(x[0] - y[0], x[1] - y[1]));
    dr = std::max(dr, std::abs(std::remainder(x[2] - y[2], 2 * M_PI)));
  }
  EXPECT_LT(dt, 2e-3);
  EXPECT_LT(dr, 2e-4);
  EXPECT_NEAR(s.chi2, statsChi2(stats), 1e-4 * statsChi2(stats));
  std::printf(
      "    chosen %zu/%zu as loopd-solve, max |dt| %.2e m, |dtheta| %.2e rad, chi2 %.6f vs %.6f\n",
      serverChosen.size(), solveChosen.size(), dt, dr, s.chi2, statsChi2(stats));
}

TEST(AmbiguousServerConfig, MaxHypothesesFlagAndFile) {
  EXPECT_EQ(parseServerConfig({}).maxHypotheses, 10);
  EXPECT_EQ(parseServerConfig({"--max-hypotheses", "3", "--solver", "mh"}).maxHypotheses, 3);
  EXPECT_EQ(parseServerConfig({"--max-hypotheses=4"}).maxHypotheses, 4);
  EXPECT_THROW(parseServerConfig({"--max-hypotheses", "0"}), std::invalid_argument);
  EXPECT_THROW(parseServerConfig({"--max-hypotheses", "two"}), std::invalid_argument);
  const std::string cfg = ::testing::TempDir() + "/" + std::to_string(getpid()) + "_amb.conf";
  {
    std::ofstream out(cfg);
    out << "solver = mh\nmax-hypotheses = 5\n";
  }
  const ServerConfig c = parseServerConfig({"--config", cfg});
  EXPECT_EQ(c.solver, "mh");
  EXPECT_EQ(c.maxHypotheses, 5);
  EXPECT_EQ(parseServerConfig({"--config", cfg, "--max-hypotheses", "2"}).maxHypotheses, 2);
  std::remove(cfg.c_str());
}

// --- over LCM: loopd --solver mh and the client library ------------------------------------

TEST(AmbiguousLive, ClientGroupThroughLoopdMh) {
  using namespace loopd::testing_live;
  const std::string url = uniqueUrl();
  Proc srv = Proc::start({kLoopd, "--lcm-url", url, "--solver", "mh", "--max-hypotheses", "4",
                          "--idle-seconds", "0.2"},
                         tmp("amb_srv.log"));
  std::this_thread::sleep_for(std::chrono::milliseconds(400));
  ASSERT_TRUE(srv.alive()) << srv.output();
  lcm::LCM lcm(client::receiveUrl(url));
  ASSERT_TRUE(lcm.good());
  client::FactorPublisher pub(lcm, "robot0/fe");
  client::EstimateSubscriber sub(lcm);
  std::map<std::int64_t, loop_decision_t> decisions;
  std::vector<status_t> replies;
  sub.onStatus([&](const status_t& s) {
    for (const auto& d : s.decisions) decisions[d.factor_id] = d;
    if (s.request_id == 42) replies.push_back(s);
  });
  std::map<int, int> hypothesisChunks;
  lcm.subscribeFunction(
      "LOOPD_ESTIMATE",
      +[](const lcm::ReceiveBuffer*, const std::string&, const estimate_t* m,
          std::map<int, int>* n) {
        if (m->request_id == 42) ++(*n)[m->hypothesis];
      },
      &hypothesisChunks);
  auto pump = [&](int ms) {
    const auto end = std::chrono::steady_clock::now() + std::chrono::milliseconds(ms);
    while (std::chrono::steady_clock::now() < end) lcm.handleTimeout(20);
  };
  pump(300);
  for (int i = 0; i < 16; ++i) {
    pub.odometry(0, i, i + 1, Pose2{1, 0, (i % 4 == 3) ? M_PI / 2 : 0.0},
                 Eigen::Vector3d(1, 1, 10).asDiagonal());
    pub.flush();
    pump(30);
  }
  // Settled: back at the start, not 30 m away. Open: two measurements 0.6 m apart.
  const std::int64_t settled = pub.ambiguous(
      A::MULTI_MEASUREMENT,
      {client::loopClosureFactor(KeyRef::pose(0, 16), KeyRef::pose(0, 0), Pose2{30, 0, 0}, kInfo),
       client::loopClosureFactor(KeyRef::pose(0, 16), KeyRef::pose(0, 0), Pose2{0, 0, 0}, kInfo)},
      true);
  pub.flush();
  pump(300);
  const std::int64_t open = pub.ambiguous(
      A::MULTI_MEASUREMENT,
      {client::loopClosureFactor(KeyRef::pose(0, 8), KeyRef::pose(0, 0), Pose2{4, 4, M_PI}, kInfo),
       client::loopClosureFactor(KeyRef::pose(0, 8), KeyRef::pose(0, 0), Pose2{4.6, 4, M_PI},
                                 kInfo)},
      false);
  // The client refuses what the server would.
  EXPECT_THROW(pub.ambiguous(A::MULTI_MEASUREMENT,
                             {client::loopClosureFactor(KeyRef::pose(0, 8), KeyRef::pose(0, 0),
                                                        Pose2{}, kInfo)},
                             false),
               std::invalid_argument);
  EXPECT_THROW(pub.ambiguous(A::MULTI_ASSOCIATION,
                             {client::loopClosureFactor(KeyRef::pose(0, 8), KeyRef::pose(0, 0),
                                                        Pose2{}, kInfo),
                              client::loopClosureFactor(KeyRef::pose(0, 8), KeyRef::pose(0, 4),
                                                        Pose2{1, 0, 0}, kInfo)},
                             false),
               std::invalid_argument);
  EXPECT_THROW(pub.ambiguous(A::MULTI_ASSOCIATION, {}, true, -1.0), std::invalid_argument);
  pub.flush();
  pump(800);
  const status_t s = sub.lastStatus();
  EXPECT_EQ(s.solver, "mh");
  EXPECT_EQ(s.ambiguous, 2);
  ASSERT_TRUE(decisions.count(settled));
  EXPECT_TRUE(decisions[settled].ambiguous);
  EXPECT_EQ(decisions[settled].alternative, 1);
  ASSERT_TRUE(decisions.count(open));
  EXPECT_EQ(s.live_hypotheses, 2);
  EXPECT_EQ(s.undecided_ambiguous, 1);

  command_t c{};
  c.sender = "test";
  c.request_id = 42;
  c.command = command_t::REQUEST_HYPOTHESES;
  c.argument = "";
  lcm.publish("LOOPD_COMMAND", &c);
  pump(800);
  ASSERT_FALSE(replies.empty());
  EXPECT_EQ(replies.back().num_hypotheses, 2);
  EXPECT_EQ(hypothesisChunks.size(), 2u);  // ranks 0 and 1, one chunk each
  EXPECT_EQ(hypothesisChunks[0], 1);
  EXPECT_EQ(hypothesisChunks[1], 1);
  EXPECT_EQ(sub.errorsReceived(), 0);
  srv.kill(SIGINT);
  EXPECT_EQ(srv.wait(20), 0) << srv.output();
}

// --- over LCM: an inter-robot group refused as a first link, accepted after a certain link,
// kept across kill -9 and --resume --------------------------------------------------------

TEST(AmbiguousLive, InterRobotGroupRefusedThenAcceptedSurvivesKillNine) {
  using namespace loopd::testing_live;
  const std::string url = uniqueUrl();
  const std::string journal = tmp("amb_inter_journal.lcmlog");
  std::remove(journal.c_str());
  lcm::LCM lcm(client::receiveUrl(url));
  ASSERT_TRUE(lcm.good());
  client::EstimateSubscriber sub(lcm);
  std::vector<status_t> replies;
  sub.onStatus([&](const status_t& s) {
    if (s.request_id == 42) replies.push_back(s);
  });
  auto pump = [&](int ms) {
    const auto end = std::chrono::steady_clock::now() + std::chrono::milliseconds(ms);
    while (std::chrono::steady_clock::now() < end) lcm.handleTimeout(20);
  };
  auto send = [&](const factor_batch_t& b) {
    lcm.publish("LOOPD_FACTORS", &b);
    pump(20);
  };
  auto requestStatus = [&]() -> status_t {
    replies.clear();
    command_t c{};
    c.sender = "test";
    c.request_id = 42;
    c.command = command_t::REQUEST_STATUS;
    c.argument = "";
    for (int attempt = 0; attempt < 3 && replies.empty(); ++attempt) {
      lcm.publish("LOOPD_COMMAND", &c);
      pump(600);
    }
    if (replies.empty()) {
      ADD_FAILURE() << "no reply to REQUEST_STATUS";
      return status_t{};
    }
    status_t out = replies.front();
    for (size_t i = 1; i < replies.size(); ++i)
      if (replies[i].decisions_full && replies[i].decisions_chunk_index > 0)
        out.decisions.insert(out.decisions.end(), replies[i].decisions.begin(),
                             replies[i].decisions.end());
    return out;
  };
  auto groupDecision = [](const status_t& s, std::int64_t gid) -> const loop_decision_t* {
    for (const auto& d : s.decisions)
      if (d.ambiguous && d.factor_id == gid) return &d;
    return nullptr;
  };
  {
    Proc srv = Proc::start(
        {kLoopd, "--lcm-url", url, "--solver", "mh", "--journal", journal, "--idle-seconds", "0.2"},
        tmp("amb_inter_srv1.log"));
    std::this_thread::sleep_for(std::chrono::milliseconds(400));
    ASSERT_TRUE(srv.alive()) << srv.output();
    pump(200);
    for (int i = 0; i < 16; ++i)
      send(batch("a", i + 1,
                 {odo(i, 0, i, i + 1, {1.03, 0.01, (i % 4 == 3) ? M_PI / 2 + 0.02 : 0.0})}));
    for (int i = 0; i < 8; ++i)
      send(batch("b", i + 1, {odo(1000 + i, 1, i, i + 1, {0.97, -0.01, 0.01})}));
    // The group as the first link between the robots: refused, nothing applied.
    send(batch("lc", 1, {closure(0, 16, 0, {0, 0, 0}, 50)}, {interGroup(40)}));
    pump(400);
    ASSERT_EQ(sub.errorsReceived(), 1);
    const loopd::error_t e = sub.errors().back();
    EXPECT_EQ(e.sender, "lc");
    EXPECT_EQ(e.sequence, 1);
    EXPECT_EQ(e.factor_id, 40);
    EXPECT_EQ(e.code, loopd::error_t::INVALID_FIELD);
    EXPECT_EQ(e.channel, "LOOPD_FACTORS");
    EXPECT_NE(e.reason.find("send a certain inter-robot loop closure"), std::string::npos)
        << e.reason;
    ASSERT_TRUE(srv.alive());
    status_t s = requestStatus();
    EXPECT_EQ(s.ambiguous, 0);
    EXPECT_EQ(s.batches_rejected, 1);
    EXPECT_EQ(s.robots_in_common_frame, 0);
    // A certain link, then the same group: accepted.
    send(batch("b", 9, {inter(0, 0, 1, 0, {0, 2, 0}, 2000)}));
    send(batch("lc", 2, {}, {interGroup(40)}));
    pump(600);
    s = requestStatus();
    EXPECT_EQ(s.ambiguous, 1);
    EXPECT_EQ(s.robots_in_common_frame, 2);
    EXPECT_EQ(s.batches_accepted, 16 + 9 + 1);
    ASSERT_NE(groupDecision(s, 40), nullptr);
    EXPECT_EQ(groupDecision(s, 40)->alternative, 1);
    EXPECT_EQ(sub.errorsReceived(), 1);
    srv.kill(SIGKILL);
    EXPECT_NE(srv.output().find("send a certain inter-robot loop closure"), std::string::npos)
        << srv.output();
  }
  Proc srv = Proc::start({kLoopd, "--lcm-url", url, "--solver", "mh", "--journal", journal,
                          "--resume", journal, "--idle-seconds", "0.2"},
                         tmp("amb_inter_srv2.log"));
  std::this_thread::sleep_for(std::chrono::milliseconds(600));
  ASSERT_TRUE(srv.alive()) << srv.output();
  pump(300);
  const status_t s = requestStatus();
  EXPECT_EQ(s.ambiguous, 1);
  EXPECT_EQ(s.robots_in_common_frame, 2);
  EXPECT_EQ(s.batches_accepted, 16 + 9 + 1);
  ASSERT_NE(groupDecision(s, 40), nullptr);
  EXPECT_EQ(groupDecision(s, 40)->alternative, 1);
  EXPECT_EQ(sub.errorsReceived(), 1);
  srv.kill(SIGINT);
  EXPECT_EQ(srv.wait(20), 0) << srv.output();
  std::remove(journal.c_str());
}

}  // namespace
