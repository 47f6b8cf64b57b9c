#include "solvers/graph/connected_parts.h"

#include <gtest/gtest.h>

namespace loopd {
namespace {

TEST(ConnectedParts, SlotsAreJoinedThroughChainsOnly) {
  ConnectedParts parts(6);
  parts.join(0, 1);
  parts.join(3, 2);
  parts.join(1, 4);
  EXPECT_EQ(parts.part(0), parts.part(4));
  EXPECT_EQ(parts.part(2), parts.part(3));
  EXPECT_NE(parts.part(0), parts.part(2));
  EXPECT_NE(parts.part(5), parts.part(0));
  EXPECT_NE(parts.part(5), parts.part(2));
  parts.join(4, 2);  // the two parts become one
  for (int s = 1; s < 5; ++s) EXPECT_EQ(parts.part(s), parts.part(0)) << s;
  EXPECT_EQ(parts.part(5), 5);
}

// A long chain joined end to end stays one part however it was joined (path halving).
TEST(ConnectedParts, ALongChainIsOnePart) {
  const int n = 10000;
  ConnectedParts parts(n);
  for (int s = n - 1; s > 0; --s) parts.join(s, s - 1);
  for (int s = 0; s < n; ++s) ASSERT_EQ(parts.part(s), parts.part(n - 1)) << s;
}

}  // namespace
}  // namespace loopd
