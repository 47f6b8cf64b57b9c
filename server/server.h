#pragma once
// The loopd daemon in one object: the LCM thread, the engine (run on the calling thread),
// resume and journal. main() and the tests use it.
#include <atomic>

#include "server/server_config.h"

namespace loopd::server {

/// Runs until stop becomes true; returns the exit code (0 after a clean stop).
int runServer(const ServerConfig& config, const std::atomic<bool>& stop);

}  // namespace loopd::server
