#include "server/wire.h"

#include <Eigen/Cholesky>
#include <cstdio>

namespace loopd::server {

using F = loopd::factor_t;

int factorDim(int type) {
  switch (type) {
    case F::PRIOR_SE2:
    case F::BETWEEN_SE2:
    case F::PRIOR_POINT3:
    case F::POSE_POINT3:
      return 3;
    case F::PRIOR_SE3:
    case F::BETWEEN_SE3:
      return 6;
    case F::PRIOR_POINT2:
    case F::POSE_POINT2:
    case F::BEARING_RANGE2:
      return 2;
    default:
      return 0;
  }
}

int measurementSize(int type) {
  switch (type) {
    case F::PRIOR_SE3:
    case F::BETWEEN_SE3:
      return 7;
    default:
      return factorDim(type);
  }
}

int keyCount(int type) {
  if (type >= F::PRIOR_SE2 && type <= F::PRIOR_POINT3) return 1;
  if (type >= F::BETWEEN_SE2 && type <= F::BEARING_RANGE2) return 2;
  return 0;
}

std::string factorTypeName(int type) {
  static const char* names[] = {
      "?",           "PRIOR_SE2",   "PRIOR_SE3",   "PRIOR_POINT2", "PRIOR_POINT3",
      "BETWEEN_SE2", "BETWEEN_SE3", "POSE_POINT2", "POSE_POINT3",  "BEARING_RANGE2"};
  if (type >= 1 && type <= 9) return names[type];
  return "type " + std::to_string(type);
}

bool slotIsPose(int type, int slot) {
  switch (type) {
    case F::PRIOR_POINT2:
    case F::PRIOR_POINT3:
      return false;
    case F::POSE_POINT2:
    case F::POSE_POINT3:
    case F::BEARING_RANGE2:
      return slot == 0;
    default:
      return true;
  }
}

VarType slotVarType(int type, int slot) {
  switch (type) {
    case F::PRIOR_SE2:
    case F::BETWEEN_SE2:
      return VarType::SE2;
    case F::PRIOR_SE3:
    case F::BETWEEN_SE3:
      return VarType::SE3;
    case F::PRIOR_POINT2:
      return VarType::Point2;
    case F::PRIOR_POINT3:
      return VarType::Point3;
    case F::POSE_POINT2:
    case F::BEARING_RANGE2:
      return slot == 0 ? VarType::SE2 : VarType::Point2;
    case F::POSE_POINT3:
      return slot == 0 ? VarType::SE3 : VarType::Point3;
    default:
      return VarType::Scalar;
  }
}

Key toKey(const loopd::key_t& k) {
  return makeKey(static_cast<std::uint32_t>(k.robot),
                 k.kind == loopd::key_t::LANDMARK ? KeyKind::Landmark : KeyKind::Pose,
                 static_cast<std::uint64_t>(k.index));
}

loopd::key_t toWireKey(Key k) {
  loopd::key_t w{};
  w.robot = static_cast<std::int32_t>(keyRobot(k));
  w.kind = keyKind(k) == KeyKind::Landmark ? loopd::key_t::LANDMARK : loopd::key_t::POSE;
  w.index = static_cast<std::int64_t>(keyIndex(k));
  return w;
}

std::string wireKeyName(const loopd::key_t& k) {
  const char* kind = k.kind == loopd::key_t::POSE       ? "x"
                     : k.kind == loopd::key_t::LANDMARK ? "l"
                                                        : "?";
  return "r" + std::to_string(k.robot) + ":" + kind + std::to_string(k.index);
}

Eigen::MatrixXd symmetricFromUpper(const std::vector<double>& upper, int d) {
  Eigen::MatrixXd m(d, d);
  int n = 0;
  for (int i = 0; i < d; ++i)
    for (int j = i; j < d; ++j) m(i, j) = m(j, i) = upper[static_cast<size_t>(n++)];
  return m;
}

Eigen::MatrixXd informationOf(const loopd::factor_t& f) {
  const int d = factorDim(f.type);
  Eigen::MatrixXd m = symmetricFromUpper(f.noise, d);
  if (f.noise_kind == F::NOISE_COVARIANCE) {
    Eigen::LLT<Eigen::MatrixXd> llt(m);
    m = llt.solve(Eigen::MatrixXd::Identity(d, d));
    m = 0.5 * (m + m.transpose()).eval();
  }
  return m;
}

const std::vector<std::string>& robustNames() {
  static const std::vector<std::string> names = {"",   "none", "huber",  "cauchy",  "gm",   "dcs",
                                                 "sc", "mm",   "gnc-gm", "gnc-tls", "risam"};
  return names;
}

std::string num(double v) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.6g", v);
  return buf;
}

}  // namespace loopd::server
