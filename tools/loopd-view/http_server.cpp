#include "tools/loopd-view/http_server.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cctype>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <stdexcept>
#include <string_view>
#include <system_error>
#include <vector>

#include "loopd_view_assets.h"

namespace loopd::view {

// ---------------------------------------------------------------------------------------------
// SnapshotBoard

void SnapshotBoard::publish(std::string json) {
  auto p = std::make_shared<const std::string>(std::move(json));
  {
    std::lock_guard<std::mutex> l(mu_);
    json_ = std::move(p);
    ++version_;
  }
  cv_.notify_all();
}

std::pair<std::uint64_t, std::shared_ptr<const std::string>> SnapshotBoard::latest() const {
  std::lock_guard<std::mutex> l(mu_);
  return {version_, json_};
}

std::pair<std::uint64_t, std::shared_ptr<const std::string>> SnapshotBoard::waitNewer(
    std::uint64_t seen, int timeoutMs) const {
  std::unique_lock<std::mutex> l(mu_);
  cv_.wait_for(l, std::chrono::milliseconds(timeoutMs),
               [&] { return version_ > seen || stopped_; });
  return {version_, json_};
}

void SnapshotBoard::stop() {
  {
    std::lock_guard<std::mutex> l(mu_);
    stopped_ = true;
  }
  cv_.notify_all();
}

bool SnapshotBoard::stopped() const {
  std::lock_guard<std::mutex> l(mu_);
  return stopped_;
}

// ---------------------------------------------------------------------------------------------
// Helpers

namespace {

using Clock = std::chrono::steady_clock;

bool sendAll(int fd, const char* p, std::size_t n) {
  while (n > 0) {
    const ssize_t k = ::send(fd, p, n, MSG_NOSIGNAL);
    if (k < 0) {
      if (errno == EINTR) continue;
      return false;  // EPIPE, ECONNRESET, or the send timeout (EAGAIN)
    }
    p += k;
    n -= static_cast<std::size_t>(k);
  }
  return true;
}
bool sendAll(int fd, const std::string& s) { return sendAll(fd, s.data(), s.size()); }

const char* reasonPhrase(int code) {
  switch (code) {
    case 200:
      return "OK";
    case 400:
      return "Bad Request";
    case 403:
      return "Forbidden";
    case 404:
      return "Not Found";
    case 405:
      return "Method Not Allowed";
    case 408:
      return "Request Timeout";
    case 431:
      return "Request Header Fields Too Large";
    case 503:
      return "Service Unavailable";
    case 505:
      return "HTTP Version Not Supported";
    default:
      return "Error";
  }
}

// The page loads only its own assets: the policy forbids anything else (no CDN, no fetch).
const char* kCommonHeaders =
    "Cache-Control: no-store\r\n"
    "X-Content-Type-Options: nosniff\r\n"
    "Content-Security-Policy: default-src 'self'; img-src 'self' data:; base-uri 'none'; "
    "form-action 'none'\r\n"
    "Connection: close\r\n";

bool respond(int fd, int code, const std::string& type, const char* body, std::size_t size,
             bool head, const std::string& extra = "") {
  std::string h = "HTTP/1.1 " + std::to_string(code) + " " + reasonPhrase(code) + "\r\n" +
                  "Content-Type: " + type + "\r\n" + "Content-Length: " + std::to_string(size) +
                  "\r\n" + kCommonHeaders + extra + "\r\n";
  if (!head) h.append(body, size);
  return sendAll(fd, h);
}

bool respondError(int fd, int code, const std::string& extra = "") {
  const std::string body = std::to_string(code) + " " + reasonPhrase(code) + "\n";
  return respond(fd, code, "text/plain; charset=utf-8", body.data(), body.size(), false, extra);
}

/// After an error answer: half-close and drain what the client is still sending (briefly), so
/// closing with unread input does not reset the connection before the client reads the answer.
void lingerDrain(int fd) {
  ::shutdown(fd, SHUT_WR);
  const auto end = Clock::now() + std::chrono::milliseconds(500);
  char buf[4096];
  std::size_t total = 0;
  while (Clock::now() < end && total < (1u << 20)) {
    pollfd pf{fd, POLLIN, 0};
    if (::poll(&pf, 1, 50) <= 0) continue;
    const ssize_t k = ::recv(fd, buf, sizeof buf, 0);
    if (k <= 0) return;
    total += static_cast<std::size_t>(k);
  }
}

bool isTchar(char c) {
  if ((c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9')) return true;
  return std::strchr("!#$%&'*+-.^_`|~", c) != nullptr && c != '\0';
}

/// Splits "A B C" on single spaces; false unless exactly three non-empty parts.
bool splitRequestLine(std::string_view line, std::string_view out[3]) {
  int n = 0;
  std::size_t start = 0;
  for (std::size_t i = 0; i <= line.size(); ++i) {
    if (i == line.size() || line[i] == ' ') {
      if (i == start || n == 3) return false;
      out[n++] = line.substr(start, i - start);
      start = i + 1;
    }
  }
  return n == 3;
}

struct Request {
  std::string method, target, path, host;
  bool hasHost = false;
};

/// 0 if the head is well formed (fills `r`), else the status to answer with.
int parseHead(const std::string& head, Request& r) {
  std::vector<std::string_view> lines;
  std::string_view h(head);
  std::size_t pos = 0;
  while (pos < h.size()) {
    std::size_t e = h.find('\n', pos);
    if (e == std::string_view::npos) e = h.size();
    std::string_view line = h.substr(pos, e - pos);
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    lines.push_back(line);
    pos = e + 1;
  }
  while (!lines.empty() && lines.back().empty()) lines.pop_back();
  if (lines.empty()) return 400;
  std::string_view parts[3];
  if (!splitRequestLine(lines[0], parts)) return 400;
  for (char c : parts[0])
    if (!isTchar(c)) return 400;
  if (parts[0].size() > 32) return 400;
  if (parts[1].size() > 4096 || parts[1].empty() || parts[1][0] != '/') return 400;
  for (char c : parts[1])
    if (static_cast<unsigned char>(c) <= 0x20 || static_cast<unsigned char>(c) >= 0x7f) return 400;
  const std::string_view v = parts[2];
  if (v != "HTTP/1.1" && v != "HTTP/1.0") {
    const bool looksHttp = v.size() == 8 && v.substr(0, 5) == "HTTP/" &&
                           std::isdigit(static_cast<unsigned char>(v[5])) && v[6] == '.' &&
                           std::isdigit(static_cast<unsigned char>(v[7]));
    return looksHttp ? 505 : 400;
  }
  for (std::size_t i = 1; i < lines.size(); ++i) {
    const std::string_view l = lines[i];
    if (l.empty()) return 400;  // a blank line inside the head cannot happen; be strict
    const std::size_t colon = l.find(':');
    if (colon == std::string_view::npos || colon == 0) return 400;
    for (std::size_t k = 0; k < colon; ++k)
      if (!isTchar(l[k])) return 400;
    for (char c : l.substr(colon + 1)) {
      const auto u = static_cast<unsigned char>(c);
      if ((u < 0x20 && u != '\t') || u == 0x7f) return 400;
    }
    std::string name(l.substr(0, colon));
    for (char& c : name) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    if (name == "host") {
      if (r.hasHost) return 400;  // two Host headers
      std::string_view v = l.substr(colon + 1);
      while (!v.empty() && (v.front() == ' ' || v.front() == '\t')) v.remove_prefix(1);
      while (!v.empty() && (v.back() == ' ' || v.back() == '\t')) v.remove_suffix(1);
      r.host.assign(v);
      r.hasHost = true;
    }
  }
  r.method.assign(parts[0]);
  r.target.assign(parts[1]);
  const std::size_t q = r.target.find_first_of("?#");
  r.path = r.target.substr(0, q);
  return 0;
}

/// "localhost:8080" → "localhost", "[::1]:80" → "[::1]".
std::string hostName(const std::string& host) {
  if (!host.empty() && host[0] == '[') return host.substr(0, host.find(']') + 1);
  return host.substr(0, host.find(':'));
}

/// Served on a loopback address, the view answers only requests addressed to a loopback name:
/// a web page elsewhere cannot read the map through DNS rebinding.
bool hostAllowed(const std::string& bind, const Request& r) {
  if (bind.rfind("127.", 0) != 0 || !r.hasHost) return true;  // HTTP/1.0 may omit Host
  std::string h = hostName(r.host);
  for (char& c : h) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return h == "localhost" || h == "[::1]" || h.rfind("127.", 0) == 0 ||
         (h.size() > 10 && h.compare(h.size() - 10, 10, ".localhost") == 0);
}

const assets::Asset* findAsset(const std::string& path) {
  const std::string p = path == "/" ? "/index.html" : path;
  for (const assets::Asset* a = assets::kAssets; a->path; ++a)
    if (p == a->path) return a;
  return nullptr;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// HttpServer

HttpServer::HttpServer(HttpOptions o, SnapshotBoard& board) : o_(std::move(o)), board_(board) {}

HttpServer::~HttpServer() { stop(); }

void HttpServer::start() {
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<std::uint16_t>(o_.port));
  if (inet_pton(AF_INET, o_.bind.c_str(), &addr.sin_addr) != 1)
    throw std::runtime_error("--bind: not an IPv4 address: '" + o_.bind + "'");
  listenFd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (listenFd_ < 0) throw std::runtime_error(std::string("socket: ") + std::strerror(errno));
  const int one = 1;
  setsockopt(listenFd_, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
  if (::bind(listenFd_, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) {
    const std::string err = std::strerror(errno);
    ::close(listenFd_);
    listenFd_ = -1;
    throw std::runtime_error("cannot bind " + o_.bind + ":" + std::to_string(o_.port) + ": " + err);
  }
  if (::listen(listenFd_, 128) != 0)
    throw std::runtime_error(std::string("listen: ") + std::strerror(errno));
  socklen_t len = sizeof addr;
  getsockname(listenFd_, reinterpret_cast<sockaddr*>(&addr), &len);
  port_ = ntohs(addr.sin_port);
  if (::pipe2(wakePipe_, O_CLOEXEC) != 0) throw std::runtime_error("pipe failed");
  acceptThread_ = std::thread([this] { acceptLoop(); });
}

void HttpServer::stop() {
  if (stopping_.exchange(true)) return;
  if (wakePipe_[1] >= 0) {
    const char c = 'x';
    (void)!::write(wakePipe_[1], &c, 1);
  }
  if (acceptThread_.joinable()) acceptThread_.join();
  {
    std::unique_lock<std::mutex> l(connMu_);
    for (int fd : open_) ::shutdown(fd, SHUT_RDWR);
    connCv_.wait_for(l, std::chrono::seconds(5), [&] { return open_.empty() && refusing_ == 0; });
  }
  if (listenFd_ >= 0) ::close(listenFd_);
  for (int& p : wakePipe_)
    if (p >= 0) ::close(p), p = -1;
  listenFd_ = -1;
}

void HttpServer::acceptLoop() {
  while (!stopping_) {
    if (!refusalSlotFree()) continue;  // the rest wait in the listen backlog meanwhile
    pollfd fds[2] = {{listenFd_, POLLIN, 0}, {wakePipe_[0], POLLIN, 0}};
    const int n = ::poll(fds, 2, 1000);
    if (n < 0 && errno != EINTR) break;
    if (stopping_) break;
    if (n <= 0 || !(fds[0].revents & POLLIN)) continue;
    const int fd = ::accept4(listenFd_, nullptr, nullptr, SOCK_CLOEXEC);
    if (fd < 0) {
      if (errno == EMFILE || errno == ENFILE)
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
      continue;
    }
    ++stats_.connections;
    timeval tv{10, 0};
    setsockopt(fd, SOL_SOCKET, SO_SNDTIMEO, &tv, sizeof tv);
    {
      std::lock_guard<std::mutex> l(connMu_);
      if (static_cast<int>(open_.size()) >= o_.maxConnections) {
        ++stats_.bad;
        try {
          std::thread([this, fd] { refuse(fd); }).detach();
          ++refusing_;
        } catch (const std::system_error&) {
          ::close(fd);  // no thread to answer with: the client sees a reset
        }
        continue;
      }
      open_.insert(fd);
    }
    std::thread([this, fd] {
      try {
        serve(fd);
      } catch (...) {
        // A connection never takes the server down.
      }
      ::shutdown(fd, SHUT_RDWR);
      std::lock_guard<std::mutex> l(connMu_);
      ::close(fd);
      open_.erase(fd);
      connCv_.notify_all();
    }).detach();
  }
}

bool HttpServer::refusalSlotFree() {
  std::unique_lock<std::mutex> l(connMu_);
  return connCv_.wait_for(l, std::chrono::milliseconds(100),
                          [&] { return refusing_ < o_.maxRefusing || stopping_; });
}

// Past the connection limit. The client's request is in the socket or on its way: closing at
// once, with input unread, would reset the connection, and a reset can discard the answer
// before the client reads it. So answer, half-close and drain like the other errors do, on a
// thread of its own (the drain takes up to half a second).
void HttpServer::refuse(int fd) {
  respondError(fd, 503, "Retry-After: 1\r\n");
  lingerDrain(fd);
  std::lock_guard<std::mutex> l(connMu_);
  ::close(fd);
  --refusing_;
  connCv_.notify_all();
}

void HttpServer::serve(int fd) {
  // Read the head: up to the blank line, within the size and time limits.
  std::string buf;
  const auto deadline = Clock::now() + std::chrono::milliseconds(o_.headerTimeoutMs);
  std::size_t headEnd = std::string::npos;
  char chunk[4096];
  while (true) {
    std::size_t p = buf.find("\r\n\r\n");
    if (p != std::string::npos) {
      headEnd = p + 4;
      break;
    }
    p = buf.find("\n\n");
    if (p != std::string::npos) {
      headEnd = p + 2;
      break;
    }
    if (buf.size() > o_.maxHeaderBytes) {
      ++stats_.bad;
      respondError(fd, 431);
      lingerDrain(fd);
      return;
    }
    const auto left =
        std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now()).count();
    if (left <= 0 || stopping_) {
      ++stats_.bad;
      if (!buf.empty()) {
        respondError(fd, 408);
        lingerDrain(fd);
      }
      return;
    }
    pollfd pf{fd, POLLIN, 0};
    const int n = ::poll(&pf, 1, static_cast<int>(std::min<long long>(left, 250)));
    if (n < 0 && errno != EINTR) return;
    if (n <= 0) continue;
    const ssize_t k = ::recv(fd, chunk, sizeof chunk, 0);
    if (k == 0) {
      // Closed before a complete head: answer a partial one if there is anything to answer.
      if (!buf.empty()) {
        ++stats_.bad;
        respondError(fd, 400);
      }
      return;
    }
    if (k < 0) {
      if (errno == EINTR || errno == EAGAIN) continue;
      return;
    }
    buf.append(chunk, static_cast<std::size_t>(k));
  }
  if (headEnd > o_.maxHeaderBytes) {
    ++stats_.bad;
    respondError(fd, 431);
    lingerDrain(fd);
    return;
  }
  ++stats_.requests;
  Request r;
  const int status = parseHead(buf.substr(0, headEnd), r);
  if (status != 0) {
    ++stats_.bad;
    respondError(fd, status);
    lingerDrain(fd);
    return;
  }
  if (!hostAllowed(o_.bind, r)) {
    ++stats_.bad;
    respondError(fd, 403);
    lingerDrain(fd);
    return;
  }
  const bool head = r.method == "HEAD";
  if (r.method != "GET" && !head) {
    ++stats_.bad;
    respondError(fd, 405, "Allow: GET, HEAD\r\n");
    lingerDrain(fd);
    return;
  }
  if (r.path == "/events") {
    serveEvents(fd, head);
    return;
  }
  if (r.path == "/state.json") {
    const auto [v, json] = board_.latest();
    const std::string body = json ? *json : std::string("{}");
    respond(fd, 200, "application/json", body.data(), body.size(), head);
    return;
  }
  if (r.path == "/healthz") {
    respond(fd, 200, "text/plain; charset=utf-8", "ok\n", 3, head);
    return;
  }
  if (const assets::Asset* a = findAsset(r.path)) {
    respond(fd, 200, a->contentType, reinterpret_cast<const char*>(a->data), a->size, head);
    return;
  }
  ++stats_.bad;
  respondError(fd, 404);
  lingerDrain(fd);
}

void HttpServer::serveEvents(int fd, bool head) {
  const std::string h = std::string("HTTP/1.1 200 OK\r\nContent-Type: text/event-stream\r\n") +
                        kCommonHeaders + "X-Accel-Buffering: no\r\n\r\n";
  if (!sendAll(fd, h) || head) return;
  if (!sendAll(fd, std::string("retry: 1000\n\n"))) return;
  ++stats_.sseClients;
  struct Count {
    std::atomic<std::int64_t>& c;
    ~Count() { --c; }
  } count{stats_.sseClients};
  const int one = 1;
  setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
  std::uint64_t seen = 0;
  auto lastSend = Clock::now();
  while (!stopping_) {
    // Has the client gone away (or sent anything, which it should not)?
    pollfd pf{fd, POLLIN | POLLRDHUP, 0};
    if (::poll(&pf, 1, 0) > 0) {
      if (pf.revents & (POLLRDHUP | POLLHUP | POLLERR)) return;
      char c[256];
      const ssize_t k = ::recv(fd, c, sizeof c, MSG_DONTWAIT);
      if (k == 0 || (k < 0 && errno != EAGAIN && errno != EINTR)) return;
    }
    const auto [v, json] = board_.waitNewer(seen, 250);
    if (v > seen && json) {
      seen = v;  // newest only: anything published while we were sending is skipped
      std::string ev;
      ev.reserve(json->size() + 48);
      ev += "event: state\nid: ";
      ev += std::to_string(v);
      ev += "\ndata: ";
      ev += *json;
      ev += "\n\n";
      if (!sendAll(fd, ev)) return;
      ++stats_.sseEvents;
      lastSend = Clock::now();
    } else if (Clock::now() - lastSend > std::chrono::milliseconds(o_.keepaliveMs)) {
      if (!sendAll(fd, std::string(": keepalive\n\n"))) return;
      lastSend = Clock::now();
    }
  }
}

}  // namespace loopd::view
