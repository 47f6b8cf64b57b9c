#pragma once
// Which slots the factors join into connected parts (union–find with path halving).
#include <vector>

namespace loopd {

class ConnectedParts {
 public:
  /// Slots 0 … n−1, each its own part.
  explicit ConnectedParts(int n);
  void join(int a, int b);
  /// The representative slot of s's part.
  int part(int s);

 private:
  std::vector<int> parent_;
};

}  // namespace loopd
