// riSAM's SIG wrapper: residual and Jacobians scaled by √w, w taken at the estimate it is
// pointed at (or at the evaluation point where that lacks a variable), μ changed in place.
#include "robust/risam_sig_factor.h"

#include <gtest/gtest.h>

#include <cmath>

#include "solvers/factors/between_factor_se2.h"

using namespace loopd;

namespace {

// Residual (0.3, 0, 0) at a = identity, b = (0.3, 0, 0): χ² = 100·0.09 = 9.
FactorPtr closure() {
  auto f =
      std::make_shared<BetweenFactorSE2>(makeKey(0, KeyKind::Pose, 0), makeKey(0, KeyKind::Pose, 5),
                                         SE2(0, 0, 0), Eigen::Matrix3d::Identity() * 100.0);
  f->setId(3);
  return f;
}

double gm(double chi2, double c) { return std::pow(c * c / (c * c + chi2), 2); }

struct Evaluated {
  double chi2 = 0.0;
  Eigen::Matrix3d Ja, Jb;
};

Evaluated evaluate(const Factor& f, const SE2& a, const SE2& b) {
  Values v;
  v.insert(f.key(0), a);
  v.insert(f.key(1), b);
  const double* x[2] = {v.data(0), v.data(1)};
  double r[3];
  Evaluated e;
  double* J[2] = {e.Ja.data(), e.Jb.data()};
  f.evaluate(x, r, J);
  e.chi2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2];
  return e;
}

}  // namespace

TEST(RisamSigFactor, ScalesResidualAndJacobiansBySigWeight) {
  const FactorPtr inner = closure();
  const SigShape shape{2.0, 1.0};
  const FactorPtr w = makeRisamSig(inner, 1.0, shape, nullptr, 77);
  EXPECT_EQ(w->id(), 77);
  EXPECT_EQ(w->size(), 2);
  EXPECT_EQ(w->role(), inner->role());
  const SE2 a, b(0.3, 0, 0);
  const Evaluated plain = evaluate(*inner, a, b), sig = evaluate(*w, a, b);
  ASSERT_NEAR(plain.chi2, 9.0, 1e-12);
  // μ = 1 is Geman–McClure: w = (c²/(c² + χ²))².
  EXPECT_NEAR(sig.chi2, gm(9.0, 2.0) * 9.0, 1e-12);
  const double s = std::sqrt(gm(9.0, 2.0));
  EXPECT_TRUE(sig.Ja.isApprox(s * plain.Ja, 1e-12));
  EXPECT_TRUE(sig.Jb.isApprox(s * plain.Jb, 1e-12));
  // μ = 0 is convex: w = c²/(c² + 1) whatever χ² is.
  static_cast<const RisamSigFactor&>(*w).setMu(0.0);
  EXPECT_NEAR(evaluate(*w, a, b).chi2, 4.0 / 5.0 * 9.0, 1e-12);
  // chi2Scale scales χ² inside the kernel only.
  const FactorPtr scaled = makeRisamSig(inner, 1.0, SigShape{2.0, 10.0}, nullptr, 78);
  EXPECT_NEAR(evaluate(*scaled, a, b).chi2, gm(90.0, 2.0) * 9.0, 1e-12);
}

TEST(RisamSigFactor, WeightIsTakenAtTheEstimateWhereItHasEveryVariable) {
  const FactorPtr inner = closure();
  Values estimate;  // χ² 0 there: weight 1 at μ = 1
  estimate.insert(inner->key(0), SE2());
  estimate.insert(inner->key(1), SE2());
  const FactorPtr w = makeRisamSig(inner, 1.0, SigShape{2.0, 1.0}, &estimate, 5);
  const SE2 a, b(0.3, 0, 0);
  EXPECT_NEAR(evaluate(*w, a, b).chi2, 9.0, 1e-12);
  // Moved at the estimate: its χ² there (100·0.6² = 36) sets the weight.
  estimate.set(estimate.slot(inner->key(1)), SE2(0.6, 0, 0));
  EXPECT_NEAR(evaluate(*w, a, b).chi2, gm(36.0, 2.0) * 9.0, 1e-12);

  Values partial;  // lacks the second pose: the evaluation point's χ² (9) is used
  partial.insert(inner->key(0), SE2());
  const FactorPtr fallback = makeRisamSig(inner, 1.0, SigShape{2.0, 1.0}, &partial, 6);
  EXPECT_NEAR(evaluate(*fallback, a, b).chi2, gm(9.0, 2.0) * 9.0, 1e-12);
}

TEST(RisamSigFactor, CloneIsIndependentOfTheOriginalsMu) {
  const FactorPtr w = makeRisamSig(closure(), 1.0, SigShape{2.0, 1.0}, nullptr, 9);
  const std::unique_ptr<Factor> c = w->clone();
  static_cast<const RisamSigFactor&>(*w).setMu(0.0);
  const SE2 a, b(0.3, 0, 0);
  EXPECT_NEAR(evaluate(*c, a, b).chi2, gm(9.0, 2.0) * 9.0, 1e-12);
  EXPECT_NEAR(evaluate(*w, a, b).chi2, 0.8 * 9.0, 1e-12);
  EXPECT_STREQ(c->typeName(), "Graduated");
}
