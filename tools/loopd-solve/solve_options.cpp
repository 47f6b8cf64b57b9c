#include "tools/loopd-solve/solve_options.h"

#include <cmath>
#include <cstdlib>
#include <iostream>
#include <stdexcept>

#include "robust/backend_registry.h"

namespace loopd::tools {

std::string solveUsage() {
  std::string s =
      "usage: loopd-solve INPUT [--solver NAME] [--incremental] [--out EST.g2o]\n"
      "                   [--stats STATS.json] [--covariances COV.txt]\n"
      "                   [--max-iterations N] [--init linear|file] [--robust-parameter X]\n"
      "                   [--max-hypotheses K] [--quiet]\n\n"
      "INPUT: g2o (2D/3D), TORO (VERTEX2/EDGE2/EQUIV) or Victoria Park (ODOMETRY/LANDMARK).\n"
      "--incremental  feed poses in index order, one update per pose, as a robot would\n"
      "--init         linear (default): chordal (3D) / orientation-first (2D) start;\n"
      "               file: start from the file's vertices (or composed odometry)\n"
      "--robust-parameter  the robust variant's parameter (kernel width, DCS phi, switch prior\n"
      "               sigma, max-mixture null weight, GNC cbar^2, riSAM shape c); 0 (default):\n"
      "               the variant's own default (robust/README.md)\n"
      "--max-hypotheses  mh: live hypotheses kept at most (default 10)\n"
      "INPUT may group edges as one ambiguous measurement: a line 'HYPOTHESES k [null]' makes\n"
      "the next k edges its alternatives (mh keeps them apart; other solvers take them all).\n"
      "Exit status: 0 solved; 1 unreadable input or failed solve; 2 bad arguments; 3 the solve\n"
      "diverged (a non-finite estimate: --out and --covariances are not written, --stats is,\n"
      "with \"diverged\": true).\n"
      "\nsolvers:\n";
  for (const auto& b : availableBackends())
    s += "  " + b.name + std::string(10 - std::min<size_t>(9, b.name.size()), ' ') + b.description +
         "\n";
  return s;
}

SolveOptions parseSolveOptions(int argc, char** argv) {
  SolveOptions o;
  auto value = [&](int& i, const std::string& flag) -> std::string {
    if (i + 1 >= argc) throw std::invalid_argument(flag + " needs a value");
    return argv[++i];
  };
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--help" || a == "-h") {
      std::cout << solveUsage();
      std::exit(0);
    } else if (a == "--solver") {
      o.solver = value(i, a);
    } else if (a == "--incremental") {
      o.incremental = true;
    } else if (a == "--out") {
      o.out = value(i, a);
    } else if (a == "--stats") {
      o.stats = value(i, a);
    } else if (a == "--covariances") {
      o.covariances = value(i, a);
    } else if (a == "--max-iterations") {
      const std::string v = value(i, a);
      char* end = nullptr;
      const long n = std::strtol(v.c_str(), &end, 10);
      if (*end != '\0' || n < 1 || n > 1000000)
        throw std::invalid_argument("--max-iterations takes a positive integer, got '" + v + "'");
      o.maxIterations = static_cast<int>(n);
    } else if (a == "--init") {
      const std::string v = value(i, a);
      if (v != "linear" && v != "file")
        throw std::invalid_argument("--init takes linear or file, got '" + v + "'");
      o.linearInit = v == "linear";
    } else if (a == "--robust-parameter") {
      const std::string v = value(i, a);
      char* end = nullptr;
      const double x = std::strtod(v.c_str(), &end);
      if (v.empty() || *end != '\0' || !(x >= 0.0) || !std::isfinite(x))
        throw std::invalid_argument("--robust-parameter takes a finite number >= 0, got '" + v +
                                    "'");
      o.robustParameter = x;
    } else if (a == "--max-hypotheses") {
      const std::string v = value(i, a);
      char* end = nullptr;
      const long n = std::strtol(v.c_str(), &end, 10);
      if (v.empty() || *end != '\0' || n < 1 || n > 1000)
        throw std::invalid_argument("--max-hypotheses takes an integer in 1..1000, got '" + v +
                                    "'");
      o.maxHypotheses = static_cast<int>(n);
    } else if (a == "--quiet" || a == "-q") {
      o.quiet = true;
    } else if (!a.empty() && a[0] == '-') {
      throw std::invalid_argument("unknown option " + a);
    } else if (o.input.empty()) {
      o.input = a;
    } else {
      throw std::invalid_argument("more than one input file ('" + o.input + "', '" + a + "')");
    }
  }
  if (o.input.empty()) throw std::invalid_argument("no input file");
  if (!isBackendName(o.solver)) throw std::invalid_argument("unknown solver '" + o.solver + "'");
  return o;
}

}  // namespace loopd::tools
