#include "server/journal.h"

#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <lcm/lcm-cpp.hpp>
#include <stdexcept>
#include <vector>

#include "loopd/error_t.hpp"

namespace loopd::server {

namespace {

// An LCM log event: sync word (big-endian 0xEDA1DA01), event number (8), timestamp (8),
// channel length (4), data length (4), channel, data.
constexpr unsigned char kSync[4] = {0xED, 0xA1, 0xDA, 0x01};
constexpr long kHeader = 28;

std::int32_t bigEndian32(const unsigned char* p) {
  return static_cast<std::int32_t>((std::uint32_t{p[0]} << 24) | (std::uint32_t{p[1]} << 16) |
                                   (std::uint32_t{p[2]} << 8) | std::uint32_t{p[3]});
}

// Whether the `size` bytes from `at` to the end of the file are a prefix of one event (what a
// kill -9 during a write leaves), judging by up to its header.
bool tornEvent(FILE* fp, long at, long size) {
  unsigned char h[kHeader] = {};
  const long n = std::min(size, kHeader);
  if (std::fseek(fp, at, SEEK_SET) != 0 ||
      std::fread(h, 1, static_cast<size_t>(n), fp) != static_cast<size_t>(n))
    return false;
  if (std::memcmp(h, kSync, static_cast<size_t>(std::min(n, 4L))) != 0) return false;
  if (size < kHeader) return true;
  const std::int32_t channelLen = bigEndian32(h + 20), dataLen = bigEndian32(h + 24);
  return channelLen > 0 && channelLen < 1000 && dataLen >= 0 &&
         kHeader + channelLen + static_cast<long>(dataLen) > size;
}

}  // namespace

Journal::Journal(const std::string& path, bool append)
    : path_(path), log_(std::make_unique<lcm::LogFile>(path, append ? "a" : "w")) {}

Journal::~Journal() { flush(); }

bool Journal::good() const { return log_ && log_->good(); }

bool Journal::write(const std::string& channel, const void* data, int size, std::int64_t utime) {
  if (!good()) return false;
  lcm::LogEvent ev;
  ev.eventnum = written_ + records_;
  ev.timestamp = utime;
  ev.channel = channel;
  ev.datalen = size;
  ev.data = const_cast<void*>(data);
  if (log_->writeEvent(&ev) != 0) return false;
  return std::fflush(log_->getFilePtr()) == 0;
}

bool Journal::append(const std::string& channel, const void* data, int size, std::int64_t utime) {
  if (!write(channel, data, size, utime)) return false;
  ++written_;
  return true;
}

bool Journal::appendRecord(const std::string& channel, const void* data, int size,
                           std::int64_t utime) {
  if (!write(channel, data, size, utime)) return false;
  ++records_;
  return true;
}

bool Journal::appendConsumed(const std::string& channel, const std::string& sender,
                             std::int64_t sequence, std::int8_t code, const std::string& reason,
                             std::int64_t utime) {
  loopd::error_t e{};
  e.utime = utime;
  e.sender = sender;
  e.sequence = sequence;
  e.request_id = 0;
  e.factor_id = -1;
  e.code = code;
  e.reason = reason.substr(0, 1023);
  e.channel = "";
  std::vector<std::uint8_t> buf(static_cast<size_t>(e.getEncodedSize()));
  e.encode(buf.data(), 0, static_cast<int>(buf.size()));
  return appendRecord(channel, buf.data(), static_cast<int>(buf.size()), utime);
}

void Journal::flush() {
  if (good()) std::fflush(log_->getFilePtr());
}

std::int64_t readJournal(const std::string& path,
                         const std::function<void(const std::string&, const void*, int)>& onEvent,
                         long* validBytes) {
  struct stat st {};
  lcm::LogFile log(path, "r");
  if (!log.good() || ::stat(path.c_str(), &st) != 0)
    throw std::runtime_error("cannot read journal " + path);
  const long size = static_cast<long>(st.st_size);
  std::int64_t n = 0;
  long pos = 0;
  FILE* fp = log.getFilePtr();
  // LCM's reader skips bytes up to the next sync word, and (LCM 1.3) returns an event only if
  // the end of the file or a sync word follows it (which it reads ahead: up to 3 bytes of a
  // torn sync word at the end stay read). An event must start where the one before it ended
  // (the first at byte 0), or the file is not (or no longer) a journal there.
  while (const lcm::LogEvent* ev = log.readNextEvent()) {
    const long here = std::ftell(fp);
    const long end =
        pos + kHeader + static_cast<long>(ev->channel.size()) + static_cast<long>(ev->datalen);
    if (end != here && !(here == size && end < size && size - end < 4)) {
      if (pos == 0)
        throw std::runtime_error(
            "not a loopd journal: no LCM log event at its start; the file is left as it is");
      throw std::runtime_error("journal damaged after its first " + std::to_string(n) +
                               " events (byte " + std::to_string(pos) +
                               "): no LCM log event there; the file is left as it is (to "
                               "resume those events, cut it there: truncate -s " +
                               std::to_string(pos) + ")");
    }
    onEvent(ev->channel, ev->data, ev->datalen);
    pos = end;
    ++n;
  }
  // After the last complete event: nothing, or a torn event (cut by the caller).
  if (pos < size && !tornEvent(fp, pos, size - pos)) {
    if (pos == 0)
      throw std::runtime_error(
          "not a loopd journal: no LCM log event at its start; the file is left as it is");
    throw std::runtime_error("journal damaged after its first " + std::to_string(n) +
                             " events (byte " + std::to_string(pos) + " of " +
                             std::to_string(size) +
                             "): what follows is no LCM log event and no torn one; the file "
                             "is left as it is (to resume those events, cut it there: "
                             "truncate -s " +
                             std::to_string(pos) + ")");
  }
  if (validBytes) *validBytes = pos;
  return n;
}

bool truncateFile(const std::string& path, long bytes) {
  return ::truncate(path.c_str(), bytes) == 0;
}

}  // namespace loopd::server
