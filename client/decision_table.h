#pragma once
// loopd_client: the server's verdicts on uncertain factors (loop closures, sightings, ambiguous
// measurements), kept from its status messages as lcmtypes/README.md asks of a client: each
// status's changed decisions are applied as they come; a complete listing (after
// REQUEST_STATUS, RESET, SWITCH_SOLVER or a resume), split over consecutive statuses of one
// update_seq, replaces the table once its last chunk is in. Not thread-safe: feed it from the
// thread that handles LCM.
#include <cstdint>
#include <map>
#include <string>
#include <utility>

#include "loopd/status_t.hpp"

namespace loopd::client {

class DecisionTable {
 public:
  using Name = std::pair<std::string, std::int64_t>;  // (sender, factor or ambiguous id)
  struct Decision {
    bool ambiguous = false;
    std::int32_t alternative = 0;  // ambiguous: the chosen alternative, -1 none
    bool accepted = true;
    double weight = 1.0;
  };
  enum class Applied {
    Changes,          // a status's changed decisions, applied
    PartOfListing,    // a chunk of a complete listing, held until its last chunk
    ListingComplete,  // the last chunk: the table is now exactly the listing
    ListingBroken,    // a chunk whose predecessors were lost: that listing is dropped, the
                      // table stays as it was (ask again with REQUEST_STATUS)
  };

  Applied apply(const loopd::status_t& status);
  /// Forgets every decision and any listing being assembled (the server's graph was dropped).
  void clear();

  const std::map<Name, Decision>& decisions() const { return table_; }
  /// The request_id of the listing the table holds (0: one nobody asked for, -1: none since
  /// the start or clear()).
  std::int64_t lastListingRequest() const { return lastListingRequest_; }

 private:
  std::map<Name, Decision> table_;
  std::map<Name, Decision> assembling_;
  std::int64_t assemblingSeq_ = -1;  // update_seq of the listing being assembled, -1 none
  std::int32_t nextChunk_ = 0;
  std::int64_t lastListingRequest_ = -1;
};

}  // namespace loopd::client
