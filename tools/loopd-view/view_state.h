#pragma once
// loopd-view's model of a loopd server: follows the estimate, covariance, status and error
// channels (client::EstimateSubscriber) and the factor channel (to learn the endpoints of
// loop closures, which the status decisions name only by (sender, factor id)), and renders
// the whole state as one JSON document for the page.
#include <lcm/lcm-cpp.hpp>

#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <utility>

#include "client/estimate_subscriber.h"
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

 private:
  static void factorsMsg(const lcm::ReceiveBuffer*, const std::string&,
                         const loopd::factor_batch_t* m, ViewState* self);
  void onStatus(const loopd::status_t& s);
  void onError(const loopd::error_t& e);
  void touch();

  lcm::LCM& lcm_;
  std::string prefix_, url_;
  client::EstimateSubscriber sub_;
  void* factorsSub_ = nullptr;

  mutable std::mutex mu_;
  bool dirty_ = true;
  std::int64_t messages_ = 0, statusMsgs_ = 0, factorBatches_ = 0;
  std::int64_t lastMessageUs_ = 0;
  bool statusSeen_ = false;
  struct Closure {
    loopd::key_t a, b;
  };
  using FactorName = std::pair<std::string, std::int64_t>;  // (sender, factor id)
  std::map<FactorName, Closure> closures_;                  // loop closures seen on FACTORS
  struct Decision {
    bool accepted = true;
    double weight = 1.0;
  };
  std::map<FactorName, Decision> decisions_;
  std::map<FactorName, Decision> pendingFull_;  // a chunked full listing being assembled
  std::int64_t pendingFullSeq_ = -1;
  std::int64_t errors_ = 0;
  std::map<int, std::int64_t> errorsByCode_;
  std::deque<loopd::error_t> recentErrors_;
  std::int64_t requestId_ = 0;
};

/// The error_t code's name ("UNKNOWN_KEY", ...).
const char* errorCodeName(int code);

}  // namespace loopd::view
