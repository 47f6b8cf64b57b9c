#pragma once
// The LCM thread: the one owner of lcm::LCM. Subscribes raw (so undecodable bytes and wrong
// fingerprints reach the validator instead of being dropped silently) with unlimited queues,
// runs handleTimeout(100) until stopped, and publishes under a mutex for the engine thread.
#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

namespace lcm {
class LCM;
class ReceiveBuffer;
}  // namespace lcm

namespace loopd::server {

class LcmIo {
 public:
  using Handler =
      std::function<void(const std::string& channel, const std::uint8_t* data, int size)>;
  LcmIo(const std::string& url, const std::vector<std::string>& channels, Handler handler);
  ~LcmIo();
  bool good() const;
  const std::string& url() const { return url_; }
  void publish(const std::string& channel, const std::vector<std::uint8_t>& bytes);
  /// handleTimeout(100) until stop (LCM thread).
  void run(const std::atomic<bool>& stop);

 private:
  static void onMessage(const lcm::ReceiveBuffer* rbuf, const std::string& channel, LcmIo* self);
  std::string url_;
  std::unique_ptr<lcm::LCM> lcm_;
  Handler handler_;
  std::mutex publishMu_;
};

}  // namespace loopd::server
