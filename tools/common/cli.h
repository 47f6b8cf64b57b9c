#pragma once
// Command-line pieces shared by the tools (and loopd-synth): a flag's value, and main()'s
// parse-then-run frame with its exit codes.
#include <cstdio>
#include <exception>
#include <string>

namespace loopd::tools {

/// The value of the flag argv[i]: argv[i + 1], advancing i past it. Throws
/// std::invalid_argument("FLAG needs a value") when argv[i] is the last argument.
std::string flagValue(int argc, char** argv, int& i);

/// `text` as a flag's value: the whole string a base-10 integer in [lo, hi]. Throws
/// std::invalid_argument("FLAG takes an integer in [lo, hi], got 'text'") otherwise (trailing
/// characters, overflow, out of range).
long long parseIntFlag(const std::string& flag, const std::string& text, long long lo,
                       long long hi);
/// `text` as a flag's value: the whole string a finite number in [lo, hi]. Throws
/// std::invalid_argument("FLAG takes a number in [lo, hi], got 'text'") otherwise (trailing
/// characters, nan, inf, overflow, out of range).
double parseNumberFlag(const std::string& flag, const std::string& text, double lo, double hi);

/// main() of a tool: options = parse(argc, argv), then run(options). A parse error prints
/// "NAME: message", a blank line and the usage to stderr and returns 2; a run error prints
/// "NAME: message" to stderr and returns 1; otherwise run's result.
template <class Parse, class Run>
int parseAndRun(const char* name, const char* usage, int argc, char** argv, Parse parse, Run run) {
  decltype(parse(argc, argv)) options;
  try {
    options = parse(argc, argv);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "%s: %s\n\n%s", name, e.what(), usage);
    return 2;
  }
  try {
    return run(options);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "%s: %s\n", name, e.what());
    return 1;
  }
}

}  // namespace loopd::tools
