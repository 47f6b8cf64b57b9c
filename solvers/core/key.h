#pragma once
// A variable's key: (robot id, kind, index) packed into 64 bits so keys sort by robot, then
// kind, then index. Explicit fields travel on the wire; this packing is internal.
#include <cstdint>
#include <string>

namespace loopd {

using Key = std::uint64_t;

enum class KeyKind : std::uint8_t {
  Pose = 0,
  Landmark = 1,
  Anchor = 2,  // a robot's frame in the world (multi-robot anchors)
  Switch = 3,  // robust variants' auxiliary variables
};

constexpr int kKeyIndexBits = 40;
constexpr int kKeyKindBits = 8;
constexpr std::uint64_t kMaxKeyIndex = (std::uint64_t{1} << kKeyIndexBits) - 1;
constexpr std::uint32_t kMaxRobotId = 0xFFFF;

constexpr Key makeKey(std::uint32_t robot, KeyKind kind, std::uint64_t index) {
  return (static_cast<Key>(robot) << (kKeyIndexBits + kKeyKindBits)) |
         (static_cast<Key>(kind) << kKeyIndexBits) | (index & kMaxKeyIndex);
}
constexpr Key poseKey(std::uint64_t index, std::uint32_t robot = 0) {
  return makeKey(robot, KeyKind::Pose, index);
}
constexpr Key landmarkKey(std::uint64_t index, std::uint32_t robot = 0) {
  return makeKey(robot, KeyKind::Landmark, index);
}
/// Robot r's anchor A_r: places r's frame in the common one (multi-robot anchors).
constexpr Key anchorKey(std::uint32_t robot) { return makeKey(robot, KeyKind::Anchor, 0); }
constexpr std::uint32_t keyRobot(Key k) {
  return static_cast<std::uint32_t>(k >> (kKeyIndexBits + kKeyKindBits));
}
constexpr KeyKind keyKind(Key k) {
  return static_cast<KeyKind>((k >> kKeyIndexBits) & ((1u << kKeyKindBits) - 1));
}
constexpr std::uint64_t keyIndex(Key k) { return k & kMaxKeyIndex; }

/// "r0:x12" (pose), "r1:l3" (landmark), "r0:a0" (anchor), "r0:s7" (switch).
std::string keyToString(Key k);

}  // namespace loopd
