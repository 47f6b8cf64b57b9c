#include "server/lcm_io.h"

#include <spdlog/spdlog.h>
#include <lcm/lcm-cpp.hpp>

namespace loopd::server {

LcmIo::LcmIo(const std::string& url, const std::vector<std::string>& channels, Handler handler)
    : url_(url), lcm_(std::make_unique<lcm::LCM>(url)), handler_(std::move(handler)) {
  if (!lcm_->good()) return;
  for (const auto& ch : channels) {
    lcm::Subscription* s = lcm_->subscribeFunction(ch, &LcmIo::onMessage, this);
    if (s) s->setQueueCapacity(0);
  }
}

LcmIo::~LcmIo() = default;

bool LcmIo::good() const { return lcm_ && lcm_->good(); }

void LcmIo::onMessage(const lcm::ReceiveBuffer* rbuf, const std::string& channel, LcmIo* self) {
  self->handler_(channel, static_cast<const std::uint8_t*>(rbuf->data),
                 static_cast<int>(rbuf->data_size));
}

void LcmIo::publish(const std::string& channel, const std::vector<std::uint8_t>& bytes) {
  std::lock_guard<std::mutex> l(publishMu_);
  if (lcm_->publish(channel, bytes.data(), static_cast<unsigned>(bytes.size())) != 0)
    spdlog::warn("publish on {} ({} bytes) failed", channel, bytes.size());
}

void LcmIo::run(const std::atomic<bool>& stop) {
  while (!stop.load()) {
    if (lcm_->handleTimeout(100) < 0) {
      spdlog::error("LCM handle failed; stopping the LCM thread");
      break;
    }
  }
}

}  // namespace loopd::server
