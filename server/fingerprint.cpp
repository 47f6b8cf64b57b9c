#include "server/fingerprint.h"

#include "loopd/command_t.hpp"
#include "loopd/covariance_t.hpp"
#include "loopd/error_t.hpp"
#include "loopd/estimate_t.hpp"
#include "loopd/factor_batch_t.hpp"
#include "loopd/status_t.hpp"

namespace loopd::server {

std::string fingerprintName(std::int64_t hash) {
  struct T {
    std::int64_t h;
    const char* n;
  };
  const T known[] = {{loopd::command_t::getHash(), "command_t"},
                     {loopd::estimate_t::getHash(), "estimate_t"},
                     {loopd::covariance_t::getHash(), "covariance_t"},
                     {loopd::status_t::getHash(), "status_t"},
                     {loopd::error_t::getHash(), "error_t"},
                     {loopd::factor_batch_t::getHash(), "factor_batch_t"}};
  for (const auto& t : known)
    if (t.h == hash) return t.n;
  return "";
}

std::int64_t readFingerprint(const std::uint8_t* p) {
  std::uint64_t h = 0;
  for (int i = 0; i < 8; ++i) h = (h << 8) | p[i];
  return static_cast<std::int64_t>(h);
}

}  // namespace loopd::server
