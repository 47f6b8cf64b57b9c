// loopd-linear-bench: one numeric factorization + one solve of the Gauss–Newton Hessian of every
// g2o dataset (at the file's initial values, first pose fixed), CHOLMOD (SparseCholesky, Auto
// and Supernodal) against BlockCholesky. Best of N, the three solvers interleaved round by
// round so that load from other processes hits them alike.
//
//   loopd-linear-bench [datasets_dir (default ../shared/datasets)] [rounds (default 5)] [name...]
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "solvers/io/dataset_reader.h"
#include "solvers/linear/block_cholesky.h"
#include "solvers/linear/hessian_layout.h"
#include "solvers/linear/normal_equations.h"
#include "solvers/linear/sparse_cholesky.h"
#include "solvers/problem/pose_graph_problem.h"

using namespace loopd;

namespace {

double nowMs() {
  using namespace std::chrono;
  return duration<double, std::milli>(steady_clock::now().time_since_epoch()).count();
}

template <typename F>
double timeMs(F&& f) {
  const double t0 = nowMs();
  f();
  return nowMs() - t0;
}

double relDiff(const std::vector<double>& a, const std::vector<double>& b) {
  double num = 0.0, den = 0.0;
  for (size_t i = 0; i < a.size(); ++i) {
    num += (a[i] - b[i]) * (a[i] - b[i]);
    den += b[i] * b[i];
  }
  return std::sqrt(num / std::max(den, 1e-300));
}

}  // namespace

int main(int argc, char** argv) {
  const std::string dir = argc > 1 ? argv[1] : "../shared/datasets";
  const int rounds = argc > 2 ? std::max(1, std::atoi(argv[2])) : 5;
  std::vector<std::string> files;
  if (argc > 3) {
    for (int i = 3; i < argc; ++i) files.push_back(dir + "/" + argv[i]);
  } else {
    for (const auto& e : std::filesystem::directory_iterator(dir))
      if (e.path().extension() == ".g2o") files.push_back(e.path().string());
    std::sort(files.begin(), files.end());
  }

  std::printf("%-16s %7s %9s %10s | %9s %9s %9s %6s | %7s %7s %7s | %8s %9s\n", "dataset", "n",
              "nnz(L)", "flops", "chol-auto", "chol-sup", "block", "ratio", "slv-ch", "slv-blk",
              "ratio", "GF/s blk", "rel.diff");
  for (const std::string& file : files) {
    const std::string name = std::filesystem::path(file).stem().string();
    PoseGraphProblem problem;
    try {
      problem = buildProblem(io::readDataset(file));
    } catch (const std::exception& e) {
      std::printf("%-16s skipped: %s\n", name.c_str(), e.what());
      continue;
    }
    std::vector<char> fixed(problem.initial.size(), 0);
    fixed[problem.initial.slot(problem.firstPose)] = 1;
    const HessianLayout layout(problem.graph, problem.initial, fixed);
    NormalEquations ne(layout);
    ne.build(problem.graph, problem.initial);
    const int n = layout.dimension();
    const std::vector<double>& H = ne.hessian();
    std::vector<double> b = ne.gradient();

    SparseCholesky autoChol(FactorizationKind::Auto), superChol(FactorizationKind::Supernodal);
    autoChol.analyze(n, layout.columnStart(), layout.rowIndex());
    superChol.analyze(n, layout.columnStart(), layout.rowIndex());
    BlockCholesky block;
    block.analyze(layout.blockOffsets(), layout.columnStart(), layout.rowIndex());

    double tAuto = 1e300, tSuper = 1e300, tBlock = 1e300, sAuto = 1e300, sBlock = 1e300;
    bool ok = true;
    std::vector<double> xc(n), xb(n);
    for (int r = 0; r < rounds; ++r) {
      tAuto = std::min(tAuto, timeMs([&] { ok &= autoChol.factorize(H); }));
      tSuper = std::min(tSuper, timeMs([&] { ok &= superChol.factorize(H); }));
      tBlock = std::min(tBlock, timeMs([&] { ok &= block.factorize(H); }));
      sAuto = std::min(sAuto, timeMs([&] { autoChol.solve(b.data(), xc.data()); }));
      sBlock = std::min(sBlock, timeMs([&] { block.solve(b.data(), xb.data()); }));
    }
    const double best = std::min(tAuto, tSuper);
    std::printf(
        "%-16s %7d %9ld %10.3g | %9.3f %9.3f %9.3f %6.2f | %7.3f %7.3f %7.2f | %8.2f %9.1e%s\n",
        name.c_str(), n, block.factorNonZeros(), block.flops(), tAuto, tSuper, tBlock,
        best / tBlock, sAuto, sBlock, sAuto / sBlock, block.flops() / (tBlock * 1e6),
        relDiff(xb, xc), ok ? "" : "  (factorization FAILED)");
    std::fflush(stdout);
  }
  return 0;
}
