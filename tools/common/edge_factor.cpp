#include "tools/common/edge_factor.h"

#include "client/factor_publisher.h"

namespace loopd::tools {

loopd::factor_t edgeFactor(const io::Edge& e, int ra, int rb, bool odometry) {
  using client::KeyRef;
  const int d = io::edgeDimension(e.type);
  const Eigen::MatrixXd info = e.information.topLeftCorner(d, d);
  loopd::factor_t f{};
  f.id = e.index;
  f.noise_kind = loopd::factor_t::NOISE_INFORMATION;
  f.noise = client::upperTriangle(info.data(), d);
  f.num_noise = static_cast<std::int16_t>(f.noise.size());
  f.measurement.assign(e.measurement.begin(),
                       e.measurement.begin() + io::edgeMeasurementSize(e.type));
  f.num_measurement = static_cast<std::int16_t>(f.measurement.size());
  f.robust = "";
  if (io::isBetween(e.type)) {
    f.type = e.type == io::EdgeType::BetweenSE2 ? loopd::factor_t::BETWEEN_SE2
                                                : loopd::factor_t::BETWEEN_SE3;
    f.role = odometry ? loopd::factor_t::ROLE_ODOMETRY : loopd::factor_t::ROLE_LOOP_CLOSURE;
    f.keys = {client::wireKey(KeyRef::pose(ra, e.from)), client::wireKey(KeyRef::pose(rb, e.to))};
  } else {
    f.type = e.type == io::EdgeType::PosePoint2   ? loopd::factor_t::POSE_POINT2
             : e.type == io::EdgeType::PosePoint3 ? loopd::factor_t::POSE_POINT3
                                                  : loopd::factor_t::BEARING_RANGE2;
    f.role = loopd::factor_t::ROLE_LANDMARK;
    f.keys = {client::wireKey(KeyRef::pose(ra, e.from)), client::wireKey(KeyRef::point(ra, e.to))};
  }
  f.num_keys = static_cast<std::int16_t>(f.keys.size());
  return f;
}

}  // namespace loopd::tools
