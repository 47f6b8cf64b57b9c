#include "server/session_table.h"

#include <algorithm>

namespace loopd::server {

bool SessionTable::receive(const std::string& sender, std::int64_t seq) {
  Sender& s = senders_[sender];
  if (seq <= s.lastContiguous || s.above.count(seq)) return false;
  if (seq == s.lastContiguous + 1) {
    s.lastContiguous = seq;
    while (!s.above.empty() && *s.above.begin() == s.lastContiguous + 1) {
      s.lastContiguous = *s.above.begin();
      s.above.erase(s.above.begin());
    }
  } else {
    s.above.insert(seq);
  }
  return true;
}

bool SessionTable::hasGapBelow(const std::string& sender, std::int64_t seq) const {
  auto it = senders_.find(sender);
  if (it == senders_.end()) return seq > 1;
  const Sender& s = it->second;
  if (seq <= s.lastContiguous + 1) return false;
  // Sequences lastContiguous+1 .. seq−1 must all be in `above`.
  const auto n = static_cast<std::int64_t>(
      std::distance(s.above.lower_bound(s.lastContiguous + 1), s.above.lower_bound(seq)));
  return n != seq - 1 - s.lastContiguous;
}

std::vector<SenderGap> SessionTable::gaps() const {
  std::vector<SenderGap> out;
  for (const auto& [name, s] : senders_) {
    if (s.above.empty()) continue;
    SenderGap g;
    g.sender = name;
    g.lastContiguous = s.lastContiguous;
    g.highest = *s.above.rbegin();
    g.missing = g.highest - s.lastContiguous - static_cast<std::int64_t>(s.above.size());
    out.push_back(g);
  }
  std::sort(out.begin(), out.end(), [](const SenderGap& a, const SenderGap& b) {
    return a.missing != b.missing ? a.missing > b.missing : a.sender < b.sender;
  });
  return out;
}

bool SessionTable::idUsed(const std::string& sender, std::int64_t id) const {
  auto it = senders_.find(sender);
  return it != senders_.end() && it->second.used.count(id);
}

bool SessionTable::idLive(const std::string& sender, std::int64_t id) const {
  return liveId(sender, id).has_value();
}

std::optional<FactorId> SessionTable::liveId(const std::string& sender, std::int64_t id) const {
  auto it = senders_.find(sender);
  if (it == senders_.end()) return std::nullopt;
  auto jt = it->second.live.find(id);
  if (jt == it->second.live.end()) return std::nullopt;
  return jt->second;
}

void SessionTable::addId(const std::string& sender, std::int64_t id, FactorId internal) {
  Sender& s = senders_[sender];
  s.used.insert(id);
  s.live[id] = internal;
}

FactorId SessionTable::removeId(const std::string& sender, std::int64_t id) {
  Sender& s = senders_[sender];
  auto it = s.live.find(id);
  const FactorId f = it->second;
  s.live.erase(it);
  return f;
}

void SessionTable::undoAdd(const std::string& sender, std::int64_t id) {
  Sender& s = senders_[sender];
  s.used.erase(id);
  s.live.erase(id);
}

void SessionTable::undoRemove(const std::string& sender, std::int64_t id, FactorId internal) {
  senders_[sender].live[id] = internal;
}

}  // namespace loopd::server
