#include "robust/backend_registry.h"

#include <stdexcept>

#include "solvers/batch/batch_backend.h"
#include "solvers/incremental/isam2.h"

namespace loopd {

namespace {

struct Entry {
  BackendInfo info;
  BackendFactory make;
};

std::unique_ptr<Backend> batch(OptimizerMethod m, BackendOptions o) {
  o.method = m;
  return std::make_unique<BatchBackend>(std::move(o));
}

const std::vector<Entry>& registry() {
  static const std::vector<Entry> entries = {
      {{"lm", "batch Levenberg-Marquardt (default)", false},
       [](const BackendOptions& o) { return batch(OptimizerMethod::LevenbergMarquardt, o); }},
      {{"gn", "batch Gauss-Newton", false},
       [](const BackendOptions& o) { return batch(OptimizerMethod::GaussNewton, o); }},
      {{"dogleg", "batch Powell's Dogleg", false},
       [](const BackendOptions& o) { return batch(OptimizerMethod::Dogleg, o); }},
      {{"isam2", "incremental Bayes tree (iSAM2): fluid relinearization, wildfire updates", true},
       [](const BackendOptions& o) { return std::make_unique<Isam2Backend>(o); }},
  };
  return entries;
}

}  // namespace

std::unique_ptr<Backend> makeBackend(const std::string& name, const BackendOptions& options) {
  for (const auto& e : registry())
    if (e.info.name == name) return e.make(options);
  std::string known;
  for (const auto& e : registry()) known += (known.empty() ? "" : ", ") + e.info.name;
  throw std::invalid_argument("unknown solver '" + name + "' (known: " + known + ")");
}

std::vector<BackendInfo> availableBackends() {
  std::vector<BackendInfo> out;
  for (const auto& e : registry()) out.push_back(e.info);
  return out;
}

bool isBackendName(const std::string& name) {
  for (const auto& e : registry())
    if (e.info.name == name) return true;
  return false;
}

}  // namespace loopd
