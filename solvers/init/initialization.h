#pragma once
// Initial estimates that avoid the local minima an odometry start falls into:
//  - 2D, orientation first (LAGO-style, Carlone et al.): orientations along a spanning tree
//    fix each relative angle's multiple of 2π; a linear least-squares solve over all edges
//    gives the orientations; with pose–point landmark sightings, a relaxed joint solve then
//    takes the headings from the sightings too (landmark_headings.h); a second linear solve
//    gives positions (and 2D landmarks).
//  - 3D, chordal relaxation (Carlone et al., ICRA 2015): rotations from a linear solve that
//    ignores orthogonality, projected to SO(3); then positions (and 3D landmarks) linearly.
// Only between and pose–point factors are used; the anchor pose keeps its guessed value.
#include "solvers/graph/factor_graph.h"

namespace loopd {

/// Returns guess with poses (and landmarks observed by PosePoint factors) replaced by the
/// linear estimate. Variables not connected to the anchor keep their guessed value.
Values initializeOrientationFirst2D(const FactorGraph& graph, const Values& guess, Key anchor);
Values initializeChordal3D(const FactorGraph& graph, const Values& guess, Key anchor);

/// Picks the one that fits the anchor's type.
Values initializeLinear(const FactorGraph& graph, const Values& guess, Key anchor);

/// initializeLinear anchored at guess's lowest pose key; empty if guess has no pose or the
/// graph no factor. With several robots (solvers/init/common_frame.h), solved in the common
/// frame with the anchored between factors as plain ones, and each robot whose lowest pose
/// that leaves unreached starts another solve there (kept where the guess puts it): so every
/// robot's poses come from its own odometry, however the robots are joined.
Values initializeLinearFromLowestPose(const FactorGraph& graph, const Values& guess);

}  // namespace loopd
