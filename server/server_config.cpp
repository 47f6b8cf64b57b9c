#include "server/server_config.h"
#include "lcmtypes/lcm_url.h"

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <limits>
#include <map>
#include <stdexcept>

#include "robust/backend_registry.h"

namespace loopd::server {

namespace {

std::string trim(const std::string& s) {
  const auto b = s.find_first_not_of(" \t\r\n");
  if (b == std::string::npos) return "";
  const auto e = s.find_last_not_of(" \t\r\n");
  return s.substr(b, e - b + 1);
}

const char* const kKeys[] = {
    "lcm-url",        "solver",           "channel-prefix",     "journal",        "resume",
    "publish-every",  "log-level",        "hold-seconds",       "hold-max",       "idle-seconds",
    "max-hypotheses", "poses-per-update", "landmark-namespace", "join-agreement", "idle-rounds",
    "config"};

// The ranges of the numeric flags (serverUsage() and README name them).
constexpr int kMaxCount = 1000000;       // --publish-every, --hold-max, --poses-per-update
constexpr double kMaxSeconds = 86400.0;  // --hold-seconds, --idle-seconds: a day
constexpr int kMaxHypotheses = 1000;     // --max-hypotheses (as loopd-solve's)
constexpr int kMaxAgreement = 1000;      // --join-agreement
constexpr int kMaxIdleRounds = 1000;     // --idle-rounds

bool knownKey(const std::string& k) {
  for (const char* x : kKeys)
    if (k == x) return true;
  return false;
}

// A finite number in [lo, hi], written whole (no NaN, inf or trailing characters).
double toDouble(const std::string& k, const std::string& v, double lo, double hi) {
  double d = std::nan("");
  try {
    size_t n = 0;
    d = std::stod(v, &n);
    if (n != v.size() || v.empty() || std::isspace(static_cast<unsigned char>(v.front())))
      d = std::nan("");
  } catch (const std::exception&) {
  }
  if (!std::isfinite(d) || d < lo || d > hi) {
    char range[64];
    std::snprintf(range, sizeof range, "%g to %g", lo, hi);
    throw std::invalid_argument("--" + k + ": '" + v + "' is not a number from " + range);
  }
  return d;
}

// A decimal integer in [lo, hi], written whole.
int toInt(const std::string& k, const std::string& v, int lo, int hi) {
  long long i = 0;
  const auto r = std::from_chars(v.data(), v.data() + v.size(), i);
  if (v.empty() || r.ec != std::errc() || r.ptr != v.data() + v.size() || i < lo || i > hi)
    throw std::invalid_argument("--" + k + ": '" + v + "' is not an integer from " +
                                std::to_string(lo) + " to " + std::to_string(hi));
  return static_cast<int>(i);
}

void apply(ServerConfig& c, const std::string& k, const std::string& v) {
  if (k == "lcm-url")
    c.lcmUrl = v;
  else if (k == "solver")
    c.solver = v;
  else if (k == "channel-prefix")
    c.channelPrefix = v;
  else if (k == "journal")
    c.journal = v;
  else if (k == "resume")
    c.resume = v;
  else if (k == "publish-every")
    c.publishEvery = toInt(k, v, 0, kMaxCount);
  else if (k == "log-level") {
    const auto& names = logLevelNames();
    if (std::find(names.begin(), names.end(), v) == names.end()) {
      std::string list;
      for (const auto& n : names) list += (list.empty() ? "" : "|") + n;
      throw std::invalid_argument("--log-level: '" + v + "' is not one of " + list);
    }
    c.logLevel = v;
  } else if (k == "hold-seconds")
    c.holdSeconds = toDouble(k, v, 0, kMaxSeconds);
  else if (k == "hold-max")
    c.holdMax = toInt(k, v, 0, kMaxCount);
  else if (k == "idle-seconds")
    c.idleSeconds = toDouble(k, v, 0, kMaxSeconds);
  else if (k == "idle-rounds")
    c.idleRounds = toInt(k, v, 1, kMaxIdleRounds);
  else if (k == "max-hypotheses")
    c.maxHypotheses = toInt(k, v, 1, kMaxHypotheses);
  else if (k == "poses-per-update")
    c.posesPerUpdate = toInt(k, v, 0, kMaxCount);
  else if (k == "join-agreement")
    c.joinAgreement = toInt(k, v, 1, kMaxAgreement);
  else if (k == "landmark-namespace") {
    // A comma-separated list of robot ids (key_t.robot is an int32 ≥ 0).
    c.landmarkNamespaces.clear();
    size_t from = 0;
    while (true) {
      const size_t comma = v.find(',', from);
      const std::string id = v.substr(from, comma == std::string::npos ? comma : comma - from);
      c.landmarkNamespaces.insert(
          static_cast<std::uint32_t>(toInt(k, id, 0, std::numeric_limits<std::int32_t>::max())));
      if (comma == std::string::npos) break;
      from = comma + 1;
    }
  }
}

void loadFile(ServerConfig& c, const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::invalid_argument("--config: cannot read " + path);
  std::string line;
  int n = 0;
  while (std::getline(in, line)) {
    ++n;
    const auto hash = line.find('#');
    if (hash != std::string::npos) line.resize(hash);
    line = trim(line);
    if (line.empty()) continue;
    const auto eq = line.find('=');
    if (eq == std::string::npos)
      throw std::invalid_argument(path + ":" + std::to_string(n) + ": expected key = value");
    const std::string k = trim(line.substr(0, eq)), v = trim(line.substr(eq + 1));
    if (!knownKey(k) || k == "config")
      throw std::invalid_argument(path + ":" + std::to_string(n) + ": unknown key '" + k + "'");
    apply(c, k, v);
  }
}

}  // namespace

const std::vector<std::string>& logLevelNames() {
  static const std::vector<std::string> names = {"trace", "debug",    "info", "warn",
                                                 "error", "critical", "off"};
  return names;
}

std::string defaultSolver() { return isBackendName("isam2") ? "isam2" : "lm"; }

ServerConfig parseServerConfig(const std::vector<std::string>& args) {
  std::vector<std::pair<std::string, std::string>> flags;
  ServerConfig c;
  for (size_t i = 0; i < args.size(); ++i) {
    const std::string& a = args[i];
    if (a == "--help" || a == "-h") {
      c.help = true;
      continue;
    }
    if (a.rfind("--", 0) != 0) throw std::invalid_argument("unexpected argument '" + a + "'");
    std::string k = a.substr(2), v;
    const auto eq = k.find('=');
    if (eq != std::string::npos) {
      v = k.substr(eq + 1);
      k.resize(eq);
    } else {
      if (!knownKey(k)) throw std::invalid_argument("unknown flag --" + k);
      if (i + 1 >= args.size()) throw std::invalid_argument("--" + k + " needs a value");
      v = args[++i];
    }
    if (!knownKey(k)) throw std::invalid_argument("unknown flag --" + k);
    flags.emplace_back(k, v);
  }
  for (const auto& [k, v] : flags)
    if (k == "config") loadFile(c, v);
  for (const auto& [k, v] : flags) apply(c, k, v);
  if (c.solver.empty()) c.solver = defaultSolver();
  if (!isBackendName(c.solver))
    throw std::invalid_argument("--solver: unknown solver '" + c.solver + "'");
  if (c.channelPrefix.size() > 53)
    throw std::invalid_argument("--channel-prefix: at most 53 characters");
  return c;
}

std::string effectiveLcmUrl(const std::string& url) { return lcmReceiveUrl(url); }

std::string serverUsage() {
  return "usage: loopd [flags]\n"
         "  --lcm-url URL         LCM provider (default: LCM_DEFAULT_URL or "
         "udpm://239.255.76.67:7667?ttl=0;\n"
         "                        recv_buf_size=4194304 is added to udpm URLs without one)\n"
         "  --solver NAME         back-end variant (default: " +
         defaultSolver() +
         ")\n"
         "  --channel-prefix P    channel prefix (default LOOPD_): P FACTORS, COMMAND in;\n"
         "                        ESTIMATE, COVARIANCE, STATUS, ERROR out\n"
         "  --journal FILE        append every accepted batch to this LCM log\n"
         "  --resume FILE         replay this journal at start-up (keeps appending if --journal is "
         "the same)\n"
         "  --publish-every N     full estimate snapshot every N updates, 0-1000000 (default 50; "
         "0 = only on request)\n"
         "  --hold-seconds S      how long a batch may wait for a pose not yet introduced, "
         "0-86400 (default 30)\n"
         "  --hold-max N          at most N held batches, 0-1000000 (default 1000)\n"
         "  --idle-seconds S      input pause before iterating to convergence, 0-86400 (default "
         "0.5)\n"
         "  --idle-rounds N       optimize() calls per pause at most: one that stops on its\n"
         "                        iteration budget is resumed, 1-1000 (default 10)\n"
         "  --max-hypotheses K    mh: live hypotheses kept at most, 1-1000 (default 10)\n"
         "  --poses-per-update N  batches queued while solving are applied together, at most\n"
         "                        N new poses of one robot per update, 0-1000000 (default\n"
         "                        100; 0 = no bound)\n"
         "  --landmark-namespace N[,M...]  robot ids that hold landmarks only (a shared tag map):\n"
         "                        poses there are refused; a namespace's landmarks live in the\n"
         "                        frame of the first robot to sight one (default none)\n"
         "  --join-agreement N    under a solver that judges loop closures, two robots' frames\n"
         "                        join once N of their inter-robot closures agree, 1-1000\n"
         "                        (default 2; 1 = the first closure joins them)\n"
         "  --log-level L         trace|debug|info|warn|error|critical|off (default info)\n"
         "  --config FILE         `key = value` lines with the names above; flags override\n"
         "  --help                this text\n";
}

}  // namespace loopd::server
