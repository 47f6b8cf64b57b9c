#include "server/server.h"

#include <spdlog/spdlog.h>
#include <sys/stat.h>

#include <memory>
#include <thread>

#include "server/engine.h"
#include "server/journal.h"
#include "server/lcm_io.h"
#include "server/publisher.h"

namespace loopd::server {

namespace {
bool sameFile(const std::string& a, const std::string& b) {
  struct stat sa {
  }, sb{};
  if (::stat(a.c_str(), &sa) != 0 || ::stat(b.c_str(), &sb) != 0) return a == b;
  return sa.st_dev == sb.st_dev && sa.st_ino == sb.st_ino;
}
bool exists(const std::string& p) {
  struct stat s {};
  return ::stat(p.c_str(), &s) == 0;
}
}  // namespace

int runServer(const ServerConfig& cfg, const std::atomic<bool>& stop) {
  const Channels ch = Channels::withPrefix(cfg.channelPrefix);
  const std::string url = effectiveLcmUrl(cfg.lcmUrl);
  Engine* enginePtr = nullptr;
  LcmIo io(url, {ch.factors, ch.command},
           [&](const std::string& channel, const std::uint8_t* d, int n) {
             if (enginePtr) enginePtr->post(Inbound{channel, std::vector<std::uint8_t>(d, d + n)});
           });
  if (!io.good()) {
    spdlog::error(
        "cannot open LCM at '{}' (is there a multicast route? see scripts/ensure-multicast.sh)",
        url);
    return 1;
  }
  Publisher pub(ch, [&](const std::string& channel, const std::vector<std::uint8_t>& b) {
    io.publish(channel, b);
  });

  // Resume: replay first; then append to the journal (cutting a partial last event).
  const bool resumeIntoJournal =
      !cfg.resume.empty() && !cfg.journal.empty() && sameFile(cfg.resume, cfg.journal);
  long validBytes = -1;
  std::unique_ptr<Journal> journal;
  EngineOptions eo;
  eo.solver = cfg.solver;
  eo.publishEvery = cfg.publishEvery;
  eo.holdSeconds = cfg.holdSeconds;
  eo.holdMaxBatches = cfg.holdMax;
  eo.idleSeconds = cfg.idleSeconds;
  eo.idleRounds = cfg.idleRounds;
  eo.maxHypotheses = cfg.maxHypotheses;
  eo.posesPerUpdate = cfg.posesPerUpdate;
  eo.joinAgreement = cfg.joinAgreement;
  eo.landmarkNamespaces = cfg.landmarkNamespaces;
  if (!cfg.journal.empty() && !resumeIntoJournal) {
    journal = std::make_unique<Journal>(cfg.journal, exists(cfg.journal));
    if (!journal->good()) {
      spdlog::error("cannot open journal {}", cfg.journal);
      return 1;
    }
  }
  Engine engine(eo, pub, journal.get());
  if (!cfg.resume.empty()) {
    if (!exists(cfg.resume)) {
      spdlog::warn("--resume {}: no such file, starting empty", cfg.resume);
    } else {
      try {
        const auto t0 = std::chrono::steady_clock::now();
        const std::int64_t n =
            engine.replay(cfg.resume, /*rejournal=*/journal != nullptr, &validBytes);
        const auto c = engine.counters();
        spdlog::info(
            "resumed {} events from {} in {:.2f} s: {} batches accepted, {} rejected, {} expired, "
            "{} poses, chi2 {:.9g}",
            n, cfg.resume,
            std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(),
            c.accepted, c.rejected, c.expired, engine.backend().estimate().size(),
            engine.backend().graph().empty() ? 0.0 : engine.backend().chi2());
      } catch (const std::exception& e) {
        // Not a journal (or damaged before its tail): refuse to start, the file untouched.
        spdlog::error("--resume {}: {}; not starting", cfg.resume, e.what());
        return 1;
      }
    }
  }
  if (resumeIntoJournal) {
    // Only a torn last event (kill -9 during a write) is cut; readJournal refused anything else.
    if (validBytes >= 0 && !truncateFile(cfg.journal, validBytes)) {
      spdlog::error("cannot cut the torn tail of journal {}", cfg.journal);
      return 1;
    }
    journal = std::make_unique<Journal>(cfg.journal, exists(cfg.journal));
    if (!journal->good()) {
      spdlog::error("cannot open journal {}", cfg.journal);
      return 1;
    }
  }
  // The engine was built with the pre-resume journal pointer; give it the final one.
  Engine* e = &engine;
  if (resumeIntoJournal) {
    // Re-create nothing: the engine only needs the pointer, set below.
  }
  e->setJournal(journal.get());
  enginePtr = e;
  spdlog::info(
      "loopd: solver {}, LCM {}, channels {}FACTORS/{}COMMAND -> "
      "ESTIMATE/COVARIANCE/STATUS/ERROR{}",
      engine.backend().name(), url, cfg.channelPrefix, cfg.channelPrefix,
      journal ? ", journal " + cfg.journal : std::string());

  std::atomic<bool> ioStop{false};
  std::thread ioThread([&] { io.run(ioStop); });
  engine.run(stop);
  ioStop = true;
  ioThread.join();
  enginePtr = nullptr;
  engine.step();
  if (journal) journal->flush();
  const auto c = engine.counters();
  spdlog::info(
      "loopd: stopped; {} batches accepted, {} rejected, {} duplicate, {} expired, {} journaled",
      c.accepted, c.rejected, c.duplicate, c.expired, c.journaled);
  return 0;
}

}  // namespace loopd::server
