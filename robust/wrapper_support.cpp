#include "robust/wrapper_support.h"

namespace loopd {

void scaleBlocks(const Factor& f, int numKeys, double s, double* r, double* const* J) {
  const int d = f.dim();
  for (int k = 0; k < d; ++k) r[k] *= s;
  if (J == nullptr) return;
  for (int i = 0; i < numKeys; ++i)
    if (J[i] != nullptr) {
      const int n = d * varDim(f.varType(i));
      for (int k = 0; k < n; ++k) J[i][k] *= s;
    }
}

}  // namespace loopd
