#pragma once
// Initial values for a file with edges only (no vertex lines): poses composed along the
// between edges from the lowest pose id, landmarks placed by their first sighting.
// Internal to the readers.
#include "solvers/io/dataset.h"

namespace loopd::io::detail {

/// Fills ds.poses and ds.landmarks (both sorted by id, line 0) from ds.edges.
///
/// The spanning tree is a breadth-first walk from the lowest pose id that takes an odometry
/// edge (between poses next in id order, written either way, e.g. 4 -> 5, or 4 -> 6 when 5 is
/// a landmark) before any other, so a loop closure never replaces the odometry chain: X_b = X_a·Z
/// forwards, X_a = X_b·Z⁻¹ backwards, the lowest id at the identity. Throws DatasetError naming a
/// pose the between edges do not reach, or (when `landmarkIdsShared`) an id used both as a pose and
/// as a landmark.
void initialiseFromOdometry(Dataset& ds, bool landmarkIdsShared);

}  // namespace loopd::io::detail
