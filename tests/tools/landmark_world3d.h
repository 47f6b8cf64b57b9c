#pragma once
// A synthetic 3D world with point landmarks, for tests that need one (../shared/datasets has
// no 3D landmark file): a wavy loop of SE(3) poses with noisy odometry, landmarks scattered
// along it, and a noisy EDGE_SE3_TRACKXYZ from every pose to each landmark within 5 m.
#include <string>

namespace loopd::test {

/// Writes the world as g2o to `path` (initial values: the odometry composed; vertices of the
/// sighted landmarks only) and returns how many sightings it holds. The same seed, the same
/// file.
int writeLandmarkWorld3D(const std::string& path, int poses, int landmarks, unsigned seed);

}  // namespace loopd::test
