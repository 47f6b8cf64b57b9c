#pragma once
// Headings for a 2D graph whose poses also see landmarks (pose–point sightings).
//
// The orientation-first start takes headings from between factors only; on an odometry +
// landmark graph (Victoria Park) they are dead-reckoned, and Levenberg–Marquardt from there
// stops in a local minimum. Here each heading is relaxed to a free 2-vector (c, s) = (cos θ,
// sin θ), which makes every between and pose–point factor linear in the unknowns:
//   between i→j:    (c, s)ⱼ = Rot(zθ)·(c, s)ᵢ            weight Ωθθ·I
//                   tⱼ − tᵢ = M(zt)·(c, s)ᵢ              weight R(θ̂ᵢ)·Ωtt·R(θ̂ᵢ)ᵀ
//   pose–point i→k: pₖ − tᵢ = M(z)·(c, s)ᵢ               weight R(θ̂ᵢ)·Ωz·R(θ̂ᵢ)ᵀ
// with M(v)·(c, s) = R(θ)·v. One sparse solve over poses (t, c, s) and landmarks p gives
// headings that the landmark re-sightings have corrected; θ = atan2(s, c). θ̂ (the
// dead-reckoned headings) only rotates the translation weights into the world frame.
#include <vector>

#include "solvers/graph/factor_graph.h"

namespace loopd {

/// Whether the graph has a 2D pose–point sighting (what landmarkAidedHeadings2D uses).
bool hasPointSightings2D(const FactorGraph& graph);

/// Headings per Values slot from the relaxation above, anchored at anchorSlot (its guess is
/// known and keeps its guessed heading); weightHeadings (per slot) rotate the translation
/// weights. Slots not connected to the anchor through between and pose–point factors keep
/// weightHeadings' value. Throws std::runtime_error if the relaxed system is singular (a pose
/// held by one sighting only) or its solution not finite.
std::vector<double> landmarkAidedHeadings2D(const FactorGraph& graph, const Values& guess,
                                            int anchorSlot,
                                            const std::vector<double>& weightHeadings);

}  // namespace loopd
