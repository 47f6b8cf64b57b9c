// LCM fingerprints: each loopd type is recognised by the first 8 bytes it puts on the wire.
#include "server/fingerprint.h"

#include <gtest/gtest.h>

#include "loopd/command_t.hpp"
#include "loopd/covariance_t.hpp"
#include "loopd/error_t.hpp"
#include "loopd/estimate_t.hpp"
#include "loopd/factor_batch_t.hpp"
#include "loopd/status_t.hpp"
#include "tests/server/wire_encode.h"

using namespace loopd;
using namespace loopd::server;

namespace {

template <class T>
std::string nameOnTheWire() {
  const std::vector<std::uint8_t> bytes = test::encode(T{});
  EXPECT_GE(bytes.size(), 8u);
  EXPECT_EQ(readFingerprint(bytes.data()), T::getHash());
  return fingerprintName(readFingerprint(bytes.data()));
}

}  // namespace

TEST(Fingerprint, EveryLoopdTypeIsNamedFromItsBytes) {
  EXPECT_EQ(nameOnTheWire<loopd::command_t>(), "command_t");
  EXPECT_EQ(nameOnTheWire<loopd::estimate_t>(), "estimate_t");
  EXPECT_EQ(nameOnTheWire<loopd::covariance_t>(), "covariance_t");
  EXPECT_EQ(nameOnTheWire<loopd::status_t>(), "status_t");
  EXPECT_EQ(nameOnTheWire<loopd::error_t>(), "error_t");
  EXPECT_EQ(nameOnTheWire<loopd::factor_batch_t>(), "factor_batch_t");
}

TEST(Fingerprint, ReadsBigEndianAndLeavesForeignTypesUnnamed) {
  const std::uint8_t bytes[8] = {0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07, 0x08};
  EXPECT_EQ(readFingerprint(bytes), 0x0102030405060708);
  EXPECT_EQ(fingerprintName(0x0102030405060708), "");
}
