#include "tools/common/cli.h"

#include <stdexcept>

namespace loopd::tools {

std::string flagValue(int argc, char** argv, int& i) {
  if (i + 1 >= argc) throw std::invalid_argument(std::string(argv[i]) + " needs a value");
  return argv[++i];
}

}  // namespace loopd::tools
