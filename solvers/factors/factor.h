#pragma once
// A factor: a whitened residual r(x) ∈ R^dim over up to five variables, with analytic
// Jacobians written into caller-owned fixed-size buffers (no allocation per evaluation).
// Whitened means r = U·e with UᵀU = Ω, so chi2 = rᵀr = eᵀΩe (g2o's convention).
#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <memory>
#include <string>

#include "solvers/core/key.h"
#include "solvers/core/values.h"

namespace loopd {

using FactorId = std::uint64_t;
// 4: inter-robot factors through two anchors; 5: a switchable constraint's switch on one.
constexpr int kMaxFactorKeys = 5;
constexpr int kMaxResidualDim = 6;

/// Which factors robust variants may down-weight: loop closures and landmark sightings are
/// uncertain; priors and odometry are trusted.
enum class FactorRole : std::uint8_t { Prior, Odometry, LoopClosure, Landmark };

const char* factorRoleName(FactorRole r);
inline bool isUncertain(FactorRole r) {
  return r == FactorRole::LoopClosure || r == FactorRole::Landmark;
}

/// What a sender asked for one factor's robust handling (the wire's `robust`, `robust_param`):
/// "" = the solver's handling for its role, "none" = never down-weighted, or a robust
/// variant's name with its parameter (0 = the variant's default). Solvers ignore it; the
/// server's robust/per_factor_backend.h applies it.
struct RobustRequest {
  std::string variant;
  double parameter = 0.0;
};

/// Jacobian buffer of one key: dim × varDim, column-major with leading dimension dim.
using JacobianBlock = std::array<double, kMaxResidualDim * kMaxVarDim>;

class Factor;
using FactorPtr = std::shared_ptr<const Factor>;

class Factor {
 public:
  virtual ~Factor() = default;

  int dim() const { return dim_; }
  int size() const { return numKeys_; }
  Key key(int i) const { return keys_[i]; }
  VarType varType(int i) const { return varTypes_[i]; }
  FactorRole role() const { return role_; }

  /// Caller-chosen id (file edge index, or sender-unique id); not interpreted here.
  FactorId id() const { return id_; }
  void setId(FactorId id) { id_ = id; }
  void setRole(FactorRole r) { role_ = r; }
  const RobustRequest& robustRequest() const { return robust_; }
  void setRobustRequest(RobustRequest r) { robust_ = std::move(r); }

  /// x[i] → storage of key(i) (see Values). Writes dim() whitened residuals into r and, when
  /// J is non-null, each non-null J[i] with the dim()×varDim(i) whitened Jacobian.
  virtual void evaluate(const double* const* x, double* r, double* const* J) const = 0;

  /// Deep copy (robust wrappers and the server keep their own).
  virtual std::unique_ptr<Factor> clone() const = 0;

  /// Human-readable kind, e.g. "BetweenSE2".
  virtual const char* typeName() const = 0;

  /// Whitened error at values (all keys must be present).
  Eigen::VectorXd whitenedError(const Values& values) const;
  /// rᵀr at values (all keys must be present); no allocation, so loops over factors may
  /// call it freely.
  double chi2(const Values& values) const;
  /// rᵀr with x[i] → storage of key(i), as evaluate() takes it (e.g. a snapshot's storage).
  double chi2(const double* const* x) const;
  /// This factor's term of the objective a solver minimises, x as evaluate() takes it: rᵀr
  /// for a least-squares factor. A robust wrapper whose residual is re-weighted at each
  /// evaluation overrides it with its own cost (a kernel's ρ, a max-mixture's best component),
  /// which rᵀr of its scaled residual is not. Solvers that judge a step's gain compare it.
  virtual double objective(const double* const* x) const { return chi2(x); }
  /// A robust wrapper whose objective() is at most `weight` × its inner factor's rᵀr plus a
  /// constant, with equality at x (its re-weighting held as at x), gives that inner factor
  /// and weight and returns true: least squares over such terms bounds the objective from
  /// above, so lowering it lowers the objective. Least-squares factors return false.
  virtual bool heldAt(const double* const* /*x*/, FactorPtr& /*inner*/, double& /*weight*/) const {
    return false;
  }
  /// objective() at values (all keys must be present).
  double objectiveAt(const Values& values) const { return objective(storageIn(values).data()); }

 protected:
  Factor(std::initializer_list<std::pair<Key, VarType>> vars, int dim, FactorRole role);

 private:
  /// Storage of each key in values; throws std::out_of_range for a missing one.
  std::array<const double*, kMaxFactorKeys> storageIn(const Values& values) const;

  std::array<Key, kMaxFactorKeys> keys_{};
  std::array<VarType, kMaxFactorKeys> varTypes_{};
  int numKeys_ = 0;
  int dim_ = 0;
  FactorRole role_;
  FactorId id_ = 0;
  RobustRequest robust_;
};

/// The largest information (diagonal entry of Ω) a factor takes: σ ≥ 3.2e-8.
constexpr double kMaxInformation = 1e15;

/// Upper-triangular U with UᵀU = Ω; throws std::invalid_argument if Ω is not symmetric
/// positive definite, not finite, or beyond kMaxInformation.
template <int D>
Eigen::Matrix<double, D, D> sqrtInformation(const Eigen::Matrix<double, D, D>& information);

}  // namespace loopd
