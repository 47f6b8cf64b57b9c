#pragma once
// What the wrapper factors (robust kernel, switch, mixture, held kernel) share: makeWrapper
// picks the inner factor's key count (a compile-time parameter) at run time; scaleBlocks
// weighs the inner residual and Jacobians.
#include <memory>
#include <stdexcept>
#include <string>
#include <utility>

#include "solvers/factors/factor.h"

namespace loopd {

// Builds a wrapper of class W over inner with its key count chosen at run time.
template <class W, class... Args>
std::shared_ptr<W> makeWrapper(const FactorPtr& inner, int maxKeys, Args&&... args) {
  if (!inner) throw std::invalid_argument("robust wrapper: null inner factor");
  switch (inner->size()) {
    case 1:
      return std::make_shared<W>(std::make_index_sequence<1>{}, inner, args...);
    case 2:
      return std::make_shared<W>(std::make_index_sequence<2>{}, inner, args...);
    case 3:
      if (maxKeys >= 3) return std::make_shared<W>(std::make_index_sequence<3>{}, inner, args...);
      break;
    case 4:
      if (maxKeys >= 4) return std::make_shared<W>(std::make_index_sequence<4>{}, inner, args...);
      break;
    default:
      break;
  }
  throw std::invalid_argument(std::string("robust wrapper: unsupported key count for ") +
                              inner->typeName());
}

/// Scales the residual r (f.dim()) and the Jacobian blocks J[0 … numKeys) (null: skipped) by s.
void scaleBlocks(const Factor& f, int numKeys, double s, double* r, double* const* J);

}  // namespace loopd
