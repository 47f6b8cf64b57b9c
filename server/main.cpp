// loopd: the pose-graph SLAM back-end server (see server/server.h and lcmtypes/README.md).
#include <spdlog/spdlog.h>

#include <atomic>
#include <csignal>
#include <cstdio>

#include "server/server.h"
#include "solvers/core/allocator_tuning.h"

namespace {
std::atomic<bool> g_stop{false};
extern "C" void onSignal(int) { g_stop = true; }
}  // namespace

int main(int argc, char** argv) {
  loopd::keepFreedMemoryForReuse();
  loopd::server::ServerConfig cfg;
  try {
    cfg = loopd::server::parseServerConfig(std::vector<std::string>(argv + 1, argv + argc));
  } catch (const std::exception& e) {
    std::fprintf(stderr, "loopd: %s\n\n%s", e.what(), loopd::server::serverUsage().c_str());
    return 2;
  }
  if (cfg.help) {
    std::fputs(loopd::server::serverUsage().c_str(), stdout);
    return 0;
  }
  spdlog::set_level(spdlog::level::from_str(cfg.logLevel));
  struct sigaction sa {};
  sa.sa_handler = onSignal;
  sigemptyset(&sa.sa_mask);
  sigaction(SIGINT, &sa, nullptr);
  sigaction(SIGTERM, &sa, nullptr);
  std::signal(SIGPIPE, SIG_IGN);
  try {
    return loopd::server::runServer(cfg, g_stop);
  } catch (const std::exception& e) {
    spdlog::critical("loopd: {}", e.what());
    return 1;
  }
}
