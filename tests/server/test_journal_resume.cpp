// The journal and --resume: what the journal holds (applied batches, RESETs, the numbers of
// refused and expired batches), that a resume rebuilds the live graph and its sequence
// histories exactly, that batches the solver refuses are counted as rejected, and that a file
// which is not a journal at its start is refused untouched while a torn tail is cut off.
#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iterator>
#include <sstream>
#include <thread>

#include "client/factor_publisher.h"
#include "loopd/command_t.hpp"
#include "loopd/error_t.hpp"
#include "loopd/estimate_t.hpp"
#include "loopd/status_t.hpp"
#include "server/engine.h"
#include "server/journal.h"
#include "server/server.h"
#include "server/server_config.h"
#include "tests/server/engine_harness.h"
#include "tests/server/wire_encode.h"

using namespace loopd;
using namespace loopd::server;
using client::KeyRef;
using client::Pose2;

namespace {

// Robot 0's pose a to its pose b.
factor_t between2(std::int64_t id, std::int64_t a, std::int64_t b, Pose2 z,
                  int8_t role = factor_t::ROLE_ODOMETRY) {
  return test::between2(id, 0, a, 0, b, z, role);
}

using test::batch;

// Odometry 0 → 1 → … → n, 1 m steps, factor i from pose i.
std::vector<factor_t> straightOdometry(int n) {
  std::vector<factor_t> fs;
  for (int i = 0; i < n; ++i) fs.push_back(between2(i, i, i + 1, {1, 0, 0}));
  return fs;
}
using test::encode;

std::string tmpPath(const std::string& name) {
  return ::testing::TempDir() + "/" + std::to_string(getpid()) + "_jr_" + name;
}

std::string readAll(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

void writeAll(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

// An engine driven in-process (messages in, published messages captured), optionally
// journaling.
struct Fixture : test::EngineHarness {
  explicit Fixture(const std::string& solver = "lm", Journal* journal = nullptr,
                   double holdSeconds = 30)
      : EngineHarness(solver, holdSeconds, journal) {}
  using EngineHarness::command;
  void command(int8_t c, std::int64_t requestId) { command(c, "", {}, requestId); }
  /// Optimized, then a status in reply to REQUEST_STATUS.
  status_t status() {
    command(command_t::OPTIMIZE);
    command(command_t::REQUEST_STATUS, 8);
    for (auto it = out.statuses.rbegin(); it != out.statuses.rend(); ++it)
      if (it->request_id == 8) return *it;
    ADD_FAILURE() << "no status";
    return status_t{};
  }
  std::vector<double> pose(std::int64_t i) const {
    std::vector<double> x;
    EXPECT_TRUE(engine.commonFramePose(poseKey(static_cast<std::uint64_t>(i), 0), x)) << i;
    return x;
  }
};

// The same graph: factor and pose counts, chi2, every pose.
void expectSameGraph(Fixture& live, Fixture& resumed, int poses) {
  const status_t a = live.status(), b = resumed.status();
  EXPECT_EQ(b.factors, a.factors);
  EXPECT_EQ(b.poses, a.poses);
  EXPECT_NEAR(b.chi2, a.chi2, 1e-6 * (1 + a.chi2));
  for (int i = 0; i < poses; ++i) {
    const auto x = live.pose(i), y = resumed.pose(i);
    ASSERT_EQ(x.size(), y.size());
    for (size_t k = 0; k < x.size(); ++k) EXPECT_NEAR(y[k], x[k], 1e-6) << "pose " << i;
  }
}

// --- RESET ------------------------------------------------------------------------------------

// Session A, RESET, and the front-end restarts at sequence 1 with other data (session B): the
// resumed graph is B alone, as the live one, not A plus what of B was not a "duplicate" of A.
TEST(JournalResume, AResetIsJournaledAndReplayed) {
  const std::string path = tmpPath("reset.lcmlog");
  std::remove(path.c_str());
  {
    Journal j(path, false);
    Fixture live("lm", &j);
    live.send(batch("fe", 1, straightOdometry(5)));
    live.command(command_t::RESET, 5);
    std::vector<factor_t> b1, b2;
    for (int i = 0; i < 3; ++i) b1.push_back(between2(i, i, i + 1, {0, 0, M_PI / 2}));
    for (int i = 0; i < 2; ++i) b2.push_back(between2(10 + i, 3 + i, 4 + i, {2, 0, 0}));
    live.send(batch("fe", 1, b1));
    live.send(batch("fe", 2, b2));
    EXPECT_TRUE(live.out.errors.empty());
    const status_t s = live.status();
    EXPECT_EQ(s.factors, 6);  // 5 odometry + the first pose's prior
    EXPECT_EQ(s.poses, 6);
    EXPECT_EQ(j.written(), 3);  // batches

    Fixture resumed("lm");
    resumed.engine.replay(path, false, nullptr);
    EXPECT_TRUE(resumed.out.errors.empty());
    expectSameGraph(live, resumed, 6);
    const status_t r = resumed.status();
    EXPECT_EQ(r.batches_accepted, 3);
    EXPECT_EQ(r.batches_duplicate, 0);
    // The sequence history is B's: B's resends are duplicates, A's next number is new.
    resumed.send(batch("fe", 2, b2));
    EXPECT_EQ(resumed.engine.counters().duplicate, 1);
    resumed.send(batch("fe", 3, {between2(20, 5, 6, {1, 0, 0})}));
    EXPECT_EQ(resumed.status().poses, 7);
    // update_seq never goes back (before: the resumed engine counted from 0 again, and
    // EstimateSubscriber took its estimates for stale ones).
    EXPECT_GT(r.update_seq, s.update_seq);
  }
  std::remove(path.c_str());
}

// A journal resumed into another journal (rejournal) carries the RESET over: resuming that one
// gives the same graph again.
TEST(JournalResume, AResetIsCarriedIntoANewJournal) {
  const std::string first = tmpPath("reset1.lcmlog"), second = tmpPath("reset2.lcmlog");
  std::remove(first.c_str());
  std::remove(second.c_str());
  {
    Journal j(first, false);
    Fixture live("lm", &j);
    live.send(batch("fe", 1, {between2(0, 0, 1, {1, 0, 0}), between2(1, 1, 2, {1, 0, 0})}));
    live.command(command_t::RESET, 5);
    live.send(batch("fe", 1, {between2(0, 0, 1, {0, 2, 0})}));
  }
  {
    Journal j(second, false);
    Fixture mid("lm", &j);
    mid.engine.replay(first, true, nullptr);
    EXPECT_EQ(mid.status().factors, 2);
  }
  Fixture last("lm");
  last.engine.replay(second, false, nullptr);
  const status_t s = last.status();
  EXPECT_EQ(s.factors, 2);
  EXPECT_EQ(s.poses, 2);
  EXPECT_NEAR(last.pose(1)[1], 2.0, 1e-6);
  std::remove(first.c_str());
  std::remove(second.c_str());
}

// --- batches the solver refuses ---------------------------------------------------------------

// An odometry of 1e200 m passes validation and the solver diverges on it: the batch is refused
// with INTERNAL and counted in batches_rejected (so accepted + rejected + expired reaches the
// number of batches sent: loopd-listen --until-batches ends).
TEST(JournalResume, ABatchTheSolverRefusesIsCountedAsRejected) {
  Fixture f("isam2");
  f.send(batch("a", 1, straightOdometry(5)));
  f.send(batch("a", 2, {between2(5, 5, 6, {1e200, 0, 0})}));
  ASSERT_FALSE(f.out.errors.empty());
  EXPECT_EQ(f.out.errors.back().code, loopd::error_t::INTERNAL);
  f.send(batch("a", 3, {between2(6, 5, 6, {1, 0, 0})}));
  const status_t s = f.status();
  EXPECT_EQ(s.batches_accepted, 2);
  EXPECT_EQ(s.batches_rejected, 1);
  EXPECT_EQ(s.batches_accepted + s.batches_rejected + s.batches_expired, 3);
  EXPECT_EQ(f.engine.counters().internalErrors, 1);
}

// The journal holds only what was applied: a resume does not apply the refused batch (the
// live server has 3 accepted batches... here 2 and 7 factors; the resumed one the same), and
// the refused number is a duplicate after the resume.
TEST(JournalResume, ABatchTheSolverRefusedIsNotReplayed) {
  const std::string path = tmpPath("internal.lcmlog");
  std::remove(path.c_str());
  {
    Journal j(path, false);
    Fixture live("isam2", &j);
    live.send(batch("a", 1, straightOdometry(5)));
    live.send(batch("a", 2, {between2(5, 5, 6, {1e200, 0, 0})}));
    live.send(batch("a", 3, {between2(6, 5, 6, {1, 0, 0})}));
    EXPECT_EQ(j.written(), 2);
    const status_t s = live.status();
    EXPECT_EQ(s.factors, 7);

    Fixture resumed("isam2");
    resumed.engine.replay(path, false, nullptr);
    EXPECT_TRUE(resumed.out.errors.empty()) << resumed.out.errors.front().reason;
    expectSameGraph(live, resumed, 7);
    const status_t r = resumed.status();
    EXPECT_LT(r.chi2, 1e-6);
    EXPECT_EQ(r.batches_accepted, 2);
    EXPECT_EQ(r.batches_rejected, 1);
    EXPECT_EQ(r.num_sender_gaps, 0);
    resumed.send(batch("a", 2, {between2(5, 5, 6, {1e200, 0, 0})}));  // resent: a duplicate
    EXPECT_EQ(resumed.engine.counters().duplicate, 1);
    EXPECT_TRUE(resumed.out.errors.empty());
  }
  std::remove(path.c_str());
}

// --- refused and expired numbers ----------------------------------------------------------------

// A held batch that expires and a refused one consume their numbers: after a resume there is
// no gap, and a front-end that resends everything (what to do after a restart) gets the exact
// same graph, its resends ignored as duplicates.
TEST(JournalResume, RefusedAndExpiredNumbersSurviveAResume) {
  const std::string path = tmpPath("consumed.lcmlog");
  std::remove(path.c_str());
  const std::vector<factor_batch_t> all = {
      batch(
          "a", 1,
          {between2(0, 0, 1, {1, 0, 0}), between2(1, 1, 2, {1, 0, 0}), between2(2, 2, 3, {1, 0, 0}),
           between2(3, 3, 4, {1, 0, 0}), between2(4, 4, 5, {1, 0, 0})}),
      // A closure to pose 8, which is not there yet: held, then expired.
      batch("a", 2, {between2(50, 8, 9, {1.2, 0, 0}, factor_t::ROLE_LOOP_CLOSURE)}),
      // Refused: unknown removal.
      batch("a", 3, {between2(60, 5, 6, {1, 0, 0}), between2(61, 6, 7, {1, 0, 0})}, {999}),
      batch("a", 4,
            {between2(70, 5, 6, {1, 0, 0}), between2(71, 6, 7, {1, 0, 0}),
             between2(72, 7, 8, {1, 0, 0}), between2(73, 8, 9, {1, 0, 0})})};
  {
    Journal j(path, false);
    Fixture live("lm", &j, 0.05);
    live.send(all[0]);
    live.send(all[1]);
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    live.engine.idle();
    ASSERT_EQ(live.out.errors.size(), 1u);
    EXPECT_EQ(live.out.errors[0].code, loopd::error_t::HELD_EXPIRED);
    live.send(all[2]);
    ASSERT_EQ(live.out.errors.size(), 2u);
    EXPECT_EQ(live.out.errors[1].code, loopd::error_t::UNKNOWN_FACTOR_ID);
    live.send(all[3]);
    const status_t s = live.status();
    EXPECT_EQ(s.factors, 10);
    EXPECT_EQ(s.num_sender_gaps, 0);
    EXPECT_EQ(s.batches_accepted, 2);
    EXPECT_EQ(s.batches_rejected, 1);
    EXPECT_EQ(s.batches_expired, 1);
    EXPECT_EQ(j.written(), 2);  // the applied batches; the two numbers as records

    Fixture resumed("lm", nullptr, 0.05);
    resumed.engine.replay(path, false, nullptr);
    EXPECT_TRUE(resumed.out.errors.empty());
    const status_t r = resumed.status();
    EXPECT_EQ(r.num_sender_gaps, 0);
    EXPECT_EQ(r.batches_accepted, 2);
    EXPECT_EQ(r.batches_rejected, 1);
    EXPECT_EQ(r.batches_expired, 1);
    for (const auto& b : all) resumed.send(b);
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    resumed.engine.idle();
    EXPECT_TRUE(resumed.out.errors.empty());
    EXPECT_EQ(resumed.engine.counters().duplicate, 4);
    EXPECT_EQ(resumed.status().batches_held, 0);
    expectSameGraph(live, resumed, 10);
  }
  std::remove(path.c_str());
}

// --- files that are not journals, torn tails ------------------------------------------------

// A journal of `n` one-pose batches (valid LCM log events), written through an engine.
void writeJournal(const std::string& path, int n) {
  std::remove(path.c_str());
  Journal j(path, false);
  Fixture f("lm", &j);
  for (int i = 0; i < n; ++i) f.send(batch("a", i + 1, {between2(i, i, i + 1, {1, 0, 0})}));
  ASSERT_EQ(j.written(), n);
}

std::int64_t countEvents(const std::string& path, long* validBytes) {
  return readJournal(
      path, [](const std::string&, const void*, int) {}, validBytes);
}

TEST(JournalFile, AFileThatIsNotAJournalIsRefused) {
  const std::string path = tmpPath("notajournal.g2o");
  const std::string g2o =
      "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\n"
      "EDGE_SE2 0 1 1 0 0 100 0 0 100 0 1000\n";
  writeAll(path, g2o);
  long valid = -1;
  EXPECT_THROW(countEvents(path, &valid), std::runtime_error);
  Fixture f("lm");
  EXPECT_THROW(f.engine.replay(path, false, nullptr), std::runtime_error);
  EXPECT_EQ(readAll(path), g2o);
  std::remove(path.c_str());
}

TEST(JournalFile, AJournalWithItsFirstSyncByteFlippedIsRefused) {
  const std::string path = tmpPath("flipped.lcmlog");
  writeJournal(path, 6);
  long valid = -1;
  EXPECT_EQ(countEvents(path, &valid), 6);
  std::string bytes = readAll(path);
  EXPECT_EQ(valid, static_cast<long>(bytes.size()));
  bytes[0] = static_cast<char>(bytes[0] ^ 0x10);
  writeAll(path, bytes);
  EXPECT_THROW(countEvents(path, &valid), std::runtime_error);
  std::remove(path.c_str());
}

TEST(JournalFile, GarbageAfterTheEventsThatIsNotATornEventIsRefused) {
  const std::string path = tmpPath("garbage.lcmlog");
  writeJournal(path, 3);
  const std::string good = readAll(path);
  writeAll(path, good + "this is not an LCM log event, and more than a header's 28 bytes\n");
  long valid = -1;
  EXPECT_THROW(countEvents(path, &valid), std::runtime_error);
  std::remove(path.c_str());
}

TEST(JournalFile, ATornTailIsCutAndAnEmptyOrTornFirstEventIsAnEmptyJournal) {
  const std::string path = tmpPath("torn.lcmlog");
  writeJournal(path, 4);
  const std::string good = readAll(path);
  long valid = -1;
  ASSERT_EQ(countEvents(path, &valid), 4);
  // The first event's length: the journal of one batch.
  writeJournal(path, 1);
  const std::string one = readAll(path);
  // A kill -9 during a write leaves any prefix of an event behind.
  for (size_t cut : {size_t{1}, size_t{3}, size_t{4}, size_t{20}, size_t{28}, one.size() - 1}) {
    writeAll(path, good + one.substr(0, cut));
    ASSERT_EQ(countEvents(path, &valid), 4) << cut;
    EXPECT_EQ(valid, static_cast<long>(good.size())) << cut;
    writeAll(path, one.substr(0, cut));
    ASSERT_EQ(countEvents(path, &valid), 0) << cut;
    EXPECT_EQ(valid, 0) << cut;
  }
  writeAll(path, "");
  EXPECT_EQ(countEvents(path, &valid), 0);
  EXPECT_EQ(valid, 0);
  std::remove(path.c_str());
}

// runServer itself, in-process over LCM's memq provider (no network), already told to stop:
// it refuses a --journal F --resume F that is not a journal (exit 1, the file untouched), and
// cuts a torn tail of a real one.
int runOnce(const std::string& journal) {
  ServerConfig cfg;
  cfg.lcmUrl = "memq://";
  cfg.solver = "lm";
  cfg.journal = journal;
  cfg.resume = journal;
  cfg.idleSeconds = 0.01;
  std::atomic<bool> stop{true};
  return runServer(cfg, stop);
}

TEST(JournalFile, TheServerRefusesToResumeAFileThatIsNotAJournal) {
  const std::string path = tmpPath("server_g2o.lcmlog");
  const std::string g2o = "VERTEX_SE2 0 0 0 0\nEDGE_SE2 0 1 1 0 0 100 0 0 100 0 1000\n";
  writeAll(path, g2o);
  EXPECT_NE(runOnce(path), 0);
  EXPECT_EQ(readAll(path), g2o);
  writeJournal(path, 5);
  std::string flipped = readAll(path);
  flipped[0] = static_cast<char>(flipped[0] ^ 0x01);
  writeAll(path, flipped);
  EXPECT_NE(runOnce(path), 0);
  EXPECT_EQ(readAll(path), flipped);
  std::remove(path.c_str());
}

TEST(JournalFile, TheServerCutsATornTailAndKeepsTheJournal) {
  const std::string path = tmpPath("server_torn.lcmlog");
  writeJournal(path, 5);
  const std::string good = readAll(path);
  writeAll(path, good + good.substr(0, 40));
  EXPECT_EQ(runOnce(path), 0);
  EXPECT_EQ(readAll(path), good);
  std::remove(path.c_str());
}

}  // namespace
