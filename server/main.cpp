// loopd: the pose-graph SLAM back-end server (see server/server.h and lcmtypes/README.md).
#include <spdlog/spdlog.h>

#include <algorithm>
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
  // parseServerConfig accepted only logLevelNames(); spdlog's from_str would turn any other
  // name into "off" without a word.
  const std::vector<std::pair<const char*, spdlog::level::level_enum>> levels = {
      {"trace", spdlog::level::trace}, {"debug", spdlog::level::debug},
      {"info", spdlog::level::info},   {"warn", spdlog::level::warn},
      {"error", spdlog::level::err},   {"critical", spdlog::level::critical},
      {"off", spdlog::level::off}};
  const auto level = std::find_if(levels.begin(), levels.end(),
                                  [&](const auto& l) { return cfg.logLevel == l.first; });
  if (level == levels.end()) {
    std::fprintf(stderr, "loopd: --log-level: '%s' is not a log level\n\n%s", cfg.logLevel.c_str(),
                 loopd::server::serverUsage().c_str());
    return 2;
  }
  spdlog::set_level(level->second);
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
