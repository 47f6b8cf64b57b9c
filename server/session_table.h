#pragma once
// Per-sender bookkeeping: which sequence numbers arrived (duplicates, gaps) and the sender's
// factor ids (sender-unique, never reused) mapped to the server's own FactorIds.
#include <cstdint>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include "solvers/factors/factor.h"

namespace loopd::server {

struct SenderGap {
  std::string sender;
  std::int64_t lastContiguous = 0, highest = 0, missing = 0;
};

class SessionTable {
 public:
  /// Records (sender, sequence) as received; false if it had been already (a duplicate).
  bool receive(const std::string& sender, std::int64_t sequence);
  /// Whether some sequence in [1, sequence) of the sender was never received.
  bool hasGapBelow(const std::string& sender, std::int64_t sequence) const;
  /// Senders with missing sequences, most missing first.
  std::vector<SenderGap> gaps() const;

  bool idUsed(const std::string& sender, std::int64_t id) const;
  bool idLive(const std::string& sender, std::int64_t id) const;
  std::optional<FactorId> liveId(const std::string& sender, std::int64_t id) const;
  void addId(const std::string& sender, std::int64_t id, FactorId internal);
  /// Marks a live id removed (it stays used); returns its FactorId.
  FactorId removeId(const std::string& sender, std::int64_t id);
  /// Undo of addId / removeId (an update that failed inside the backend).
  void undoAdd(const std::string& sender, std::int64_t id);
  void undoRemove(const std::string& sender, std::int64_t id, FactorId internal);

  size_t senders() const { return senders_.size(); }
  void clear() { senders_.clear(); }

 private:
  struct Sender {
    std::int64_t lastContiguous = 0;  // 1..lastContiguous all received
    std::set<std::int64_t> above;     // received beyond lastContiguous
    std::unordered_map<std::int64_t, FactorId> live;
    std::unordered_set<std::int64_t> used;
  };
  std::unordered_map<std::string, Sender> senders_;
};

}  // namespace loopd::server
