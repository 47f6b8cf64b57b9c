#include "robust/backend_registry.h"

#include <stdexcept>
#include <utility>

#include "robust/gnc_backend.h"
#include "robust/mh_backend.h"
#include "robust/risam_backend.h"
#include "robust/robust_backend.h"
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

// iSAM2 checking for relinearization at every update.
Isam2Options everyUpdate() {
  Isam2Options isam;
  isam.relinearizeSkip = 1;
  return isam;
}

// Robust decorators run over the incremental iSAM2 backend (the batch LM one if a build has
// no "isam2" entry). The kernel/switch/mixture decorators check relinearization at every
// update (relinearizeSkip 1): their weights and choices only refresh when a factor is
// relinearized. riSAM keeps iSAM2's own skip and forces relinearization on its graduation
// steps only (RisamOptions::relinearizeGraduation) and after a step of a radian or a metre
// (Isam2Options::urgentRelinearizeThreshold: its SIG weights follow the estimate).
std::unique_ptr<Backend> robustInner(const BackendOptions& o, Isam2Options isam = everyUpdate()) {
  if (isBackendName("isam2")) return std::make_unique<Isam2Backend>(o, isam);
  return batch(OptimizerMethod::LevenbergMarquardt, o);
}

std::unique_ptr<Backend> decorated(const char* name, RobustMethod m, KernelType k,
                                   const BackendOptions& o, Isam2Options isam = everyUpdate()) {
  RobustBackendOptions r;
  r.method = m;
  r.kernel = k;
  r.parameter = o.robustParameter;
  return std::make_unique<RobustBackend>(name, robustInner(o, isam), r);
}

std::unique_ptr<Backend> gnc(GncLoss loss, const BackendOptions& o) {
  GncOptions g;
  g.loss = loss;
  return std::make_unique<GncBackend>(o, g);
}

std::vector<Entry>& registry() {
  static std::vector<Entry> entries = {
      {{"lm", "batch Levenberg-Marquardt (default)", false},
       [](const BackendOptions& o) { return batch(OptimizerMethod::LevenbergMarquardt, o); }},
      {{"gn", "batch Gauss-Newton", false},
       [](const BackendOptions& o) { return batch(OptimizerMethod::GaussNewton, o); }},
      {{"dogleg", "batch Powell's Dogleg", false},
       [](const BackendOptions& o) { return batch(OptimizerMethod::Dogleg, o); }},
      {{"isam2", "incremental Bayes tree (iSAM2): fluid relinearization, wildfire updates", true},
       [](const BackendOptions& o) { return std::make_unique<Isam2Backend>(o); }},
      {{"huber", "Huber kernel (IRLS) on loop closures, over isam2; k = sqrt(chi2_dim(0.95))",
        true},
       [](const BackendOptions& o) {
         return decorated("huber", RobustMethod::Kernel, KernelType::Huber, o);
       }},
      {{"cauchy", "Cauchy kernel (IRLS) on loop closures, over isam2; k = sqrt(chi2_dim(0.95))",
        true},
       [](const BackendOptions& o) {
         return decorated("cauchy", RobustMethod::Kernel, KernelType::Cauchy, o);
       }},
      {{"gm", "Geman-McClure kernel (IRLS) on loop closures, over isam2; k = sqrt(chi2_dim(0.95))",
        true},
       [](const BackendOptions& o) {
         return decorated("gm", RobustMethod::Kernel, KernelType::GemanMcClure, o);
       }},
      {{"dcs", "dynamic covariance scaling (Agarwal 2013) over isam2; phi = 1", true},
       [](const BackendOptions& o) {
         return decorated("dcs", RobustMethod::Kernel, KernelType::DCS, o);
       }},
      {{"sc", "switchable constraints (Suenderhauf 2012) over isam2; switch prior 1, sigma 1",
        true},
       [](const BackendOptions& o) {
         return decorated("sc", RobustMethod::Switchable, KernelType::DCS, o);
       }},
      {{"mm",
        "max-mixtures (Olson 2013) over isam2; null weight 1e-7, sigma x1.6e7, steps that raise "
        "the mixture's cost cut back",
        true},
       [](const BackendOptions& o) {
         Isam2Options isam = everyUpdate();
         isam.guardSteps = true;
         return decorated("mm", RobustMethod::MaxMixture, KernelType::DCS, o, isam);
       }},
      {{"gnc-gm", "batch GNC, Geman-McClure (Yang 2020); cbar^2 = chi2_dim(0.99), noise-aware gate",
        false},
       [](const BackendOptions& o) { return gnc(GncLoss::GemanMcClure, o); }},
      {{"gnc-tls",
        "batch GNC, truncated least squares (Yang 2020); cbar^2 = chi2_dim(0.99), noise-aware gate",
        false},
       [](const BackendOptions& o) { return gnc(GncLoss::TruncatedLeastSquares, o); }},
      {{"risam",
        "incremental GNC in the riSAM manner (SIG kernel, c = sqrt(chi2_dim(0.95)), noise-aware "
        "test) over isam2",
        true},
       [](const BackendOptions& o) {
         RisamOptions r;
         if (o.robustParameter > 0.0) r.shape = o.robustParameter;
         r.interrupt = o.interrupt;
         r.stopping = o.stopping;
         Isam2Options isam;
         isam.urgentRelinearizeThreshold = 1.0;
         return std::make_unique<RisamBackend>(robustInner(o, isam), r);
       }},
      {{"mh", "multi-hypothesis iSAM2 (MH-iSAM2 manner) for ambiguous measurements; K = 10", true},
       [](const BackendOptions& o) { return std::make_unique<MhBackend>(o, MhOptions{}); }},
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

void registerBackend(BackendInfo info, BackendFactory make) {
  if (info.name.empty() || isBackendName(info.name) || !make)
    throw std::invalid_argument("registerBackend: '" + info.name +
                                "' is empty, taken or has no factory");
  registry().push_back({std::move(info), std::move(make)});
}

bool isBackendName(const std::string& name) {
  for (const auto& e : registry())
    if (e.info.name == name) return true;
  return false;
}

}  // namespace loopd
