#pragma once
// The journal: every accepted batch, as the raw bytes it arrived with and its channel, in an
// LCM log file (replayable by lcm-logplayer), flushed per batch so a kill -9 loses nothing
// accepted. --resume reads it back.
#include <cstdint>
#include <functional>
#include <memory>
#include <string>

namespace lcm {
class LogFile;
}

namespace loopd::server {

class Journal {
 public:
  /// Opens for writing ("w") or appending to an existing log ("a").
  Journal(const std::string& path, bool append);
  ~Journal();
  bool good() const;
  const std::string& path() const { return path_; }
  /// Appends one event and flushes it to the OS. False on an I/O error.
  bool append(const std::string& channel, const void* data, int size, std::int64_t utime);
  void flush();
  std::int64_t written() const { return written_; }

 private:
  std::string path_;
  std::unique_ptr<lcm::LogFile> log_;
  std::int64_t written_ = 0;
};

/// Reads every complete event of a log in order. Returns the number read; `validBytes` is the
/// file offset after the last complete event (a kill -9 may have left a partial one behind,
/// which the caller truncates before appending). Throws std::runtime_error if unreadable.
std::int64_t readJournal(
    const std::string& path,
    const std::function<void(const std::string& channel, const void* data, int size)>& onEvent,
    long* validBytes = nullptr);

/// Cuts a file to `bytes` (drops a partial trailing event).
bool truncateFile(const std::string& path, long bytes);

}  // namespace loopd::server
