#pragma once
// loopd-view's model of a loopd server: follows the estimate, covariance, status and error
// channels (client::EstimateSubscriber) and the factor channel (to learn the endpoints of
// loop closures, which the status decisions name only by (sender, factor id)), and renders
// the whole state as one JSON document for the page.
//
// Only what the server accepted is drawn. A batch seen on the factor channel waits until the
// server settles it: an error_t naming (sender, sequence) refuses it; the first decision
// naming one of its closures accepts it (the server applies a batch whole), and its closures
// are drawn from then on with their decisions. A second batch with a (sender, sequence) seen
// before is a duplicate the server ignores; so is it here. Removals hide their closures at
// once and bring them back if the batch is refused; a complete decision listing drops the
// closures it does not name. When the subscriber forgets its tables (RESET, restart) the view
// forgets its closures and decisions too, and asks for everything again.
#include <lcm/lcm-cpp.hpp>

#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <utility>

#include "client/decision_table.h"
#include "client/estimate_subscriber.h"
#include "loopd/command_t.hpp"
#include "loopd/factor_batch_t.hpp"
#include "loopd/key_t.hpp"

namespace loopd::view {

class ViewState {
 public:
  ViewState(lcm::LCM& lcm, std::string channelPrefix, std::string lcmUrl);
  ~ViewState();

  /// Asks the server for a full estimate and the full decision list (read-only commands), so a
  /// view started after the server still shows everything.
  void requestEverything();

  /// Something changed since the last render.
  bool dirty() const;
  /// The whole state as JSON (clears dirty). `seq` is the snapshot number.
  std::string renderJson(std::uint64_t seq);

  std::int64_t messagesSeen() const;
  bool statusSeen() const;
  /// Something was lost or forgotten (a status missed, the tables dropped): the view wants a
  /// full estimate and decision listing (requestEverything() clears this).
  bool wantsEverything() const;

 private:
  static void factorsMsg(const lcm::ReceiveBuffer*, const std::string&,
                         const loopd::factor_batch_t* m, ViewState* self);
  static void commandMsg(const lcm::ReceiveBuffer*, const std::string&, const loopd::command_t* m,
                         ViewState* self);
  void onStatus(const loopd::status_t& s);
  void onError(const loopd::error_t& e);
  void onForget();
  void touch();

  struct Closure {
    loopd::key_t a, b;
  };
  using FactorName = std::pair<std::string, std::int64_t>;              // (sender, factor id)
  using BatchName = std::pair<std::string, std::int64_t>;               // (sender, sequence)
  using NamedClosures = std::vector<std::pair<std::int64_t, Closure>>;  // factor id, endpoints
  struct PendingBatch {
    BatchName name;
    NamedClosures closures;
    NamedClosures removed;  // accepted closures it removes: hidden now, back if it is refused
  };
  // All under mu_.
  void trackBatch(const loopd::factor_batch_t& m);
  void applyDecisions(const loopd::status_t& s);
  void adoptBatchWith(const FactorName& closure);
  void refuseBatch(const BatchName& batch);
  void dropPending(std::uint64_t arrival);
  void pruneClosuresWithoutDecision();

  lcm::LCM& lcm_;
  std::string prefix_, url_;
  client::EstimateSubscriber sub_;
  void* factorsSub_ = nullptr;
  void* commandSub_ = nullptr;  // to see RESET commands: sequence numbers may start again

  mutable std::mutex mu_;
  bool dirty_ = true;
  std::int64_t messages_ = 0, statusMsgs_ = 0, factorBatches_ = 0;
  std::int64_t lastMessageUs_ = 0;
  bool statusSeen_ = false;
  std::map<FactorName, Closure> closures_;         // accepted loop closures: the ones drawn
  std::map<std::uint64_t, PendingBatch> pending_;  // by arrival: seen, not settled yet
  std::map<BatchName, std::uint64_t> pendingByBatch_;
  std::map<FactorName, std::set<std::uint64_t>> pendingByClosure_;
  std::uint64_t arrivals_ = 0;
  std::uint64_t resetMark_ = 0;  // batches that arrived up to it predate a RESET command
  /// One sender's sequence numbers seen since the last reset: all up to `contiguous`, and
  /// the ones above it.
  struct SeenSequences {
    std::int64_t contiguous = 0;
    std::set<std::int64_t> above;
    bool insert(std::int64_t sequence);  // false: seen before
  };
  std::map<std::string, SeenSequences> seenBatches_;  // a batch seen again is a duplicate
  std::int64_t duplicates_ = 0;
  std::int64_t lastStatusSeq_ = 0;
  bool wantEverything_ = false;
  client::DecisionTable decisions_;
  std::int64_t errors_ = 0;
  std::map<int, std::int64_t> errorsByCode_;
  std::deque<loopd::error_t> recentErrors_;
  std::int64_t requestId_ = 0;
};

/// The error_t code's name ("UNKNOWN_KEY", ...).
const char* errorCodeName(int code);

}  // namespace loopd::view
