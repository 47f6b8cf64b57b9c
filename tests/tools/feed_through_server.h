#pragma once
// A dataset fed by loopd-feed to a fresh loopd server, recorded by loopd-listen until the
// server has handled every batch: the end-to-end path the README's multi-robot and robust runs
// take (scripts/feed-through-server.sh does the same from the shell).
#include <cmath>
#include <string>
#include <vector>

#include "tests/server/live_util.h"

namespace loopd::testing_live {

/// `dataset` fed by loopd-feed with `feedArgs` to a fresh server (with `serverArgs`) until
/// `batches` are handled; loopd-listen writes tmp(name + ".g2o") (and whatever `listenArgs` ask
/// for). Returns what loopd-listen said at the end and the server's log.
inline void feedThroughServer(const std::string& name, const std::string& dataset, int batches,
                              const std::vector<std::string>& feedArgs, std::string& said,
                              std::string& log, const std::vector<std::string>& serverArgs = {},
                              const std::vector<std::string>& listenArgs = {}) {
  const std::string url = uniqueUrl();
  std::vector<std::string> server = {kLoopd, "--lcm-url", url};
  server.insert(server.end(), serverArgs.begin(), serverArgs.end());
  Proc srv = Proc::start(server, tmp(name + "_srv.log"));
  ASSERT_TRUE(srv.waitForOutput("loopd: solver", 20)) << srv.output();
  std::vector<std::string> listenCmd = {kListen,
                                        "--lcm-url",
                                        url,
                                        "--out",
                                        tmp(name + ".g2o"),
                                        "--until-batches",
                                        std::to_string(batches)};
  listenCmd.insert(listenCmd.end(), listenArgs.begin(), listenArgs.end());
  Proc listen = Proc::start(listenCmd, tmp(name + "_listen.log"));
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  std::vector<std::string> feed = {kFeed, dataset, "--rate", "2000", "--lcm-url", url, "--quiet"};
  feed.insert(feed.end(), feedArgs.begin(), feedArgs.end());
  ASSERT_EQ(runTool(feed, tmp(name + "_feed.log")), 0);
  ASSERT_EQ(listen.wait(120), 0) << listen.output();
  srv.kill(SIGINT);
  EXPECT_EQ(srv.wait(20), 0);
  said = listen.output();
  log = srv.output();
}

/// The server's χ² in loopd-listen's summary (NaN when it is not there).
inline double chi2Said(const std::string& said) {
  const size_t at = said.find("chi2 ");
  return at == std::string::npos ? std::nan("") : std::stod(said.substr(at + 5));
}

}  // namespace loopd::testing_live
