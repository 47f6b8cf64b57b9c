// loopd-view (issue 7) as users run it: its HTTP endpoints against well-formed and hostile
// requests over raw sockets, and end to end — loopd, loopd-view and loopd-feed over real LCM,
// the page in headless Chromium (Debian's `chromium`, driven by the DevTools protocol over
// --remote-debugging-pipe), the drawing checked through the data-* attributes the page writes
// after each frame, and a screenshot saved next to the test's other temporary files.
#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>

#include <lcm/lcm-cpp.hpp>

#include <functional>
#include <regex>
#include <set>

#include "client/factor_publisher.h"
#include "loopd/command_t.hpp"
#include "tests/server/live_util.h"

using namespace loopd::testing_live;

namespace {

const std::string kView = kBin + "/tools/loopd-view/loopd-view";
const std::string kOutliers = kBin + "/tools/loopd-outliers";

/// Starts loopd-view on a free HTTP port; returns the port (0 on failure).
int startView(Proc& view, const std::string& lcmUrl, const std::string& log,
              const std::vector<std::string>& extra = {}) {
  std::vector<std::string> args = {kView, "--lcm-url", lcmUrl, "--port", "0"};
  args.insert(args.end(), extra.begin(), extra.end());
  view = Proc::start(args, log);
  const std::regex re("http://127\\.0\\.0\\.1:([0-9]+)/");
  for (int i = 0; i < 250; ++i) {
    std::smatch m;
    const std::string out = view.output();
    if (std::regex_search(out, m, re)) return std::stoi(m[1]);
    if (!view.alive()) return 0;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return 0;
}

int connectTo(int port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(static_cast<uint16_t>(port));
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) {
    ::close(fd);
    return -1;
  }
  return fd;
}

/// Reads until the peer closes, `until` appears, or `seconds` pass.
std::string readFrom(int fd, double seconds, const std::string& until = "") {
  std::string out;
  const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
  char buf[65536];
  while (std::chrono::steady_clock::now() < end) {
    pollfd p{fd, POLLIN, 0};
    if (::poll(&p, 1, 50) <= 0) continue;
    const ssize_t k = ::recv(fd, buf, sizeof buf, 0);
    if (k <= 0) break;
    out.append(buf, static_cast<size_t>(k));
    if (!until.empty() && out.find(until) != std::string::npos) break;
  }
  return out;
}

/// Reads until the peer closes or `seconds` pass; `reset` tells whether the connection ended
/// with a reset (ECONNRESET) instead of an orderly close.
std::string readToClose(int fd, double seconds, bool& reset) {
  std::string out;
  reset = false;
  const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
  char buf[4096];
  while (std::chrono::steady_clock::now() < end) {
    pollfd p{fd, POLLIN, 0};
    if (::poll(&p, 1, 50) <= 0) continue;
    const ssize_t k = ::recv(fd, buf, sizeof buf, 0);
    if (k < 0 && errno == EINTR) continue;
    if (k <= 0) {
      reset = k < 0 && errno == ECONNRESET;
      break;
    }
    out.append(buf, static_cast<size_t>(k));
  }
  return out;
}

/// Sends raw bytes as one request and returns everything the server answers.
std::string raw(int port, const std::string& bytes, double seconds = 5) {
  const int fd = connectTo(port);
  if (fd < 0) return "<connect failed>";
  size_t off = 0;
  while (off < bytes.size()) {
    const ssize_t k = ::send(fd, bytes.data() + off, bytes.size() - off, MSG_NOSIGNAL);
    if (k <= 0) break;
    off += static_cast<size_t>(k);
  }
  std::string out = readFrom(fd, seconds);
  ::close(fd);
  return out;
}

int statusOf(const std::string& response) {
  if (response.rfind("HTTP/1.1 ", 0) != 0 || response.size() < 12) return -1;
  return std::stoi(response.substr(9, 3));
}

std::string get(int port, const std::string& path) {
  return raw(port, "GET " + path + " HTTP/1.1\r\nHost: localhost\r\n\r\n");
}

/// Waits until the view has heard the server (its status is relayed): feeding before the
/// server listens would lose batches.
bool waitForServer(int port, double seconds = 20) {
  const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
  while (std::chrono::steady_clock::now() < end) {
    if (get(port, "/state.json").find("\"status\":{") != std::string::npos) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  return false;
}

// ---------------------------------------------------------------------------------------------

TEST(LoopdViewHttp, ServesThePageItsAssetsAndState) {
  Proc view;
  const int port = startView(view, uniqueUrl(), tmp("view.log"));
  ASSERT_GT(port, 0) << view.output();
  const std::string page = get(port, "/");
  EXPECT_EQ(statusOf(page), 200) << page.substr(0, 300);
  EXPECT_NE(page.find("Content-Type: text/html"), std::string::npos);
  EXPECT_NE(page.find("<canvas id=\"map\""), std::string::npos);
  EXPECT_NE(page.find("Content-Security-Policy: default-src 'self'"), std::string::npos);
  for (const char* p :
       {"/index.html", "/app.js", "/style.css", "/healthz", "/state.json", "/?plane=xz"})
    EXPECT_EQ(statusOf(get(port, p)), 200) << p;
  EXPECT_NE(get(port, "/app.js").find("text/javascript"), std::string::npos);
  // Nothing on the page comes from anywhere else (no CDN): no absolute URLs in the assets.
  for (const char* p : {"/", "/app.js", "/style.css"}) {
    const std::string body = get(port, p);
    EXPECT_EQ(body.find("https://"), std::string::npos) << p;
    EXPECT_EQ(body.find("http://"), std::string::npos) << p;
  }
  const std::string state = get(port, "/state.json");
  EXPECT_NE(state.find("{\"seq\":"), std::string::npos) << state.substr(0, 400);
  EXPECT_NE(state.find("\"status\":null"), std::string::npos);  // no server on this URL
  // HEAD: headers only.
  const std::string head = raw(port, "HEAD / HTTP/1.1\r\nHost: localhost\r\n\r\n");
  EXPECT_EQ(statusOf(head), 200);
  EXPECT_EQ(head.find("<canvas"), std::string::npos);
  // Loopback names in Host are fine.
  for (const char* host :
       {"localhost", "localhost:8080", "127.0.0.1:1234", "[::1]:80", "view.localhost"})
    EXPECT_EQ(
        statusOf(raw(port, std::string("GET /healthz HTTP/1.1\r\nHost: ") + host + "\r\n\r\n")),
        200)
        << host;
  // HTTP/1.0 and a bare-LF client are served too.
  EXPECT_EQ(statusOf(raw(port, "GET /healthz HTTP/1.0\n\n")), 200);
  view.kill(SIGINT);
  EXPECT_EQ(view.wait(10), 0) << view.output();
}

TEST(LoopdViewHttp, RejectsBadRequestsCleanlyAndKeepsServing) {
  Proc view;
  const int port = startView(view, uniqueUrl(), tmp("view.log"));
  ASSERT_GT(port, 0) << view.output();
  struct Case {
    std::string name, bytes;
    int status;
  };
  const std::string nul("GET /\0 HTTP/1.1\r\n\r\n", 20);
  const std::vector<Case> cases = {
      {"unknown path", "GET /nope HTTP/1.1\r\nHost: localhost\r\n\r\n", 404},
      {"path traversal", "GET /../../etc/passwd HTTP/1.1\r\n\r\n", 404},
      {"POST", "POST / HTTP/1.1\r\nContent-Length: 3\r\n\r\nabc", 405},
      {"PUT", "PUT /state.json HTTP/1.1\r\n\r\n", 405},
      {"DELETE", "DELETE /events HTTP/1.1\r\n\r\n", 405},
      {"garbage line", "HELLO\r\n\r\n", 400},
      {"two parts", "GET /\r\n\r\n", 400},
      {"four parts", "GET / HTTP/1.1 extra\r\n\r\n", 400},
      {"double space", "GET  / HTTP/1.1\r\n\r\n", 400},
      {"target not a path", "GET index.html HTTP/1.1\r\n\r\n", 400},
      {"absolute URL target", "GET http://evil/ HTTP/1.1\r\n\r\n", 400},
      {"bad version", "GET / FTP/1.1\r\n\r\n", 400},
      {"unsupported version", "GET / HTTP/2.0\r\n\r\n", 505},
      {"method with bad chars", "G(T / HTTP/1.1\r\n\r\n", 400},
      {"header without colon", "GET / HTTP/1.1\r\nNoColonHere\r\n\r\n", 400},
      {"header name with space", "GET / HTTP/1.1\r\nBad Name: x\r\n\r\n", 400},
      {"control character in header",
       "GET / HTTP/1.1\r\nX: a\x01"
       "b\r\n\r\n",
       400},
      {"NUL in target", nul, 400},
      {"binary", std::string("\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03\r\n\r\n", 15), 400},
      {"oversized headers", "GET / HTTP/1.1\r\nX-Big: " + std::string(40000, 'a') + "\r\n\r\n",
       431},
      {"endless header, never terminated", "GET / HTTP/1.1\r\n" + std::string(100000, 'b'), 431},
      {"truncated request, then closed", "GET / HT", 400},
      {"foreign Host (DNS rebinding)",
       "GET /state.json HTTP/1.1\r\nHost: evil.example:8080\r\n\r\n", 403},
      {"two Host headers", "GET / HTTP/1.1\r\nHost: localhost\r\nHost: evil.example\r\n\r\n", 400},
  };
  for (const auto& c : cases) {
    std::string r;
    if (c.name == "truncated request, then closed") {
      const int fd = connectTo(port);
      ASSERT_GE(fd, 0);
      ::send(fd, c.bytes.data(), c.bytes.size(), MSG_NOSIGNAL);
      ::shutdown(fd, SHUT_WR);
      r = readFrom(fd, 5);
      ::close(fd);
    } else {
      r = raw(port, c.bytes);
    }
    EXPECT_EQ(statusOf(r), c.status) << c.name << ": " << r.substr(0, 200);
    EXPECT_NE(r.find("Connection: close"), std::string::npos) << c.name;
    EXPECT_TRUE(view.alive()) << c.name;
  }
  EXPECT_NE(raw(port, "POST / HTTP/1.1\r\n\r\n").find("Allow: GET, HEAD"), std::string::npos);

  // A client that connects and says nothing holds only its own connection: others are served
  // at once, and the silent one is dropped after the header timeout.
  const int silent = connectTo(port);
  ASSERT_GE(silent, 0);
  const auto t0 = std::chrono::steady_clock::now();
  EXPECT_EQ(statusOf(get(port, "/healthz")), 200);
  EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), 1.0);
  ::close(silent);

  // Past 64 simultaneous connections: a clean 503 for the extra ones, and service again once
  // they are gone.
  std::vector<int> idle;
  for (int i = 0; i < 80; ++i) idle.push_back(connectTo(port));
  int refused = 0, closed = 0;
  for (int fd : idle) {
    const std::string r = readFrom(fd, 0.05);
    refused += statusOf(r) == 503;
    closed += !r.empty() && statusOf(r) != 503;
  }
  EXPECT_GE(refused, 16) << "refused " << refused << ", other answers " << closed;
  EXPECT_EQ(closed, 0);
  EXPECT_TRUE(view.alive());
  for (int fd : idle) ::close(fd);
  bool back = false;
  for (int i = 0; i < 50 && !back; ++i) {
    back = statusOf(get(port, "/healthz")) == 200;
    if (!back) std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  EXPECT_TRUE(back);
  EXPECT_TRUE(view.alive());
  view.kill(SIGINT);
  EXPECT_EQ(view.wait(10), 0) << view.output();
}

// A browser sends its request right after connecting. Past the limit the view used to answer
// 503 and close with that request unread: the kernel then resets the connection (many
// clients, Windows' and browsers', drop the answer on a reset; Linux shows it, then
// ECONNRESET).
TEST(LoopdViewHttp, AnswersAConnectionPastTheLimitWith503NotAReset) {
  Proc view;
  const int port = startView(view, uniqueUrl(), tmp("view.log"));
  ASSERT_GT(port, 0) << view.output();
  std::vector<int> held;
  for (int i = 0; i < 64; ++i) held.push_back(connectTo(port));  // silent: held for 10 s
  std::this_thread::sleep_for(std::chrono::milliseconds(300));   // all accepted
  const std::string req = "GET /healthz HTTP/1.1\r\nHost: localhost\r\n\r\n";
  std::vector<int> extra;
  for (int i = 0; i < 8; ++i) {
    const int fd = connectTo(port);
    ASSERT_GE(fd, 0);
    ::send(fd, req.data(), req.size(), MSG_NOSIGNAL);
    extra.push_back(fd);
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(300));  // a reset would be here by now
  for (int fd : extra) {
    bool reset = false;
    const std::string r = readToClose(fd, 5, reset);
    EXPECT_FALSE(reset) << "the connection was reset after '" << r.substr(0, 40) << "...'";
    EXPECT_EQ(statusOf(r), 503) << r.substr(0, 200);
    EXPECT_NE(r.find("Retry-After: 1\r\n"), std::string::npos);
    EXPECT_NE(r.find("Connection: close"), std::string::npos);
    ::close(fd);
  }
  for (int fd : held) ::close(fd);
  bool back = false;
  for (int i = 0; i < 50 && !back; ++i) {
    back = statusOf(get(port, "/healthz")) == 200;
    if (!back) std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  EXPECT_TRUE(back);
  view.kill(SIGINT);
  EXPECT_EQ(view.wait(10), 0) << view.output();
}

TEST(LoopdViewHttp, SeveralEventStreamsGetTheNewestState) {
  const std::string url = uniqueUrl();
  Proc srv = Proc::start({kLoopd, "--lcm-url", url}, tmp("srv.log"));
  Proc view;
  const int port = startView(view, url, tmp("view.log"));
  ASSERT_GT(port, 0) << view.output();
  std::vector<int> tabs;
  for (int i = 0; i < 5; ++i) {
    const int fd = connectTo(port);
    ASSERT_GE(fd, 0);
    const std::string req = "GET /events HTTP/1.1\r\nAccept: text/event-stream\r\n\r\n";
    ::send(fd, req.data(), req.size(), MSG_NOSIGNAL);
    tabs.push_back(fd);
  }
  ASSERT_TRUE(waitForServer(port)) << "no status from loopd";
  ASSERT_EQ(runTool({kFeed, kData + "/intel.g2o", "--poses", "300", "--rate", "1000", "--lcm-url",
                     url, "--quiet"},
                    tmp("feed.log")),
            0);
  // Every tab sees the 300 poses (the server's status, relayed) within a few seconds.
  for (int fd : tabs) {
    const std::string s = readFrom(fd, 10, "\"poses\":300,");
    EXPECT_NE(s.find("Content-Type: text/event-stream"), std::string::npos);
    EXPECT_NE(s.find("event: state\n"), std::string::npos);
    EXPECT_NE(s.find("\"poses\":300,"), std::string::npos) << s.substr(0, 300);
    ::close(fd);
  }
  EXPECT_EQ(statusOf(get(port, "/healthz")), 200);
  view.kill(SIGINT);
  EXPECT_EQ(view.wait(10), 0) << view.output();
  srv.kill(SIGINT);
  srv.wait(20);
}

// ---------------------------------------------------------------------------------------------
// What the view shows against what the server holds: a front-end of the test's own publishes
// over LCM; /state.json is read back.

/// The view's state once `done` holds on it, or its last state after `seconds`.
std::string stateWhen(int port, const std::function<bool(const std::string&)>& done,
                      double seconds = 20) {
  const auto end =
      std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds * kSlowdown);
  while (true) {
    const std::string s = get(port, "/state.json");
    if (done(s) || std::chrono::steady_clock::now() > end) return s;
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
}

/// The number after `"key":` in the part of the state that starts at `section` (-1 if none).
long long numberIn(const std::string& state, const std::string& key,
                   const std::string& section = "\"status\":{") {
  const size_t from = state.find(section);
  if (from == std::string::npos) return -1;
  const size_t p = state.find("\"" + key + "\":", from);
  if (p == std::string::npos) return -1;
  return std::atoll(state.c_str() + p + key.size() + 3);
}

/// How many links the page is given to draw.
int linksIn(const std::string& state) {
  const size_t b = state.find("\"links\":[");
  if (b == std::string::npos) return -1;
  int depth = 0, n = 0;
  for (size_t i = b + 8; i < state.size(); ++i) {
    if (state[i] == '[' && ++depth == 2) ++n;
    if (state[i] == ']' && --depth == 0) break;
  }
  return n;
}

/// robot id → poses the page is given to draw.
std::map<int, int> robotsIn(const std::string& state) {
  std::map<int, int> out;
  const std::regex re("\\{\"id\":([0-9]+),[^\\[]*\"d\":([23]),\"p\":\\[([^\\]]*)\\]");
  const size_t b = state.find("\"robots\":[");
  const size_t e = state.find("\"covariances\":[");
  if (b == std::string::npos || e == std::string::npos) return out;
  const std::string robots = state.substr(b, e - b);
  for (std::sregex_iterator it(robots.begin(), robots.end(), re), end; it != end; ++it) {
    const std::string p = (*it)[3];
    const long numbers = p.empty() ? 0 : std::count(p.begin(), p.end(), ',') + 1;
    out[std::stoi((*it)[1])] = static_cast<int>(numbers / std::stoi((*it)[2]));
  }
  return out;
}

const Eigen::Matrix3d kInfo = Eigen::Vector3d(100, 100, 1000).asDiagonal();

/// `n` odometry steps of `robot` from pose 0, in one batch.
void drive(loopd::client::FactorPublisher& pub, int robot, int n) {
  for (int i = 1; i <= n; ++i)
    pub.odometry(robot, i - 1, i, loopd::client::Pose2{1.0, 0.0, i % 3 == 0 ? 1.5 : 0.0}, kInfo);
  pub.flush();
}

std::int64_t closeLoop(loopd::client::FactorPublisher& pub, int robot, int from, int to,
                       const Eigen::Matrix3d& info = kInfo) {
  using loopd::client::KeyRef;
  return pub.loopClosure(KeyRef::pose(robot, from), KeyRef::pose(robot, to),
                         loopd::client::Pose2{0.0, 0.0, 0.0}, info);
}

void sendReset(lcm::LCM& lcm) {
  loopd::command_t c{};
  c.sender = "test";
  c.request_id = 7;
  c.command = loopd::command_t::RESET;
  c.num_keys = 0;
  lcm.publish("LOOPD_COMMAND", &c);
}

// Before the fix the view drew every loop closure it saw on the factor channel: those of a
// refused batch, of a duplicate the server ignored, and it hid the closure a refused batch
// wanted removed.
TEST(LoopdViewState, DrawsOnlyTheClosuresTheServerAccepted) {
  const std::string url = uniqueUrl();
  Proc srv = Proc::start({kLoopd, "--lcm-url", url}, tmp("srv.log"));
  Proc view;
  const int port = startView(view, url, tmp("view.log"));
  ASSERT_GT(port, 0) << view.output();
  ASSERT_TRUE(waitForServer(port)) << "no status from loopd";
  lcm::LCM lcm(url);
  loopd::client::FactorPublisher pub(lcm, "front");
  drive(pub, 0, 6);  // seq 1
  const std::int64_t kept = closeLoop(pub, 0, 6, 0);
  pub.flush();  // seq 2: accepted
  closeLoop(pub, 0, 5, 1, Eigen::Matrix3d::Zero());
  pub.flush();  // seq 3: refused, NOT_POSITIVE_DEFINITE
  pub.setNextSequence(2);
  closeLoop(pub, 0, 4, 0);
  pub.flush();  // seq 2 again: a duplicate, ignored
  pub.setNextSequence(4);
  pub.remove(kept);
  closeLoop(pub, 0, 3, 0, Eigen::Matrix3d::Zero());
  pub.flush();  // seq 4: refused whole, the removal with it
  std::string st = stateWhen(port, [](const std::string& s) {
    return numberIn(s, "batches_rejected") == 2 && numberIn(s, "batches_duplicate") == 1;
  });
  ASSERT_EQ(numberIn(st, "batches_rejected"), 2) << st.substr(0, 2000);
  ASSERT_EQ(numberIn(st, "batches_duplicate"), 1);
  // Refusals are published on arrival, the estimate after the solve: on a loaded machine the
  // status can run ahead of it (CI once read the state before the poses were in).
  st = stateWhen(port, [](const std::string& s) { return robotsIn(s)[0] == 7; });
  ASSERT_EQ(robotsIn(st)[0], 7) << st.substr(0, 2000);
  std::this_thread::sleep_for(std::chrono::milliseconds(300));  // anything left in flight
  st = get(port, "/state.json");
  EXPECT_EQ(numberIn(st, "loop_closures"), 1);
  EXPECT_EQ(linksIn(st), 1) << st.substr(st.find("\"links\""), 400);
  EXPECT_EQ(numberIn(st, "accepted", "\"link_counts\":{"), 1);
  EXPECT_EQ(numberIn(st, "pending", "\"link_counts\":{"), 0);
  EXPECT_EQ(numberIn(st, "duplicate_batches", "\"link_counts\":{"), 1);

  pub.remove(kept);
  pub.flush();  // seq 5: accepted, the closure is gone
  st = stateWhen(port, [](const std::string& s) { return numberIn(s, "loop_closures") == 0; });
  EXPECT_EQ(numberIn(st, "loop_closures"), 0);
  EXPECT_EQ(linksIn(st), 0);
  view.kill(SIGINT);
  EXPECT_EQ(view.wait(10), 0) << view.output();
  srv.kill(SIGINT);
  srv.wait(20);
}

// Before the fix the view (and client::EstimateSubscriber under it) kept every robot, pose and
// closure after a RESET, and after a restart without --resume.
TEST(LoopdViewState, ForgetsTheGraphAfterResetAndAfterARestart) {
  const std::string url = uniqueUrl();
  Proc srv = Proc::start({kLoopd, "--lcm-url", url}, tmp("srv.log"));
  Proc view;
  const int port = startView(view, url, tmp("view.log"));
  ASSERT_GT(port, 0) << view.output();
  ASSERT_TRUE(waitForServer(port)) << "no status from loopd";
  lcm::LCM lcm(url);
  loopd::client::FactorPublisher pub(lcm, "front");
  drive(pub, 0, 6);
  drive(pub, 1, 4);
  closeLoop(pub, 0, 6, 0);
  pub.flush();
  std::string st = stateWhen(port, [](const std::string& s) {
    return robotsIn(s) == std::map<int, int>{{0, 7}, {1, 5}} && linksIn(s) == 1;
  });
  ASSERT_EQ(robotsIn(st), (std::map<int, int>{{0, 7}, {1, 5}})) << st.substr(0, 2000);
  ASSERT_EQ(linksIn(st), 1);

  sendReset(lcm);
  st = stateWhen(port, [](const std::string& s) { return robotsIn(s).empty(); });
  EXPECT_TRUE(robotsIn(st).empty()) << st.substr(0, 2000);
  EXPECT_EQ(linksIn(st), 0);
  EXPECT_EQ(numberIn(st, "decisions", "\"link_counts\":{"), 0);
  EXPECT_NE(st.find("\"covariances\":[]"), std::string::npos);

  // Sequences start again at 1 after a RESET: not duplicates.
  pub.setNextSequence(1);
  drive(pub, 0, 3);
  closeLoop(pub, 0, 3, 0);
  pub.flush();
  st = stateWhen(port, [](const std::string& s) {
    return robotsIn(s) == std::map<int, int>{{0, 4}} && linksIn(s) == 1;
  });
  EXPECT_EQ(robotsIn(st), (std::map<int, int>{{0, 4}})) << st.substr(0, 2000);
  EXPECT_EQ(linksIn(st), 1);

  // A restart without --resume that gets data before its first heartbeat.
  srv.kill(SIGINT);
  ASSERT_EQ(srv.wait(20), 0);
  srv = Proc::start({kLoopd, "--lcm-url", url}, tmp("srv2.log"));
  ASSERT_TRUE(srv.waitForOutput("loopd: solver", 20 * kSlowdown)) << srv.output();
  std::this_thread::sleep_for(std::chrono::milliseconds(50));
  loopd::client::FactorPublisher pub2(lcm, "other");
  drive(pub2, 5, 2);
  st = stateWhen(port, [](const std::string& s) {
    return robotsIn(s) == std::map<int, int>{{5, 3}};
  });
  EXPECT_EQ(robotsIn(st), (std::map<int, int>{{5, 3}})) << st.substr(0, 2000);
  EXPECT_EQ(linksIn(st), 0);
  view.kill(SIGINT);
  EXPECT_EQ(view.wait(10), 0) << view.output();
  srv.kill(SIGINT);
  srv.wait(20);
}

TEST(LoopdViewHttp, BadCommandLines) {
  EXPECT_EQ(runTool({kView, "--port", "70000"}, tmp("v.log")), 2);
  EXPECT_EQ(runTool({kView, "--frobnicate"}, tmp("v.log")), 2);
  EXPECT_EQ(runTool({kView, "--port"}, tmp("v.log")), 2);
  EXPECT_EQ(runTool({kView, "--bind", "not-an-address", "--port", "0"}, tmp("v.log")), 1);
  EXPECT_EQ(runTool({kView, "--help"}, tmp("v.log")), 0);
}

// ---------------------------------------------------------------------------------------------
// Headless Chromium over the DevTools protocol (--remote-debugging-pipe: NUL-terminated JSON
// messages, commands on the browser's fd 3, answers and events on its fd 4). No websocket, no
// node, nothing downloaded: Debian's chromium only.

std::string chromiumPath() {
  if (const char* e = std::getenv("LOOPD_CHROMIUM"); e && *e) return e;
  for (const char* p :
       {"/usr/bin/chromium", "/usr/bin/chromium-browser", "/usr/lib/chromium/chromium"})
    if (::access(p, X_OK) == 0) return p;
  return "";
}

class Browser {
 public:
  bool start(const std::string& exe, const std::string& profile, const std::string& log) {
    int toB[2], fromB[2];
    if (::pipe2(toB, O_CLOEXEC) != 0 || ::pipe2(fromB, O_CLOEXEC) != 0) return false;
    // The child's ends must not already be fds 3 or 4: dup2(3, 3) would keep close-on-exec.
    for (int* fd : {&toB[0], &fromB[1]}) {
      const int high = ::fcntl(*fd, F_DUPFD_CLOEXEC, 10);
      ::close(*fd);
      *fd = high;
    }
    const std::vector<std::string> args = {exe,
                                           "--headless",
                                           "--no-sandbox",
                                           "--disable-gpu",
                                           "--disable-quic",
                                           "--no-first-run",
                                           "--disable-background-networking",
                                           "--disable-component-update",
                                           "--disable-sync",
                                           "--disable-dev-shm-usage",
                                           "--hide-scrollbars",
                                           "--user-data-dir=" + profile,
                                           "--remote-debugging-pipe",
                                           "about:blank"};
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_addopen(&fa, 1, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawn_file_actions_adddup2(&fa, 1, 2);
    posix_spawn_file_actions_adddup2(&fa, toB[0], 3);
    posix_spawn_file_actions_adddup2(&fa, fromB[1], 4);
    std::vector<char*> argv;
    for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    const int rc = posix_spawn(&pid_, argv[0], &fa, nullptr, argv.data(), environ);
    posix_spawn_file_actions_destroy(&fa);
    ::close(toB[0]);
    ::close(fromB[1]);
    out_ = toB[1];
    in_ = fromB[0];
    return rc == 0;
  }
  ~Browser() {
    if (out_ >= 0) ::close(out_);
    if (in_ >= 0) ::close(in_);
    if (pid_ > 0) {
      ::kill(pid_, SIGKILL);
      int st;
      waitpid(pid_, &st, 0);
    }
  }
  /// Sends a command; returns its answer (the whole JSON message) or "" on timeout.
  std::string call(const std::string& method, const std::string& params = "{}",
                   const std::string& session = "", double seconds = 20) {
    const int id = ++id_;
    std::string msg =
        "{\"id\":" + std::to_string(id) + ",\"method\":\"" + method + "\",\"params\":" + params;
    if (!session.empty()) msg += ",\"sessionId\":\"" + session + "\"";
    msg += "}";
    msg.push_back('\0');
    size_t off = 0;
    while (off < msg.size()) {
      const ssize_t k = ::write(out_, msg.data() + off, msg.size() - off);
      if (k <= 0) return "";
      off += static_cast<size_t>(k);
    }
    const std::string tag = "{\"id\":" + std::to_string(id) + ",";
    const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
    while (std::chrono::steady_clock::now() < end) {
      size_t z;
      while ((z = buf_.find('\0')) != std::string::npos) {
        std::string m = buf_.substr(0, z);
        buf_.erase(0, z + 1);
        if (m.rfind(tag, 0) == 0) return m;  // answers start with their id; events have none
      }
      pollfd p{in_, POLLIN, 0};
      if (::poll(&p, 1, 100) <= 0) continue;
      char b[65536];
      const ssize_t k = ::read(in_, b, sizeof b);
      if (k <= 0) return "";
      buf_.append(b, static_cast<size_t>(k));
    }
    return "";
  }
  void close() {
    call("Browser.close", "{}", "", 5);
    for (int i = 0; i < 100 && pid_ > 0; ++i) {
      int st;
      if (waitpid(pid_, &st, WNOHANG) == pid_)
        pid_ = -1;
      else
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
  }

 private:
  pid_t pid_ = -1;
  int out_ = -1, in_ = -1, id_ = 0;
  std::string buf_;
};

/// The string after `"key":"` in a JSON message (no escapes expected).
std::string field(const std::string& json, const std::string& key) {
  const std::string k = "\"" + key + "\":\"";
  const size_t p = json.find(k);
  if (p == std::string::npos) return "";
  const size_t e = json.find('"', p + k.size());
  return e == std::string::npos ? "" : json.substr(p + k.size(), e - p - k.size());
}

std::string base64Decode(const std::string& in) {
  std::string out;
  unsigned val = 0;  // only the low 14 bits matter; unsigned so the shift cannot overflow
  int bits = -8;
  for (unsigned char c : in) {
    int d;
    if (c >= 'A' && c <= 'Z')
      d = c - 'A';
    else if (c >= 'a' && c <= 'z')
      d = c - 'a' + 26;
    else if (c >= '0' && c <= '9')
      d = c - '0' + 52;
    else if (c == '+')
      d = 62;
    else if (c == '/')
      d = 63;
    else
      continue;
    val = ((val << 6) | static_cast<unsigned>(d)) & 0xFFFFFFu;
    bits += 6;
    if (bits >= 0) {
      out.push_back(static_cast<char>((val >> bits) & 0xFF));
      bits -= 8;
    }
  }
  return out;
}

/// "posesDrawn=1728 rejectedLinks=10 ..." → map.
std::map<std::string, std::string> pageState(Browser& b, const std::string& session) {
  const std::string expr =
      "['state','connection','posesDrawn','robotsDrawn','rejectedLinks','linksAccepted','"
      "linksUndecided',"
      "'ellipsesDrawn','serverPoses','serverRejected','errorsSeen','framesDrawn','framesSkipped','"
      "plane','seq']"
      ".map(k => k + '=' + document.body.dataset[k]).join(' ')";
  std::string params = "{\"expression\":\"" + expr + "\",\"returnByValue\":true}";
  const std::string r = b.call("Runtime.evaluate", params, session, 10);
  std::map<std::string, std::string> out;
  std::istringstream s(field(r, "value"));
  std::string kv;
  while (s >> kv) {
    const size_t eq = kv.find('=');
    if (eq != std::string::npos) out[kv.substr(0, eq)] = kv.substr(eq + 1);
  }
  return out;
}

long num(const std::map<std::string, std::string>& m, const std::string& k) {
  auto it = m.find(k);
  if (it == m.end()) return -1;
  try {
    return std::stol(it->second);
  } catch (...) {
    return -1;
  }
}

TEST(LoopdViewBrowser, DrawsTheMapLiveWithRejectedClosuresInHeadlessChromium) {
  const std::string chromium = chromiumPath();
  ASSERT_FALSE(chromium.empty())
      << "Debian's chromium is not installed (it is needed for the end-to-end test of loopd-view): "
         "run scripts/install-deps.sh, or apt-get install -y chromium";
  // intel with 10 wrong loop closures; the dcs server rejects them.
  const std::string g2o = tmp("intel_outliers.g2o");
  ASSERT_EQ(runTool({kOutliers, kData + "/intel.g2o", "--count", "10", "--mode", "random", "--seed",
                     "3", "--out", g2o, "--truth", tmp("truth.json")},
                    tmp("outliers.log")),
            0);
  const std::string url = uniqueUrl();
  Proc srv = Proc::start({kLoopd, "--lcm-url", url, "--solver", "dcs"}, tmp("srv.log"));
  Proc view;
  const int port = startView(view, url, tmp("view.log"));
  ASSERT_GT(port, 0) << view.output();
  const std::string page = "http://127.0.0.1:" + std::to_string(port) + "/";

  Browser b;
  ASSERT_TRUE(b.start(chromium, tmp("chromium-profile"), tmp("chromium.log")));
  const std::string created = b.call("Target.createTarget", "{\"url\":\"" + page + "\"}");
  const std::string target = field(created, "targetId");
  ASSERT_FALSE(target.empty()) << "chromium did not answer over --remote-debugging-pipe ("
                               << created << "); its log:\n"
                               << std::ifstream(tmp("chromium.log")).rdbuf();
  const std::string session =
      field(b.call("Target.attachToTarget", "{\"targetId\":\"" + target + "\",\"flatten\":true}"),
            "sessionId");
  ASSERT_FALSE(session.empty());
  b.call("Emulation.setDeviceMetricsOverride",
         "{\"width\":1280,\"height\":820,\"deviceScaleFactor\":1,\"mobile\":false}", session);

  // The page is up and connected before anything is fed: it then follows the map live.
  std::map<std::string, std::string> st;
  for (int i = 0; i < 100; ++i) {
    st = pageState(b, session);
    if (st["connection"] == "ok" && num(st, "framesDrawn") > 0) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  ASSERT_EQ(st["connection"], "ok") << "the page never connected to /events";
  ASSERT_TRUE(waitForServer(port)) << "no status from loopd";

  Proc feed =
      Proc::start({kFeed, g2o, "--rate", "2000", "--lcm-url", url, "--quiet"}, tmp("feed.log"));
  // While the feed runs the page draws intermediate maps (fewer poses than fed).
  int feedRc = -2;
  auto feedFinished = [&] {
    int status = 0;
    if (feedRc == -2 && feed.pid > 0 && waitpid(feed.pid, &status, WNOHANG) == feed.pid) {
      feedRc = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
      feed.pid = -1;
    }
    return feedRc != -2;
  };
  std::set<long> seen;
  const auto t0 = std::chrono::steady_clock::now();
  bool done = false;
  while (std::chrono::steady_clock::now() - t0 < std::chrono::seconds(30)) {
    st = pageState(b, session);
    seen.insert(num(st, "posesDrawn"));
    if (num(st, "posesDrawn") == 1728 && num(st, "serverPoses") == 1728 &&
        num(st, "serverRejected") >= 1 && num(st, "rejectedLinks") == num(st, "serverRejected") &&
        feedFinished()) {
      // Let the server converge (idle 0.5 s), then read the final state.
      std::this_thread::sleep_for(std::chrono::milliseconds(1500));
      st = pageState(b, session);
      done = true;
      break;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  if (!feedFinished()) feedRc = feed.wait(10);
  EXPECT_EQ(feedRc, 0) << feed.output();
  std::string summary;
  for (const auto& [k, v] : st) summary += k + "=" + v + " ";
  ASSERT_TRUE(done) << "page state: " << summary << "\nview log:\n" << view.output();
  EXPECT_EQ(num(st, "posesDrawn"), 1728) << summary;  // every fed pose is on the canvas
  EXPECT_EQ(num(st, "robotsDrawn"), 1);
  EXPECT_GE(num(st, "rejectedLinks"), 5)
      << summary;  // the injected wrong closures, shown as rejected
  EXPECT_EQ(num(st, "rejectedLinks"), num(st, "serverRejected")) << summary;
  EXPECT_GT(num(st, "linksAccepted"), 700) << summary;  // intel's loop closures
  EXPECT_EQ(num(st, "linksUndecided"), 0) << summary;
  EXPECT_EQ(num(st, "ellipsesDrawn"), 1) << summary;  // the latest pose's 2σ ellipse
  EXPECT_EQ(num(st, "errorsSeen"), 0) << summary;
  EXPECT_GE(seen.size(), 2u) << "the page drew no intermediate state";

  const std::string shot =
      field(b.call("Page.captureScreenshot", "{\"format\":\"png\"}", session, 30), "data");
  const std::string png = base64Decode(shot);
  ASSERT_GT(png.size(), 5000u);
  EXPECT_EQ(png.substr(1, 3), "PNG");
  const std::string path = ::testing::TempDir() + "loopd_view_intel_dcs.png";
  std::ofstream(path, std::ios::binary) << png;
  std::printf("screenshot: %s\n", path.c_str());

  // Another projection plane, picked from the URL: the same poses are drawn.
  b.call("Page.navigate", "{\"url\":\"" + page + "?plane=xz\"}", session);
  for (int i = 0; i < 50; ++i) {
    st = pageState(b, session);
    if (st["plane"] == "xz" && num(st, "posesDrawn") == 1728) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  EXPECT_EQ(st["plane"], "xz");
  EXPECT_EQ(num(st, "posesDrawn"), 1728);

  b.close();
  EXPECT_TRUE(view.alive());
  view.kill(SIGINT);
  EXPECT_EQ(view.wait(10), 0) << view.output();
  srv.kill(SIGINT);
  srv.wait(20);
}

}  // namespace
