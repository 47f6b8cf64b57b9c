#pragma once
// Helpers for tests that run loopd, loopd-feed, loopd-listen and loopd-solve as processes over
// real LCM: a unique udpm URL per test, a multicast route if the host has none, spawning with
// a timeout, reading g2o vertex files.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

extern char** environ;

namespace loopd::testing_live {

inline const std::string kBin = LOOPD_BINARY_DIR;
inline const std::string kLoopd = kBin + "/server/loopd";
inline const std::string kFeed = kBin + "/tools/loopd-feed";
inline const std::string kListen = kBin + "/tools/loopd-listen";
inline const std::string kSolve = kBin + "/tools/loopd-solve";
inline const std::string kData = LOOPD_DATASETS_DIR;

// An AddressSanitizer build runs the server several times slower: a batch of 4-robot
// city10000 or an idle optimize can outlast a quiet period sized for Release. Quiet periods
// and waits scale by this.
#if defined(__SANITIZE_ADDRESS__)
inline constexpr double kSlowdown = 10.0;
#else
inline constexpr double kSlowdown = 1.0;
#endif

/// A loopd-listen --until-quiet argument: `seconds` in a Release build.
inline std::string quietFor(double seconds) { return std::to_string(seconds * kSlowdown); }

/// Routes multicast through lo when the host has no route (scripts/ensure-multicast.sh).
inline void ensureMulticast() {
  static bool done = false;
  if (done) return;
  done = true;
  if (std::system("ip route get 239.255.76.67 >/dev/null 2>&1") == 0) return;
  std::system(
      "ip link set lo up 2>/dev/null; ip link set lo multicast on 2>/dev/null; "
      "ip route add 224.0.0.0/4 dev lo 2>/dev/null");
}

/// A udpm URL of its own for each test (port from the test's name and the pid).
inline std::string uniqueUrl(int salt = 0) {
  ensureMulticast();
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  std::size_t h = std::hash<std::string>()(std::string(info->test_suite_name()) + info->name());
  const int port = 20000 + static_cast<int>((h + static_cast<std::size_t>(getpid()) * 7 +
                                             static_cast<std::size_t>(salt)) %
                                            30000);
  return "udpm://239.255.76.67:" + std::to_string(port) + "?ttl=0";
}

inline std::string tmp(const std::string& name) {
  return ::testing::TempDir() + "/" + std::to_string(getpid()) + "_" + name;
}

struct Proc {
  pid_t pid = -1;
  std::string log;
  /// Starts argv[0] with args; stdout+stderr to `log`.
  static Proc start(const std::vector<std::string>& args, const std::string& log) {
    Proc p;
    p.log = log;
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_addopen(&fa, 1, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawn_file_actions_adddup2(&fa, 1, 2);
    std::vector<char*> argv;
    for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    if (posix_spawn(&p.pid, argv[0], &fa, nullptr, argv.data(), environ) != 0) p.pid = -1;
    posix_spawn_file_actions_destroy(&fa);
    return p;
  }
  /// Waits up to `seconds` (× kSlowdown); returns the exit code, or −1 on timeout (then kills it),
  /// 128+sig.
  int wait(double seconds) {
    const auto end =
        std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds * kSlowdown);
    while (std::chrono::steady_clock::now() < end) {
      int st = 0;
      const pid_t r = waitpid(pid, &st, WNOHANG);
      if (r == pid) {
        pid = -1;
        return WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    kill(SIGKILL);
    return -1;
  }
  void kill(int sig) {
    if (pid > 0) {
      ::kill(pid, sig);
      if (sig == SIGKILL) {
        int st;
        waitpid(pid, &st, 0);
        pid = -1;
      }
    }
  }
  bool alive() const {
    if (pid <= 0) return false;
    int st;
    return waitpid(pid, &st, WNOHANG) == 0;
  }
  std::string output() const {
    std::stringstream s;
    s << std::ifstream(log).rdbuf();
    return s.str();
  }
  /// Waits until the log holds `text` (a slow start, as under the sanitizers, takes seconds).
  bool waitForOutput(const std::string& text, double seconds) const {
    const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
    while (output().find(text) == std::string::npos) {
      if (std::chrono::steady_clock::now() > end) return false;
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return true;
  }
  ~Proc() {
    if (pid > 0) kill(SIGKILL);
  }
  Proc() = default;
  Proc(Proc&& o) noexcept : pid(o.pid), log(std::move(o.log)) { o.pid = -1; }
  Proc& operator=(Proc&& o) noexcept {
    if (pid > 0) kill(SIGKILL);
    pid = o.pid;
    log = std::move(o.log);
    o.pid = -1;
    return *this;
  }
};

inline int runTool(const std::vector<std::string>& args, const std::string& log,
                   double timeout = 120) {
  Proc p = Proc::start(args, log);
  return p.wait(timeout);
}

/// The whole of a text file ("" if it cannot be read).
inline std::string readText(const std::string& path) {
  std::stringstream text;
  text << std::ifstream(path).rdbuf();
  return text.str();
}

/// id → values of every VERTEX line.
inline std::map<long, std::vector<double>> readVertices(const std::string& path) {
  std::map<long, std::vector<double>> out;
  std::ifstream in(path);
  std::string line;
  while (std::getline(in, line)) {
    std::istringstream s(line);
    std::string tag;
    long id;
    if (!(s >> tag >> id) || tag.rfind("VERTEX", 0) != 0) continue;
    std::vector<double> v;
    double x;
    while (s >> x) v.push_back(x);
    out[id] = v;
  }
  return out;
}

/// Largest position and (2D) heading difference between two SE2 estimates over shared ids.
inline std::pair<double, double> maxDifference(const std::map<long, std::vector<double>>& a,
                                               const std::map<long, std::vector<double>>& b) {
  double dt = 0, dr = 0;
  for (const auto& [id, x] : a) {
    auto it = b.find(id);
    if (it == b.end()) continue;
    const auto& y = it->second;
    dt = std::max(dt, std::hypot(x[0] - y[0], x[1] - y[1]));
    double d = std::remainder(x[2] - y[2], 2 * M_PI);
    dr = std::max(dr, std::abs(d));
  }
  return {dt, dr};
}

/// "chi2 511.985164" from loopd-listen's summary line.
inline double listenedChi2(const std::string& out) {
  const auto p = out.find("chi2 ");
  return p == std::string::npos ? -1.0 : std::stod(out.substr(p + 5));
}

/// final_chi2 from a loopd-solve stats JSON.
inline double statsChi2(const std::string& json) {
  std::stringstream s;
  s << std::ifstream(json).rdbuf();
  const std::string t = s.str();
  const auto p = t.find("\"final_chi2\":");
  return p == std::string::npos ? -1.0 : std::stod(t.substr(p + 13));
}

}  // namespace loopd::testing_live
