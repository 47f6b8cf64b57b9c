#pragma once
// Wire (lcmtypes) ↔ solver conversions shared by the validator, the engine and the publisher.
#include <Eigen/Core>
#include <string>
#include <vector>

#include "loopd/factor_t.hpp"
#include "loopd/key_t.hpp"
#include "solvers/core/key.h"
#include "solvers/core/values.h"

namespace loopd::server {

/// Residual (noise) dimension of a factor_t type, 0 if the type is unknown.
int factorDim(int type);
/// Measurement numbers of a factor_t type (SE3: 7), 0 if unknown.
int measurementSize(int type);
/// Keys of a factor_t type (1 for priors, 2 otherwise), 0 if unknown.
int keyCount(int type);
/// "BETWEEN_SE2", ... or "type 42".
std::string factorTypeName(int type);
/// The variable type slot i of a factor type needs (poses SE2/SE3, landmarks Point2/3).
VarType slotVarType(int type, int slot);
/// True if slot i of the type is a pose (false: a landmark).
bool slotIsPose(int type, int slot);

Key toKey(const loopd::key_t& k);
loopd::key_t toWireKey(Key k);
std::string wireKeyName(const loopd::key_t& k);

/// The symmetric d×d matrix from its upper triangle, row-major (g2o order).
Eigen::MatrixXd symmetricFromUpper(const std::vector<double>& upper, int d);
/// The information matrix of a (validated) factor: noise as given, or the covariance inverted.
Eigen::MatrixXd informationOf(const loopd::factor_t& f);

/// Variant names accepted in factor_t.robust ("" and "none" included).
const std::vector<std::string>& robustNames();

/// "%.6g"-style number for reasons.
std::string num(double v);

}  // namespace loopd::server
