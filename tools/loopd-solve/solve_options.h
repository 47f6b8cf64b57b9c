#pragma once
// The command line of loopd-solve (the contract later tools and checks rely on).
#include <string>

namespace loopd::tools {

struct SolveOptions {
  std::string input;
  std::string solver = "lm";
  bool incremental = false;
  std::string out;          // --out EST.g2o
  std::string stats;        // --stats STATS.json
  std::string covariances;  // --covariances COV.txt
  int maxIterations = 100;
  bool quiet = false;
  bool linearInit = true;  // --init linear|file
  // --robust-parameter X (BackendOptions::robustParameter; 0 = default)
  double robustParameter = 0.0;
  int maxHypotheses = 10;  // --max-hypotheses K (mh)
};

/// Parses argv; on --help prints usage and exits 0; on a bad command line throws
/// std::invalid_argument with the reason.
SolveOptions parseSolveOptions(int argc, char** argv);
std::string solveUsage();

}  // namespace loopd::tools
