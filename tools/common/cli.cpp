#include "tools/common/cli.h"

#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <sstream>
#include <stdexcept>

namespace loopd::tools {

std::string flagValue(int argc, char** argv, int& i) {
  if (i + 1 >= argc) throw std::invalid_argument(std::string(argv[i]) + " needs a value");
  return argv[++i];
}

namespace {

// strtoll/strtod skip leading blanks: a value must start with its sign or first digit.
bool startsWell(const std::string& text) {
  return !text.empty() && !std::isspace(static_cast<unsigned char>(text[0]));
}

std::string shortest(double x) {
  std::ostringstream s;
  s << x;
  return s.str();
}

}  // namespace

long long parseIntFlag(const std::string& flag, const std::string& text, long long lo,
                       long long hi) {
  char* end = nullptr;
  errno = 0;
  const long long n = startsWell(text) ? std::strtoll(text.c_str(), &end, 10) : 0;
  if (!startsWell(text) || *end != '\0' || errno == ERANGE || n < lo || n > hi)
    throw std::invalid_argument(flag + " takes an integer in [" + std::to_string(lo) + ", " +
                                std::to_string(hi) + "], got '" + text + "'");
  return n;
}

double parseNumberFlag(const std::string& flag, const std::string& text, double lo, double hi) {
  char* end = nullptr;
  errno = 0;
  const double x = startsWell(text) ? std::strtod(text.c_str(), &end) : 0.0;
  if (!startsWell(text) || *end != '\0' || errno == ERANGE || !std::isfinite(x) || x < lo || x > hi)
    throw std::invalid_argument(flag + " takes a number in [" + shortest(lo) + ", " + shortest(hi) +
                                "], got '" + text + "'");
  return x;
}

}  // namespace loopd::tools
