#include "server/batch_validator.h"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <map>
#include <unordered_map>
#include <unordered_set>

#include "loopd/error_t.hpp"
#include "server/wire.h"
#include "solvers/factors/factor.h"

namespace loopd::server {

using E = loopd::error_t;
using F = loopd::factor_t;
using B = loopd::factor_batch_t;

namespace {

bool allFinite(const std::vector<double>& v) {
  return std::all_of(v.begin(), v.end(), [](double x) { return std::isfinite(x); });
}

std::string itemName(const F& f, std::int64_t reportId) {
  return "factor " + std::to_string(reportId) + " (" + factorTypeName(f.type) + ")";
}

bool quaternionOk(const double* q, double& norm) {
  norm = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  return std::abs(norm - 1.0) <= 1e-3;
}

bool validKeyFields(const loopd::key_t& k, std::string& why) {
  if (k.robot < 0 || static_cast<std::uint32_t>(k.robot) > kMaxRobotId) {
    why = "robot id " + std::to_string(k.robot) + " out of range [0, " +
          std::to_string(kMaxRobotId) + "]";
    return false;
  }
  if (k.kind != loopd::key_t::POSE && k.kind != loopd::key_t::LANDMARK) {
    why = "key kind " + std::to_string(k.kind) + " is neither POSE (0) nor LANDMARK (1)";
    return false;
  }
  if (k.index < 0 || static_cast<std::uint64_t>(k.index) > kMaxKeyIndex) {
    why = "key index " + std::to_string(k.index) + " out of range [0, 2^40)";
    return false;
  }
  return true;
}

}  // namespace

void FactorBatchValidator::checkFactor(const F& f, std::int64_t reportId,
                                       std::vector<Issue>& out) const {
  auto bad = [&](std::int8_t code, const std::string& why) {
    out.push_back({reportId, code, itemName(f, reportId) + ": " + why});
  };
  const size_t before = out.size();
  if (f.type < F::PRIOR_SE2 || f.type > F::BEARING_RANGE2) {
    bad(E::INVALID_FIELD, "unknown factor type " + std::to_string(f.type));
    return;
  }
  // Role allowed for the type.
  const bool prior = f.type <= F::PRIOR_POINT3;
  const bool between = f.type == F::BETWEEN_SE2 || f.type == F::BETWEEN_SE3;
  bool roleOk = false;
  if (prior)
    roleOk = f.role == F::ROLE_PRIOR;
  else if (between)
    roleOk = f.role == F::ROLE_ODOMETRY || f.role == F::ROLE_LOOP_CLOSURE;
  else
    roleOk = f.role == F::ROLE_LANDMARK;
  if (!roleOk)
    bad(E::INVALID_FIELD, "role " + std::to_string(f.role) + " not allowed for this type");

  const int nk = keyCount(f.type);
  if (f.num_keys != nk || static_cast<int>(f.keys.size()) != nk) {
    bad(E::WRONG_DIMENSION, std::to_string(f.num_keys) + " keys, expected " + std::to_string(nk));
  } else {
    for (int i = 0; i < nk; ++i) {
      std::string why;
      const auto& k = f.keys[static_cast<size_t>(i)];
      if (!validKeyFields(k, why)) {
        bad(E::INVALID_FIELD, "key " + std::to_string(i) + ": " + why);
        continue;
      }
      const bool wantPose = slotIsPose(f.type, i);
      if ((k.kind == loopd::key_t::POSE) != wantPose)
        bad(E::WRONG_KEY_KIND, "key " + std::to_string(i) + " " + wireKeyName(k) + " must be a " +
                                   (wantPose ? "pose" : "landmark"));
    }
    if (nk == 2 && f.keys[0].robot == f.keys[1].robot && f.keys[0].kind == f.keys[1].kind &&
        f.keys[0].index == f.keys[1].index)
      bad(E::INVALID_FIELD, "both keys are " + wireKeyName(f.keys[0]));
    if (between && f.role == F::ROLE_ODOMETRY && f.keys[0].robot != f.keys[1].robot)
      bad(E::INVALID_FIELD, "ROLE_ODOMETRY joins poses of two robots (use ROLE_LOOP_CLOSURE)");
  }

  const int ms = measurementSize(f.type);
  const bool measurementSized =
      f.num_measurement == ms && static_cast<int>(f.measurement.size()) == ms;
  if (!measurementSized)
    bad(E::WRONG_DIMENSION,
        std::to_string(f.num_measurement) + " measurement numbers, expected " + std::to_string(ms));
  else if (!allFinite(f.measurement))
    bad(E::NON_FINITE, "measurement has NaN or Inf");
  else if (ms == 7) {
    double norm;
    if (!quaternionOk(&f.measurement[3], norm))
      bad(E::INVALID_FIELD, "quaternion norm " + num(norm) + " is not 1 (±1e-3)");
  } else if (f.type == F::BEARING_RANGE2 && !(f.measurement[1] > 0.0)) {
    bad(E::INVALID_FIELD, "range " + num(f.measurement[1]) + " must be > 0");
  }

  if (f.noise_kind != F::NOISE_INFORMATION && f.noise_kind != F::NOISE_COVARIANCE)
    bad(E::INVALID_FIELD, "noise_kind " + std::to_string(f.noise_kind) + " is neither 1 nor 2");
  const int d = factorDim(f.type);
  const int nn = d * (d + 1) / 2;
  if (f.num_noise != nn || static_cast<int>(f.noise.size()) != nn) {
    bad(E::WRONG_DIMENSION,
        std::to_string(f.num_noise) + " noise entries, expected " + std::to_string(nn));
  } else if (!allFinite(f.noise)) {
    bad(E::NON_FINITE, "noise has NaN or Inf");
  } else {
    const Eigen::MatrixXd m = symmetricFromUpper(f.noise, d);
    Eigen::LLT<Eigen::MatrixXd> llt(m);
    if (llt.info() != Eigen::Success) {
      Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(m, Eigen::EigenvaluesOnly);
      bad(E::NOT_POSITIVE_DEFINITE,
          std::string(f.noise_kind == F::NOISE_COVARIANCE ? "covariance" : "information") +
              " not positive definite (smallest eigenvalue " + num(es.eigenvalues()(0)) + ")");
    } else if (out.size() == before) {
      // Also the derived information must be finite and PD (extreme covariances), and within
      // what the factors take (kMaxInformation: beyond it χ² overflows and the solve with it).
      const Eigen::MatrixXd info = informationOf(f);
      Eigen::LLT<Eigen::MatrixXd> l2(info);
      if (!info.allFinite() || l2.info() != Eigen::Success)
        bad(E::NOT_POSITIVE_DEFINITE, "covariance too ill-conditioned to invert");
      else if (info.diagonal().maxCoeff() > kMaxInformation)
        bad(E::LIMIT_EXCEEDED, "information " + num(info.diagonal().maxCoeff()) +
                                   " exceeds 1e15 (a standard deviation below 3.2e-8)");
    }
  }
  if (f.robust.size() > static_cast<size_t>(F::MAX_ROBUST_LENGTH))
    bad(E::LIMIT_EXCEEDED, "robust name longer than 15 characters");
  else if (std::find(robustNames().begin(), robustNames().end(), f.robust) == robustNames().end())
    bad(E::INVALID_FIELD, "unknown robust handling '" + f.robust + "'");
  else if ((f.role == F::ROLE_PRIOR || f.role == F::ROLE_ODOMETRY) && !f.robust.empty() &&
           f.robust != "none")
    bad(E::INVALID_FIELD,
        "robust '" + f.robust +
            "' on a prior or odometry factor: those are trusted (use \"\" or \"none\")");
  if (!std::isfinite(f.robust_param) || f.robust_param < 0.0)
    bad(E::INVALID_FIELD, "robust_param " + num(f.robust_param) + " must be finite and >= 0");
}

void FactorBatchValidator::checkAmbiguous(const loopd::ambiguous_factor_t& a,
                                          std::vector<Issue>& out) const {
  using A = loopd::ambiguous_factor_t;
  const std::string name = "ambiguous " + std::to_string(a.id);
  auto bad = [&](std::int8_t code, const std::string& why) {
    out.push_back({a.id, code, name + ": " + why});
  };
  if (a.mode != A::MULTI_MEASUREMENT && a.mode != A::MULTI_ASSOCIATION)
    bad(E::INVALID_FIELD, "unknown mode " + std::to_string(a.mode) +
                              " (MULTI_MEASUREMENT = 1, MULTI_ASSOCIATION = 2)");
  if (a.num_alternatives < 0 || static_cast<size_t>(a.num_alternatives) != a.alternatives.size()) {
    bad(E::DECODE_FAILED, "num_alternatives does not match its contents");
    return;
  }
  const int k = a.num_alternatives;
  if (k > A::MAX_ALTERNATIVES)
    bad(E::LIMIT_EXCEEDED,
        std::to_string(k) + " alternatives, at most " + std::to_string(A::MAX_ALTERNATIVES));
  if (k < (a.null_hypothesis ? 1 : 2))
    bad(E::INVALID_FIELD, std::to_string(k) + " alternative(s): need at least 2, or 1 with " +
                              "null_hypothesis (otherwise send a factor_t)");
  if (!std::isfinite(a.null_weight))
    bad(E::NON_FINITE, "null_weight is NaN or Inf");
  else if (a.null_weight < 0.0)
    bad(E::INVALID_FIELD, "null_weight " + num(a.null_weight) + " must be >= 0 (0 = default 1)");
  const size_t before = out.size();
  for (int i = 0; i < k; ++i) {
    const F& f = a.alternatives[static_cast<size_t>(i)];
    std::vector<Issue> one;
    checkFactor(f, a.id, one);
    for (Issue& is : one) {
      is.reason = name + " alternative " + std::to_string(i) + ": " + is.reason;
      out.push_back(std::move(is));
    }
    if (!one.empty()) continue;
    if (f.role != F::ROLE_LOOP_CLOSURE && f.role != F::ROLE_LANDMARK)
      bad(E::INVALID_FIELD,
          "alternative " + std::to_string(i) + ": role must be ROLE_LOOP_CLOSURE or ROLE_LANDMARK");
  }
  if (out.size() != before || k < 1 || k > A::MAX_ALTERNATIVES) return;
  // Every alternative well-formed: the group's own rules.
  const F& f0 = a.alternatives.front();
  auto sameKeys = [](const F& x, const F& y) {
    if (x.keys.size() != y.keys.size()) return false;
    for (size_t j = 0; j < x.keys.size(); ++j)
      if (x.keys[j].robot != y.keys[j].robot || x.keys[j].kind != y.keys[j].kind ||
          x.keys[j].index != y.keys[j].index)
        return false;
    return true;
  };
  for (int i = 1; i < k; ++i) {
    const F& f = a.alternatives[static_cast<size_t>(i)];
    const std::string alt = "alternative " + std::to_string(i);
    if (f.type != f0.type || f.role != f0.role) {
      bad(E::INVALID_FIELD, alt + " is " + factorTypeName(f.type) + " role " +
                                std::to_string(f.role) + ", alternative 0 " +
                                factorTypeName(f0.type) + " role " + std::to_string(f0.role) +
                                ": all alternatives have one type and role");
      continue;
    }
    if (a.mode == A::MULTI_MEASUREMENT && !sameKeys(f, f0))
      bad(E::INVALID_FIELD, alt + ": MULTI_MEASUREMENT needs the same keys in every alternative");
    if (a.mode == A::MULTI_ASSOCIATION) {
      if (f.measurement != f0.measurement || f.noise_kind != f0.noise_kind || f.noise != f0.noise)
        bad(E::INVALID_FIELD,
            alt + ": MULTI_ASSOCIATION needs the same measurement and noise in every alternative");
      for (int j = 0; j < i; ++j)
        if (sameKeys(f, a.alternatives[static_cast<size_t>(j)]))
          bad(E::INVALID_FIELD, alt + " has the same keys as alternative " + std::to_string(j) +
                                    ": MULTI_ASSOCIATION alternatives differ in their keys");
    }
  }
}

std::vector<Issue> FactorBatchValidator::check(const B& b) const {
  std::vector<Issue> out;
  auto whole = [&](std::int8_t code, const std::string& why) { out.push_back({-1, code, why}); };
  if (b.sender.empty()) whole(E::INVALID_FIELD, "empty sender");
  if (b.sender.size() > static_cast<size_t>(B::MAX_SENDER_LENGTH))
    whole(E::LIMIT_EXCEEDED, "sender longer than 63 characters");
  if (b.sequence < 1)
    whole(E::INVALID_FIELD, "sequence " + std::to_string(b.sequence) + " must be >= 1");
  if (b.num_factors < 0 || b.num_ambiguous < 0 || b.num_initial_values < 0 ||
      b.num_remove_ids < 0 || static_cast<size_t>(b.num_factors) != b.factors.size() ||
      static_cast<size_t>(b.num_ambiguous) != b.ambiguous.size() ||
      static_cast<size_t>(b.num_initial_values) != b.initial_values.size() ||
      static_cast<size_t>(b.num_remove_ids) != b.remove_ids.size()) {
    whole(E::DECODE_FAILED, "array counts do not match their contents");
    return out;
  }
  size_t items = b.factors.size() + b.initial_values.size() + b.remove_ids.size();
  for (const auto& a : b.ambiguous)
    items += static_cast<size_t>(std::max<int>(0, a.num_alternatives));
  if (items > static_cast<size_t>(B::MAX_ITEMS))
    whole(E::LIMIT_EXCEEDED,
          std::to_string(items) + " items, at most " + std::to_string(B::MAX_ITEMS));
  if (!out.empty()) return out;

  std::unordered_set<std::int64_t> ids;
  auto checkId = [&](std::int64_t id) {
    if (id < 0) {
      out.push_back({id, E::INVALID_FIELD, "id " + std::to_string(id) + " is negative"});
      return;
    }
    if (!ids.insert(id).second)
      out.push_back(
          {id, E::DUPLICATE_FACTOR_ID, "id " + std::to_string(id) + " appears twice in the batch"});
  };
  for (const auto& f : b.factors) {
    checkId(f.id);
    checkFactor(f, f.id, out);
  }
  for (const auto& a : b.ambiguous) {
    checkId(a.id);
    checkAmbiguous(a, out);
  }
  for (const auto& v : b.initial_values) {
    std::string why;
    const std::string name = "initial value of " + wireKeyName(v.key);
    if (!validKeyFields(v.key, why)) {
      out.push_back({-1, E::INVALID_FIELD, name + ": " + why});
      continue;
    }
    int want = 0;
    bool pose = true;
    switch (v.type) {
      case loopd::initial_value_t::SE2:
        want = 3;
        break;
      case loopd::initial_value_t::SE3:
        want = 7;
        break;
      case loopd::initial_value_t::POINT2:
        want = 2;
        pose = false;
        break;
      case loopd::initial_value_t::POINT3:
        want = 3;
        pose = false;
        break;
      default:
        out.push_back(
            {-1, E::INVALID_FIELD, name + ": unknown value type " + std::to_string(v.type)});
        continue;
    }
    if ((v.key.kind == loopd::key_t::POSE) != pose)
      out.push_back({-1, E::WRONG_KEY_KIND,
                     name + ": a " + (pose ? "pose" : "point") + " value for a " +
                         (pose ? "landmark" : "pose")});
    if (v.num_value != want || static_cast<int>(v.value.size()) != want)
      out.push_back({-1, E::WRONG_DIMENSION,
                     name + ": " + std::to_string(v.num_value) + " numbers, expected " +
                         std::to_string(want)});
    else if (!allFinite(v.value))
      out.push_back({-1, E::NON_FINITE, name + ": NaN or Inf"});
    else if (want == 7) {
      double norm;
      if (!quaternionOk(&v.value[3], norm))
        out.push_back(
            {-1, E::INVALID_FIELD, name + ": quaternion norm " + num(norm) + " is not 1"});
    }
  }
  for (std::int64_t id : b.remove_ids) {
    if (id < 0)
      out.push_back({id, E::INVALID_FIELD, "removal id " + std::to_string(id) + " is negative"});
    else if (ids.count(id))
      out.push_back({id, E::UNKNOWN_FACTOR_ID,
                     "removal of id " + std::to_string(id) + " added in the same batch"});
  }
  return out;
}

std::vector<Issue> FactorBatchValidator::checkContext(const B& b, const GraphView& g) const {
  std::vector<Issue> out;
  // Graduated schemes act on all uncertain factors together: one factor cannot opt into them.
  auto scheme = [&](const F& f, std::int64_t reportId) {
    if ((f.robust == "gnc-gm" || f.robust == "gnc-tls" || f.robust == "risam") &&
        f.robust != g.solver())
      out.push_back({reportId, E::INVALID_FIELD,
                     "robust '" + f.robust +
                         "' is a whole-graph scheme: it applies only as the "
                         "server's --solver (now '" +
                         g.solver() +
                         "'); per factor use none, huber, "
                         "cauchy, gm, dcs, sc or mm"});
  };
  for (const auto& f : b.factors) scheme(f, f.id);
  for (const auto& a : b.ambiguous)
    for (const auto& f : a.alternatives) scheme(f, a.id);
  for (const auto& f : b.factors)
    if (g.idUsed(b.sender, f.id))
      out.push_back({f.id, E::DUPLICATE_FACTOR_ID,
                     "id " + std::to_string(f.id) + " already used by this sender"});
  for (const auto& a : b.ambiguous)
    if (g.idUsed(b.sender, a.id))
      out.push_back({a.id, E::DUPLICATE_FACTOR_ID,
                     "id " + std::to_string(a.id) + " already used by this sender"});
  std::unordered_set<std::int64_t> removing;
  for (std::int64_t id : b.remove_ids) {
    if (!g.idLive(b.sender, id))
      out.push_back({id, E::UNKNOWN_FACTOR_ID,
                     "removal of id " + std::to_string(id) + ": not a live factor of this sender"});
    else if (!removing.insert(id).second)
      out.push_back({id, E::UNKNOWN_FACTOR_ID, "id " + std::to_string(id) + " removed twice"});
  }
  // Variable types: the graph's, the batch's uses, and each robot's pose type agree.
  std::unordered_map<Key, VarType> seen;
  std::map<std::uint32_t, VarType> robotType;
  auto use = [&](Key k, VarType t, std::int64_t id, const std::string& what) {
    std::optional<VarType> known = g.varType(k);
    auto it = seen.find(k);
    if (!known && it != seen.end()) known = it->second;
    if (known && *known != t) {
      out.push_back({id, E::WRONG_DIMENSION,
                     what + ": " + keyToString(k) + " is " + varTypeName(*known) + ", used as " +
                         varTypeName(t)});
      return;
    }
    seen.emplace(k, t);
    if (keyKind(k) == KeyKind::Pose && g.isLandmarkNamespace(keyRobot(k))) {
      out.push_back({id, E::WRONG_KEY_KIND,
                     what + ": " + keyToString(k) + " is a pose of robot " +
                         std::to_string(keyRobot(k)) +
                         ", a landmark namespace (--landmark-namespace): landmarks only"});
      return;
    }
    if (keyKind(k) == KeyKind::Pose) {
      std::optional<VarType> rt = g.robotPoseType(keyRobot(k));
      auto jt = robotType.find(keyRobot(k));
      if (!rt && jt != robotType.end()) rt = jt->second;
      if (rt && *rt != t)
        out.push_back({id, E::WRONG_DIMENSION,
                       what + ": robot " + std::to_string(keyRobot(k)) + " has " +
                           varTypeName(*rt) + " poses, " + keyToString(k) + " used as " +
                           varTypeName(t)});
      else
        robotType.emplace(keyRobot(k), t);
    }
  };
  for (const auto& f : b.factors)
    for (int i = 0; i < f.num_keys; ++i)
      use(toKey(f.keys[static_cast<size_t>(i)]), slotVarType(f.type, i), f.id, itemName(f, f.id));
  for (const auto& a : b.ambiguous)
    for (const auto& f : a.alternatives)
      for (int i = 0; i < f.num_keys; ++i)
        use(toKey(f.keys[static_cast<size_t>(i)]), slotVarType(f.type, i), a.id,
            "ambiguous " + std::to_string(a.id) + " " + itemName(f, a.id));
  // A landmark namespace's landmarks have no frame until a robot's sighting adopts one for them
  // (engine.h), so a prior cannot say where one is.
  auto namespacePrior = [&](const F& f, std::int64_t id, const std::string& what) {
    if ((f.type == F::PRIOR_POINT2 || f.type == F::PRIOR_POINT3) &&
        g.isLandmarkNamespace(static_cast<std::uint32_t>(f.keys[0].robot)))
      out.push_back({id, E::INVALID_FIELD,
                     what + ": a prior on " + keyToString(toKey(f.keys[0])) +
                         ", a landmark of a landmark namespace (--landmark-namespace): its "
                         "landmarks are placed by sightings only"});
  };
  for (const auto& f : b.factors) namespacePrior(f, f.id, itemName(f, f.id));
  for (const auto& a : b.ambiguous)
    for (const auto& f : a.alternatives)
      namespacePrior(f, a.id, "ambiguous " + std::to_string(a.id) + " " + itemName(f, a.id));
  // Inter-robot alternatives: an alternative cannot create the anchor that joins two robots'
  // frames (under "none" or another alternative the anchor would be unconstrained, and each
  // alternative implies another anchor value), so its robots must already share a frame
  // through certain inter-robot factors (earlier ones or this batch's own).
  std::optional<std::map<std::uint32_t, std::uint32_t>> frames;
  auto frameOf = [&](std::uint32_t r) {
    const auto it = frames->find(r);
    return it == frames->end() ? r : it->second;
  };
  for (const auto& a : b.ambiguous)
    for (size_t i = 0; i < a.alternatives.size(); ++i) {
      const F& f = a.alternatives[i];
      if (f.num_keys != 2) continue;
      const auto r = static_cast<std::uint32_t>(f.keys[0].robot);
      auto s = static_cast<std::uint32_t>(f.keys[1].robot);
      if (keyKind(toKey(f.keys[1])) == KeyKind::Landmark) s = g.landmarkFrame(s);
      if (r == s) continue;
      if (!frames) frames = g.frameGroups(b);
      if (frameOf(r) == frameOf(s)) continue;
      out.push_back({a.id, E::INVALID_FIELD,
                     "ambiguous " + std::to_string(a.id) + " alternative " + std::to_string(i) +
                         " joins robots " + std::to_string(r) + " and " + std::to_string(s) +
                         ", whose frames no certain factor has joined yet: an ambiguous "
                         "alternative cannot be the first link between two robots' frames; "
                         "send a certain inter-robot loop closure (under a robust solver: "
                         "robust \"none\", or --join-agreement closures that agree), or "
                         "sightings of enough of the other robot's landmarks (factor_t), first"});
      break;  // one issue per group
    }
  for (const auto& v : b.initial_values) {
    const VarType t = v.type == loopd::initial_value_t::SE2      ? VarType::SE2
                      : v.type == loopd::initial_value_t::SE3    ? VarType::SE3
                      : v.type == loopd::initial_value_t::POINT2 ? VarType::Point2
                                                                 : VarType::Point3;
    use(toKey(v.key), t, -1, "initial value of " + wireKeyName(v.key));
  }
  return out;
}

std::string describe(const B& b, const Issue& issue) {
  return "sender '" + b.sender + "' seq " + std::to_string(b.sequence) + ": " + issue.reason;
}

}  // namespace loopd::server
