#pragma once
// The loopd command line and config file. The file holds `key = value` lines with the flags'
// names (without the dashes; `#` starts a comment); flags given on the command line override it.
#include <cstdint>
#include <set>
#include <string>
#include <vector>

namespace loopd::server {

struct ServerConfig {
  std::string lcmUrl;  // "" = LCM's default (LCM_DEFAULT_URL or udpm 239.255.76.67:7667)
  std::string solver;  // "" = isam2 if registered, else lm
  std::string channelPrefix = "LOOPD_";
  std::string journal;  // append every accepted batch here
  std::string resume;   // replay this journal at start-up
  int publishEvery = 50;
  std::string logLevel = "info";  // one of logLevelNames()
  double holdSeconds = 30.0;
  int holdMax = 1000;
  double idleSeconds = 0.5;
  int idleRounds = 10;                         // EngineOptions::idleRounds
  int maxHypotheses = 10;                      // mh: live hypotheses at most (K)
  int posesPerUpdate = 100;                    // EngineOptions::posesPerUpdate
  int joinAgreement = 2;                       // EngineOptions::joinAgreement
  std::set<std::uint32_t> landmarkNamespaces;  // EngineOptions::landmarkNamespaces
  bool help = false;
};

/// Parses argv (and the --config file it names). Throws std::invalid_argument on bad input: an
/// unknown flag or log level, a number that is not finite or outside its range (serverUsage()).
ServerConfig parseServerConfig(const std::vector<std::string>& args);
std::string serverUsage();
/// The --log-level names: trace debug info warn error critical off (spdlog's, "warn" for
/// "warning"); anything else is a usage error.
const std::vector<std::string>& logLevelNames();
/// The solver used when --solver is not given.
std::string defaultSolver();
/// Adds recv_buf_size to a udpm URL that lacks it (resolving "" to LCM's default first).
std::string effectiveLcmUrl(const std::string& url);

}  // namespace loopd::server
