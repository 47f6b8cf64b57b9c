#pragma once
// What both generators (wrong loop closures, ambiguous measurements) draw and measure with:
// their own uniform draws on std::mt19937_64 (no library distributions, so a seed gives the
// same graph with every standard library) and the dataset's loop-closure statistics.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <random>
#include <vector>

#include "solvers/io/dataset.h"

namespace loopd::tools {

class Rng {
 public:
  explicit Rng(std::uint64_t seed) : g_(seed) {}
  double uniform() { return static_cast<double>(g_() >> 11) * (1.0 / 9007199254740992.0); }
  double uniform(double lo, double hi) { return lo + (hi - lo) * uniform(); }
  // Integer in [lo, hi].
  std::int64_t integer(std::int64_t lo, std::int64_t hi) {
    if (hi <= lo) return lo;
    const std::uint64_t span = static_cast<std::uint64_t>(hi - lo) + 1;
    return lo + static_cast<std::int64_t>(g_() % span);
  }
  double normal() {
    const double u1 = std::max(uniform(), 1e-300), u2 = uniform();
    return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * M_PI * u2);
  }
  double sign() { return uniform() < 0.5 ? -1.0 : 1.0; }

 private:
  std::mt19937_64 g_;
};

inline bool isBetween(const io::Edge& e) { return io::isBetween(e.type); }
inline bool isLoop(const io::Edge& e) { return isBetween(e) && std::llabs(e.to - e.from) != 1; }

inline double translationNorm(const io::Edge& e) {
  if (e.type == io::EdgeType::BetweenSE2) return std::hypot(e.measurement[0], e.measurement[1]);
  return std::sqrt(e.measurement[0] * e.measurement[0] + e.measurement[1] * e.measurement[1] +
                   e.measurement[2] * e.measurement[2]);
}

template <class T>
T median(std::vector<T> v) {
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

}  // namespace loopd::tools
