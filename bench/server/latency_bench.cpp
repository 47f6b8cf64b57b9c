// loopd-latency-bench / loopd-throughput-bench: a live loopd server fed a dataset pose by pose
// over real LCM (udpm on a private port, ttl=0).
//
// latency (default of loopd-latency-bench): one robot publishes one batch per pose at --rate Hz
//   (loopd-feed's batches: the pose's identity initial value if first, and every edge whose ends
//   have appeared). Latency of a pose = time from just before its batch is published to the
//   arrival of the first estimate_t chunk (published after an update, request_id 0) that
//   contains that pose. The server always includes a newly added pose in the update's "moved"
//   set, so this is the end-to-end "batch in -> estimate out" time. Also reported: the part up
//   to the server's publication (estimate_t.utime − send wall clock, same host).
// throughput (default of loopd-throughput-bench): the whole dataset as fast as possible; time
//   from the first publication to (a) the estimate holding the last pose and (b) the converged
//   estimate (the server's idle optimize, minus its --idle-seconds wait), against the offline
//   `loopd-solve --solver S --incremental` solve_s (which includes its final optimize) on the
//   same file.
// Both: lost batches = batches published − batches the server accepted (status counters,
// taken before and after), plus poses whose estimate never arrived.
#include <cstring>

#include "bench/server/server_bench_common.h"

using namespace loopd;
using namespace loopd::bench;

#ifndef LOOPD_BENCH_DEFAULT_MODE
#define LOOPD_BENCH_DEFAULT_MODE "latency"
#endif

namespace {

const char* kUsage =
    "usage: loopd-latency-bench | loopd-throughput-bench [flags]\n"
    "  --mode latency|throughput   (default: " LOOPD_BENCH_DEFAULT_MODE
    ")\n"
    "  --dataset FILE      default ../shared/datasets/city10000.g2o\n"
    "  --rate HZ           poses per second (latency default 10; throughput default 0 = flat out)\n"
    "  --poses N           only the first N poses (latency default 600; throughput: all)\n"
    "  --robots N          split into N robots, interleaved (default 1)\n"
    "  --solver NAME       server back-end and offline comparison (default isam2)\n"
    "  --lcm-url URL       default: a private udpm port from the pid, ttl=0\n"
    "  --server EXE        loopd to start (default <build>/server/loopd)\n"
    "  --connect           use an already running server on --lcm-url (sends RESET first)\n"
    "  --server-arg ARG    extra argument for the started server (repeatable)\n"
    "  --channel-prefix P  default LOOPD_\n"
    "  --drain-seconds S   wait for outstanding estimates after the last batch (default 15)\n"
    "  --offline-solve EXE loopd-solve for the throughput comparison (default "
    "<build>/tools/loopd-solve)\n"
    "  --no-offline        skip the offline comparison\n"
    "  --json FILE         write the results as JSON\n"
    "  --csv FILE          latency: one line per pose (step, id, sent_s, latency_ms, server_ms, "
    "update_seq)\n"
    "  --warmup N          latency: leave the first N poses out of the percentiles (default 1: "
    "the\n"
    "                      session's first batch, which pays the server's cold start; reported "
    "apart)\n"
    "  --label TEXT        free text stored in the JSON\n";

struct OfflineResult {
  bool ok = false;
  double solveS = 0, finalChi2 = 0;
  int poses = 0;
};

double jsonNumber(const std::string& text, const std::string& key) {
  const auto p = text.find("\"" + key + "\":");
  if (p == std::string::npos) return std::nan("");
  return std::strtod(text.c_str() + p + key.size() + 3, nullptr);
}

OfflineResult runOffline(const std::string& exe, const std::string& dataset,
                         const std::string& solver, const std::string& tmpBase) {
  OfflineResult r;
  const std::string stats = tmpBase + "-offline.json";
  const std::string cmd = "'" + exe + "' '" + dataset + "' --solver " + solver +
                          " --incremental --quiet --stats '" + stats + "' > '" + tmpBase +
                          "-offline.log' 2>&1";
  std::fprintf(stderr, "offline: %s\n", cmd.c_str());
  if (std::system(cmd.c_str()) != 0) return r;
  std::ifstream in(stats);
  std::stringstream s;
  s << in.rdbuf();
  r.solveS = jsonNumber(s.str(), "solve_s");
  r.finalChi2 = jsonNumber(s.str(), "final_chi2");
  r.poses = static_cast<int>(jsonNumber(s.str(), "poses"));
  r.ok = std::isfinite(r.solveS) && r.solveS > 0;
  return r;
}

int run(const Args& a) {
  const std::string mode = a.get("mode", LOOPD_BENCH_DEFAULT_MODE);
  if (mode != "latency" && mode != "throughput")
    throw std::invalid_argument("--mode latency|throughput");
  const bool thr = mode == "throughput";
  const std::string dataset = a.get("dataset", kDatasetsDir + "/city10000.g2o");
  const double rate = a.num("rate", thr ? 0.0 : 10.0);
  const long poses = a.integer("poses", thr ? -1 : 600);
  const int robots = static_cast<int>(a.integer("robots", 1));
  const std::string solver = a.get("solver", "isam2");
  const std::string prefix = a.get("channel-prefix", "LOOPD_");
  const bool connect = a.has("connect");
  const std::string url = a.get("lcm-url", connect ? "" : privateUrl(thr ? 1 : 0));
  const double drain = a.num("drain-seconds", 15.0);
  double idleSeconds = 0.5;
  for (size_t i = 0; i + 1 < a.serverArgs.size(); ++i)
    if (a.serverArgs[i] == "--idle-seconds") idleSeconds = std::stod(a.serverArgs[i + 1]);
  const std::string tmpBase = "/tmp/loopd-bench-" + std::to_string(getpid());

  const io::Dataset ds = io::readDataset(dataset);
  const Schedule sched = buildSchedule(ds, robots, robots > 1, poses);
  const size_t n = sched.steps.size();
  std::fprintf(stderr, "%s: %s, %zu poses, %d robot(s), rate %s, solver %s, LCM %s\n", mode.c_str(),
               dataset.c_str(), n, sched.robots,
               rate > 0 ? (std::to_string(rate) + " Hz").c_str() : "flat out", solver.c_str(),
               url.c_str());

  Monitor mon(url, prefix);
  ServerProcess server;
  std::vector<std::string> extra = a.serverArgs;
  extra.insert(extra.begin(), {"--solver", solver});
  const std::string serverLog = tmpBase + "-loopd.log";
  if (!connect)
    startServer(server, mon, a.get("server", kBinaryDir + "/server/loopd"), url, prefix, extra,
                serverLog);
  else if (!mon.command(loopd::command_t::RESET, 15.0))
    throw std::runtime_error("no server answered RESET on " + url);
  loopd::status_t before{};
  if (!mon.command(loopd::command_t::REQUEST_STATUS, 10.0, &before))
    throw std::runtime_error("no status from server");
  mon.expect(sched);
  mon.resetConverged();
  const double loadStart = loadAverage1();

  lcm::LCM pubLcm(url);
  if (!pubLcm.good()) throw std::runtime_error("cannot open LCM for publishing");
  std::vector<std::unique_ptr<client::FactorPublisher>> pubs;
  const std::string senderBase = "bench" + std::to_string(getpid()) + "_";
  for (int r = 0; r < sched.robots; ++r)
    pubs.push_back(std::make_unique<client::FactorPublisher>(pubLcm, senderBase + std::to_string(r),
                                                             prefix + "FACTORS"));

  const auto t0 = Clock::now();
  for (size_t i = 0; i < n; ++i) {
    if (rate > 0)
      std::this_thread::sleep_until(
          t0 + std::chrono::microseconds(static_cast<std::int64_t>(i * 1e6 / rate)));
    const Step& st = sched.steps[i];
    mon.markSent(i);
    publishStep(*pubs[static_cast<size_t>(st.robot)], st, sched.is3d);
    if (!server.alive() && !connect)
      throw std::runtime_error("loopd died during the feed (log: " + serverLog + ")");
  }
  const auto tLastSent = Clock::now();
  std::int64_t sent = 0;
  for (auto& p : pubs) sent += p->batchesPublished();
  std::fprintf(stderr, "published %lld batches in %.2f s; waiting for estimates\n",
               static_cast<long long>(sent), secondsSince(t0, tLastSent));
  const auto drainEnd =
      Clock::now() + std::chrono::duration<double>(thr ? std::max(drain, 300.0) : drain);
  while (mon.seenCount() < n && Clock::now() < drainEnd)
    std::this_thread::sleep_for(std::chrono::milliseconds(10));

  const std::vector<PoseTiming> tm = mon.timings();
  std::vector<double> lat, srv;
  Clock::time_point lastSeen = t0;
  std::int64_t maxSeq = 0;
  size_t unseen = 0;
  const size_t warmup = thr ? 0 : static_cast<size_t>(std::max(0L, a.integer("warmup", 1)));
  std::vector<double> warm;
  for (size_t i = 0; i < tm.size(); ++i) {
    const auto& t = tm[i];
    if (!t.seen) {
      ++unseen;
      continue;
    }
    if (i < warmup) {
      warm.push_back(std::chrono::duration<double, std::milli>(t.received - t.sent).count());
      continue;
    }
    lat.push_back(std::chrono::duration<double, std::milli>(t.received - t.sent).count());
    srv.push_back(static_cast<double>(t.serverUtime - t.sentWallUs) / 1e3);
    lastSeen = std::max(lastSeen, t.received);
    maxSeq = std::max(maxSeq, t.updateSeq);
  }
  // Throughput: the converged estimate after the last update.
  Clock::time_point convAt{};
  loopd::status_t conv{};
  bool converged = false;
  if (thr && unseen == 0) converged = mon.waitConverged(maxSeq, 120.0, convAt, conv);

  loopd::status_t after{};
  const bool gotStatus = mon.command(loopd::command_t::REQUEST_STATUS, 10.0, &after);
  const double loadEnd = loadAverage1();
  const long rss = server.rssKb(), hwm = server.hwmKb();
  int serverExit = 0;
  if (!connect) serverExit = server.stop(30);

  const std::int64_t accepted = after.batches_accepted - before.batches_accepted;
  const std::int64_t lost = sent - accepted;
  long long gapMissing = 0;
  for (const auto& g : after.sender_gaps)
    if (g.sender.rfind(senderBase, 0) == 0) gapMissing += g.missing;

  Json j;
  j.str("bench", mode)
      .str("dataset", dataset)
      .str("solver", solver)
      .str("lcm_url", url)
      .integer("poses", static_cast<long long>(n));
  j.integer("robots", sched.robots).num("rate_hz", rate).integer("batches_sent", sent);
  j.integer("batches_accepted", accepted)
      .integer("lost_batches", lost)
      .integer("batches_rejected", after.batches_rejected - before.batches_rejected)
      .integer("batches_duplicate", after.batches_duplicate - before.batches_duplicate)
      .integer("batches_expired", after.batches_expired - before.batches_expired)
      .integer("batches_held_at_end", after.batches_held)
      .integer("sequence_gaps_missing", gapMissing)
      .integer("unseen_poses", static_cast<long long>(unseen))
      .integer("status_ok", gotStatus ? 1 : 0);
  j.num("publish_s", secondsSince(t0, tLastSent))
      .num("load_avg_1m_start", loadStart)
      .num("load_avg_1m_end", loadEnd);
  j.integer("server_rss_kb_end", rss)
      .integer("server_hwm_kb", hwm)
      .integer("server_exit", serverExit);
  j.num("server_chi2", after.chi2)
      .integer("server_poses", after.poses)
      .integer("server_updates", after.update_seq - before.update_seq);
  j.str("label", a.get("label", ""));

  std::printf(
      "== loopd %s bench: %s, %zu poses, %s, solver %s\n", mode.c_str(), dataset.c_str(), n,
      rate > 0 ? (std::to_string(static_cast<int>(rate)) + " Hz").c_str() : "as fast as possible",
      solver.c_str());
  int rc = 0;
  if (!thr) {
    const double p50 = percentile(lat, 50), p90 = percentile(lat, 90), p99 = percentile(lat, 99),
                 mx = lat.empty() ? std::nan("") : *std::max_element(lat.begin(), lat.end());
    j.num("latency_ms_mean", mean(lat))
        .num("latency_ms_p50", p50)
        .num("latency_ms_p90", p90)
        .num("latency_ms_p99", p99)
        .num("latency_ms_max", mx)
        .num("server_side_ms_p50", percentile(srv, 50))
        .num("server_side_ms_p99", percentile(srv, 99))
        .integer("warmup_poses", static_cast<long long>(warmup))
        .num("warmup_latency_ms_max",
             warm.empty() ? std::nan("") : *std::max_element(warm.begin(), warm.end()));
    std::printf(
        "latency (publish -> first estimate holding the pose): p50 %.2f ms  p90 %.2f ms  p99 %.2f "
        "ms  "
        "max %.2f ms  mean %.2f ms\n",
        p50, p90, p99, mx, mean(lat));
    std::printf(
        "  of which up to the server's publication: p50 %.2f ms  p99 %.2f ms; over poses %zu..%zu "
        "(the first "
        "%zu, cold start, apart: max %.2f ms)\n",
        percentile(srv, 50), percentile(srv, 99), warmup + 1, n, warmup,
        warm.empty() ? 0.0 : *std::max_element(warm.begin(), warm.end()));
    if (a.has("csv")) {
      std::ofstream csv(a.get("csv", ""));
      csv << "step,id,sent_s,latency_ms,server_ms,update_seq\n";
      for (size_t i = 0; i < tm.size(); ++i) {
        csv << i << "," << sched.steps[i].id << "," << secondsSince(t0, tm[i].sent) << ",";
        if (tm[i].seen)
          csv << std::chrono::duration<double, std::milli>(tm[i].received - tm[i].sent).count()
              << "," << static_cast<double>(tm[i].serverUtime - tm[i].sentWallUs) / 1e3 << ","
              << tm[i].updateSeq << "\n";
        else
          csv << ",,\n";
      }
    }
  } else {
    const double applyS = secondsSince(t0, lastSeen);
    const double convS = converged ? secondsSince(t0, convAt) - idleSeconds : std::nan("");
    const double rateApplied = static_cast<double>(n) / applyS;
    const double rateConv = static_cast<double>(n) / convS;
    j.num("server_s_last_pose", applyS)
        .num("server_s_converged_minus_idle", convS)
        .num("idle_seconds", idleSeconds)
        .num("server_poses_per_s_applied", rateApplied)
        .num("server_poses_per_s_converged", rateConv)
        .num("server_converged_chi2", converged ? conv.chi2 : std::nan(""))
        .num("server_mean_update_ms", after.mean_update_ms)
        .integer("server_update_rounds", after.update_seq - before.update_seq);
    std::printf(
        "server: published in %.2f s; last pose in an estimate after %.2f s (%.0f poses/s); "
        "converged "
        "estimate after %.2f s net of the %.2f s idle wait (%.0f poses/s), chi2 %.6g, %lld update "
        "rounds\n",
        secondsSince(t0, tLastSent), applyS, rateApplied, convS, idleSeconds, rateConv,
        converged ? conv.chi2 : std::nan(""),
        static_cast<long long>(after.update_seq - before.update_seq));
    if (!a.has("no-offline")) {
      if (poses >= 0)
        std::fprintf(stderr, "note: --poses given; the offline run solves the whole file\n");
      const OfflineResult off = runOffline(
          a.get("offline-solve", kBinaryDir + "/tools/loopd-solve"), dataset, solver, tmpBase);
      if (off.ok) {
        const double offRate =
            static_cast<double>(off.poses > 0 ? off.poses : static_cast<int>(n)) / off.solveS;
        j.num("offline_solve_s", off.solveS)
            .num("offline_poses_per_s", offRate)
            .num("offline_final_chi2", off.finalChi2)
            .num("ratio_converged", rateConv / offRate)
            .num("ratio_applied", rateApplied / offRate);
        std::printf(
            "offline loopd-solve --solver %s --incremental: solve_s %.2f (%.0f poses/s), chi2 "
            "%.6g\n",
            solver.c_str(), off.solveS, offRate, off.finalChi2);
        std::printf(
            "ratio server/offline: %.2f (converged)  %.2f (last pose applied)   target >= 0.90\n",
            rateConv / offRate, rateApplied / offRate);
      } else {
        std::printf("offline run failed (see %s-offline.log)\n", tmpBase.c_str());
        rc = 1;
      }
    }
  }
  std::printf(
      "batches: %lld sent, %lld accepted, %lld lost (sent - accepted), %zu poses never in an "
      "estimate, "
      "%lld sequence numbers missing; server exit %d; load average %.2f -> %.2f\n",
      static_cast<long long>(sent), static_cast<long long>(accepted), static_cast<long long>(lost),
      unseen, gapMissing, serverExit, loadStart, loadEnd);
  std::printf("server RSS %.1f MB (peak %.1f MB); server log %s\n", rss / 1024.0, hwm / 1024.0,
              serverLog.c_str());
  j.write(a.get("json", ""));
  if (lost != 0 || unseen != 0 || !gotStatus || serverExit != 0) rc = 1;
  return rc;
}

}  // namespace

int main(int argc, char** argv) {
  return benchMain(
      argc, argv,
      {"mode", "dataset", "rate", "poses", "robots", "solver", "lcm-url", "server", "server-arg",
       "channel-prefix", "drain-seconds", "offline-solve", "json", "csv", "warmup", "label"},
      {"connect", "no-offline"}, kUsage, "bench", run);
}
