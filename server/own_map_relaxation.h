#pragma once
// Each robot's map as its own factors alone would have it. Inter-robot closures bend the maps
// they join: a wrong group that joined two robots pulls their tails toward each other, and the
// pair's true closures, judged on those bent maps (closure_agreement.h takes each map as
// exact), then split into small sets that agree (sphere2500 + 100 grouped, two robots: a ring
// of 50 true closures into sets of at most 6). Relaxed on its own odometry and loop closures,
// from where the solver left it, a robot's map loses the bend and keeps what its own closures
// say; the own closures the solver rejected on the bent map and that fit the relaxed one are
// taken back (closuresThatFit).
#include <vector>

#include "solvers/core/values.h"
#include "solvers/factors/factor.h"

namespace loopd::server {

/// The relaxation's Levenberg–Marquardt iterations at most: it starts from the solver's maps,
/// which its own factors already hold near their optimum but for the bend.
constexpr int kRelaxIterations = 20;

/// Improves `poses` (several robots' poses, each in its own frame) on `factors` alone (each
/// robot's odometry and own loop closures: pose–pose factors within one robot), with one pose
/// of each connected part held (the part's lowest key). At most `maxIterations` LM steps;
/// `poses` is left as it was if the solve fails.
void relaxOwnMaps(const std::vector<FactorPtr>& factors, Values& poses, int maxIterations);

/// The χ²_dim quantile under which closuresThatFit takes a closure.
constexpr double kFitProbability = 0.999;

/// Those of `closures` whose keys are all in `poses` and whose χ² there (at their stated noise)
/// is below χ²_dim(kFitProbability). The solver rejects true own closures where a wrong join
/// bends a robot's map; on the relaxed map they fit again, and the relaxation takes them back.
std::vector<FactorPtr> closuresThatFit(const std::vector<FactorPtr>& closures, const Values& poses);

}  // namespace loopd::server
