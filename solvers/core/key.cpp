#include "solvers/core/key.h"

namespace loopd {

std::string keyToString(Key k) {
  static const char kLetters[] = {'x', 'l', 'a', 's'};
  const auto kind = static_cast<unsigned>(keyKind(k));
  const char letter = kind < sizeof(kLetters) ? kLetters[kind] : '?';
  return "r" + std::to_string(keyRobot(k)) + ":" + letter + std::to_string(keyIndex(k));
}

}  // namespace loopd
