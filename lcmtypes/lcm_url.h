#pragma once
// The LCM URL every loopd receiver opens: an empty URL means LCM_DEFAULT_URL or LCM's default,
// and udpm URLs get a 4 MB receive buffer (the kernel default drops bursts; LCM_NOTES.md).
// Header-only so the server and the client library share it without depending on each other.
#include <cstdlib>
#include <string>

namespace loopd {

inline std::string lcmReceiveUrl(const std::string& url) {
  std::string u = url;
  if (u.empty()) {
    const char* env = std::getenv("LCM_DEFAULT_URL");
    u = env && *env ? env : "udpm://239.255.76.67:7667?ttl=0";
  }
  if (u.rfind("udpm://", 0) == 0 && u.find("recv_buf_size") == std::string::npos)
    u += (u.find('?') == std::string::npos ? "?" : "&") + std::string("recv_buf_size=4194304");
  return u;
}

}  // namespace loopd
