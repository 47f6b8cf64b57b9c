#pragma once
// The ground truth the robust tests drive around: a square, 10 m a side, walked in 1 m steps
// with a quarter turn at each corner (kLap poses per lap).
#include <cmath>

#include "solvers/geometry/se2.h"

namespace loopd::square {

constexpr int kLap = 40;

/// Pose i of the square walk.
inline SE2 walk(int i) {
  SE2 x;
  for (int k = 0; k < i; ++k) x = x * SE2(1.0, 0.0, (k + 1) % 10 == 0 ? M_PI / 2 : 0.0);
  return x;
}

}  // namespace loopd::square
