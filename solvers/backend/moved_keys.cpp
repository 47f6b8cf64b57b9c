#include "solvers/backend/moved_keys.h"

#include <cmath>

namespace loopd {

std::vector<Key> movedKeys(const Values& before, const Values& after, double threshold) {
  std::vector<Key> moved;
  for (int s = 0; s < after.size(); ++s) {
    const int old = before.slot(after.key(s));
    bool m = old < 0;
    for (int i = 0; !m && i < kValueStride; ++i)
      m = std::abs(after.data(s)[i] - before.data(old)[i]) > threshold;
    if (m) moved.push_back(after.key(s));
  }
  return moved;
}

}  // namespace loopd
