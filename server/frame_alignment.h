#pragma once
// Frame alignment from shared landmarks: robots r and s have each mapped the same landmarks in
// their own frames, giving correspondences (q_i in s's frame, p_i in r's frame). The rigid
// transform M (the pose of s's frame in r's frame) minimising Σ|M·q_i − p_i|² (no scale) is
// the closed-form least-squares solution of Umeyama (1991) / Arun et al. (1987).
#include <optional>
#include <vector>

#include "solvers/geometry/se2.h"
#include "solvers/geometry/se3.h"

namespace loopd::server {

/// One landmark seen by both robots: its position in s's frame and in r's frame. Several
/// pairs may be of the same landmark (repeat sightings); they are just points.
struct PointPair2 {
  Vec2 inS, inR;
};
struct PointPair3 {
  Vec3 inS, inR;
};

/// Least-squares rigid transform M with M·inS ≈ inR, or std::nullopt when the pairs do not fix
/// it or hold a non-finite number. Judged on the inS points' spread: 2D needs two distinct
/// points (largest distance from their centroid > 1e-9·(1 + largest |inS|)), 3D three
/// non-collinear ones (second singular value of the centred inS points > 1e-9·(1 + largest)).
std::optional<SE2> alignFrames(const std::vector<PointPair2>& pairs);
std::optional<SE3> alignFrames(const std::vector<PointPair3>& pairs);

}  // namespace loopd::server
