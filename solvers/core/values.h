#pragma once
// Values: the current estimate of every variable, in insertion order ("slots"). Each slot
// holds its variable in a fixed-size stride of doubles, so solvers address variables by slot
// without hashing in their inner loops.
#include <Eigen/Core>
#include <cstdint>
#include <unordered_map>
#include <vector>

#include "solvers/core/key.h"
#include "solvers/geometry/se2.h"
#include "solvers/geometry/se3.h"

namespace loopd {

enum class VarType : std::uint8_t { SE2, SE3, Point2, Point3, Scalar };

/// Tangent dimension: SE2 3, SE3 6, Point2 2, Point3 3, Scalar 1.
int varDim(VarType t);
const char* varTypeName(VarType t);

/// Doubles per slot. SE3 stores R column-major (9) then t (3).
constexpr int kValueStride = 12;
constexpr int kMaxVarDim = 6;

class Values {
 public:
  int size() const { return static_cast<int>(keys_.size()); }
  bool empty() const { return keys_.empty(); }
  bool contains(Key k) const { return slots_.count(k) != 0; }
  /// False if any stored number is NaN or ±inf (what a diverged solve leaves).
  bool allFinite() const;
  /// False if any stored number is NaN, ±inf or beyond ±bound in magnitude.
  bool allWithin(double bound) const;
  /// allWithin for one slot's numbers.
  bool slotWithin(int slot, double bound) const;
  /// The largest magnitude of a stored number, NaN skipped: the map's extent in metres once
  /// beyond 1 (rotations, angles and switch values stay near 1).
  double largestMagnitude() const;
  /// Slot of k, or −1.
  int slot(Key k) const;
  Key key(int slot) const { return keys_[slot]; }
  VarType type(int slot) const { return types_[slot]; }
  const std::vector<Key>& keys() const { return keys_; }

  const double* data(int slot) const { return &data_[static_cast<size_t>(slot) * kValueStride]; }
  double* data(int slot) { return &data_[static_cast<size_t>(slot) * kValueStride]; }

  /// Inserts a new variable; throws std::invalid_argument if k is already present.
  int insert(Key k, const SE2& x);
  int insert(Key k, const SE3& x);
  int insertPoint2(Key k, const Vec2& p);
  int insertPoint3(Key k, const Vec3& p);
  int insertScalar(Key k, double s);
  /// Copies a variable (type and storage) from another Values.
  int insertFrom(const Values& other, int otherSlot);

  /// Overwrites an existing variable's value (same type).
  void set(int slot, const SE2& x);
  void set(int slot, const SE3& x);
  void setPoint2(int slot, const Vec2& p);
  void setPoint3(int slot, const Vec3& p);
  void setScalar(int slot, double s);

  SE2 se2(int slot) const;
  SE3 se3(int slot) const;
  Vec2 point2(int slot) const;
  Vec3 point3(int slot) const;
  double scalar(int slot) const { return data(slot)[0]; }

  /// x ⊕ δ for one slot; δ has varDim(type(slot)) entries.
  void retract(int slot, const double* delta);
  /// x ⊕ δ for all slots; offsets[s] is slot s's first entry in delta (−1: leave as is).
  void retractAll(const std::vector<int>& offsets, const double* delta);

  /// Copies all storage (same keys and types required).
  void assignFrom(const Values& o) { data_ = o.data_; }

 private:
  int insertRaw(Key k, VarType t);

  std::vector<Key> keys_;
  std::vector<VarType> types_;
  std::vector<double> data_;
  std::unordered_map<Key, int> slots_;
};

}  // namespace loopd
