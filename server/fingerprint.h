#pragma once
// LCM fingerprints: what a message that is not the type a channel expects turns out to be.
#include <cstdint>
#include <string>

namespace loopd::server {

/// The fingerprint an LCM message starts with (its first 8 bytes, big-endian).
std::int64_t readFingerprint(const std::uint8_t* bytes);
/// The loopd type with that fingerprint ("command_t", ...), "" if none.
std::string fingerprintName(std::int64_t hash);

}  // namespace loopd::server
