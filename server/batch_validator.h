#pragma once
// FactorBatchValidator: everything about a factor_batch_t that can be judged without the
// graph (static: fields, enums, limits, finite numbers, dimensions, key kinds, positive-definite
// noise, unique ids) and what needs it (context: ids new for the sender, removals of live ids,
// variable types consistent with the graph). A batch is accepted only with no issue at all;
// every issue becomes one error_t.
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "loopd/factor_batch_t.hpp"
#include "solvers/core/values.h"

namespace loopd::server {

struct Issue {
  std::int64_t factorId = -1;  // offending item id; −1 = the whole batch / an initial value
  std::int8_t code = 0;        // error_t code
  std::string reason;
};

/// What the contextual checks need to know about the graph (implemented by the engine).
class GraphView {
 public:
  virtual ~GraphView() = default;
  /// Type of a variable already in the graph (or staged), nullopt if unknown.
  virtual std::optional<VarType> varType(Key k) const = 0;
  /// The pose type (SE2/SE3) of a robot's trajectory, nullopt if the robot has no pose yet.
  virtual std::optional<VarType> robotPoseType(std::uint32_t robot) const = 0;
  /// Whether this sender already used the id (live or removed).
  virtual bool idUsed(const std::string& sender, std::int64_t id) const = 0;
  /// Whether this sender's id names a live factor or ambiguous group.
  virtual bool idLive(const std::string& sender, std::int64_t id) const = 0;
  /// The robots' common frames as they will be once `batch` is applied: robot → a
  /// representative of the robots it is joined to through certain (non-ambiguous) inter-robot
  /// factors (those in the graph or staged, minus the batch's removals, plus the batch's own).
  /// A robot not listed is alone in its own frame. Only asked for when the batch has an
  /// inter-robot ambiguous alternative.
  /// The server's solver now (per-factor `robust` naming a whole-graph scheme must match it).
  virtual std::string solver() const { return ""; }
  virtual std::map<std::uint32_t, std::uint32_t> frameGroups(
      const loopd::factor_batch_t& /*batch*/) const {
    return {};
  }
  /// Whether a robot id names a landmark namespace (landmarks only: a pose there is refused).
  virtual bool isLandmarkNamespace(std::uint32_t /*robot*/) const { return false; }
  /// The robot whose frame robot `robot`'s landmarks live in: itself, or the robot that
  /// adopted a landmark namespace.
  virtual std::uint32_t landmarkFrame(std::uint32_t robot) const { return robot; }
};

class FactorBatchValidator {
 public:
  /// Static checks; empty = well-formed.
  std::vector<Issue> check(const loopd::factor_batch_t& batch) const;
  /// Checks of one factor (also used for ambiguous alternatives).
  void checkFactor(const loopd::factor_t& f, std::int64_t reportId, std::vector<Issue>& out) const;
  /// Checks of one ambiguous group: mode, number of alternatives, null weight, every
  /// alternative as a factor, and the mode's rules (same keys / same measurement and noise).
  void checkAmbiguous(const loopd::ambiguous_factor_t& a, std::vector<Issue>& out) const;
  /// Checks against the graph: ids, removals, variable types, inter-robot ambiguous
  /// alternatives only between robots already in one common frame, and per-factor `robust`
  /// naming a whole-graph scheme (gnc-gm, gnc-tls, risam) only if it is the server's solver.
  /// Run after check() passed.
  std::vector<Issue> checkContext(const loopd::factor_batch_t& batch, const GraphView& graph) const;
};

/// "sender 'robot1' seq 12: factor 43: reason" for logs.
std::string describe(const loopd::factor_batch_t& b, const Issue& issue);

}  // namespace loopd::server
