// ceres_baseline: the Ceres 2.1 peer of the loopd benchmark (issue 2, "Figures to reach").
//
//   ceres_baseline FILE.g2o [--json] [--max-iterations N] [--full-report]
//
// Levenberg–Marquardt, SPARSE_NORMAL_CHOLESKY (SuiteSparse/CHOLMOD), first pose (lowest id)
// held constant, one thread, Ceres's default tolerances, starting from the file's vertices (or
// the composed odometry). Residuals as in ../shared/REFERENCE.md, automatic differentiation.
// chi2 = Σ rᵀΩr over all edges, computed here (Ceres's cost is ½ of it).
#include "g2o_reader.h"
#include "residuals.h"

#include <ceres/ceres.h>

#include <dlfcn.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <memory>
#include <string>

namespace cb = ceres_baseline;

namespace {

// Ceres's num_threads does not reach the libraries under it: Debian's OpenBLAS is the pthread
// build, and CHOLMOD (SuiteSparse 5.12) opens OpenMP regions with a fixed num_threads(4) in its
// supernodal factorization. Both read their thread limits from the environment when they are
// loaded, i.e. before main(); so, unless the caller chose otherwise, set OPENBLAS_NUM_THREADS=1
// and OMP_THREAD_LIMIT=1 and re-execute once. The dlsym calls are a fallback if exec fails.
void single_threaded_libraries(char** argv) {
  if (!std::getenv("CERES_BASELINE_REEXEC") &&
      (!std::getenv("OPENBLAS_NUM_THREADS") || !std::getenv("OMP_THREAD_LIMIT"))) {
    setenv("OPENBLAS_NUM_THREADS", "1", 0);
    setenv("OMP_THREAD_LIMIT", "1", 0);
    setenv("OMP_NUM_THREADS", "1", 0);
    setenv("CERES_BASELINE_REEXEC", "1", 1);
    execv("/proc/self/exe", argv);  // returns only on failure
  }
  using SetFn = void (*)(int);
  for (const char* name :
       {"openblas_set_num_threads", "goto_set_num_threads", "omp_set_num_threads"})
    if (void* f = dlsym(RTLD_DEFAULT, name)) reinterpret_cast<SetFn>(f)(1);
}

// θ ⊞ δ = wrap(θ + δ), as the pose_graph_2d example of Ceres does.
class AngleManifold final : public ceres::Manifold {
 public:
  int AmbientSize() const override { return 1; }
  int TangentSize() const override { return 1; }
  bool Plus(const double* x, const double* d, double* y) const override {
    y[0] = cb::wrap_angle(x[0] + d[0]);
    return true;
  }
  bool PlusJacobian(const double*, double* j) const override {
    j[0] = 1.0;
    return true;
  }
  bool Minus(const double* y, const double* x, double* d) const override {
    d[0] = cb::wrap_angle(y[0] - x[0]);
    return true;
  }
  bool MinusJacobian(const double*, double* j) const override {
    j[0] = 1.0;
    return true;
  }
};

// CPU time of the whole process (all threads). On a shared, loaded machine the wall time of a
// solve can be several times its CPU time; the bench may want both.
double process_cpu_s() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

double chi2(const cb::Graph& g) {
  double sum = 0.0;
  if (g.dim == 2) {
    for (const cb::Edge2& e : g.e2) {
      const cb::Se2Residual f{e.dx, e.dy, e.dth, e.sqrt_info};
      double r[3];
      f(g.xy[e.i].data(), &g.th[e.i], g.xy[e.j].data(), &g.th[e.j], r);
      sum += r[0] * r[0] + r[1] * r[1] + r[2] * r[2];
    }
  } else {
    for (const cb::Edge3& e : g.e3) {
      const cb::Se3Residual f{e.t, e.q, e.sqrt_info};
      double r[6];
      f(g.t[e.i].data(), g.q[e.i].data(), g.t[e.j].data(), g.q[e.j].data(), r);
      for (double v : r) sum += v * v;
    }
  }
  return sum;
}

void build_problem(cb::Graph& g, ceres::Problem& problem) {
  if (g.dim == 2) {
    for (const cb::Edge2& e : g.e2) {
      auto* cost = new ceres::AutoDiffCostFunction<cb::Se2Residual, 3, 2, 1, 2, 1>(
          new cb::Se2Residual{e.dx, e.dy, e.dth, e.sqrt_info});
      problem.AddResidualBlock(cost, nullptr, g.xy[e.i].data(), &g.th[e.i], g.xy[e.j].data(),
                               &g.th[e.j]);
    }
    // θ is kept in [-π, π) as in Ceres's own pose_graph_2d example; the residual wraps too.
    ceres::Manifold* angle = new AngleManifold;  // owned by the problem
    for (std::size_t k = 0; k < g.th.size(); ++k)
      if (problem.HasParameterBlock(&g.th[k])) problem.SetManifold(&g.th[k], angle);
    // The first pose (lowest id that some edge uses) is held constant.
    for (std::size_t k = 0; k < g.xy.size(); ++k)
      if (problem.HasParameterBlock(g.xy[k].data())) {
        problem.SetParameterBlockConstant(g.xy[k].data());
        problem.SetParameterBlockConstant(&g.th[k]);
        break;
      }
  } else {
    ceres::Manifold* quat = new ceres::EigenQuaternionManifold;  // owned by the problem
    for (const cb::Edge3& e : g.e3) {
      auto* cost = new ceres::AutoDiffCostFunction<cb::Se3Residual, 6, 3, 4, 3, 4>(
          new cb::Se3Residual{e.t, e.q, e.sqrt_info});
      problem.AddResidualBlock(cost, nullptr, g.t[e.i].data(), g.q[e.i].data(), g.t[e.j].data(),
                               g.q[e.j].data());
    }
    for (std::size_t k = 0; k < g.q.size(); ++k)
      if (problem.HasParameterBlock(g.q[k].data())) problem.SetManifold(g.q[k].data(), quat);
    for (std::size_t k = 0; k < g.t.size(); ++k)
      if (problem.HasParameterBlock(g.t[k].data())) {
        problem.SetParameterBlockConstant(g.t[k].data());
        problem.SetParameterBlockConstant(g.q[k].data());
        break;
      }
  }
}

const char* termination_name(ceres::TerminationType t) {
  switch (t) {
    case ceres::CONVERGENCE:
      return "CONVERGENCE";
    case ceres::NO_CONVERGENCE:
      return "NO_CONVERGENCE";
    case ceres::FAILURE:
      return "FAILURE";
    case ceres::USER_SUCCESS:
      return "USER_SUCCESS";
    case ceres::USER_FAILURE:
      return "USER_FAILURE";
  }
  return "FAILURE";
}

std::string json_escape(const std::string& s) {
  std::string o;
  for (char c : s) {
    if (c == '"' || c == '\\') {
      o += '\\';
      o += c;
    } else if (static_cast<unsigned char>(c) < 0x20) {
      char buf[8];
      std::snprintf(buf, sizeof buf, "\\u%04x", c);
      o += buf;
    } else {
      o += c;
    }
  }
  return o;
}

// JSON has no NaN/Inf: print null for them.
std::string json_number(double v, int digits) {
  if (!std::isfinite(v)) return "null";
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*g", digits, v);
  return buf;
}

std::string dataset_name(const std::string& path) {
  std::string base =
      path.substr(path.find_last_of('/') == std::string::npos ? 0 : path.find_last_of('/') + 1);
  const std::size_t dot = base.find_last_of('.');
  if (dot != std::string::npos && dot > 0) base.resize(dot);
  return base;
}

int usage(const char* argv0) {
  std::fprintf(stderr,
               "usage: %s FILE.g2o [--json] [--max-iterations N] [--full-report]\n"
               "  Ceres 2.1 baseline: LM, SPARSE_NORMAL_CHOLESKY, first pose fixed, one thread.\n"
               "  --json           one JSON object on stdout\n"
               "  --max-iterations N   (default 100)\n"
               "  --full-report    print Ceres's Summary::FullReport() on stderr\n",
               argv0);
  return 2;
}

}  // namespace

int main(int argc, char** argv) {
  std::string path;
  bool json = false, full_report = false;
  int max_iterations = 100;
  for (int a = 1; a < argc; ++a) {
    const std::string arg = argv[a];
    if (arg == "--json") {
      json = true;
    } else if (arg == "--full-report") {
      full_report = true;
    } else if (arg == "--max-iterations" && a + 1 < argc) {
      char* end = nullptr;
      const long v = std::strtol(argv[++a], &end, 10);
      if (*end != '\0' || v < 0) return usage(argv[0]);
      max_iterations = static_cast<int>(v);
    } else if (arg == "-h" || arg == "--help") {
      usage(argv[0]);
      return 0;
    } else if (!arg.empty() && arg[0] == '-') {
      std::fprintf(stderr, "ceres_baseline: unknown option '%s'\n", arg.c_str());
      return usage(argv[0]);
    } else if (path.empty()) {
      path = arg;
    } else {
      return usage(argv[0]);
    }
  }
  if (path.empty()) return usage(argv[0]);
  single_threaded_libraries(argv);

  google::InitGoogleLogging(argv[0]);
  FLAGS_logtostderr = true;
  FLAGS_minloglevel = 1;  // warnings and errors only

  cb::Graph g;
  std::string err;
  if (!cb::read_g2o(path, g, err)) {
    std::fprintf(stderr, "ceres_baseline: %s\n", err.c_str());
    return 1;
  }

  const double initial_chi2 = chi2(g);

  using Clock = std::chrono::steady_clock;
  const auto t0 = Clock::now();
  auto problem = std::make_unique<ceres::Problem>();
  build_problem(g, *problem);
  const auto t1 = Clock::now();

  ceres::Solver::Options opt;
  opt.minimizer_type = ceres::TRUST_REGION;
  opt.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
  opt.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
  opt.sparse_linear_algebra_library_type = ceres::SUITE_SPARSE;
  opt.num_threads = 1;
  opt.max_num_iterations = max_iterations;
  opt.function_tolerance = 1e-6;
  opt.gradient_tolerance = 1e-10;
  opt.parameter_tolerance = 1e-8;
  opt.minimizer_progress_to_stdout = false;
  opt.logging_type = ceres::SILENT;
  std::string opt_err;
  if (!opt.IsValid(&opt_err)) {
    std::fprintf(stderr, "ceres_baseline: invalid solver options: %s\n", opt_err.c_str());
    return 1;
  }

  ceres::Solver::Summary summary;
  const double c2 = process_cpu_s();
  const auto t2 = Clock::now();
  ceres::Solve(opt, problem.get(), &summary);
  const auto t3 = Clock::now();
  const double solve_cpu_s = process_cpu_s() - c2;

  const double setup_s = std::chrono::duration<double>(t1 - t0).count();
  const double solve_s = std::chrono::duration<double>(t3 - t2).count();
  const double final_chi2 = chi2(g);
  // LM iterations (steps tried), not counting Ceres's iteration 0 (the initial evaluation),
  // which its num_successful_steps includes: MIT stops at "iterations: 100" here.
  const int iterations = summary.iterations.empty() ? 0 : summary.iterations.back().iteration;
  const std::string name = dataset_name(path);

  if (full_report) std::fprintf(stderr, "%s\n", summary.FullReport().c_str());

  if (json) {
    std::printf(
        "{\"dataset\":\"%s\",\"poses\":%zu,\"edges\":%zu,\"solve_s\":%s,\"setup_s\":%s,"
        "\"iterations\":%d,\"initial_chi2\":%s,\"final_chi2\":%s,\"termination\":\"%s\","
        "\"solve_cpu_s\":%s}\n",
        json_escape(name).c_str(), g.poses(), g.edges(), json_number(solve_s, 9).c_str(),
        json_number(setup_s, 9).c_str(), iterations, json_number(initial_chi2, 17).c_str(),
        json_number(final_chi2, 17).c_str(), termination_name(summary.termination_type),
        json_number(solve_cpu_s, 9).c_str());
  } else {
    std::printf("dataset       %s (%s, %s)\n", name.c_str(), g.dim == 2 ? "SE(2)" : "SE(3)",
                g.had_vertices ? "file's vertices" : "composed odometry");
    std::printf("poses         %zu\n", g.poses());
    std::printf("edges         %zu\n", g.edges());
    std::printf("setup_s       %.6f\n", setup_s);
    std::printf("solve_s       %.6f (CPU %.6f)\n", solve_s, solve_cpu_s);
    std::printf("iterations    %d (%d accepted, %d rejected steps)\n", iterations,
                std::max(0, summary.num_successful_steps - 1), summary.num_unsuccessful_steps);
    std::printf("initial_chi2  %.10g\n", initial_chi2);
    std::printf("final_chi2    %.10g\n", final_chi2);
    std::printf("termination   %s (%s)\n", termination_name(summary.termination_type),
                summary.message.c_str());
  }
  // A completed solve exits 0 whatever its termination (the bench reads `termination`; a
  // peer's time to failure still counts). Non-zero exits are for bad input or usage only.
  return 0;
}
