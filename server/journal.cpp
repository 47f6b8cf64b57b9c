#include "server/journal.h"

#include <unistd.h>
#include <lcm/lcm-cpp.hpp>
#include <stdexcept>

namespace loopd::server {

Journal::Journal(const std::string& path, bool append)
    : path_(path), log_(std::make_unique<lcm::LogFile>(path, append ? "a" : "w")) {}

Journal::~Journal() { flush(); }

bool Journal::good() const { return log_ && log_->good(); }

bool Journal::append(const std::string& channel, const void* data, int size, std::int64_t utime) {
  if (!good()) return false;
  lcm::LogEvent ev;
  ev.eventnum = written_;
  ev.timestamp = utime;
  ev.channel = channel;
  ev.datalen = size;
  ev.data = const_cast<void*>(data);
  if (log_->writeEvent(&ev) != 0) return false;
  ++written_;
  return std::fflush(log_->getFilePtr()) == 0;
}

void Journal::flush() {
  if (good()) std::fflush(log_->getFilePtr());
}

std::int64_t readJournal(const std::string& path,
                         const std::function<void(const std::string&, const void*, int)>& onEvent,
                         long* validBytes) {
  lcm::LogFile log(path, "r");
  if (!log.good()) throw std::runtime_error("cannot read journal " + path);
  std::int64_t n = 0;
  long pos = 0;
  FILE* fp = log.getFilePtr();
  while (const lcm::LogEvent* ev = log.readNextEvent()) {
    // A partial event at the end (kill -9 during a write) reads short: stop there.
    const long here = std::ftell(fp);
    onEvent(ev->channel, ev->data, ev->datalen);
    pos = here;
    ++n;
  }
  if (validBytes) *validBytes = pos;
  return n;
}

bool truncateFile(const std::string& path, long bytes) {
  return ::truncate(path.c_str(), bytes) == 0;
}

}  // namespace loopd::server
