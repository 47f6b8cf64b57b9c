// loopd-synth: a Manhattan-style world of any size for scaling benchmarks. A robot walks a
// unit grid (forward, or turn ±90° then forward), measuring noisy odometry; whenever it
// stands where it stood more than `--min-gap` poses ago it measures a loop closure to the
// most recent such pose (with probability --closure-prob). Written as g2o 2D with the
// odometry-composed start as vertices. Deterministic for a seed.
//
// Two worlds (--world):
//  city    (default) the robot drives across a city that is larger than anything it maps:
//          it roams a neighbourhood (a square of side 2·--window+1 cells) whose centre moves
//          one cell east every --advance poses, so it keeps exploring new streets while it
//          revisits the ones around it. Loop density per pose is that of the square world
//          at 1000 poses, at every size; loops are as long as a neighbourhood is wide.
//  square  the robot stays in one square whose side grows like √N, so at 100k poses it
//          revisits places it left tens of thousands of poses before, anywhere on the map
//          (the worst case for an incremental solver: loops of every length, and a graph
//          whose separators grow like √N).
//
//   loopd-synth --poses N --out world.g2o [--world city|square] [--seed S]
//               [--closure-prob P] [--min-gap G] [--window H] [--advance K]
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "solvers/geometry/se2.h"
#include "tools/common/cli.h"

using loopd::SE2;

namespace {

struct Options {
  long poses = 1000;
  std::string out;
  unsigned seed = 1;
  double closureProb = 0.5;
  long minGap = 20;
  std::string world = "city";
  long window = 15;   // city: half side of the neighbourhood roamed
  long advance = 40;  // city: poses per one-cell move of the neighbourhood
};

Options parse(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto next = [&] { return loopd::tools::flagValue(argc, argv, i); };
    if (a == "--poses")
      o.poses = std::stol(next());
    else if (a == "--out")
      o.out = next();
    else if (a == "--seed")
      o.seed = static_cast<unsigned>(std::stoul(next()));
    else if (a == "--closure-prob")
      o.closureProb = std::stod(next());
    else if (a == "--min-gap")
      o.minGap = std::stol(next());
    else if (a == "--world")
      o.world = next();
    else if (a == "--window")
      o.window = std::stol(next());
    else if (a == "--advance")
      o.advance = std::stol(next());
    else
      throw std::invalid_argument("unknown option " + a);
  }
  if (o.out.empty() || o.poses < 2) throw std::invalid_argument("need --poses N>=2 and --out");
  if (o.world != "city" && o.world != "square")
    throw std::invalid_argument("--world is city or square");
  if (o.window < 2 || o.advance < 1)
    throw std::invalid_argument("need --window >= 2, --advance >= 1");
  return o;
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  try {
    o = parse(argc, argv);
  } catch (const std::exception& e) {
    std::fprintf(
        stderr,
        "loopd-synth: %s\nusage: loopd-synth --poses N --out world.g2o [--seed S] "
        "[--world city|square] [--closure-prob P] [--min-gap G] [--window H] [--advance K]\n",
        e.what());
    return 2;
  }
  std::mt19937_64 rng(o.seed);
  std::normal_distribution<double> n01(0.0, 1.0);
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  const double sigmaXY = 0.05, sigmaTheta = 0.01;
  auto noisy = [&](const SE2& z) {
    return SE2(z.x + sigmaXY * n01(rng), z.y + sigmaXY * n01(rng),
               loopd::wrapAngle(z.theta + sigmaTheta * n01(rng)));
  };

  // Ground truth on the grid; the robot turns at random but stays within a square: of side
  // ~√N for the square world (revisits keep happening at every size), or the neighbourhood
  // around a centre that moves east for the city world.
  const bool city = o.world == "city";
  const long half =
      city ? o.window
           : std::max<long>(5, static_cast<long>(std::sqrt(static_cast<double>(o.poses)) / 2));
  std::vector<SE2> truth{SE2()};
  std::vector<std::pair<long, long>> cell{{0, 0}};
  std::map<std::pair<long, long>, long> lastVisit{{{0, 0}, 0}};
  struct Edge {
    long a, b;
    SE2 z;
  };
  std::vector<Edge> edges;
  std::vector<SE2> estimate{SE2()};
  int heading = 0;  // 0 +x, 1 +y, 2 −x, 3 −y
  for (long k = 1; k < o.poses; ++k) {
    const double r = u01(rng);
    int turn = r < 0.15 ? 1 : (r < 0.3 ? -1 : 0);
    auto [cx, cy] = cell.back();
    const long centre = city ? k / o.advance : 0;
    auto inside = [&](long x, long y) {
      return std::labs(x - centre) <= half && std::labs(y) <= half;
    };
    bool found = false;
    for (int attempt = 0; attempt < 4; ++attempt) {
      const int h = (heading + turn + 4) % 4;
      const long nx = cx + (h == 0) - (h == 2), ny = cy + (h == 1) - (h == 3);
      if (inside(nx, ny)) {
        found = true;
        break;
      }
      turn = turn == 0 ? 1 : turn + 1;  // bounce off the border
    }
    if (city && !found && !inside(cx, cy)) turn = (0 - heading + 4) % 4;  // left behind: drive east
    heading = (heading + turn + 4) % 4;
    cx += (heading == 0) - (heading == 2);
    cy += (heading == 1) - (heading == 3);
    const SE2 next(static_cast<double>(cx), static_cast<double>(cy), heading * M_PI / 2);
    const SE2 z = noisy(truth.back().between(next));
    edges.push_back({k - 1, k, z});
    estimate.push_back(estimate.back() * z);
    truth.push_back(next);
    cell.emplace_back(cx, cy);
    auto seen = lastVisit.find({cx, cy});
    if (seen != lastVisit.end() && k - seen->second > o.minGap && u01(rng) < o.closureProb)
      edges.push_back({seen->second, k, noisy(truth[seen->second].between(next))});
    lastVisit[{cx, cy}] = k;
  }

  FILE* f = std::fopen(o.out.c_str(), "w");
  if (!f) {
    std::perror(o.out.c_str());
    return 1;
  }
  for (size_t i = 0; i < estimate.size(); ++i)
    std::fprintf(f, "VERTEX_SE2 %zu %.17g %.17g %.17g\n", i, estimate[i].x, estimate[i].y,
                 estimate[i].theta);
  const double ixy = 1.0 / (sigmaXY * sigmaXY), ith = 1.0 / (sigmaTheta * sigmaTheta);
  for (const Edge& e : edges)
    std::fprintf(f, "EDGE_SE2 %ld %ld %.17g %.17g %.17g %g 0 0 %g 0 %g\n", e.a, e.b, e.z.x, e.z.y,
                 e.z.theta, ixy, ixy, ith);
  std::fclose(f);
  std::fprintf(stderr, "loopd-synth: %ld poses, %zu edges (%zu loop closures) -> %s\n", o.poses,
               edges.size(), edges.size() - static_cast<size_t>(o.poses - 1), o.out.c_str());
  return 0;
}
