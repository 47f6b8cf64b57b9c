#include "client/decision_table.h"

namespace loopd::client {

namespace {

void put(std::map<DecisionTable::Name, DecisionTable::Decision>& t,
         const loopd::loop_decision_t& d) {
  t[{d.sender, d.factor_id}] =
      DecisionTable::Decision{d.ambiguous != 0, d.alternative, d.accepted != 0, d.weight};
}

}  // namespace

DecisionTable::Applied DecisionTable::apply(const loopd::status_t& s) {
  if (!s.decisions_full) {
    for (const auto& d : s.decisions) put(table_, d);
    return Applied::Changes;
  }
  // A first chunk starts a listing (dropping one whose last chunks were lost); any other chunk
  // must be the next one of the listing being assembled, or that listing has a hole.
  if (s.decisions_chunk_index == 0) {
    assembling_.clear();
    assemblingSeq_ = s.update_seq;
    nextChunk_ = 0;
  } else if (s.update_seq != assemblingSeq_ || s.decisions_chunk_index != nextChunk_) {
    assembling_.clear();
    assemblingSeq_ = -1;
    return Applied::ListingBroken;
  }
  for (const auto& d : s.decisions) put(assembling_, d);
  ++nextChunk_;
  if (s.decisions_chunk_index + 1 < s.decisions_chunk_count) return Applied::PartOfListing;
  table_.swap(assembling_);
  assembling_.clear();
  assemblingSeq_ = -1;
  lastListingRequest_ = s.request_id;
  return Applied::ListingComplete;
}

void DecisionTable::clear() {
  table_.clear();
  assembling_.clear();
  assemblingSeq_ = -1;
  lastListingRequest_ = -1;  // the table no longer holds that listing
}

}  // namespace loopd::client
