// flattenAmbiguous: the backend.h fallback for variants without hypotheses.
#include "solvers/backend/backend.h"

namespace loopd {

void flattenAmbiguous(BackendUpdate& update) {
  for (AmbiguousFactor& a : update.ambiguous)
    for (FactorPtr& f : a.alternatives) update.factors.push_back(std::move(f));
  update.ambiguous.clear();
}

}  // namespace loopd
