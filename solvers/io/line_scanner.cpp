#include "solvers/io/line_scanner.h"

#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <memory>

#include "solvers/core/key.h"
#include "solvers/io/dataset.h"

namespace loopd::io::detail {

namespace {

bool isBlank(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f'; }

// from_chars takes no leading '+', which some writers emit.
std::string_view withoutPlus(std::string_view s) {
  return s.size() > 1 && s[0] == '+' && s[1] != '+' && s[1] != '-' ? s.substr(1) : s;
}

}  // namespace

std::string readWholeFile(const std::string& path) {
  std::unique_ptr<std::FILE, int (*)(std::FILE*)> f(std::fopen(path.c_str(), "rb"), &std::fclose);
  if (!f) throw DatasetError(path, 0, std::strerror(errno));
  std::string data;
  char chunk[1 << 16];
  for (;;) {
    const std::size_t n = std::fread(chunk, 1, sizeof chunk, f.get());
    // fopen succeeds on a directory; the read reports EISDIR. Check before errno can change.
    if (n < sizeof chunk && std::ferror(f.get())) {
      throw DatasetError(path, 0, std::strerror(errno));
    }
    data.append(chunk, n);
    if (n < sizeof chunk) return data;
  }
}

std::string quoted(std::string_view token) {
  constexpr std::size_t kMax = 40;
  if (token.size() <= kMax) return "'" + std::string(token) + "'";
  return "'" + std::string(token.substr(0, kMax)) + "...'";
}

LineScanner::LineScanner(std::string path, std::string_view text)
    : path_(std::move(path)), text_(text) {
  fields_.reserve(32);
}

bool LineScanner::next() {
  while (pos_ < text_.size()) {
    const std::size_t end = std::min(text_.find('\n', pos_), text_.size());
    const std::string_view line = text_.substr(pos_, end - pos_);
    pos_ = end + 1;
    ++line_;
    fields_.clear();
    for (std::size_t i = 0; i < line.size();) {
      if (isBlank(line[i])) {
        ++i;
        continue;
      }
      if (line[i] == '#') break;  // a comment runs to the end of the line
      std::size_t j = i;
      while (j < line.size() && !isBlank(line[j])) ++j;
      fields_.push_back(line.substr(i, j - i));
      i = j;
    }
    if (!fields_.empty()) return true;
  }
  return false;
}

namespace {

std::string numbers(std::size_t n) { return std::to_string(n) + (n == 1 ? " number" : " numbers"); }

}  // namespace

void LineScanner::expectCount(std::size_t n) const {
  if (count() != n) {
    fail(std::string(tag()) + " expects " + numbers(n) + " after the tag, found " +
         std::to_string(count()));
  }
}

void LineScanner::expectAtLeast(std::size_t min) const {
  if (count() < min) {
    fail(std::string(tag()) + " expects at least " + numbers(min) + " after the tag, found " +
         std::to_string(count()));
  }
}

// Fields are numbered as awk does: the tag is field 1.
std::string LineScanner::fieldName(std::size_t i) const {
  return std::string(tag()) + " field " + std::to_string(i + 2) + " " + quoted(fields_[i + 1]);
}

std::int64_t LineScanner::id(std::size_t i) const {
  const std::string_view s = withoutPlus(fields_[i + 1]);
  std::int64_t v = 0;
  const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (ec == std::errc::result_out_of_range) fail(fieldName(i) + " is out of range for an id");
  if (ec != std::errc() || end != s.data() + s.size()) {
    fail(fieldName(i) + " is not an integer id");
  }
  // A key keeps kKeyIndexBits of the id: beyond them two ids would be one variable.
  if (v < 0 || static_cast<std::uint64_t>(v) > kMaxKeyIndex)
    fail(fieldName(i) + " is out of range for an id (0 to " + std::to_string(kMaxKeyIndex) + ")");
  return v;
}

double LineScanner::number(std::size_t i) const {
  const std::string_view s = withoutPlus(fields_[i + 1]);
  double v = 0.0;
  const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (ec == std::errc::result_out_of_range) fail(fieldName(i) + " is out of range for a double");
  if (ec != std::errc() || end != s.data() + s.size()) fail(fieldName(i) + " is not a number");
  if (!std::isfinite(v)) fail(fieldName(i) + " is not finite");
  return v;
}

void LineScanner::fail(const std::string& reason) const {
  throw DatasetError(path_, line_, reason);
}

}  // namespace loopd::io::detail
