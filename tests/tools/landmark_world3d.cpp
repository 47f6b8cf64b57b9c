#include "tests/tools/landmark_world3d.h"

#include <cmath>
#include <cstdio>
#include <random>
#include <set>
#include <stdexcept>
#include <vector>

#include "solvers/geometry/se3.h"

namespace loopd::test {

namespace {

constexpr double kOdometrySigmaT = 0.05, kOdometrySigmaR = 0.01, kSightingSigma = 0.1;
constexpr double kRange = 5.0;

void writePose(std::FILE* f, const char* tag, const SE3& x) {
  double v[7];
  x.toTranslationQuaternion(v);
  std::fprintf(f, "%s %.9f %.9f %.9f %.9f %.9f %.9f %.9f", tag, v[0], v[1], v[2], v[3], v[4], v[5],
               v[6]);
}

}  // namespace

int writeLandmarkWorld3D(const std::string& path, int poses, int landmarks, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> gauss(0.0, 1.0);
  std::uniform_real_distribution<double> uniform(-1.0, 1.0);
  auto noise6 = [&](double sigmaT, double sigmaR) {
    Vec6 d;
    for (int k = 0; k < 3; ++k) d[k] = sigmaT * gauss(rng);
    for (int k = 3; k < 6; ++k) d[k] = sigmaR * gauss(rng);
    return d;
  };
  // The truth: 1 m steps turning 2π in 150 poses, with small pitch and roll and a wavy height.
  std::vector<SE3> truth = {SE3()};
  for (int i = 1; i < poses; ++i) {
    Vec6 step;
    step << 1.0, 0.0, 0.05 * std::sin(i / 15.0), 0.01 * std::sin(i / 7.0), 0.01 * std::cos(i / 9.0),
        2 * M_PI / 150;
    truth.push_back(truth.back() * expSE3(step));
  }
  std::uniform_int_distribution<int> anyPose(0, poses - 1);
  std::vector<Vec3> points;
  for (int k = 0; k < landmarks; ++k)
    points.push_back(truth[static_cast<size_t>(anyPose(rng))].t +
                     Vec3(4 * uniform(rng), 4 * uniform(rng), 2 * uniform(rng)));

  std::FILE* f = std::fopen(path.c_str(), "w");
  if (!f) throw std::runtime_error("cannot write " + path);
  std::vector<SE3> odometry, composed = {SE3()};
  for (int i = 1; i < poses; ++i) {
    const SE3 z = truth[static_cast<size_t>(i - 1)].between(truth[static_cast<size_t>(i)]) *
                  expSE3(noise6(kOdometrySigmaT, kOdometrySigmaR));
    odometry.push_back(z);
    composed.push_back(composed.back() * z);
  }
  std::vector<std::pair<int, int>> sightings;  // (pose, landmark)
  std::set<int> sighted;
  for (int i = 0; i < poses; ++i)
    for (int k = 0; k < landmarks; ++k)
      if ((points[static_cast<size_t>(k)] - truth[static_cast<size_t>(i)].t).norm() < kRange) {
        sightings.emplace_back(i, k);
        sighted.insert(k);
      }
  for (int i = 0; i < poses; ++i) {
    writePose(f, ("VERTEX_SE3:QUAT " + std::to_string(i)).c_str(),
              composed[static_cast<size_t>(i)]);
    std::fputc('\n', f);
  }
  for (int k : sighted) {
    const Vec3& p = points[static_cast<size_t>(k)];
    std::fprintf(f, "VERTEX_TRACKXYZ %d %.9f %.9f %.9f\n", poses + k, p.x(), p.y(), p.z());
  }
  const double it = 1 / (kOdometrySigmaT * kOdometrySigmaT),
               ir = 1 / (kOdometrySigmaR * kOdometrySigmaR);
  for (int i = 1; i < poses; ++i) {
    writePose(f, ("EDGE_SE3:QUAT " + std::to_string(i - 1) + " " + std::to_string(i)).c_str(),
              odometry[static_cast<size_t>(i - 1)]);
    std::fprintf(f, " %g 0 0 0 0 0 %g 0 0 0 0 %g 0 0 0 %g 0 0 %g 0 %g\n", it, it, it, ir, ir, ir);
  }
  const double il = 1 / (kSightingSigma * kSightingSigma);
  for (const auto& [i, k] : sightings) {
    const Vec3 z = truth[static_cast<size_t>(i)].transformTo(points[static_cast<size_t>(k)]) +
                   kSightingSigma * Vec3(gauss(rng), gauss(rng), gauss(rng));
    std::fprintf(f, "EDGE_SE3_TRACKXYZ %d %d %.9f %.9f %.9f %g 0 0 %g 0 %g\n", i, poses + k, z.x(),
                 z.y(), z.z(), il, il, il);
  }
  std::fclose(f);
  return static_cast<int>(sightings.size());
}

}  // namespace loopd::test
