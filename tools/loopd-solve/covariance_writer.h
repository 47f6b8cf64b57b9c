#pragma once
// --covariances: every pose's (and landmark's) marginal covariance as text.
//   POSE id  c11 c12 … (upper triangle, row-major)
//   LANDMARK id  c11 …
// Tangent order: SE2 x y θ; SE3 x y z then rotation (body frame); points x y [z].
#include <string>

#include "solvers/backend/backend.h"
#include "solvers/io/dataset.h"

namespace loopd::tools {

void writeCovariances(const std::string& path, Backend& backend, const io::Dataset& dataset);

}  // namespace loopd::tools
