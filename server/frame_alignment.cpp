#include "server/frame_alignment.h"

#include <Eigen/Geometry>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>

namespace loopd::server {

namespace {
constexpr double kDegenerate = 1e-9;

// Points as columns: (source inS, destination inR); false if any number is not finite.
template <int N, class Pair>
bool columns(const std::vector<Pair>& pairs, Eigen::Matrix<double, N, Eigen::Dynamic>& src,
             Eigen::Matrix<double, N, Eigen::Dynamic>& dst) {
  const auto n = static_cast<Eigen::Index>(pairs.size());
  src.resize(N, n);
  dst.resize(N, n);
  for (Eigen::Index i = 0; i < n; ++i) {
    src.col(i) = pairs[static_cast<size_t>(i)].inS;
    dst.col(i) = pairs[static_cast<size_t>(i)].inR;
  }
  return src.allFinite() && dst.allFinite();
}
}  // namespace

std::optional<SE2> alignFrames(const std::vector<PointPair2>& pairs) {
  Eigen::Matrix<double, 2, Eigen::Dynamic> src, dst;
  if (pairs.size() < 2 || !columns<2>(pairs, src, dst)) return std::nullopt;
  const Vec2 centroid = src.rowwise().mean();
  const double spread = (src.colwise() - centroid).colwise().norm().maxCoeff();
  const double extent = src.colwise().norm().maxCoeff();
  if (!(spread > kDegenerate * (1.0 + extent))) return std::nullopt;
  const Eigen::Matrix3d T = Eigen::umeyama(src, dst, false);
  if (!T.allFinite()) return std::nullopt;
  return SE2(T(0, 2), T(1, 2), std::atan2(T(1, 0), T(0, 0)));
}

std::optional<SE3> alignFrames(const std::vector<PointPair3>& pairs) {
  Eigen::Matrix<double, 3, Eigen::Dynamic> src, dst;
  if (pairs.size() < 3 || !columns<3>(pairs, src, dst)) return std::nullopt;
  const Vec3 centroid = src.rowwise().mean();
  const Eigen::Matrix<double, 3, Eigen::Dynamic> centred = src.colwise() - centroid;
  const Eigen::JacobiSVD<Eigen::Matrix<double, 3, Eigen::Dynamic>> svd(centred);
  const Vec3 sigma = svd.singularValues();  // decreasing
  if (!(sigma[1] > kDegenerate * (1.0 + sigma[0]))) return std::nullopt;
  const Eigen::Matrix4d T = Eigen::umeyama(src, dst, false);
  if (!T.allFinite()) return std::nullopt;
  return SE3(T.topLeftCorner<3, 3>(), T.topRightCorner<3, 1>());
}

}  // namespace loopd::server
