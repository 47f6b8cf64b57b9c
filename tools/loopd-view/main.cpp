// loopd-view: a live web view of a loopd server (issue 7).
//
//   loopd-view [--lcm-url URL] [--channel-prefix P] [--port 8080] [--bind 127.0.0.1]
//              [--max-rate HZ] [--no-request]
//
// Follows the server's ESTIMATE, COVARIANCE, STATUS and ERROR channels (and FACTORS, for the
// endpoints of loop closures) and serves a page that updates live over server-sent events.
// The state is coalesced here: at most --max-rate snapshots a second (fewer for very large
// maps), each one the whole newest state; the page draws only the newest one it has.
#include <signal.h>
#include <lcm/lcm-cpp.hpp>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <stdexcept>
#include <string>
#include <thread>

#include "client/estimate_subscriber.h"
#include "tools/common/cli.h"
#include "tools/loopd-view/http_server.h"
#include "tools/loopd-view/view_state.h"

namespace {

std::atomic<bool> gStop{false};
void onSignal(int) { gStop = true; }

void installSignalHandlers() {
  struct sigaction sa {};
  sa.sa_handler = onSignal;
  sigemptyset(&sa.sa_mask);
  sigaction(SIGINT, &sa, nullptr);
  sigaction(SIGTERM, &sa, nullptr);
  signal(SIGPIPE, SIG_IGN);
}

struct Options {
  std::string lcmUrl, prefix = "LOOPD_", bind = "127.0.0.1";
  int port = 8080;
  double maxRate = 10.0;
  bool request = true;
};

const char* kUsage =
    "usage: loopd-view [--lcm-url URL] [--channel-prefix P] [--port 8080] [--bind 127.0.0.1]\n"
    "                  [--max-rate HZ] [--no-request]\n"
    "  --lcm-url URL         LCM provider (default: LCM_DEFAULT_URL or "
    "udpm://239.255.76.67:7667?ttl=0)\n"
    "  --channel-prefix P    the server's channel prefix (default LOOPD_)\n"
    "  --port N              HTTP port (default 8080; 0 = any free port, printed at start)\n"
    "  --bind ADDR           IPv4 address to listen on (default 127.0.0.1; the view has no\n"
    "                        authentication, so think twice before 0.0.0.0)\n"
    "  --max-rate HZ         at most this many snapshots a second to the page (default 10, 1..30)\n"
    "  --no-request          do not ask the server for a full estimate and decision list at start\n"
    "Open the printed URL in a browser. Pages: / (the view), /state.json, /events (SSE), "
    "/healthz.\n";

Options parse(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto val = [&] { return loopd::tools::flagValue(argc, argv, i); };
    auto integer = [&](const std::string& v, long lo, long hi) {
      char* end = nullptr;
      const long n = std::strtol(v.c_str(), &end, 10);
      if (v.empty() || *end || n < lo || n > hi)
        throw std::invalid_argument(a + " takes an integer in [" + std::to_string(lo) + ", " +
                                    std::to_string(hi) + "]");
      return static_cast<int>(n);
    };
    if (a == "--help" || a == "-h") {
      std::fputs(kUsage, stdout);
      std::exit(0);
    } else if (a == "--lcm-url")
      o.lcmUrl = val();
    else if (a == "--channel-prefix")
      o.prefix = val();
    else if (a == "--port")
      o.port = integer(val(), 0, 65535);
    else if (a == "--bind")
      o.bind = val();
    else if (a == "--max-rate")
      o.maxRate = integer(val(), 1, 30);
    else if (a == "--no-request")
      o.request = false;
    else
      throw std::invalid_argument("unknown argument " + a);
  }
  if (o.prefix.empty() || o.prefix.size() > 53)
    throw std::invalid_argument("--channel-prefix: 1 to 53 characters");
  return o;
}

int run(const Options& o) {
  using Clock = std::chrono::steady_clock;
  const std::string url = loopd::client::receiveUrl(o.lcmUrl);
  lcm::LCM lcm(url);
  if (!lcm.good()) throw std::runtime_error("cannot open LCM '" + url + "'");
  loopd::view::ViewState state(lcm, o.prefix, url);
  loopd::view::SnapshotBoard board;
  loopd::view::HttpOptions ho;
  ho.bind = o.bind;
  ho.port = o.port;
  loopd::view::HttpServer http(ho, board);
  http.start();
  board.publish(state.renderJson(0));
  std::printf("loopd-view: http://%s:%d/  (channels %s*, %s)\n",
              o.bind == "0.0.0.0" ? "127.0.0.1" : o.bind.c_str(), http.port(), o.prefix.c_str(),
              url.c_str());
  std::fflush(stdout);

  std::thread lcmThread([&] {
    while (!gStop) lcm.handleTimeout(100);
  });

  const auto minInterval = std::chrono::duration<double>(1.0 / o.maxRate);
  auto lastSnapshot = Clock::now() - std::chrono::seconds(1);
  auto start = Clock::now();
  bool requested = false, statusSeen = false;
  auto lastRequest = Clock::now() - std::chrono::seconds(1);
  std::uint64_t seq = 1;
  std::size_t lastSize = 0;
  while (!gStop) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
    if (o.request) {
      // Ask once the LCM thread is listening, again when a server first shows up, and when
      // the view lost or forgot something (at most once a second: full estimates are big).
      const bool s = state.statusSeen();
      if ((!requested && Clock::now() - start > std::chrono::milliseconds(300)) ||
          (s && !statusSeen) ||
          (state.wantsEverything() && Clock::now() - lastRequest >= std::chrono::seconds(1))) {
        state.requestEverything();
        requested = true;
        lastRequest = Clock::now();
      }
      statusSeen = s;
    }
    // Very large states go out less often (≈ 4 MB/s of JSON at most per tab).
    const auto interval = std::max<std::chrono::duration<double>>(
        minInterval, std::chrono::duration<double>(static_cast<double>(lastSize) / 4.0e6));
    if (!state.dirty() || Clock::now() - lastSnapshot < interval) continue;
    lastSnapshot = Clock::now();
    std::string json = state.renderJson(seq++);
    lastSize = json.size();
    board.publish(std::move(json));
  }
  std::fprintf(stderr, "loopd-view: stopping (%lld requests, %lld bad, %lld events sent)\n",
               static_cast<long long>(http.stats().requests.load()),
               static_cast<long long>(http.stats().bad.load()),
               static_cast<long long>(http.stats().sseEvents.load()));
  board.stop();
  http.stop();
  lcmThread.join();
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  return loopd::tools::parseAndRun("loopd-view", kUsage, argc, argv, parse, [](const Options& o) {
    installSignalHandlers();
    return run(o);
  });
}
