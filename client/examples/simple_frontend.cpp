// A minimal loopd front-end: a robot drives around a square, publishes its odometry one pose at
// a time, closes the loop when it is back at the start, and prints the corrected trajectory.
//
//   loopd &                                # the server, default LCM URL and channels
//   loopd-simple-frontend [LCM_URL]
#include <lcm/lcm-cpp.hpp>

#include <cmath>
#include <cstdio>
#include <map>

#include "client/estimate_subscriber.h"
#include "client/factor_publisher.h"

using loopd::client::KeyRef;
using loopd::client::Pose2;

int main(int argc, char** argv) {
  lcm::LCM lcm(loopd::client::receiveUrl(argc > 1 ? argv[1] : ""));  // + recv_buf_size
  if (!lcm.good()) return 1;

  // One publisher per front-end: its sender name is the id space of its factors and sequences.
  loopd::client::FactorPublisher pub(lcm, "robot0/odometry");
  // The subscriber keeps the latest estimate of every robot (the server publishes after each
  // update).
  loopd::client::EstimateSubscriber sub(lcm);
  // Decisions arrive as deltas in status messages: keep the ambiguous ones (id → alternative).
  std::map<long long, int> chosen;
  sub.onStatus([&](const loopd::status_t& s) {
    for (const auto& d : s.decisions)
      if (d.ambiguous) chosen[d.factor_id] = d.alternative;
  });

  const Eigen::Matrix3d info =
      Eigen::Vector3d(100, 100, 1000).asDiagonal();  // information, not covariance
  const int robot = 0, steps = 16;
  for (int i = 1; i <= steps; ++i) {
    // 1 m forward, and a quarter turn at every corner (with a little drift).
    const Pose2 step{1.02, 0.0, (i % 4 == 0) ? M_PI / 2 + 0.01 : 0.0};
    pub.odometry(robot, i - 1, i, step, info);  // the server composes the new pose's initial value
    pub.flush();                                // one batch (sequence i) per pose
    lcm.handleTimeout(50);                      // let estimates arrive
  }
  // Back at the start: a loop closure (robust handling "" = the server's default for closures).
  // A server running `--solver mh` can be told what the place recognition really knows: the
  // start and the first corner look alike, so it is one of the two (or neither).
  if (sub.lastStatus().solver == "mh") {
    using loopd::client::loopClosureFactor;
    pub.ambiguous(loopd::ambiguous_factor_t::MULTI_ASSOCIATION,
                  {loopClosureFactor(KeyRef::pose(robot, steps), KeyRef::pose(robot, 0),
                                     Pose2{0, 0, 0}, info),
                   loopClosureFactor(KeyRef::pose(robot, steps), KeyRef::pose(robot, 4),
                                     Pose2{0, 0, 0}, info)},
                  /*nullHypothesis=*/true);
  } else {
    pub.loopClosure(KeyRef::pose(robot, steps), KeyRef::pose(robot, 0), Pose2{0, 0, 0}, info);
  }
  pub.flush();

  // Wait for the estimate that includes the closure (the server publishes the moved poses).
  for (int i = 0; i < 40 && sub.robot(robot).poses.size() < steps + 1; ++i) lcm.handleTimeout(100);
  for (int i = 0; i < 10; ++i) lcm.handleTimeout(100);  // and the converged one after the pause
  for (const auto& [index, x] : sub.robot(robot).poses)
    std::printf("pose %2lld: x %7.3f  y %7.3f  theta %7.3f\n", static_cast<long long>(index), x[0],
                x[1], x[2]);
  const auto status = sub.lastStatus();
  std::printf("server: %s, %lld poses, chi2 %.4f\n", status.solver.c_str(),
              static_cast<long long>(status.poses), status.chi2);
  for (const auto& [id, alternative] : chosen)  // the ambiguous closure: -1 = neither
    std::printf("ambiguous %lld: alternative %d (%d live hypotheses)\n", id, alternative,
                status.live_hypotheses);
  return 0;
}
