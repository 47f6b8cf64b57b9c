#pragma once
// A dataset turned into what the solvers take: the factor graph (one factor per file edge, in
// file order), the initial values, and the mapping back to file ids for writing estimates.
#include <cstdint>
#include <vector>

#include "solvers/backend/backend.h"
#include "solvers/graph/factor_graph.h"
#include "solvers/io/dataset.h"

namespace loopd {

/// One ambiguous measurement of the file (a HYPOTHESES group): its alternatives are factors
/// of the graph, at most one of them true (none, with `null`).
struct AmbiguousGroup {
  std::vector<int> factors;  // graph indices, in file order
  bool null = false;
};

struct PoseGraphProblem {
  FactorGraph graph;  // factor i is the file's edge i (id() = i), alternatives included
  std::vector<AmbiguousGroup> ambiguous;  // file order
  Values initial;                         // poses first (file order), then landmarks
  bool is3d = false;
  Key firstPose = 0;  // the gauge: lowest pose id

  int poseCount() const { return poses; }
  int landmarkCount() const { return landmarks; }
  int poses = 0;
  int landmarks = 0;
};

/// Builds factors and initial values. Between edges whose ends are next to each other in the
/// file's pose ids (neighboursInIdOrder) are odometry, others (and every alternative of a
/// HYPOTHESES group) loop closures; pose–landmark edges are landmark sightings. EQUIV pairs become
/// tight between constraints (io::equivalenceEdge), trusted as odometry is. Throws
/// std::invalid_argument (naming the file line) for an edge the factors reject.
PoseGraphProblem buildProblem(const io::Dataset& dataset);

/// Whether poses a and b are next to each other in sortedPoseIds (every pose id, ascending):
/// consecutive poses, joined by odometry, whatever the ids' step (a file keeping every second
/// pose, Victoria Park's ids shared with landmarks).
bool neighboursInIdOrder(const std::vector<std::int64_t>& sortedPoseIds, std::int64_t a,
                         std::int64_t b);

/// Group g as the Backend seam takes it: id g, alternatives the group's factors.
AmbiguousFactor ambiguousFactor(const PoseGraphProblem& problem, int group);
/// Every group, in file order.
std::vector<AmbiguousFactor> ambiguousFactors(const PoseGraphProblem& problem);

/// The whole problem as one update, as `loopd-solve` solves in batch: every factor but the
/// groups' alternatives, the groups as ambiguous measurements (flattenAmbiguous() for a
/// backend without them), and the initial values.
BackendUpdate wholeProblemUpdate(const PoseGraphProblem& problem);

/// Copies an estimate back into a dataset's vertices (same ids), for the writers.
void storeEstimate(const Values& estimate, io::Dataset& dataset);

/// The key a file vertex gets: poses are poseKey(id), landmarks landmarkKey(id).
Key vertexKey(const io::Vertex& v);

}  // namespace loopd
