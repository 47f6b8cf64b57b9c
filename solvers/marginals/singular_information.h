#pragma once
// The one reason marginal covariances are refused, said alike by the batch and Bayes-tree paths.

namespace loopd {

inline constexpr const char* kSingularInformationMessage =
    "marginals: the information matrix is singular at the estimate (a part of the graph not tied "
    "to the first pose, or a variable no factor fully constrains)";

}  // namespace loopd
