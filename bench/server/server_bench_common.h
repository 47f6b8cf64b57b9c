#pragma once
// Shared pieces of the live-server benchmarks (latency, throughput, soak): a dataset cut into
// per-pose batches exactly as loopd-feed does it, a loopd child process (spawn, RSS from
// /proc, SIGINT stop), and a monitor that follows the server's ESTIMATE and STATUS channels on
// its own thread and records, per published pose, when the first estimate containing it came
// back.
#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <lcm/lcm-cpp.hpp>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <map>
#include <memory>
#include <mutex>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <unordered_map>
#include <vector>

#include "client/estimate_subscriber.h"
#include "client/factor_publisher.h"
#include "loopd/command_t.hpp"
#include "loopd/estimate_t.hpp"
#include "loopd/status_t.hpp"
#include "solvers/io/dataset_reader.h"
#include "tools/common/feed_order.h"

extern char** environ;

namespace loopd::bench {

using Clock = std::chrono::steady_clock;

inline const std::string kBinaryDir = LOOPD_BINARY_DIR;
inline const std::string kDatasetsDir = LOOPD_DATASETS_DIR;

inline double secondsSince(Clock::time_point t0, Clock::time_point t = Clock::now()) {
  return std::chrono::duration<double>(t - t0).count();
}

inline std::int64_t wallUs() {
  return std::chrono::duration_cast<std::chrono::microseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

/// A private udpm URL: port from the pid (and a salt), ttl=0 so nothing leaves the host.
inline std::string privateUrl(int salt = 0) {
  std::system(
      "bash -c 'ip route get 239.255.76.67 >/dev/null 2>&1 || "
      "{ ip link set lo up; ip link set lo multicast on; ip route add 224.0.0.0/4 dev lo; } "
      ">/dev/null 2>&1'");
  const int port = 20000 + static_cast<int>((static_cast<long>(getpid()) * 7 + salt) % 30000);
  return "udpm://239.255.76.67:" + std::to_string(port) + "?ttl=0";
}

inline double loadAverage1() {
  std::ifstream in("/proc/loadavg");
  double l = -1;
  in >> l;
  return l;
}

// --- the dataset as batches (loopd-feed's schedule) -------------------------------------------

struct Step {
  std::int32_t robot = 0;
  std::int64_t id = 0;  // pose index (= file id)
  bool first = false;   // the robot's first pose: sent with an identity initial value
  std::vector<loopd::factor_t> factors;
};

struct Schedule {
  bool is3d = false;
  int robots = 1;
  std::vector<Step> steps;  // in publication order
};

/// Poses (by id, optionally the first `poses`) cut into `robots` consecutive segments; steps in
/// id order or round-robin over the robots (`interleave`); each step carries every edge whose
/// ends have all appeared. Factor ids = file edge indices. Robot ids are offset by robotOffset.
inline Schedule buildSchedule(const io::Dataset& ds, int robotsWanted, bool interleave, long poses,
                              int robotOffset = 0) {
  const tools::FeedOrder feed(ds, poses, robotsWanted, interleave);
  const std::vector<std::int64_t>& order = feed.poses();
  Schedule s;
  s.is3d = ds.is3d;
  s.robots = feed.robots();
  s.steps.resize(order.size());
  for (size_t i = 0; i < order.size(); ++i) {
    const int r = feed.robotOf(order[i]);
    s.steps[i].robot = r + robotOffset;
    s.steps[i].id = order[i];
    s.steps[i].first = feed.startsItsRobot(i);
  }
  for (const auto& e : ds.edges) {
    const long at = feed.dueAt(e);
    if (at >= 0) s.steps[static_cast<size_t>(at)].factors.push_back(feed.factor(e, robotOffset));
  }
  return s;
}

/// Queues one step into its robot's publisher and publishes it (returns the last sequence).
inline std::int64_t publishStep(client::FactorPublisher& pub, const Step& st, bool is3d) {
  if (st.first) {
    if (is3d)
      pub.initialValue(client::KeyRef::pose(st.robot, st.id), client::Pose3{});
    else
      pub.initialValue(client::KeyRef::pose(st.robot, st.id), client::Pose2{});
  }
  for (const auto& f : st.factors) pub.factor(f);
  return pub.flush();
}

// --- the server as a child process ----------------------------------------------------------

struct ServerProcess {
  pid_t pid = -1;
  std::string log;

  bool start(const std::vector<std::string>& args, const std::string& logPath) {
    log = logPath;
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_addopen(&fa, 1, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawn_file_actions_adddup2(&fa, 1, 2);
    std::vector<char*> argv;
    for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    const int rc = posix_spawn(&pid, argv[0], &fa, nullptr, argv.data(), environ);
    posix_spawn_file_actions_destroy(&fa);
    if (rc != 0) pid = -1;
    return pid > 0;
  }
  bool alive() const {
    if (pid <= 0) return false;
    int st;
    return waitpid(pid, &st, WNOHANG) == 0;
  }
  /// VmRSS / VmHWM in kB from /proc (−1 if gone).
  long procKb(const char* field) const {
    if (pid <= 0) return -1;
    std::ifstream in("/proc/" + std::to_string(pid) + "/status");
    std::string line;
    const std::string f = std::string(field) + ":";
    while (std::getline(in, line))
      if (line.rfind(f, 0) == 0) return std::atol(line.c_str() + f.size());
    return -1;
  }
  long rssKb() const { return procKb("VmRSS"); }
  long hwmKb() const { return procKb("VmHWM"); }
  /// SIGINT, wait up to `seconds`, then SIGKILL. Exit code, 128+signal, or −1 if killed.
  int stop(double seconds = 20) {
    if (pid <= 0) return -2;
    ::kill(pid, SIGINT);
    const auto end = Clock::now() + std::chrono::duration<double>(seconds);
    while (Clock::now() < end) {
      int st = 0;
      if (waitpid(pid, &st, WNOHANG) == pid) {
        pid = -1;
        return WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    ::kill(pid, SIGKILL);
    int st;
    waitpid(pid, &st, 0);
    pid = -1;
    return -1;
  }
  ~ServerProcess() {
    if (pid > 0) {
      ::kill(pid, SIGKILL);
      int st;
      waitpid(pid, &st, 0);
    }
  }
};

// --- following the server -------------------------------------------------------------------

struct PoseTiming {
  Clock::time_point sent{};
  std::int64_t sentWallUs = 0;
  bool isSent = false, seen = false;
  Clock::time_point received{};
  std::int64_t serverUtime = 0;  // estimate_t.utime (server clock at publication)
  std::int64_t updateSeq = 0;
};

/// Listens on ESTIMATE and STATUS on its own thread. Poses to time are registered up front
/// (expect), marked sent just before publication (markSent), and marked seen at the first
/// estimate_t chunk that contains them.
class Monitor {
 public:
  Monitor(const std::string& url, const std::string& prefix)
      : prefix_(prefix), lcm_(client::receiveUrl(url)) {
    if (!lcm_.good()) throw std::runtime_error("cannot open LCM at " + url);
    lcm_.subscribe(prefix + "ESTIMATE", &Monitor::onEstimate, this)->setQueueCapacity(0);
    lcm_.subscribe(prefix + "STATUS", &Monitor::onStatus, this)->setQueueCapacity(0);
    thread_ = std::thread([this] {
      while (!stop_) lcm_.handleTimeout(50);
    });
  }
  ~Monitor() {
    stop_ = true;
    if (thread_.joinable()) thread_.join();
  }

  static std::uint64_t keyOf(std::int32_t robot, std::int64_t index) {
    return (static_cast<std::uint64_t>(static_cast<std::uint32_t>(robot)) << 40) ^
           static_cast<std::uint64_t>(index);
  }
  /// Registers poses to time (before any is sent); clears previous ones.
  void expect(const Schedule& s) {
    std::lock_guard<std::mutex> l(mu_);
    timing_.assign(s.steps.size(), PoseTiming{});
    slot_.clear();
    for (size_t i = 0; i < s.steps.size(); ++i) slot_[keyOf(s.steps[i].robot, s.steps[i].id)] = i;
    seenCount_ = 0;
  }
  void markSent(size_t step) {
    std::lock_guard<std::mutex> l(mu_);
    timing_[step].sent = Clock::now();
    timing_[step].sentWallUs = wallUs();
    timing_[step].isSent = true;
  }
  size_t seenCount() const {
    std::lock_guard<std::mutex> l(mu_);
    return seenCount_;
  }
  std::vector<PoseTiming> timings() const {
    std::lock_guard<std::mutex> l(mu_);
    return timing_;
  }
  Clock::time_point lastEstimateAt() const {
    std::lock_guard<std::mutex> l(mu_);
    return lastEstimate_;
  }
  std::int64_t estimatesReceived() const {
    std::lock_guard<std::mutex> l(mu_);
    return estimates_;
  }
  loopd::status_t lastStatus() const {
    std::lock_guard<std::mutex> l(mu_);
    return last_;
  }
  /// First status arrival (after `since`) that is converged with update_seq >= minSeq.
  bool waitConverged(std::int64_t minSeq, double timeout, Clock::time_point& at,
                     loopd::status_t& st) {
    std::unique_lock<std::mutex> l(mu_);
    const auto ok = [&] { return convergedSeq_ >= minSeq && convergedSeq_ > 0; };
    if (!cv_.wait_for(l, std::chrono::duration<double>(timeout), ok)) return false;
    at = convergedAt_;
    st = convergedStatus_;
    return true;
  }
  void resetConverged() {
    std::lock_guard<std::mutex> l(mu_);
    convergedSeq_ = -1;
  }
  /// Sends a command and waits for the status that acknowledges it (REQUEST_STATUS, RESET, ...).
  bool command(std::int8_t cmd, double timeout, loopd::status_t* out = nullptr,
               const std::string& arg = "") {
    const std::int64_t id = ++nextRequest_;
    loopd::command_t c{};
    c.utime = wallUs();
    c.sender = "loopd-bench";
    c.request_id = id;
    c.command = cmd;
    c.argument = arg;
    c.num_keys = 0;
    std::unique_lock<std::mutex> l(mu_);
    const auto end = Clock::now() + std::chrono::duration<double>(timeout);
    while (Clock::now() < end) {
      l.unlock();
      lcm_.publish(prefix_ + "COMMAND", &c);
      l.lock();
      if (cv_.wait_for(l, std::chrono::milliseconds(500), [&] { return replies_.count(id) > 0; })) {
        if (out) *out = replies_[id];
        return true;
      }
    }
    return false;
  }

 private:
  void onEstimate(const lcm::ReceiveBuffer*, const std::string&, const loopd::estimate_t* m) {
    const auto now = Clock::now();
    std::lock_guard<std::mutex> l(mu_);
    ++estimates_;
    lastEstimate_ = now;
    if (m->request_id != 0) return;  // replies to requests do not count as "the update's estimate"
    for (size_t i = 0; i < m->pose_indices.size(); ++i) {
      auto it = slot_.find(keyOf(m->robot, m->pose_indices[i]));
      if (it == slot_.end()) continue;
      PoseTiming& t = timing_[it->second];
      if (t.seen || !t.isSent) continue;
      t.seen = true;
      t.received = now;
      t.serverUtime = m->utime;
      t.updateSeq = m->update_seq;
      ++seenCount_;
    }
  }
  void onStatus(const lcm::ReceiveBuffer*, const std::string&, const loopd::status_t* m) {
    const auto now = Clock::now();
    {
      std::lock_guard<std::mutex> l(mu_);
      if (m->decisions_chunk_index != 0) return;
      last_ = *m;
      if (m->request_id != 0) replies_[m->request_id] = *m;
      if (m->converged && m->update_seq > convergedSeq_) {
        convergedSeq_ = m->update_seq;
        convergedAt_ = now;
        convergedStatus_ = *m;
      }
    }
    cv_.notify_all();
  }

  std::string prefix_;
  lcm::LCM lcm_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
  mutable std::mutex mu_;
  std::condition_variable cv_;
  std::vector<PoseTiming> timing_;
  std::unordered_map<std::uint64_t, size_t> slot_;
  size_t seenCount_ = 0;
  std::int64_t estimates_ = 0;
  Clock::time_point lastEstimate_{};
  loopd::status_t last_{};
  std::map<std::int64_t, loopd::status_t> replies_;
  std::int64_t convergedSeq_ = -1;
  Clock::time_point convergedAt_{};
  loopd::status_t convergedStatus_{};
  std::atomic<std::int64_t> nextRequest_{1000};
};

/// Starts `loopd` on `url` (unless connecting to a running one) and waits until it answers.
inline void startServer(ServerProcess& server, Monitor& mon, const std::string& exe,
                        const std::string& url, const std::string& prefix,
                        const std::vector<std::string>& extra, const std::string& logPath) {
  std::vector<std::string> args = {exe, "--lcm-url", url, "--log-level", "warn"};
  if (prefix != "LOOPD_") {
    args.push_back("--channel-prefix");
    args.push_back(prefix);
  }
  args.insert(args.end(), extra.begin(), extra.end());
  if (!server.start(args, logPath)) throw std::runtime_error("cannot start " + exe);
  if (!mon.command(loopd::command_t::REQUEST_STATUS, 15.0))
    throw std::runtime_error("loopd did not answer within 15 s (log: " + logPath + ")");
}

// --- small statistics -----------------------------------------------------------------------

/// Nearest-rank percentile (p in [0, 100]) of unsorted values.
inline double percentile(std::vector<double> v, double p) {
  if (v.empty()) return std::nan("");
  std::sort(v.begin(), v.end());
  const size_t k = static_cast<size_t>(std::ceil(p / 100.0 * static_cast<double>(v.size())));
  return v[std::min(v.size() - 1, k == 0 ? 0 : k - 1)];
}

inline double mean(const std::vector<double>& v) {
  if (v.empty()) return std::nan("");
  double s = 0;
  for (double x : v) s += x;
  return s / static_cast<double>(v.size());
}

/// Minimal JSON object writer (flat, numbers and strings).
class Json {
 public:
  Json& num(const std::string& k, double v) {
    std::ostringstream s;
    s.precision(10);
    if (std::isfinite(v))
      s << v;
    else
      s << "null";
    add(k, s.str());
    return *this;
  }
  Json& integer(const std::string& k, long long v) {
    add(k, std::to_string(v));
    return *this;
  }
  Json& str(const std::string& k, const std::string& v) {
    std::string e;
    for (char c : v) {
      if (c == '"' || c == '\\') e += '\\';
      e += c;
    }
    add(k, "\"" + e + "\"");
    return *this;
  }
  Json& raw(const std::string& k, const std::string& v) {
    add(k, v);
    return *this;
  }
  std::string text() const { return "{" + body_ + "}"; }
  bool write(const std::string& path) const {
    if (path.empty()) return true;
    std::ofstream out(path);
    out << text() << "\n";
    return static_cast<bool>(out);
  }

 private:
  void add(const std::string& k, const std::string& v) {
    if (!body_.empty()) body_ += ", ";
    body_ += "\"" + k + "\": " + v;
  }
  std::string body_;
};

/// Command-line helper: --flag value pairs, repeatable --server-arg.
struct Args {
  std::map<std::string, std::string> kv;
  std::vector<std::string> serverArgs;
  bool has(const std::string& k) const { return kv.count(k) > 0; }
  std::string get(const std::string& k, const std::string& d) const {
    auto it = kv.find(k);
    return it == kv.end() ? d : it->second;
  }
  double num(const std::string& k, double d) const { return has(k) ? std::stod(kv.at(k)) : d; }
  long integer(const std::string& k, long d) const { return has(k) ? std::stol(kv.at(k)) : d; }
};

inline Args parseArgs(int argc, char** argv, const std::vector<std::string>& known,
                      const std::vector<std::string>& switches, const char* usage) {
  Args a;
  for (int i = 1; i < argc; ++i) {
    std::string k = argv[i];
    if (k == "--help" || k == "-h") {
      std::fputs(usage, stdout);
      std::exit(0);
    }
    if (k.rfind("--", 0) != 0) throw std::invalid_argument("unexpected argument " + k);
    k = k.substr(2);
    if (std::find(switches.begin(), switches.end(), k) != switches.end()) {
      a.kv[k] = "1";
      continue;
    }
    if (std::find(known.begin(), known.end(), k) == known.end())
      throw std::invalid_argument("unknown flag --" + k);
    if (i + 1 >= argc) throw std::invalid_argument("--" + k + " needs a value");
    if (k == "server-arg")
      a.serverArgs.push_back(argv[++i]);
    else
      a.kv[k] = argv[++i];
  }
  return a;
}

/// main() of a benchmark: run(parseArgs(...)). A parse error prints the message, a blank line
/// and the usage to stderr and returns 2; a run error prints "TAG: message" to stderr and
/// returns 1; otherwise run's result.
inline int benchMain(int argc, char** argv, const std::vector<std::string>& known,
                     const std::vector<std::string>& switches, const char* usage, const char* tag,
                     int (*run)(const Args&)) {
  Args a;
  try {
    a = parseArgs(argc, argv, known, switches, usage);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "%s\n\n%s", e.what(), usage);
    return 2;
  }
  try {
    return run(a);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "%s: %s\n", tag, e.what());
    return 1;
  }
}

}  // namespace loopd::bench
