// client::DecisionTable: the server's decisions kept from its statuses — changes applied as
// they come, a chunked complete listing replacing the table only once its last chunk is in,
// and a listing with a lost chunk dropped (never taken for the whole).
#include <gtest/gtest.h>

#include "client/decision_table.h"

using loopd::loop_decision_t;
using loopd::status_t;
using loopd::client::DecisionTable;
using Applied = DecisionTable::Applied;

namespace {

loop_decision_t decision(const std::string& sender, std::int64_t id, bool accepted) {
  loop_decision_t d{};
  d.sender = sender;
  d.factor_id = id;
  d.accepted = accepted;
  d.weight = accepted ? 1.0 : 0.0;
  return d;
}

loop_decision_t ambiguousChoice(std::int64_t id, std::int32_t alternative) {
  loop_decision_t d = decision("feed0", id, true);
  d.ambiguous = true;
  d.alternative = alternative;
  return d;
}

status_t changes(std::int64_t seq, std::vector<loop_decision_t> ds) {
  status_t s{};
  s.update_seq = seq;
  s.decisions_chunk_count = 1;
  s.num_decisions = static_cast<std::int16_t>(ds.size());
  s.decisions = std::move(ds);
  return s;
}

status_t chunk(std::int64_t seq, int index, int count, std::vector<loop_decision_t> ds,
               std::int64_t requestId = 0) {
  status_t s = changes(seq, std::move(ds));
  s.decisions_full = true;
  s.decisions_chunk_index = index;
  s.decisions_chunk_count = count;
  s.request_id = requestId;
  return s;
}

TEST(DecisionTable, AppliesChangesAsTheyCome) {
  DecisionTable t;
  EXPECT_EQ(t.apply(changes(1, {decision("a", 5, true), decision("b", 5, false)})),
            Applied::Changes);
  EXPECT_EQ(t.apply(changes(2, {decision("a", 5, false), ambiguousChoice(9, 2)})),
            Applied::Changes);
  ASSERT_EQ(t.decisions().size(), 3u);
  EXPECT_FALSE(t.decisions().at({"a", 5}).accepted);  // the later verdict wins
  EXPECT_FALSE(t.decisions().at({"b", 5}).accepted);  // same id, another sender: its own
  EXPECT_TRUE(t.decisions().at({"feed0", 9}).ambiguous);
  EXPECT_EQ(t.decisions().at({"feed0", 9}).alternative, 2);
  EXPECT_EQ(t.lastListingRequest(), -1);
}

TEST(DecisionTable, AChunkedListingReplacesTheTableWhenItsLastChunkIsIn) {
  DecisionTable t;
  t.apply(changes(1, {decision("a", 1, true), decision("a", 2, true)}));
  EXPECT_EQ(t.apply(chunk(7, 0, 2, {decision("a", 2, false)}, 42)), Applied::PartOfListing);
  EXPECT_EQ(t.decisions().size(), 2u);  // unchanged until the listing is whole
  EXPECT_TRUE(t.decisions().at({"a", 2}).accepted);
  EXPECT_EQ(t.apply(chunk(7, 1, 2, {decision("a", 3, true)}, 42)), Applied::ListingComplete);
  ASSERT_EQ(t.decisions().size(), 2u);  // factor 1 is gone: the listing does not name it
  EXPECT_FALSE(t.decisions().at({"a", 2}).accepted);
  EXPECT_TRUE(t.decisions().count({"a", 3}));
  EXPECT_EQ(t.lastListingRequest(), 42);
}

TEST(DecisionTable, AListingWithALostChunkIsDroppedNotTakenForTheWhole) {
  DecisionTable t;
  t.apply(changes(1, {decision("a", 1, true)}));
  // Chunk 0 of update 7 lost: chunks 1 and 2 alone must not replace the table.
  EXPECT_EQ(t.apply(chunk(7, 1, 3, {decision("a", 2, true)})), Applied::ListingBroken);
  EXPECT_EQ(t.apply(chunk(7, 2, 3, {decision("a", 3, true)})), Applied::ListingBroken);
  ASSERT_EQ(t.decisions().size(), 1u);
  EXPECT_TRUE(t.decisions().count({"a", 1}));
  // A hole in the middle, and a chunk of another update, break it too.
  EXPECT_EQ(t.apply(chunk(8, 0, 3, {decision("a", 2, true)})), Applied::PartOfListing);
  EXPECT_EQ(t.apply(chunk(8, 2, 3, {decision("a", 3, true)})), Applied::ListingBroken);
  EXPECT_EQ(t.apply(chunk(9, 0, 2, {decision("a", 2, true)})), Applied::PartOfListing);
  EXPECT_EQ(t.apply(chunk(10, 1, 2, {decision("a", 3, true)})), Applied::ListingBroken);
  EXPECT_EQ(t.decisions().size(), 1u);
  EXPECT_EQ(t.lastListingRequest(), -1);
  // A new first chunk starts over and completes.
  EXPECT_EQ(t.apply(chunk(11, 0, 1, {decision("a", 4, false)}, 3)), Applied::ListingComplete);
  ASSERT_EQ(t.decisions().size(), 1u);
  EXPECT_FALSE(t.decisions().at({"a", 4}).accepted);
  EXPECT_EQ(t.lastListingRequest(), 3);
}

TEST(DecisionTable, ClearForgetsTheTableAndAnyListingBeingAssembled) {
  DecisionTable t;
  t.apply(chunk(1, 0, 1, {decision("a", 1, true)}, 3));
  t.apply(chunk(2, 0, 2, {decision("a", 2, true)}));
  t.clear();
  EXPECT_TRUE(t.decisions().empty());
  EXPECT_EQ(t.lastListingRequest(), -1);  // the listing of request 3 is gone with the table
  EXPECT_EQ(t.apply(chunk(2, 1, 2, {decision("a", 3, true)})), Applied::ListingBroken);
  EXPECT_TRUE(t.decisions().empty());
}

}  // namespace
