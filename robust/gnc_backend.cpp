#include "robust/gnc_backend.h"

#include <algorithm>
#include <cmath>

#include "robust/gnc_run.h"
#include "robust/robust_factors.h"
#include "solvers/init/initialization.h"

namespace loopd {

GncBackend::GncBackend(BackendOptions options, GncOptions gnc)
    : BatchBackend(std::move(options)), gnc_(std::move(gnc)) {
  // Every solve reports each iteration (BatchBackend hands progress to its optimizer): the
  // interrupt is asked there.
  if (gnc_.interrupt)
    options_.progress = [report = std::move(options_.progress),
                         checkpoint = interruptCheckpoint()](const IterationReport& r) {
      if (report) report(r);
      checkpoint();
    };
}

std::function<void()> GncBackend::interruptCheckpoint() const {
  if (!gnc_.interrupt) return {};
  return [interrupt = gnc_.interrupt] {
    if (interrupt()) throw GncInterrupted();
  };
}

std::string GncBackend::name() const {
  return gnc_.loss == GncLoss::GemanMcClure ? "gnc-gm" : "gnc-tls";
}

double GncBackend::barc2(const Factor& f) const {
  if (options_.robustParameter > 0.0) return options_.robustParameter;
  return chi2Quantile(std::max(f.dim(), 1), gnc_.inlierProbability);
}

void GncBackend::updateWeights(const std::vector<double>& r2, const std::vector<double>& c2) {
  for (int i = 0; i < graph_.size(); ++i) {
    if (c2[i] <= 0.0) {
      weights_[i] = 1.0;
      continue;
    }
    const double r = r2[i], c = c2[i];
    if (gnc_.loss == GncLoss::GemanMcClure) {
      const double a = mu_ * c;
      weights_[i] = (a / (r + a)) * (a / (r + a));
    } else {
      const double lower = mu_ / (mu_ + 1.0) * c, upper = (mu_ + 1.0) / mu_ * c;
      if (r <= lower)
        weights_[i] = 1.0;
      else if (r >= upper)
        weights_[i] = 0.0;
      else
        weights_[i] = std::clamp(std::sqrt(c / r) * std::sqrt(mu_ * (mu_ + 1.0)) - mu_, 0.0, 1.0);
    }
  }
}

Values GncBackend::trustedLinearStart(const std::vector<char>& alsoUse) const {
  FactorGraph trusted;
  for (int i = 0; i < graph_.size(); ++i)
    if (!isUncertain(graph_[i]->role()) || (!alsoUse.empty() && alsoUse[i])) trusted.add(graph_[i]);
  return initializeLinearFromLowestPose(trusted, estimate_);
}

bool GncBackend::someVariableUntrusted() const {
  std::vector<char> touched(static_cast<std::size_t>(estimate_.size()), 0);
  for (int i = 0; i < graph_.size(); ++i) {
    if (isUncertain(graph_[i]->role())) continue;
    for (int k = 0; k < graph_[i]->size(); ++k) {
      const int slot = estimate_.slot(graph_[i]->key(k));
      if (slot >= 0) touched[static_cast<std::size_t>(slot)] = 1;
    }
  }
  return std::find(touched.begin(), touched.end(), 0) != touched.end();
}

void GncBackend::optimize() {
  if (graph_.empty()) return;
  // The odometry start: the trusted factors' linear initialization (recomputed on every run;
  // empty if there is none), one of the GNC's starting points.
  Values odometryStart;
  bool batchStartCandidate = false;  // the first solve started from the trusted factors
  const bool wantOdometryStart = gnc_.odometryStart && gnc_.trustedInitialization;
  if (wantOdometryStart) odometryStart = trustedLinearStart();
  // The first solve only: the flag is cleared below.
  if (options_.linearInitialization && gnc_.trustedInitialization) {
    // Linear initialization from the trusted factors only; the base class must not redo it
    // with the outliers included.
    Values start = odometryStart.size() > 0 ? odometryStart : trustedLinearStart();
    // A variable no trusted factor touches (a landmark seen only through sightings) would
    // start where the file put it, at the end of dead-reckoned headings: the first pass, a
    // least-squares solve with every factor, then starts from the batch solvers' start.
    if (someVariableUntrusted())
      start = initializeLinearFromLowestPose(graph_, estimate_);
    else
      batchStartCandidate = gnc_.batchStartWhenNoneRejected && start.size() > 0;
    if (start.size() > 0) estimate_ = start;
    options_.linearInitialization = false;
  }

  Run(*this, std::move(odometryStart), batchStartCandidate).execute();
}

std::vector<std::pair<FactorId, double>> GncBackend::decisions() const {
  std::vector<std::pair<FactorId, double>> out;
  const bool have = weights_.size() == static_cast<size_t>(graph_.size());
  for (int i = 0; i < graph_.size(); ++i)
    if (isUncertain(graph_[i]->role())) out.emplace_back(graph_[i]->id(), have ? weights_[i] : 1.0);
  return out;
}

std::vector<FactorId> GncBackend::rejected() const {
  std::vector<FactorId> out;
  const double below = gnc_.rejectBelow > 0.0               ? gnc_.rejectBelow
                       : gnc_.loss == GncLoss::GemanMcClure ? 0.25
                                                            : 0.5;
  for (const auto& [id, w] : decisions())
    if (w < below) out.push_back(id);
  return out;
}

}  // namespace loopd
