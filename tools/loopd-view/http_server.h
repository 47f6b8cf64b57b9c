#pragma once
// loopd-view's HTTP server: plain POSIX sockets, one thread per connection (bounded), one
// request per connection (Connection: close). GET/HEAD only. Routes:
//   /  /index.html  /app.js  /style.css   the page, compiled into the binary
//   /state.json                            the newest state snapshot
//   /events                                server-sent events: one `state` event per new snapshot
//   /healthz                               "ok"
// Bad requests get a clean status and the connection is closed: 400 (malformed request line
// or header), 403 (a Host that is not a loopback name while bound to loopback: no DNS
// rebinding), 404 (unknown path), 405 (not GET/HEAD), 408 (headers too slow), 431 (headers
// over 16 KiB), 503 with Retry-After (too many connections: answered and drained before the
// close, never a reset). SSE clients always receive the newest snapshot
// only: a slow tab skips the ones it could not take, it never queues them.
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <thread>

namespace loopd::view {

/// The newest state, shared by the producer and every SSE connection.
class SnapshotBoard {
 public:
  void publish(std::string json);
  /// The newest snapshot and its version (0 = none yet).
  std::pair<std::uint64_t, std::shared_ptr<const std::string>> latest() const;
  /// Waits until a version newer than `seen` exists, `timeoutMs` passes or stop() is called.
  std::pair<std::uint64_t, std::shared_ptr<const std::string>> waitNewer(std::uint64_t seen,
                                                                         int timeoutMs) const;
  void stop();
  bool stopped() const;

 private:
  mutable std::mutex mu_;
  mutable std::condition_variable cv_;
  std::uint64_t version_ = 0;
  std::shared_ptr<const std::string> json_;
  bool stopped_ = false;
};

struct HttpOptions {
  std::string bind = "127.0.0.1";
  int port = 8080;          // 0 = any free port (see HttpServer::port())
  int maxConnections = 64;  // beyond this: 503 and close
  int maxRefusing = 64;     // 503s being answered at once; more connections wait to be accepted
  int headerTimeoutMs = 10000;
  std::size_t maxHeaderBytes = 16384;
  int keepaliveMs = 15000;  // SSE comment line when nothing new arrives
};

struct HttpStats {
  std::atomic<std::int64_t> requests{0}, bad{0}, sseClients{0}, sseEvents{0}, connections{0};
};

class HttpServer {
 public:
  HttpServer(HttpOptions o, SnapshotBoard& board);
  ~HttpServer();
  /// Binds and listens; throws std::runtime_error on failure.
  void start();
  /// Stops accepting, closes every connection, joins the threads.
  void stop();
  int port() const { return port_; }
  const HttpStats& stats() const { return stats_; }

 private:
  void acceptLoop();
  void serve(int fd);
  void refuse(int fd);
  /// Waits (briefly) until fewer than maxRefusing refusals are under way.
  bool refusalSlotFree();
  void serveEvents(int fd, bool head);

  HttpOptions o_;
  SnapshotBoard& board_;
  HttpStats stats_;
  int listenFd_ = -1;
  int wakePipe_[2] = {-1, -1};
  int port_ = 0;
  std::atomic<bool> stopping_{false};
  std::thread acceptThread_;
  std::mutex connMu_;
  std::condition_variable connCv_;
  std::set<int> open_;  // fds of live connections
  int refusing_ = 0;    // connections being answered 503
};

}  // namespace loopd::view
