// Robust wrappers: Jacobians against central differences (through Values::retract), kernel
// weights at known points, χ² quantiles, and the decorators' bookkeeping.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "robust/backend_registry.h"
#include "robust/robust_backend.h"
#include "robust/robust_factors.h"
#include "solvers/factors/between_factor_se2.h"
#include "solvers/factors/between_factor_se3.h"
#include "solvers/factors/prior_factors.h"

namespace loopd {
namespace {

// Numerical Jacobian of f at values w.r.t. key i (central differences on the retraction).
Eigen::MatrixXd numericJacobian(const Factor& f, const Values& values, int i, double h = 1e-6) {
  const int slot = values.slot(f.key(i));
  const int n = varDim(values.type(slot));
  Eigen::MatrixXd J(f.dim(), n);
  for (int k = 0; k < n; ++k) {
    double d[kMaxVarDim] = {};
    Values p = values, m = values;
    d[k] = h;
    p.retract(slot, d);
    d[k] = -h;
    m.retract(slot, d);
    J.col(k) = (f.whitenedError(p) - f.whitenedError(m)) / (2 * h);
  }
  return J;
}

// Analytic Jacobians of f at values.
std::vector<Eigen::MatrixXd> analyticJacobians(const Factor& f, const Values& values,
                                               Eigen::VectorXd* r = nullptr) {
  std::vector<const double*> x(f.size());
  std::vector<JacobianBlock> blocks(f.size());
  std::vector<double*> J(f.size());
  for (int i = 0; i < f.size(); ++i) {
    x[i] = values.data(values.slot(f.key(i)));
    J[i] = blocks[i].data();
  }
  Eigen::VectorXd res(f.dim());
  f.evaluate(x.data(), res.data(), J.data());
  if (r) *r = res;
  std::vector<Eigen::MatrixXd> out;
  for (int i = 0; i < f.size(); ++i)
    out.push_back(Eigen::Map<Eigen::MatrixXd>(blocks[i].data(), f.dim(), varDim(f.varType(i))));
  return out;
}

struct Fixture2D {
  Values values;
  FactorPtr between;
  Fixture2D(double noise) {
    values.insert(poseKey(0), SE2(0.3, -0.2, 0.4));
    values.insert(poseKey(1), SE2(1.5, 0.7, -0.9));
    Eigen::Matrix3d info;
    info << 20, 2, 1, 2, 30, 0.5, 1, 0.5, 100;
    // Measurement = actual relative pose perturbed by `noise`.
    const SE2 rel = values.se2(0).inverse() * values.se2(1);
    const SE2 z(rel.t().x() + noise, rel.t().y() - 0.5 * noise, rel.theta + 0.3 * noise);
    auto b = std::make_shared<BetweenFactorSE2>(poseKey(0), poseKey(1), z, info);
    b->setId(7);
    between = b;
  }
};

TEST(RobustKernels, WeightsAtKnownPoints) {
  EXPECT_DOUBLE_EQ(kernelWeight(KernelType::Huber, 1.0, 2.0), 1.0);
  EXPECT_DOUBLE_EQ(kernelWeight(KernelType::Huber, 16.0, 2.0), 0.5);
  EXPECT_DOUBLE_EQ(kernelWeight(KernelType::Cauchy, 1.0, 1.0), 0.5);
  EXPECT_DOUBLE_EQ(kernelWeight(KernelType::GemanMcClure, 1.0, 1.0), 0.25);
  EXPECT_DOUBLE_EQ(kernelWeight(KernelType::DCS, 0.5, 1.0), 1.0);
  EXPECT_DOUBLE_EQ(kernelWeight(KernelType::DCS, 3.0, 1.0), 0.25);
  EXPECT_DOUBLE_EQ(kernelWeight(KernelType::GemanMcClure, 0.0, 3.0), 1.0);
  // SIG: μ = 0 is a constant scale c²/(c²+1), μ = 1 is Geman–McClure.
  EXPECT_NEAR(sigWeight(123.0, 0.0, 3.0), 9.0 / 10.0, 1e-12);
  EXPECT_NEAR(sigWeight(4.0, 1.0, 3.0), kernelWeight(KernelType::GemanMcClure, 4.0, 3.0), 1e-12);
  EXPECT_EQ(kernelWeight(KernelType::Cauchy, std::nan(""), 1.0), 0.0);
}

TEST(RobustKernels, ChiSquareQuantiles) {
  EXPECT_NEAR(chi2Quantile(1, 0.95), 3.841459, 1e-5);
  EXPECT_NEAR(chi2Quantile(3, 0.95), 7.814728, 1e-5);
  EXPECT_NEAR(chi2Quantile(3, 0.99), 11.344867, 1e-5);
  EXPECT_NEAR(chi2Quantile(6, 0.99), 16.811894, 1e-5);
  EXPECT_NEAR(chi2Quantile(2, 0.5), 1.386294, 1e-5);
  EXPECT_NEAR(defaultKernelParameter(KernelType::Huber, 3), std::sqrt(7.814728), 1e-5);
  EXPECT_EQ(defaultKernelParameter(KernelType::DCS, 3), 1.0);
}

TEST(RobustFactors, KernelJacobiansAreFrozenWeightIrls) {
  for (double noise : {0.01, 0.5, 3.0})
    for (KernelType k :
         {KernelType::Huber, KernelType::Cauchy, KernelType::GemanMcClure, KernelType::DCS}) {
      Fixture2D fx(noise);
      auto kf = KernelFactor::make(fx.between, k);
      EXPECT_EQ(kf->id(), 7u);
      EXPECT_EQ(kf->role(), FactorRole::LoopClosure);
      const double chi2 = fx.between->chi2(fx.values);
      const double w = kernelWeight(k, chi2, defaultKernelParameter(k, 3));
      EXPECT_NEAR(kf->weightAt(fx.values), w, 1e-12);
      Eigen::VectorXd r;
      const auto J = analyticJacobians(*kf, fx.values, &r);
      EXPECT_NEAR(r.squaredNorm(), w * chi2, 1e-9 * (1 + chi2));
      for (int i = 0; i < 2; ++i) {
        const Eigen::MatrixXd Jn = std::sqrt(w) * numericJacobian(*fx.between, fx.values, i);
        EXPECT_LT((J[i] - Jn).norm(), 1e-6 * (1 + Jn.norm())) << kernelName(k) << " " << noise;
      }
      auto c = kf->clone();
      EXPECT_NEAR(c->chi2(fx.values), kf->chi2(fx.values), 1e-12);
    }
}

TEST(RobustFactors, SwitchableExactJacobiansIncludingSwitch) {
  for (double s : {0.0, 0.3, 0.7, 1.0}) {
    Fixture2D fx(0.4);
    const Key sk = makeKey(0, KeyKind::Switch, 0);
    fx.values.insertScalar(sk, s);
    auto sf = SwitchableFactor::make(fx.between, sk);
    ASSERT_EQ(sf->size(), 3);
    EXPECT_EQ(sf->switchKey(), sk);
    Eigen::VectorXd r;
    const auto J = analyticJacobians(*sf, fx.values, &r);
    const Eigen::VectorXd r0 = fx.between->whitenedError(fx.values);
    EXPECT_LT((r - s * r0).norm(), 1e-12);
    // ∂/∂s = r (the unscaled error), not Ψ·r (Vertigo's bug).
    EXPECT_LT((J[2] - r0).norm(), 1e-12);
    if (s > 0.0 && s < 1.0) {
      for (int i = 0; i < 3; ++i) {
        const Eigen::MatrixXd Jn = numericJacobian(*sf, fx.values, i);
        EXPECT_LT((J[i] - Jn).norm(), 1e-6 * (1 + Jn.norm())) << "key " << i << " s " << s;
      }
    } else {
      for (int i = 0; i < 2; ++i)  // pose blocks are exact at the ends too
        EXPECT_LT((J[i] - s * numericJacobian(*fx.between, fx.values, i)).norm(), 1e-6 * 100);
    }
  }
  SwitchPriorFactor p(makeKey(0, KeyKind::Switch, 0), 1.0, 2.0);
  Values v;
  v.insertScalar(makeKey(0, KeyKind::Switch, 0), 0.2);
  Eigen::VectorXd r;
  const auto J = analyticJacobians(p, v, &r);
  EXPECT_NEAR(r[0], (0.2 - 1.0) / 2.0, 1e-15);
  EXPECT_NEAR(J[0](0, 0), numericJacobian(p, v, 0)(0, 0), 1e-8);
  EXPECT_EQ(p.role(), FactorRole::Odometry);  // trusted, and never removes the batch gauge
}

TEST(RobustFactors, MaxMixtureChoosesByNormalizedCost) {
  Fixture2D small(0.01), big(30.0);
  auto a = MaxMixtureFactor::make(small.between);
  auto b = MaxMixtureFactor::make(big.between);
  // Threshold: ½χ²(1 − 1/σ²) > 3·ln σ − ln w.
  EXPECT_NEAR(a->switchChi2(), 2.0 * (3.0 * std::log(1.6e7) - std::log(1e-7)), 1e-6);
  EXPECT_FALSE(a->nullChosenAt(small.values));
  EXPECT_TRUE(b->nullChosenAt(big.values));
  EXPECT_NEAR(a->chi2(small.values), small.between->chi2(small.values), 1e-12);
  EXPECT_NEAR(b->chi2(big.values), big.between->chi2(big.values) / (1.6e7 * 1.6e7), 1e-12);
  for (auto* fx : {&small, &big}) {
    auto m = MaxMixtureFactor::make(fx->between);
    const auto J = analyticJacobians(*m, fx->values);
    for (int i = 0; i < 2; ++i) {
      const Eigen::MatrixXd Jn = numericJacobian(*m, fx->values, i);
      EXPECT_LT((J[i] - Jn).norm(), 1e-6 * (1 + Jn.norm()));
    }
  }
}

double objectiveAt(const Factor& f, const Values& values) {
  std::vector<const double*> x(f.size());
  for (int i = 0; i < f.size(); ++i) x[i] = values.data(values.slot(f.key(i)));
  return f.objective(x.data());
}

// ρ(χ²) is what IRLS minimises: its slope in χ² is the weight, and it starts at 0 with slope 1.
TEST(RobustKernels, CostIsTheIntegralOfTheWeight) {
  for (KernelType k :
       {KernelType::Huber, KernelType::Cauchy, KernelType::GemanMcClure, KernelType::DCS}) {
    const double p = defaultKernelParameter(k, 3);
    EXPECT_EQ(kernelCost(k, 0.0, p), 0.0) << kernelName(k);
    for (double c : {0.3, 0.9, 1.7, 5.0, 20.0, 400.0}) {
      const double h = 1e-5 * c;
      const double slope = (kernelCost(k, c + h, p) - kernelCost(k, c - h, p)) / (2 * h);
      EXPECT_NEAR(slope, kernelWeight(k, c, p), 1e-6) << kernelName(k) << " at " << c;
    }
  }
  EXPECT_DOUBLE_EQ(kernelCost(KernelType::DCS, 1.0, 1.0), 1.0);  // continuous at χ² = Φ
  EXPECT_DOUBLE_EQ(kernelCost(KernelType::DCS, 3.0, 1.0), 2.0);  // Φ(3χ² − Φ)/(Φ + χ²)
  EXPECT_DOUBLE_EQ(kernelCost(KernelType::GemanMcClure, INFINITY, 2.0), 4.0);
  Fixture2D fx(3.0);
  const auto kf = KernelFactor::make(fx.between, KernelType::Cauchy);
  const double p = defaultKernelParameter(KernelType::Cauchy, 3);
  EXPECT_NEAR(objectiveAt(*kf, fx.values),
              kernelCost(KernelType::Cauchy, fx.between->chi2(fx.values), p), 1e-12);
  EXPECT_NEAR(objectiveAt(*fx.between, fx.values), fx.between->chi2(fx.values), 1e-12);
}

// A max-mixture's objective is its better component's −2 ln, relative to the inlier's
// normaliser: χ² up to the switch point, then the null's χ²/σ₀² plus its normaliser.
TEST(RobustFactors, MaxMixtureObjectiveIsTheBetterComponentsCost) {
  for (double noise : {0.01, 1.0, 30.0}) {
    Fixture2D fx(noise);
    const auto m = MaxMixtureFactor::make(fx.between);
    const double c = fx.between->chi2(fx.values), s2 = 1.6e7 * 1.6e7;
    const double null = c / s2 + 2.0 * (3.0 * std::log(1.6e7) - std::log(1e-7));
    EXPECT_NEAR(objectiveAt(*m, fx.values), std::min(c, null), 1e-9 * (1 + c)) << noise;
    EXPECT_EQ(c > m->switchChi2(), noise == 30.0);  // both branches seen
  }
}

// Where a held factor's bound is checked: points around the fixture's values, near and far,
// and where pose 1 agrees with the measurement (χ² = 0).
std::vector<Values> pointsAround(const Fixture2D& fx) {
  std::vector<Values> ys;
  for (double step : {-2.0, -0.7, -0.05, 0.05, 0.3, 1.0, 3.0}) {
    ys.push_back(fx.values);
    const double d[3] = {step, -0.5 * step, 0.3 * step};
    ys.back().retract(1, d);
  }
  ys.push_back(fx.values);
  ys.back().set(1, fx.values.se2(0) * static_cast<const BetweenFactorSE2&>(*fx.between).measured());
  return ys;
}

// heldAt (isam2's optimize() falls back to minimising the held least squares): the component
// chosen at x, as its inner factor at weight 1 or 1/σ₀², bounds the objective from above up to
// a constant and touches it at x, on both sides of the switch point. Least squares hold nothing.
TEST(RobustFactors, MaxMixtureHeldAtBoundsItsObjectiveFromAbove) {
  for (double noise : {0.01, 1.0, 30.0}) {
    Fixture2D fx(noise);
    const auto m = MaxMixtureFactor::make(fx.between);
    std::vector<const double*> x{fx.values.data(0), fx.values.data(1)};
    FactorPtr inner;
    double w = 0.0;
    ASSERT_TRUE(m->heldAt(x.data(), inner, w));
    EXPECT_EQ(inner, fx.between);
    const bool null = fx.between->chi2(fx.values) > m->switchChi2();
    EXPECT_EQ(w, null ? 1.0 / (1.6e7 * 1.6e7) : 1.0) << noise;
    const double k = objectiveAt(*m, fx.values) - w * fx.between->chi2(fx.values);
    int crossed = 0;
    for (const Values& y : pointsAround(fx)) {
      const double c = fx.between->chi2(y);
      crossed += (c > m->switchChi2()) != null;
      EXPECT_LE(objectiveAt(*m, y), w * c + k + 1e-9 * (1.0 + c)) << noise << " at χ² " << c;
    }
    EXPECT_GT(crossed, 0) << noise;  // the bound is tested across the switch point too
  }
  FactorPtr inner;
  double w = 0.0;
  Fixture2D fx(1.0);
  std::vector<const double*> x{fx.values.data(0), fx.values.data(1)};
  EXPECT_FALSE(fx.between->heldAt(x.data(), inner, w));
}

// A kernel held at x (its IRLS weight ρ'(χ²) there) bounds ρ from above up to a constant and
// touches it at x, for every kernel: ρ is concave in χ², on each side of the kernels' bends.
TEST(RobustFactors, KernelHeldAtBoundsItsObjectiveFromAbove) {
  for (KernelType kernel :
       {KernelType::Huber, KernelType::Cauchy, KernelType::GemanMcClure, KernelType::DCS}) {
    for (double noise : {0.01, 1.0, 30.0}) {
      Fixture2D fx(noise);
      const auto k = KernelFactor::make(fx.between, kernel);
      std::vector<const double*> x{fx.values.data(0), fx.values.data(1)};
      FactorPtr inner;
      double w = 0.0;
      ASSERT_TRUE(k->heldAt(x.data(), inner, w));
      EXPECT_EQ(inner, fx.between);
      const double c0 = fx.between->chi2(fx.values);
      EXPECT_EQ(w, kernelWeight(kernel, c0, k->parameter()));
      const double offset = objectiveAt(*k, fx.values) - w * c0;
      for (const Values& y : pointsAround(fx)) {
        const double c = fx.between->chi2(y);
        EXPECT_LE(objectiveAt(*k, y), w * c + offset + 1e-9 * (1.0 + c))
            << kernelName(kernel) << " " << noise << " at χ² " << c;
      }
    }
  }
}

TEST(RobustFactors, WeightedAndGraduatedJacobians) {
  Fixture2D fx(0.7);
  auto w = WeightedFactor::make(fx.between, 0.36);
  const auto Jw = analyticJacobians(*w, fx.values);
  for (int i = 0; i < 2; ++i)
    EXPECT_LT((Jw[i] - 0.6 * numericJacobian(*fx.between, fx.values, i)).norm(), 1e-5);
  for (double mu : {0.0, 0.384, 1.0}) {
    auto g = GraduatedFactor::make(fx.between, mu, 3.0);
    const double wt = sigWeight(fx.between->chi2(fx.values), mu, 3.0);
    EXPECT_NEAR(g->weightAt(fx.values), wt, 1e-12);
    const auto J = analyticJacobians(*g, fx.values);
    for (int i = 0; i < 2; ++i)
      EXPECT_LT((J[i] - std::sqrt(wt) * numericJacobian(*fx.between, fx.values, i)).norm(), 1e-5);
  }
}

TEST(RobustFactors, SE3WrappersJacobians) {
  std::mt19937 rng(3);
  std::normal_distribution<double> n(0, 0.3);
  Values v;
  Vec6 a, b, z;
  for (int k = 0; k < 6; ++k) a[k] = n(rng), b[k] = n(rng) + 1, z[k] = n(rng);
  v.insert(poseKey(0), expSE3(a));
  v.insert(poseKey(1), expSE3(b));
  const Key sk = makeKey(0, KeyKind::Switch, 3);
  v.insertScalar(sk, 0.6);
  Mat6 info = Mat6::Identity() * 10;
  info(0, 1) = info(1, 0) = 2;
  auto inner = std::make_shared<BetweenFactorSE3>(poseKey(0), poseKey(1), expSE3(z), info);
  std::vector<FactorPtr> wrappers = {KernelFactor::make(inner, KernelType::Cauchy),
                                     SwitchableFactor::make(inner, sk),
                                     MaxMixtureFactor::make(inner)};
  const double w = kernelWeight(KernelType::Cauchy, inner->chi2(v),
                                defaultKernelParameter(KernelType::Cauchy, 6));
  for (size_t f = 0; f < wrappers.size(); ++f) {
    const auto J = analyticJacobians(*wrappers[f], v);
    for (int i = 0; i < wrappers[f]->size(); ++i) {
      Eigen::MatrixXd Jn = numericJacobian(*wrappers[f], v, i);
      if (f == 0) Jn = std::sqrt(w) * numericJacobian(*inner, v, i);
      EXPECT_LT((J[i] - Jn).norm(), 1e-5 * (1 + Jn.norm())) << "wrapper " << f << " key " << i;
    }
  }
}

TEST(RobustRegistry, EveryVariantIsRegistered) {
  for (const char* n : {"huber", "cauchy", "gm", "dcs", "sc", "mm", "gnc-gm", "gnc-tls", "risam"}) {
    EXPECT_TRUE(isBackendName(n)) << n;
    auto b = makeBackend(n);
    EXPECT_EQ(b->name(), n);
  }
}

TEST(RobustBackendDecorator, SwitchableBookkeepingAndRemoval) {
  auto b = makeBackend("sc");
  BackendUpdate u;
  u.initial.insert(poseKey(0), SE2(0, 0, 0));
  u.initial.insert(poseKey(1), SE2(1, 0, 0));
  u.initial.insert(poseKey(2), SE2(2, 0, 0));
  auto o1 =
      std::make_shared<BetweenFactorSE2>(poseKey(0), poseKey(1), SE2(1, 0, 0),
                                         Eigen::Matrix3d::Identity() * 100, FactorRole::Odometry);
  o1->setId(0);
  auto o2 =
      std::make_shared<BetweenFactorSE2>(poseKey(1), poseKey(2), SE2(1, 0, 0),
                                         Eigen::Matrix3d::Identity() * 100, FactorRole::Odometry);
  o2->setId(1);
  auto good = std::make_shared<BetweenFactorSE2>(poseKey(0), poseKey(2), SE2(2, 0, 0),
                                                 Eigen::Matrix3d::Identity() * 10);
  good->setId(2);
  auto bad = std::make_shared<BetweenFactorSE2>(poseKey(0), poseKey(2), SE2(-5, 3, 2.0),
                                                Eigen::Matrix3d::Identity() * 10);
  bad->setId(3);
  u.factors = {o1, o2, good, bad};
  b->update(u);
  b->optimize();
  EXPECT_EQ(b->graph().size(), 4);  // the original factors, no switch priors
  EXPECT_NEAR(b->chi2(), b->graph().chi2(b->estimate()), 1e-12);
  const auto rej = b->rejected();
  ASSERT_EQ(rej.size(), 1u);
  EXPECT_EQ(rej[0], 3u);
  EXPECT_EQ(b->decisions().size(), 2u);
  BackendUpdate r;
  r.removals = {3};
  b->update(r);
  EXPECT_EQ(b->graph().size(), 3);
  EXPECT_TRUE(b->rejected().empty());
  // An invalid update leaves it unchanged.
  BackendUpdate badU;
  badU.removals = {99};
  EXPECT_THROW(b->update(badU), std::invalid_argument);
  EXPECT_EQ(b->graph().size(), 3);
}

// A tiny 2D graph: a 3-pose chain, one good and one bad loop closure (ids 2 and 3).
BackendUpdate tinyGraph() {
  BackendUpdate u;
  u.initial.insert(poseKey(0), SE2(0, 0, 0));
  u.initial.insert(poseKey(1), SE2(1, 0, 0));
  u.initial.insert(poseKey(2), SE2(2, 0, 0));
  auto odo = [](int id, int a, int b) {
    auto f =
        std::make_shared<BetweenFactorSE2>(poseKey(a), poseKey(b), SE2(1, 0, 0),
                                           Eigen::Matrix3d::Identity() * 100, FactorRole::Odometry);
    f->setId(id);
    return f;
  };
  auto good = std::make_shared<BetweenFactorSE2>(poseKey(0), poseKey(2), SE2(2, 0, 0),
                                                 Eigen::Matrix3d::Identity() * 10);
  good->setId(2);
  auto bad = std::make_shared<BetweenFactorSE2>(poseKey(0), poseKey(2), SE2(-5, 3, 2.0),
                                                Eigen::Matrix3d::Identity() * 10);
  bad->setId(3);
  u.factors = {odo(0, 0, 1), odo(1, 1, 2), good, bad};
  return u;
}

TEST(RobustBackendDecorator, EveryVariantRejectsTheBadClosureAndHandlesRemoval) {
  for (const char* n : {"dcs", "sc", "mm", "gm", "cauchy", "gnc-gm", "gnc-tls", "risam"}) {
    auto b = makeBackend(n);
    b->update(tinyGraph());
    b->optimize();
    EXPECT_EQ(b->graph().size(), 4) << n;
    EXPECT_NEAR(b->chi2(), b->graph().chi2(b->estimate()), 1e-9) << n;
    const auto rej = b->rejected();
    ASSERT_EQ(rej.size(), 1u) << n;
    EXPECT_EQ(rej[0], 3u) << n;
    EXPECT_EQ(b->decisions().size(), 2u) << n;
    // Remove the bad closure, then re-add the good one under a new id in one update.
    BackendUpdate r;
    r.removals = {3, 2};
    auto again = std::make_shared<BetweenFactorSE2>(poseKey(0), poseKey(2), SE2(2, 0, 0),
                                                    Eigen::Matrix3d::Identity() * 10);
    again->setId(2);
    r.factors = {again};
    b->update(r);
    EXPECT_EQ(b->graph().size(), 3) << n;
    EXPECT_TRUE(b->rejected().empty()) << n;
    EXPECT_LT(b->chi2(), 1e-6) << n;
    EXPECT_THROW(b->update(BackendUpdate{{}, {}, {42}}), std::invalid_argument) << n;
    EXPECT_EQ(b->graph().size(), 3) << n;
  }
}

TEST(RobustBackendDecorator, RejectsReservedIds) {
  for (const char* n : {"dcs", "risam"}) {
    auto b = makeBackend(n);
    BackendUpdate u = tinyGraph();
    std::const_pointer_cast<Factor>(u.factors[3])->setId(RobustBackend::kInternalIdBit | 3);
    EXPECT_THROW(b->update(u), std::invalid_argument) << n;
  }
}

}  // namespace
}  // namespace loopd
