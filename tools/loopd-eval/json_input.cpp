#include "tools/loopd-eval/json_input.h"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <map>
#include <sstream>
#include <stdexcept>

namespace loopd::tools {

namespace {

// A strict reader of one JSON document (RFC 8259) that keeps the spans of its top-level
// object's members: enough to tell a truth or stats file from anything else.
class JsonDocument {
 public:
  explicit JsonDocument(const std::string& text) : s_(text) {
    space();
    if (p_ >= s_.size() || s_[p_] != '{') fail("not a JSON object");
    object(0, true);
    space();
    if (p_ != s_.size()) fail("not JSON: text after the object");
  }
  const std::string* member(const std::string& key) const {
    auto it = members_.find(key);
    return it == members_.end() ? nullptr : &it->second;
  }

 private:
  [[noreturn]] void fail(const std::string& what) const {
    const size_t at = std::min(p_, s_.size());
    const size_t line = 1 + static_cast<size_t>(std::count(s_.begin(), s_.begin() + at, '\n'));
    throw std::runtime_error(what + " (line " + std::to_string(line) + ")");
  }
  void space() {
    while (p_ < s_.size() && (s_[p_] == ' ' || s_[p_] == '\t' || s_[p_] == '\n' || s_[p_] == '\r'))
      ++p_;
  }
  bool eat(char c) {
    space();
    if (p_ < s_.size() && s_[p_] == c) return ++p_, true;
    return false;
  }
  void expect(char c, const char* where) {
    if (!eat(c)) fail(std::string("not JSON: expected '") + c + "' " + where);
  }
  void value(int depth) {
    if (depth > 64) fail("not JSON: nested too deeply");
    space();
    if (p_ >= s_.size()) fail("not JSON: unexpected end");
    const char c = s_[p_];
    if (c == '{')
      object(depth + 1, false);
    else if (c == '[')
      array(depth + 1);
    else if (c == '"')
      string();
    else if (c == '-' || (c >= '0' && c <= '9'))
      number();
    else if (!literal("true") && !literal("false") && !literal("null"))
      fail("not JSON: unexpected character");
  }
  bool literal(const char* word) {
    const size_t n = std::strlen(word);
    if (s_.compare(p_, n, word) != 0) return false;
    p_ += n;
    return true;
  }
  void number() {
    if (s_[p_] == '-') ++p_;
    auto digits = [&] {
      const size_t from = p_;
      while (p_ < s_.size() && s_[p_] >= '0' && s_[p_] <= '9') ++p_;
      if (p_ == from) fail("not JSON: malformed number");
      return p_ - from;
    };
    const size_t first = p_;
    if (digits() > 1 && s_[first] == '0') fail("not JSON: number with a leading zero");
    if (p_ < s_.size() && s_[p_] == '.') ++p_, digits();
    if (p_ < s_.size() && (s_[p_] == 'e' || s_[p_] == 'E')) {
      ++p_;
      if (p_ < s_.size() && (s_[p_] == '+' || s_[p_] == '-')) ++p_;
      digits();
    }
  }
  std::string string() {
    ++p_;  // the opening quote
    std::string out;
    while (p_ < s_.size() && s_[p_] != '"') {
      const char c = s_[p_++];
      if (static_cast<unsigned char>(c) < 0x20) fail("not JSON: control character in a string");
      if (c == '\\') {
        if (p_ >= s_.size()) break;
        const char e = s_[p_++];
        if (e == 'u') {
          for (int k = 0; k < 4; ++k, ++p_)
            if (p_ >= s_.size() || !std::isxdigit(static_cast<unsigned char>(s_[p_])))
              fail("not JSON: malformed \\u escape");
        } else if (std::strchr("\"\\/bfnrt", e) == nullptr || e == '\0') {
          fail("not JSON: unknown escape in a string");
        }
        out += e;  // only keys are kept, and only compared with plain names
      } else {
        out += c;
      }
    }
    if (p_ >= s_.size()) fail("not JSON: unterminated string");
    ++p_;
    return out;
  }
  void array(int depth) {
    ++p_;
    if (eat(']')) return;
    do value(depth);
    while (eat(','));
    expect(']', "after an array element");
  }
  void object(int depth, bool top) {
    ++p_;
    if (eat('}')) return;
    do {
      space();
      if (p_ >= s_.size() || s_[p_] != '"') fail("not JSON: expected a quoted key");
      const std::string key = string();
      expect(':', "after a key");
      space();
      const size_t from = p_;
      value(depth);
      if (top && !members_.emplace(key, s_.substr(from, p_ - from)).second)
        fail("duplicate key \"" + key + "\"");
    } while (eat(','));
    expect('}', "after an object member");
  }

  const std::string& s_;
  size_t p_ = 0;
  std::map<std::string, std::string> members_;
};

// A member's value as an array of integers (JSON integers: no fraction, no exponent).
std::vector<std::int64_t> intArray(const std::string& value, const std::string& key) {
  const std::string what = "\"" + key + "\" is not an array of integers";
  if (value.empty() || value[0] != '[') throw std::runtime_error(what + ": " + value.substr(0, 40));
  std::vector<std::int64_t> out;
  size_t p = 1;
  auto space = [&] {
    while (p < value.size() && std::isspace(static_cast<unsigned char>(value[p]))) ++p;
  };
  space();
  if (value[p] == ']') return out;
  for (;;) {
    space();
    const size_t from = p;
    if (p < value.size() && value[p] == '-') ++p;
    while (p < value.size() && std::isdigit(static_cast<unsigned char>(value[p]))) ++p;
    size_t to = p;
    while (to < value.size() && value[to] != ',' && value[to] != ']' &&
           !std::isspace(static_cast<unsigned char>(value[to])))
      ++to;
    const std::string tok = value.substr(from, to - from);
    if (to != p || p == from || tok == "-")
      throw std::runtime_error(what + ": element " + std::to_string(out.size()) + " is " + tok);
    errno = 0;
    const long long v = std::strtoll(tok.c_str(), nullptr, 10);
    if (errno == ERANGE)
      throw std::runtime_error("\"" + key + "\": " + tok + " does not fit a 64-bit integer");
    out.push_back(v);
    space();
    if (value[p] == ']') return out;
    ++p;  // ',' (the document was checked as JSON)
  }
}

}  // namespace

std::vector<std::int64_t> jsonIntArray(const std::string& json, const std::string& key) {
  const JsonDocument doc(json);
  const std::string* value = doc.member(key);
  return value ? intArray(*value, key) : std::vector<std::int64_t>{};
}

bool jsonHasKey(const std::string& json, const std::string& key) {
  return JsonDocument(json).member(key) != nullptr;
}

std::vector<std::int64_t> readIntArray(const std::string& path, const std::string& key,
                                       std::int64_t minValue, const std::string& kind) {
  const std::string text = readTextFile(path);
  try {
    const JsonDocument doc(text);
    const std::string* value = doc.member(key);
    if (!value)
      throw std::runtime_error("no \"" + key + "\" array" +
                               (kind.empty() ? std::string() : " (not " + kind + "?)"));
    std::vector<std::int64_t> out = intArray(*value, key);
    for (std::int64_t v : out)
      if (v < minValue)
        throw std::runtime_error("\"" + key + "\" holds " + std::to_string(v) + ", below " +
                                 std::to_string(minValue));
    return out;
  } catch (const std::runtime_error& e) {
    throw std::runtime_error(path + ": " + e.what());
  }
}

double jsonNumber(const std::string& json, const std::string& key, double fallback) {
  const std::string quoted = "\"" + key + "\"";
  size_t p = json.find(quoted);
  if (p == std::string::npos) return fallback;
  p = json.find(':', p + quoted.size());
  if (p == std::string::npos) return fallback;
  try {
    return std::stod(json.substr(p + 1));
  } catch (const std::exception&) {
    return fallback;
  }
}

std::string readTextFile(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error("cannot read " + path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

}  // namespace loopd::tools
