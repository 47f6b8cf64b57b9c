#pragma once
// Every Backend variant by name: the server, loopd-solve and the comparison scripts pick one
// with makeBackend("lm"), so adding a variant touches only this registry.
#include <memory>
#include <string>
#include <vector>

#include "solvers/backend/backend.h"

namespace loopd {

struct BackendInfo {
  std::string name;
  std::string description;
  bool incremental;  // updates cost what they touch (vs. a full re-solve)
};

/// Throws std::invalid_argument naming the known variants if name is unknown.
std::unique_ptr<Backend> makeBackend(const std::string& name, const BackendOptions& options = {});
std::vector<BackendInfo> availableBackends();
bool isBackendName(const std::string& name);
/// Adds a variant under a new name (tests, applications embedding the server), before any
/// thread uses the registry. Throws std::invalid_argument if the name is empty or taken.
void registerBackend(BackendInfo info, BackendFactory make);

}  // namespace loopd
