// loopd-listen: record what a loopd server publishes into files loopd-solve and the evaluation
// tools read.
//
//   loopd-listen [--lcm-url URL] [--channel-prefix P] --out EST.g2o [--covariances COV.txt]
//                [--decisions STATS.json] [--until-quiet SECONDS] [--until-batches N] [--quiet]
//
// EST.g2o: one VERTEX_SE2 / VERTEX_SE3:QUAT line per pose (id = pose index, the value as
// published: in the common frame once its robot is joined), then VERTEX_XY / VERTEX_TRACKXYZ
// per landmark. COV.txt: the latest-pose covariances the server published, one line per pose
// (`POSE id` then the upper triangle, loopd-solve's format). STATS.json: the server's decisions
// on uncertain factors in loopd-solve's stats form, which loopd-eval reads: "rejected" (factor
// ids, which are the file's edge indices when loopd-feed sent them; merged over senders) and,
// for ambiguous measurements, "chosen" (alternatives in id order). Without --until-quiet it records
// until SIGINT/SIGTERM; with it, it exits once no new estimate arrived for that long (status
// heartbeats do not count; the wait starts with the first estimate). With --until-batches it
// exits once the server's status says it has handled N distinct batches (accepted, rejected or
// expired; resends do not count), holds and queues none, and its estimate is converged: an end
// that does not depend on the server's speed (one long update can outlast any quiet time).
// At start it asks the server for a full snapshot (REQUEST_ESTIMATE), so it may join a running
// server; before it exits it asks for one more (repairs any chunk udpm lost), and with
// --decisions for the complete decision listing (REQUEST_STATUS), which it waits for.
#include <lcm/lcm-cpp.hpp>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <map>
#include <string>

#include "client/decision_table.h"
#include "client/estimate_subscriber.h"
#include "loopd/command_t.hpp"
#include "solvers/io/estimate_writer.h"
#include "tools/common/cli.h"
#include "tools/common/json_writer.h"

using namespace loopd;

namespace {

std::atomic<bool> g_stop{false};
extern "C" void onSignal(int) { g_stop = true; }

const char* kUsage =
    "usage: loopd-listen [--lcm-url URL] [--channel-prefix P] --out EST.g2o\n"
    "                    [--covariances COV.txt] [--decisions STATS.json]\n"
    "                    [--until-quiet SECONDS] [--until-batches N] [--quiet]\n";

// The decisions as loopd-solve's stats count them: rejected factor ids, and the chosen
// alternative of each ambiguous measurement in id order (loopd-feed numbers them in file order).
struct DecisionSummary {
  std::vector<std::int64_t> rejected, chosen;
  std::int64_t uncertain = 0;  // plain uncertain factors (ambiguous measurements apart)
};

DecisionSummary summarize(const client::DecisionTable& table) {
  DecisionSummary out;
  std::map<std::int64_t, std::int64_t> chosenById;
  for (const auto& [name, d] : table.decisions()) {
    if (d.ambiguous) {
      chosenById[name.second] = d.alternative;
      continue;
    }
    ++out.uncertain;
    if (!d.accepted) out.rejected.push_back(name.second);
  }
  std::sort(out.rejected.begin(), out.rejected.end());
  out.rejected.erase(std::unique(out.rejected.begin(), out.rejected.end()), out.rejected.end());
  for (const auto& [id, alternative] : chosenById) out.chosen.push_back(alternative);
  return out;
}

tools::JsonObject decisionStats(const DecisionSummary& d, const loopd::status_t& st) {
  tools::JsonObject o;
  o.add("solver", st.solver)
      .add("update_seq", st.update_seq)
      .add("converged", st.converged != 0)
      .add("final_chi2", st.chi2)
      .add("uncertain_factors", d.uncertain)
      .add("rejected", d.rejected);
  if (!d.chosen.empty()) o.add("chosen", d.chosen);
  return o;
}

}  // namespace

int main(int argc, char** argv) {
  std::string url, prefix = "LOOPD_", out, cov, decisionsOut;
  double quietSeconds = -1.0;
  long long untilBatches = -1;
  bool quiet = false;
  try {
    for (int i = 1; i < argc; ++i) {
      const std::string a = argv[i];
      auto val = [&] { return tools::flagValue(argc, argv, i); };
      if (a == "--help" || a == "-h") {
        std::fputs(kUsage, stdout);
        return 0;
      } else if (a == "--lcm-url")
        url = val();
      else if (a == "--channel-prefix")
        prefix = val();
      else if (a == "--out")
        out = val();
      else if (a == "--covariances")
        cov = val();
      else if (a == "--decisions")
        decisionsOut = val();
      else if (a == "--until-quiet") {
        quietSeconds = tools::parseNumberFlag(a, val(), 0.0, 1e9);
      } else if (a == "--until-batches") {
        untilBatches = tools::parseIntFlag(a, val(), 1, 1000000000000LL);
      } else if (a == "--quiet")
        quiet = true;
      else
        throw std::invalid_argument("unknown argument " + a);
    }
    if (out.empty()) throw std::invalid_argument("--out is required");
  } catch (const std::exception& e) {
    std::fprintf(stderr, "loopd-listen: %s\n\n%s", e.what(), kUsage);
    return 2;
  }
  url = client::receiveUrl(url);
  lcm::LCM lcm(url);
  if (!lcm.good()) {
    std::fprintf(stderr, "loopd-listen: cannot open LCM '%s'\n", url.c_str());
    return 1;
  }
  std::signal(SIGINT, onSignal);
  std::signal(SIGTERM, onSignal);
  client::EstimateSubscriber sub(lcm, prefix);
  using Clock = std::chrono::steady_clock;
  Clock::time_point lastEstimate{};
  bool any = false;
  std::map<std::int64_t, std::vector<double>> poseCov;  // pose index → upper triangle
  sub.onEstimate([&](const client::RobotEstimate&, const loopd::estimate_t&) {
    lastEstimate = Clock::now();
    any = true;
  });
  client::DecisionTable decisions;
  sub.onForget([&](std::int64_t) { decisions.clear(); });
  // The server has handled every batch expected and published the optimum of its graph.
  bool done = false;
  sub.onStatus([&](const loopd::status_t& st) {
    decisions.apply(st);
    // Duplicates do not count: a resend of a handled batch is not a new one.
    const long long handled = st.batches_accepted + st.batches_rejected + st.batches_expired;
    if (untilBatches > 0 && handled >= untilBatches && st.converged && st.queue_depth == 0 &&
        st.batches_held == 0)
      done = true;
  });
  sub.onCovariance([&](const loopd::covariance_t& m) {
    if (m.joint) return;
    size_t off = 0;
    for (int i = 0; i < m.num_keys; ++i) {
      const int d = m.dims[static_cast<size_t>(i)];
      std::vector<double> up;
      for (int r = 0; r < d; ++r)
        for (int c = r; c < d; ++c) up.push_back(m.values[off + static_cast<size_t>(r * d + c)]);
      if (m.keys[static_cast<size_t>(i)].kind == loopd::key_t::POSE)
        poseCov[m.keys[static_cast<size_t>(i)].index] = up;
      off += static_cast<size_t>(d * d);
    }
  });
  loopd::command_t req{};
  req.utime = 0;
  req.sender = "loopd-listen";
  req.request_id = 1;
  req.command = loopd::command_t::REQUEST_ESTIMATE;
  req.argument = "";
  req.num_keys = 0;
  lcm.publish(prefix + "COMMAND", &req);

  bool finalRequested = false;
  auto since = [&](Clock::time_point t) {
    return std::chrono::duration<double>(Clock::now() - t).count();
  };
  // With --decisions: the complete listing, asked again if a chunk is lost or no reply comes.
  constexpr std::int64_t kListingRequest = 3;
  constexpr int kListingAsks = 5;
  Clock::time_point listingAsked{};
  int listingAsks = 0;
  auto askListing = [&] {
    loopd::command_t s = req;
    s.request_id = kListingRequest;
    s.command = loopd::command_t::REQUEST_STATUS;
    lcm.publish(prefix + "COMMAND", &s);
    listingAsked = Clock::now();
    ++listingAsks;
  };
  bool listingMissing = false;
  while (!g_stop) {
    lcm.handleTimeout(100);
    if (finalRequested) {
      // The last snapshot is in once its estimates stop.
      const bool listingIn =
          decisionsOut.empty() || decisions.lastListingRequest() == kListingRequest;
      if (listingIn &&
          since(lastEstimate) >= (quietSeconds >= 0 ? std::min(quietSeconds, 1.0) : 1.0))
        break;
      if (!listingIn && since(listingAsked) >= 2.0) {
        if (listingAsks >= kListingAsks) {
          listingMissing = true;
          break;
        }
        askListing();
      }
    } else if (done || (quietSeconds >= 0 && any && since(lastEstimate) >= quietSeconds)) {
      // Ask for one full snapshot (repairs any chunk udpm lost), then stop after it.
      finalRequested = true;
      req.request_id = 2;
      lcm.publish(prefix + "COMMAND", &req);
      lastEstimate = Clock::now();
      if (!decisionsOut.empty()) askListing();
    }
  }

  io::Dataset ds;
  ds.path = out;
  for (const auto& [robot, t] : sub.all()) {
    for (const auto& [index, x] : t.poses) {
      io::Vertex v;
      v.id = index;
      v.type = t.se3 ? io::VertexType::SE3 : io::VertexType::SE2;
      ds.is3d |= t.se3;
      std::copy(x.begin(), x.end(), v.value.begin());
      ds.poses.push_back(v);
    }
    for (const auto& [index, p] : t.landmarks) {
      io::Vertex v;
      v.id = index;
      v.type = p.size() == 3 ? io::VertexType::Point3 : io::VertexType::Point2;
      std::copy(p.begin(), p.end(), v.value.begin());
      ds.landmarks.push_back(v);
    }
  }
  std::sort(ds.poses.begin(), ds.poses.end(),
            [](const auto& a, const auto& b) { return a.id < b.id; });
  try {
    io::writeG2oVertices(out, ds);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "loopd-listen: %s\n", e.what());
    return 1;
  }
  if (!cov.empty()) {
    FILE* f = std::fopen(cov.c_str(), "w");
    if (!f) {
      std::fprintf(stderr, "loopd-listen: cannot write %s\n", cov.c_str());
      return 1;
    }
    std::fprintf(
        f,
        "# loopd marginal covariances (latest-pose covariances as published): KIND id, then the "
        "upper triangle (row-major) in tangent order\n");
    for (const auto& [id, up] : poseCov) {
      std::fprintf(f, "POSE %lld", static_cast<long long>(id));
      for (double c : up) std::fprintf(f, " %.17g", c);
      std::fputc('\n', f);
    }
    std::fclose(f);
  }
  if (listingMissing) {
    std::fprintf(stderr,
                 "loopd-listen: no complete decision listing from the server (asked %d times): %s "
                 "not written\n",
                 kListingAsks, decisionsOut.c_str());
    return 1;
  }
  if (!decisionsOut.empty()) {
    // Stopped by a signal, the table is what the statuses so far said (no final listing).
    const DecisionSummary summary = summarize(decisions);
    try {
      decisionStats(summary, sub.lastStatus()).writeFile(decisionsOut);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "loopd-listen: %s\n", e.what());
      return 1;
    }
    if (!quiet) {
      // The counts the file holds: an ambiguous measurement that chose none is not "rejected".
      std::string ambiguous;
      if (!summary.chosen.empty())
        ambiguous = ", " + std::to_string(summary.chosen.size()) + " ambiguous (" +
                    std::to_string(std::count(summary.chosen.begin(), summary.chosen.end(), -1)) +
                    " chose none)";
      std::fprintf(stderr, "loopd-listen: %lld decisions (%zu rejected)%s written to %s\n",
                   static_cast<long long>(summary.uncertain), summary.rejected.size(),
                   ambiguous.c_str(), decisionsOut.c_str());
    }
  }
  if (!quiet) {
    const auto st = sub.lastStatus();
    // A table without poses is a landmark namespace's (loopd --landmark-namespace), not a robot's.
    int robots = 0, common = 0, namespaces = 0;
    for (const auto& [r, t] : sub.all()) {
      if (t.poses.empty()) {
        ++namespaces;
        continue;
      }
      ++robots;
      common += t.commonFrame ? 1 : 0;
    }
    const std::string alsoNamespaces = namespaces == 0 ? ""
                                                       : ", " + std::to_string(namespaces) +
                                                             " landmark namespace" +
                                                             (namespaces > 1 ? "s" : "");
    std::fprintf(
        stderr,
        "loopd-listen: %zu poses, %zu landmarks written to %s (%lld estimate messages, %d robots, "
        "%d in a common frame%s; server %s%s, chi2 %.12g, %lld batches accepted, %lld duplicate, "
        "%lld rejected, %lld expired, %lld held)\n",
        ds.poses.size(), ds.landmarks.size(), out.c_str(),
        static_cast<long long>(sub.estimatesReceived()), robots, common, alsoNamespaces.c_str(),
        st.solver.c_str(), st.converged ? " converged" : "", st.chi2,
        static_cast<long long>(st.batches_accepted), static_cast<long long>(st.batches_duplicate),
        static_cast<long long>(st.batches_rejected), static_cast<long long>(st.batches_expired),
        static_cast<long long>(st.batches_held));
  }
  return 0;
}
