#pragma once
// The journal: an LCM log file (replayable by lcm-logplayer) of what changed the graph and the
// sequence histories, in the order it happened, each event flushed to the OS as it is written:
//  - on the factors channel, every applied batch as the raw bytes it arrived with, written
//    right after the update that applied it and before anything reports it (estimate, status);
//  - on the command channel, every RESET (the raw command_t);
//  - on the error channel, an error_t (sender, sequence, code, reason) for every batch number
//    consumed without being applied: refused (validation, or INTERNAL: the solver refused it)
//    or held and expired (HELD_EXPIRED).
// --resume reads it back (Engine::replay); journals holding only batches (older servers) read
// the same as before.
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
  /// Appends one batch event and flushes it to the OS. False on an I/O error.
  bool append(const std::string& channel, const void* data, int size, std::int64_t utime);
  /// Appends a record (a RESET command, a consumed number) and flushes it; counted in
  /// records(), not written().
  bool appendRecord(const std::string& channel, const void* data, int size, std::int64_t utime);
  /// The record of a batch number consumed without being applied: an error_t on `channel`
  /// (the error channel) naming sender, sequence, code and reason.
  bool appendConsumed(const std::string& channel, const std::string& sender, std::int64_t sequence,
                      std::int8_t code, const std::string& reason, std::int64_t utime);
  void flush();
  /// Batches written (by this object).
  std::int64_t written() const { return written_; }
  /// Records written (RESETs, consumed numbers).
  std::int64_t records() const { return records_; }

 private:
  bool write(const std::string& channel, const void* data, int size, std::int64_t utime);
  std::string path_;
  std::unique_ptr<lcm::LogFile> log_;
  std::int64_t written_ = 0, records_ = 0;
};

/// Reads every complete event of a journal in order. Returns the number read; `validBytes` is
/// the file offset after the last complete event: what follows it may only be a torn event (a
/// kill -9 during a write: a prefix of an event), which the caller truncates before appending.
/// Throws std::runtime_error (before any truncation) if the file is unreadable, or is not a
/// journal: non-empty without an LCM log event at its very start (another file, a damaged
/// first event), bytes between events that are no event, or bytes after the last event that
/// are not a torn event.
std::int64_t readJournal(
    const std::string& path,
    const std::function<void(const std::string& channel, const void* data, int size)>& onEvent,
    long* validBytes = nullptr);

/// Cuts a file to `bytes` (drops a partial trailing event).
bool truncateFile(const std::string& path, long bytes);

}  // namespace loopd::server
