#include "robust/ambiguous_choice.h"

#include <limits>
#include <unordered_map>
#include <unordered_set>

namespace loopd {

std::vector<int> chosenAlternatives(const Backend& backend,
                                    const std::vector<AmbiguousFactor>& measurements) {
  std::unordered_map<FactorId, double> weight;
  for (const auto& [id, w] : backend.decisions()) weight[id] = w;
  std::unordered_set<FactorId> rejected;
  for (FactorId id : backend.rejected()) rejected.insert(id);

  std::vector<int> out;
  out.reserve(measurements.size());
  for (const AmbiguousFactor& m : measurements) {
    if (const auto chosen = backend.chosenAlternative(m.id)) {
      out.push_back(*chosen);
      continue;
    }
    int best = -1;
    double bestWeight = -1.0, bestChi2 = std::numeric_limits<double>::infinity();
    for (int a = 0; a < static_cast<int>(m.alternatives.size()); ++a) {
      const Factor& f = *m.alternatives[a];
      if (rejected.count(f.id())) continue;
      const auto it = weight.find(f.id());
      const double w = it == weight.end() ? 1.0 : it->second;
      const double chi2 = f.chi2(backend.estimate());
      if (w > bestWeight || (w == bestWeight && chi2 < bestChi2)) {
        best = a;
        bestWeight = w;
        bestChi2 = chi2;
      }
    }
    out.push_back(best);
  }
  return out;
}

}  // namespace loopd
