#pragma once
// The bytes an LCM message puts on the wire, for feeding decoders in unit tests.
#include <cstdint>
#include <vector>

namespace loopd::test {

template <class T>
std::vector<uint8_t> encode(const T& m) {
  std::vector<uint8_t> buf(static_cast<size_t>(m.getEncodedSize()));
  m.encode(buf.data(), 0, static_cast<int>(buf.size()));
  return buf;
}

}  // namespace loopd::test
