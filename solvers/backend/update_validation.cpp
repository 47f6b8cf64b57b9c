#include "solvers/backend/update_validation.h"

#include <stdexcept>
#include <string>

namespace loopd {

void validateUpdate(const BackendUpdate& u, const Values& existing,
                    const std::unordered_map<FactorId, int>& factorIndex, const Values& initial) {
  if (!u.ambiguous.empty())
    throw std::invalid_argument(
        "this solver does not keep ambiguous measurements apart: flatten them first "
        "(flattenAmbiguous) or use the mh solver");
  std::unordered_map<FactorId, int> removing;
  for (FactorId id : u.removals) {
    if (!factorIndex.count(id))
      throw std::invalid_argument("removal of unknown factor id " + std::to_string(id));
    if (!removing.emplace(id, 0).second)
      throw std::invalid_argument("factor id " + std::to_string(id) + " removed twice");
  }
  for (Key k : u.initial.keys())
    if (existing.contains(k))
      throw std::invalid_argument("initial value for existing variable " + keyToString(k));
  std::unordered_map<FactorId, int> adding;
  for (const auto& f : u.factors) {
    if (!f) throw std::invalid_argument("null factor in update");
    if ((factorIndex.count(f->id()) && !removing.count(f->id())) ||
        !adding.emplace(f->id(), 0).second)
      throw std::invalid_argument("duplicate factor id " + std::to_string(f->id()));
    for (int k = 0; k < f->size(); ++k) {
      const Key key = f->key(k);
      const Values& where = existing.contains(key) ? existing : initial;
      const int s = where.slot(key);
      if (s < 0)
        throw std::invalid_argument("factor " + std::to_string(f->id()) + " refers to " +
                                    keyToString(key) + " which has no value");
      if (where.type(s) != f->varType(k))
        throw std::invalid_argument("factor " + std::to_string(f->id()) + " expects " +
                                    varTypeName(f->varType(k)) + " for " + keyToString(key));
    }
  }
}

}  // namespace loopd
