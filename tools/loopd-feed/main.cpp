// loopd-feed: play a dataset to a loopd server as one or many robots, live over LCM or into an
// LCM log for lcm-logplayer.
//
//   loopd-feed DATASET [--robots N] [--rate HZ] [--lcm-url URL] [--sender NAME] [--log OUT.lcmlog]
//              [--channel-prefix P] [--interleave] [--poses N] [--landmark-owner R]
//              [--landmark-namespace N] [--quiet]
//
// The poses (by file id) are cut into N consecutive segments, robot k owning segment k; a pose
// keeps its file id as its index. Poses appear in id order (or, with --interleave, round-robin
// over the robots); each appearing pose is one batch, from its robot's sender, carrying every
// factor whose ends have all appeared (solvers/problem/incremental_schedule.h), factor ids =
// file edge indices. Edges between consecutive ids of one robot are odometry; every other edge
// (including those crossing segments) is a loop closure. A robot's first pose is sent with the
// initial value identity (its own frame); the server composes the others from odometry.
// A landmark belongs to the robot whose pose sights it first in feed order
// (FeedOrder::landmarkOwner): every robot's sightings of it name that robot's landmark, so
// another robot's are cross-robot sightings, published after the owner's first, and tie the
// robots' frames together. --landmark-owner R gives every landmark to robot R instead (a
// shared landmark map): the server then places a landmark R has not sighted from another
// robot's sighting once their frames are joined. --landmark-namespace N gives every landmark to
// robot id N ≥ the robots fed, which has no poses (a server run with --landmark-namespace N holds
// them in the frame of the first robot to sight one).
// TORO EQUIV pairs go as trusted identity constraints (FeedOrder::equivalenceFactor), ids
// following the edges' as in loopd-solve (TORO has no HYPOTHESES: no group id is taken).
// The k-th batch of a sender has sequence k, so feeding the same file again is a resend.
// A HYPOTHESES group goes as one ambiguous_factor_t (id = number of edges + its index in file
// order) in the batch of the pose that completes it: MULTI_MEASUREMENT when its alternatives
// share keys, MULTI_ASSOCIATION when they share the measurement (a group mixing both stops
// the feed with an error: the wire has no form for it).
#include <lcm/lcm-cpp.hpp>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "client/factor_publisher.h"
#include "solvers/io/dataset_reader.h"
#include "tools/common/cli.h"
#include "tools/common/feed_order.h"

using namespace loopd;
using client::KeyRef;

namespace {

struct Options {
  std::string dataset, lcmUrl, sender = "feed", log, prefix = "LOOPD_";
  int robots = 1;
  int landmarkOwner = -1;          // < 0: each landmark is its first sighter's
  bool landmarkNamespace = false;  // landmarkOwner names a namespace, not a robot
  double rate = 0.0;
  bool interleave = false, quiet = false;
  long poses = -1;
};

const char* kUsage =
    "usage: loopd-feed DATASET [--robots N] [--rate HZ] [--lcm-url URL] [--sender NAME]\n"
    "                  [--log OUT.lcmlog] [--channel-prefix P] [--interleave] [--poses N]\n"
    "                  [--landmark-owner R | --landmark-namespace N] [--quiet]\n"
    "  --robots N        split the poses into N (1-1000) consecutive segments, one robot each\n"
    "                    (default 1)\n"
    "  --rate HZ         poses per second, >= 0 (default 0 = as fast as possible)\n"
    "  --sender NAME     sender names are NAME0, NAME1, ... (default feed)\n"
    "  --log OUT         write an LCM log (replay with lcm-logplayer) instead of publishing\n"
    "  --interleave      robots publish round-robin instead of one segment after the other\n"
    "  --poses N         only the first N poses (N >= 1; and the edges among them)\n"
    "  --landmark-owner R every landmark is robot R's (0 <= R < N: a shared landmark map);\n"
    "                    default: each is the robot's that sights it first\n"
    "  --landmark-namespace N every landmark is robot id N's (N >= robots, up to 1000000000),\n"
    "                    which has no poses: serve with loopd --landmark-namespace N\n";

Options parse(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto val = [&] { return tools::flagValue(argc, argv, i); };
    if (a == "--help" || a == "-h") {
      std::fputs(kUsage, stdout);
      std::exit(0);
    } else if (a == "--robots")
      o.robots = static_cast<int>(tools::parseIntFlag(a, val(), 1, 1000));
    else if (a == "--rate") {
      const std::string v = val();
      o.rate = tools::parseNumberFlag(a, v, 0.0, 1e9);
      if (o.rate > 0 && o.rate < 1e-3)  // one pose in more than 1000 s: a typo, and no int64 step
        throw std::invalid_argument("--rate takes 0 or a number in [0.001, 1e+09], got '" + v +
                                    "'");
    } else if (a == "--lcm-url")
      o.lcmUrl = val();
    else if (a == "--sender")
      o.sender = val();
    else if (a == "--log")
      o.log = val();
    else if (a == "--channel-prefix")
      o.prefix = val();
    else if (a == "--poses")
      o.poses = static_cast<long>(tools::parseIntFlag(a, val(), 1, 1000000000));
    else if (a == "--interleave")
      o.interleave = true;
    else if (a == "--landmark-owner" || a == "--landmark-namespace") {
      if (o.landmarkOwner >= 0)
        throw std::invalid_argument("--landmark-owner and --landmark-namespace: one, once");
      o.landmarkNamespace = a == "--landmark-namespace";
      o.landmarkOwner = static_cast<int>(
          tools::parseIntFlag(a, val(), 0, o.landmarkNamespace ? 1000000000 : 999));
    } else if (a == "--quiet")
      o.quiet = true;
    else if (a.rfind("--", 0) == 0)
      throw std::invalid_argument("unknown flag " + a);
    else if (o.dataset.empty())
      o.dataset = a;
    else
      throw std::invalid_argument("unexpected argument " + a);
  }
  if (o.dataset.empty()) throw std::invalid_argument("no DATASET");
  if (!o.landmarkNamespace && o.landmarkOwner >= o.robots)
    throw std::invalid_argument("--landmark-owner " + std::to_string(o.landmarkOwner) +
                                " needs --robots above it (got " + std::to_string(o.robots) + ")");
  if (o.landmarkNamespace && o.landmarkOwner < o.robots)
    throw std::invalid_argument("--landmark-namespace " + std::to_string(o.landmarkOwner) +
                                " is a robot fed (--robots " + std::to_string(o.robots) +
                                "): a namespace has no poses");
  return o;
}

// The wire names one kind per group: the same keys with other measurements, or the same
// measurement at other keys. A group that mixes both has no wire form.
std::int8_t ambiguousMode(const std::vector<loopd::factor_t>& alternatives, int line) {
  bool keys = true, measurement = true;
  for (const auto& a : alternatives) {
    keys = keys && client::sameKeys(a, alternatives.front());
    measurement = measurement && a.measurement == alternatives.front().measurement &&
                  a.noise == alternatives.front().noise;
  }
  if (keys) return loopd::ambiguous_factor_t::MULTI_MEASUREMENT;
  if (measurement) return loopd::ambiguous_factor_t::MULTI_ASSOCIATION;
  throw std::runtime_error("HYPOTHESES group on line " + std::to_string(line) +
                           " mixes other keys and other measurements: no ambiguous_factor_t mode "
                           "expresses it");
}

int run(const Options& o) {
  io::Dataset ds = io::readDataset(o.dataset);
  const tools::FeedOrder feed(ds, o.poses, o.robots, o.interleave, o.landmarkOwner,
                              o.landmarkNamespace);
  const std::vector<std::int64_t> shared = feed.sharedLandmarks(ds);
  if (!shared.empty() && !o.quiet)
    std::fprintf(stderr,
                 "loopd-feed: %zu landmarks (first: %lld) are sighted by more than one robot: "
                 "their sightings go to %s landmark, which ties the robots' frames "
                 "together\n",
                 shared.size(), static_cast<long long>(shared.front()),
                 o.landmarkOwner >= 0 ? "the owner's" : "the first robot's");
  if (o.landmarkNamespace && !o.quiet)
    std::fprintf(stderr,
                 "loopd-feed: every landmark is landmark namespace %d's: serve with loopd "
                 "--landmark-namespace %d\n",
                 o.landmarkOwner, o.landmarkOwner);
  const std::vector<std::int64_t> othersOnly =
      o.landmarkNamespace ? std::vector<std::int64_t>{} : feed.landmarksOnlyOthersSight(ds);
  if (!othersOnly.empty() && !o.quiet)
    std::fprintf(stderr,
                 "loopd-feed: %zu landmarks of robot %d (first: %lld) are sighted only by other "
                 "robots: the server places them once those robots' frames are joined to its\n",
                 othersOnly.size(), o.landmarkOwner, static_cast<long long>(othersOnly.front()));
  const std::vector<std::int64_t>& order = feed.poses();
  const size_t n = order.size();
  const size_t robots = static_cast<size_t>(feed.robots());
  // Each edge is due when its last pose appears; a HYPOTHESES group when the last pose of any
  // of its alternatives does.
  std::vector<std::vector<const io::Edge*>> due(n);
  std::vector<std::vector<const io::HypothesisGroup*>> dueGroups(n);
  size_t skipped = 0;
  std::vector<char> inGroup(ds.edges.size(), 0);
  for (const io::HypothesisGroup& g : ds.hypotheses) {
    for (int k = 0; k < g.count; ++k) inGroup[static_cast<size_t>(g.firstEdge + k)] = 1;
    const long at = feed.dueAt(ds, g);  // as FeedOrder counts it for landmark owners
    if (at < 0)
      skipped += static_cast<size_t>(g.count);
    else
      dueGroups[static_cast<size_t>(at)].push_back(&g);
  }
  auto schedule = [&](std::vector<std::vector<const io::Edge*>>& into, const io::Edge& e) {
    const long at = feed.dueAt(e);
    if (at < 0)
      ++skipped;
    else
      into[static_cast<size_t>(at)].push_back(&e);
  };
  for (const auto& e : ds.edges)
    if (!inGroup[static_cast<size_t>(e.index)]) schedule(due, e);
  // TORO EQUIV pairs, numbered after the edges as loopd-solve numbers them.
  std::vector<io::Edge> equivalences;
  std::vector<std::vector<const io::Edge*>> dueEquivalences(n);
  equivalences.reserve(ds.equivalences.size());  // the pointers below stay valid
  for (const auto& [a, b] : ds.equivalences) {
    equivalences.push_back(
        io::equivalenceEdge(a, b, static_cast<int>(ds.edges.size() + equivalences.size())));
    schedule(dueEquivalences, equivalences.back());
  }

  // Where batches go.
  std::unique_ptr<lcm::LCM> lcm;
  std::unique_ptr<lcm::LogFile> log;
  std::int64_t logTime = std::chrono::duration_cast<std::chrono::microseconds>(
                             std::chrono::system_clock::now().time_since_epoch())
                             .count();
  std::int64_t events = 0;
  client::BatchSink sink;
  if (!o.log.empty()) {
    log = std::make_unique<lcm::LogFile>(o.log, "w");
    if (!log->good()) throw std::runtime_error("cannot write " + o.log);
    sink = [&](const std::string& ch, const std::vector<std::uint8_t>& b) {
      lcm::LogEvent ev;
      ev.eventnum = events++;
      ev.timestamp = logTime;
      ev.channel = ch;
      ev.datalen = static_cast<int32_t>(b.size());
      ev.data = const_cast<std::uint8_t*>(b.data());
      if (log->writeEvent(&ev) != 0)
        throw std::runtime_error("cannot write " + o.log + ": " + std::strerror(errno));
    };
  } else {
    lcm = std::make_unique<lcm::LCM>(o.lcmUrl);
    if (!lcm->good()) throw std::runtime_error("cannot open LCM '" + o.lcmUrl + "'");
    sink = [&](const std::string& ch, const std::vector<std::uint8_t>& b) {
      lcm->publish(ch, b.data(), static_cast<unsigned>(b.size()));
    };
  }
  std::vector<std::unique_ptr<client::FactorPublisher>> pubs;
  for (size_t r = 0; r < robots; ++r)
    pubs.push_back(std::make_unique<client::FactorPublisher>(sink, o.sender + std::to_string(r),
                                                             o.prefix + "FACTORS"));

  const auto t0 = std::chrono::steady_clock::now();
  const std::int64_t stepUs = o.rate > 0 ? static_cast<std::int64_t>(1e6 / o.rate) : 1000;
  for (size_t i = 0; i < n; ++i) {
    const std::int64_t id = order[i];
    const int r = feed.robotOf(id);
    client::FactorPublisher& pub = *pubs[static_cast<size_t>(r)];
    if (feed.startsItsRobot(i)) {
      if (ds.is3d)
        pub.initialValue(KeyRef::pose(r, id), client::Pose3{});
      else
        pub.initialValue(KeyRef::pose(r, id), client::Pose2{});
    }
    for (const io::Edge* e : due[i]) pub.factor(feed.factor(*e));
    for (const io::Edge* e : dueEquivalences[i]) pub.factor(feed.equivalenceFactor(*e));
    for (const io::HypothesisGroup* g : dueGroups[i]) {
      std::vector<loopd::factor_t> alternatives;
      for (int k = 0; k < g->count; ++k) {
        alternatives.push_back(feed.factor(ds.edges[static_cast<size_t>(g->firstEdge + k)]));
        alternatives.back().id = 0;
        alternatives.back().role = loopd::factor_t::ROLE_LOOP_CLOSURE;
        if (alternatives.back().type != loopd::factor_t::BETWEEN_SE2 &&
            alternatives.back().type != loopd::factor_t::BETWEEN_SE3)
          alternatives.back().role = loopd::factor_t::ROLE_LANDMARK;
      }
      // Group ids follow the edge indices: file order, never an edge's id.
      const std::int64_t id =
          static_cast<std::int64_t>(ds.edges.size()) + (g - ds.hypotheses.data());
      pub.ambiguous(ambiguousMode(alternatives, g->line), alternatives, g->null, 0.0, id);
    }
    pub.flush();
    logTime += stepUs;
    if (lcm && o.rate > 0) {
      const auto due =
          t0 + std::chrono::microseconds(static_cast<std::int64_t>((i + 1) * 1e6 / o.rate));
      std::this_thread::sleep_until(due);
    }
    if (!o.quiet && (i + 1) % 1000 == 0)
      std::fprintf(stderr, "loopd-feed: %zu/%zu poses\n", i + 1, n);
  }
  if (log) {
    // The events reach the file on the flush: a full disk shows here (or at the close).
    std::FILE* f = log->getFilePtr();
    if (std::fflush(f) != 0 || std::ferror(f))
      throw std::runtime_error("cannot write " + o.log + ": " + std::strerror(errno));
    log.reset();
  }
  std::int64_t batches = 0;
  for (auto& p : pubs) batches += p->batchesPublished();
  if (!o.quiet)
    std::fprintf(
        stderr, "loopd-feed: %zu poses, %zu robots, %lld batches%s in %.2f s%s\n", n, robots,
        static_cast<long long>(batches),
        o.log.empty() ? " published" : (" logged to " + o.log).c_str(),
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(),
        skipped ? (", " + std::to_string(skipped) + " edges outside --poses skipped").c_str() : "");
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  return tools::parseAndRun("loopd-feed", kUsage, argc, argv, parse, run);
}
