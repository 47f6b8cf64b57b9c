// loopd-soak-bench: N robots (default 8) feeding one live loopd concurrently for M minutes,
// each robot its own thread with its own LCM instance and sender. The dataset (default
// city10000, or a loopd-synth world) is cut into N consecutive segments; the robots publish on
// loopd-feed's interleaved schedule (a batch only refers to poses already published), each at
// --rate Hz, so inter-robot closures join the robots into one frame as they go. Laps repeat
// until the time is up:
//   --lap-mode reset  (default) RESET the server between laps, fresh sender names each lap: the
//                     graph is rebuilt to the same size every lap, so per-lap peak RSS must stay
//                     flat (a leak shows as a rising peak);
//   --lap-mode resend lap 1 builds the graph, later laps resend the same batches (same senders
//                     and sequences): the server must count them as duplicates and the graph
//                     (and RSS) must stop growing after lap 1;
//   --lap-mode grow   fresh senders and fresh robot ids each lap: the graph keeps growing.
// A sampler thread reads the server's VmRSS from /proc every --sample-seconds and checks it is
// alive. At the end: lost batches = sent − (accepted + duplicate + rejected) from the server's
// status counters (target 0), rejected and expired (target 0), crash (target none).
#include "bench/server/server_bench_common.h"

using namespace loopd;
using namespace loopd::bench;

namespace {

const char* kUsage =
    "usage: loopd-soak-bench [flags]\n"
    "  --minutes M          feeding time (default 10)\n"
    "  --robots N           concurrent robots (default 8)\n"
    "  --rate HZ            poses per second per robot (default 20)\n"
    "  --dataset FILE       default ../shared/datasets/city10000.g2o (or a loopd-synth world)\n"
    "  --poses N            per lap, only the first N poses\n"
    "  --lap-mode M         reset (default) | resend | grow\n"
    "  --sample-seconds S   RSS sampling period (default 5)\n"
    "  --solver NAME        default isam2\n"
    "  --lcm-url URL        default: a private udpm port from the pid, ttl=0\n"
    "  --server EXE         default <build>/server/loopd\n"
    "  --server-arg ARG     extra argument for the server (repeatable)\n"
    "  --csv FILE           RSS samples: t_s, rss_kb, lap, server_poses, queue_depth\n"
    "  --json FILE          summary as JSON\n";

struct Sample {
  double t;
  long rssKb;
  int lap;
  long long poses;
  int queue;
};

int run(const Args& a) {
  const double minutes = a.num("minutes", 10);
  const int robots = static_cast<int>(a.integer("robots", 8));
  const double rate = a.num("rate", 20);
  const std::string dataset = a.get("dataset", kDatasetsDir + "/city10000.g2o");
  const long poses = a.integer("poses", -1);
  const std::string lapMode = a.get("lap-mode", "reset");
  if (lapMode != "reset" && lapMode != "resend" && lapMode != "grow")
    throw std::invalid_argument("--lap-mode reset|resend|grow");
  const double samplePeriod = a.num("sample-seconds", 5);
  const std::string solver = a.get("solver", "isam2");
  const std::string url = a.get("lcm-url", privateUrl(2));
  const std::string prefix = "LOOPD_";
  const std::string tmpBase = "/tmp/loopd-soak-" + std::to_string(getpid());
  if (rate <= 0) throw std::invalid_argument("--rate must be > 0");

  const io::Dataset ds = io::readDataset(dataset);
  Monitor mon(url, prefix);
  ServerProcess server;
  std::vector<std::string> extra = a.serverArgs;
  extra.insert(extra.begin(), {"--solver", solver});
  const std::string serverLog = tmpBase + "-loopd.log";
  startServer(server, mon, a.get("server", kBinaryDir + "/server/loopd"), url, prefix, extra,
              serverLog);
  loopd::status_t before{};
  mon.command(loopd::command_t::REQUEST_STATUS, 10.0, &before);
  std::printf(
      "== loopd soak: %d robots x %.0f Hz for %.1f min, %s (%s laps), solver %s, LCM %s, server "
      "pid %d\n",
      robots, rate, minutes, dataset.c_str(), lapMode.c_str(), solver.c_str(), url.c_str(),
      static_cast<int>(server.pid));
  std::fflush(stdout);

  const auto t0 = Clock::now();
  const auto deadline = t0 + std::chrono::duration<double>(minutes * 60.0);
  std::atomic<bool> crashed{false}, stopSampler{false};
  std::atomic<int> lapNow{0};
  std::vector<Sample> samples;
  std::mutex samplesMu;
  std::thread sampler([&] {
    while (!stopSampler) {
      if (!server.alive()) {
        crashed = true;
        return;
      }
      const loopd::status_t st = mon.lastStatus();
      Sample s{secondsSince(t0), server.rssKb(), lapNow.load(), static_cast<long long>(st.poses),
               st.queue_depth};
      {
        std::lock_guard<std::mutex> l(samplesMu);
        samples.push_back(s);
      }
      std::printf("  t %6.1f s  rss %7.1f MB  lap %d  poses %lld  queue %d\n", s.t,
                  s.rssKb / 1024.0, s.lap, s.poses, s.queue);
      std::fflush(stdout);
      for (int i = 0; i < static_cast<int>(samplePeriod * 10) && !stopSampler; ++i)
        std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
  });

  std::atomic<long long> sent{0};
  struct LapInfo {
    int lap;
    double startS, endS;
    long long sent, poses;
    long peakRssKb, endRssKb;
    bool complete;
  };
  std::vector<LapInfo> laps;
  const double totalRate = rate * robots;
  for (int lap = 0; Clock::now() < deadline && !crashed; ++lap) {
    lapNow = lap + 1;
    const bool fresh = lapMode != "resend";
    if (lap > 0 && lapMode == "reset" && !mon.command(loopd::command_t::RESET, 30.0)) {
      std::printf("RESET not acknowledged\n");
      break;
    }
    const Schedule sched =
        buildSchedule(ds, robots, true, poses, lapMode == "grow" ? lap * robots : 0);
    const std::string senderBase =
        "soak" + std::to_string(getpid()) + "_L" + std::to_string(fresh ? lap : 0) + "_r";
    std::vector<std::vector<size_t>> mine(static_cast<size_t>(sched.robots));
    for (size_t i = 0; i < sched.steps.size(); ++i)
      mine[static_cast<size_t>(sched.steps[i].robot - (lapMode == "grow" ? lap * robots : 0))]
          .push_back(i);
    const auto lapStart = Clock::now();
    std::atomic<bool> cut{false};
    std::vector<std::thread> threads;
    for (int r = 0; r < sched.robots; ++r)
      threads.emplace_back([&, r] {
        lcm::LCM lcm(url);
        if (!lcm.good()) return;
        client::FactorPublisher pub(lcm, senderBase + std::to_string(r), prefix + "FACTORS");
        for (size_t i : mine[static_cast<size_t>(r)]) {
          const auto due = lapStart + std::chrono::microseconds(static_cast<std::int64_t>(
                                          static_cast<double>(i) * 1e6 / totalRate));
          if (due >= deadline || crashed) {
            cut = true;
            break;
          }
          std::this_thread::sleep_until(due);
          publishStep(pub, sched.steps[i], sched.is3d);
        }
        sent += pub.batchesPublished();
      });
    for (auto& t : threads) t.join();
    // Let the server drain this lap before the next one (or the end).
    loopd::status_t st{};
    const auto drainEnd = Clock::now() + std::chrono::seconds(60);
    while (Clock::now() < drainEnd && !crashed) {
      if (mon.command(loopd::command_t::REQUEST_STATUS, 5.0, &st) && st.queue_depth == 0 &&
          st.batches_held == 0 &&
          st.batches_accepted + st.batches_duplicate + st.batches_rejected -
                  before.batches_accepted - before.batches_duplicate - before.batches_rejected >=
              sent)
        break;
      std::this_thread::sleep_for(std::chrono::milliseconds(200));
    }
    long peak = 0;
    {
      std::lock_guard<std::mutex> l(samplesMu);
      for (const auto& s : samples)
        if (s.lap == lap + 1) peak = std::max(peak, s.rssKb);
    }
    const long endRss = server.rssKb();
    peak = std::max(peak, endRss);
    laps.push_back({lap + 1, secondsSince(t0, lapStart), secondsSince(t0), sent.load(),
                    static_cast<long long>(st.poses), peak, endRss, !cut});
    std::printf(
        "lap %d %s: %.1f..%.1f s, %lld batches sent so far, server: %lld poses, %d/%d robots in a "
        "common "
        "frame, accepted %lld, duplicate %lld, rejected %lld, expired %lld, mean update %.2f ms, "
        "rss %.1f MB "
        "(lap peak %.1f MB)\n",
        lap + 1, cut ? "(cut by the deadline)" : "done", laps.back().startS, laps.back().endS,
        sent.load(), static_cast<long long>(st.poses), st.robots_in_common_frame, st.robots,
        static_cast<long long>(st.batches_accepted), static_cast<long long>(st.batches_duplicate),
        static_cast<long long>(st.batches_rejected), static_cast<long long>(st.batches_expired),
        st.mean_update_ms, endRss / 1024.0, peak / 1024.0);
    std::fflush(stdout);
  }
  stopSampler = true;
  sampler.join();

  loopd::status_t after{};
  const bool gotStatus = !crashed && mon.command(loopd::command_t::REQUEST_STATUS, 10.0, &after);
  const long hwm = server.hwmKb(), rssEnd = server.rssKb();
  const int serverExit = crashed ? 128 : server.stop(60);
  const long long accepted = after.batches_accepted - before.batches_accepted;
  const long long duplicate = after.batches_duplicate - before.batches_duplicate;
  const long long rejected = after.batches_rejected - before.batches_rejected;
  const long long expired = after.batches_expired - before.batches_expired;
  const long long lost = sent - accepted - duplicate - rejected;

  // Flatness: complete laps' peaks (reset / resend modes).
  long firstPeak = 0, lastPeak = 0, maxLaterPeak = 0;
  int complete = 0;
  for (const auto& l : laps)
    if (l.complete) {
      ++complete;
      if (complete == 1)
        firstPeak = l.peakRssKb;
      else
        maxLaterPeak = std::max(maxLaterPeak, l.peakRssKb);
      lastPeak = l.peakRssKb;
    }
  std::printf(
      "== soak result: %s; %.1f min, %zu laps (%d complete), %lld batches sent, %lld accepted, "
      "%lld duplicate, "
      "%lld rejected, %lld expired, %lld lost (sent - accepted - duplicate - rejected)\n",
      crashed ? "SERVER CRASHED" : "no crash", secondsSince(t0) / 60.0, laps.size(), complete,
      sent.load(), accepted, duplicate, rejected, expired, lost);
  std::printf(
      "   RSS: first complete lap peak %.1f MB, later complete laps' max peak %.1f MB (last %.1f "
      "MB), end %.1f MB, "
      "VmHWM %.1f MB; server exit %d; server log %s\n",
      firstPeak / 1024.0, maxLaterPeak / 1024.0, lastPeak / 1024.0, rssEnd / 1024.0, hwm / 1024.0,
      serverExit, serverLog.c_str());

  if (a.has("csv")) {
    std::ofstream csv(a.get("csv", ""));
    csv << "t_s,rss_kb,lap,server_poses,queue_depth\n";
    for (const auto& s : samples)
      csv << s.t << "," << s.rssKb << "," << s.lap << "," << s.poses << "," << s.queue << "\n";
  }
  std::string lapJson = "[";
  for (size_t i = 0; i < laps.size(); ++i) {
    const auto& l = laps[i];
    lapJson += (i ? ", " : "") + Json()
                                     .integer("lap", l.lap)
                                     .num("start_s", l.startS)
                                     .num("end_s", l.endS)
                                     .integer("sent_cumulative", l.sent)
                                     .integer("server_poses", l.poses)
                                     .integer("peak_rss_kb", l.peakRssKb)
                                     .integer("end_rss_kb", l.endRssKb)
                                     .integer("complete", l.complete ? 1 : 0)
                                     .text();
  }
  lapJson += "]";
  std::string rssJson = "[";
  for (size_t i = 0; i < samples.size(); ++i)
    rssJson += (i ? ", [" : "[") + std::to_string(samples[i].t) + ", " +
               std::to_string(samples[i].rssKb) + "]";
  rssJson += "]";
  Json j;
  j.str("bench", "soak")
      .str("dataset", dataset)
      .str("solver", solver)
      .str("lap_mode", lapMode)
      .integer("robots", robots)
      .num("rate_hz_per_robot", rate)
      .num("minutes", minutes)
      .integer("crashed", crashed ? 1 : 0)
      .integer("server_exit", serverExit)
      .integer("status_ok", gotStatus ? 1 : 0)
      .integer("batches_sent", sent.load())
      .integer("batches_accepted", accepted)
      .integer("batches_duplicate", duplicate)
      .integer("batches_rejected", rejected)
      .integer("batches_expired", expired)
      .integer("lost_batches", lost)
      .integer("first_lap_peak_rss_kb", firstPeak)
      .integer("later_laps_max_peak_rss_kb", maxLaterPeak)
      .integer("end_rss_kb", rssEnd)
      .integer("hwm_kb", hwm)
      .num("load_avg_1m_end", loadAverage1())
      .raw("laps", lapJson)
      .raw("rss_samples_s_kb", rssJson);
  j.write(a.get("json", ""));
  return crashed || lost != 0 || rejected != 0 || expired != 0 || serverExit != 0 ? 1 : 0;
}

}  // namespace

int main(int argc, char** argv) {
  return benchMain(argc, argv,
                   {"minutes", "robots", "rate", "dataset", "poses", "lap-mode", "sample-seconds",
                    "solver", "lcm-url", "server", "server-arg", "csv", "json"},
                   {}, kUsage, "soak", run);
}
