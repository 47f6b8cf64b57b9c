#include "tools/common/json_writer.h"

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <stdexcept>

namespace loopd::tools {

std::string jsonEscape(const std::string& s) {
  std::string out = "\"";
  for (char c : s) {
    switch (c) {
      case '"':
        out += "\\\"";
        break;
      case '\\':
        out += "\\\\";
        break;
      case '\n':
        out += "\\n";
        break;
      case '\t':
        out += "\\t";
        break;
      default:
        if (static_cast<unsigned char>(c) < 0x20) {
          char buf[8];
          std::snprintf(buf, sizeof(buf), "\\u%04x", c);
          out += buf;
        } else {
          out += c;
        }
    }
  }
  return out + "\"";
}

namespace {

std::string number(double value) {
  if (!std::isfinite(value)) return "null";
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%.17g", value);
  return buf;
}

}  // namespace

JsonObject& JsonObject::add(const std::string& key, double value) {
  fields_.emplace_back(key, number(value));
  return *this;
}
JsonObject& JsonObject::add(const std::string& key, std::int64_t value) {
  fields_.emplace_back(key, std::to_string(value));
  return *this;
}
JsonObject& JsonObject::add(const std::string& key, bool value) {
  fields_.emplace_back(key, value ? "true" : "false");
  return *this;
}
JsonObject& JsonObject::add(const std::string& key, const std::string& value) {
  fields_.emplace_back(key, jsonEscape(value));
  return *this;
}
JsonObject& JsonObject::add(const std::string& key, const std::vector<std::int64_t>& values) {
  std::string s = "[";
  for (size_t i = 0; i < values.size(); ++i) s += (i ? "," : "") + std::to_string(values[i]);
  fields_.emplace_back(key, s + "]");
  return *this;
}

JsonObject& JsonObject::add(const std::string& key, const std::vector<double>& values) {
  std::string s = "[";
  for (size_t i = 0; i < values.size(); ++i) s += (i ? "," : "") + number(values[i]);
  fields_.emplace_back(key, s + "]");
  return *this;
}

std::string JsonObject::str() const {
  std::string s = "{\n";
  for (size_t i = 0; i < fields_.size(); ++i)
    s += "  " + jsonEscape(fields_[i].first) + ": " + fields_[i].second +
         (i + 1 < fields_.size() ? ",\n" : "\n");
  return s + "}\n";
}

void JsonObject::writeFile(const std::string& path) const { writeTextFile(path, str()); }

void writeTextFile(const std::string& path, const std::string& text) {
  std::FILE* f = std::fopen(path.c_str(), "w");
  if (!f) throw std::runtime_error("cannot write " + path + ": " + std::strerror(errno));
  // The data reach the file only on the flush: a full disk shows there (or at the close).
  errno = 0;
  bool ok = std::fwrite(text.data(), 1, text.size(), f) == text.size();
  ok = std::fflush(f) == 0 && ok;
  int err = errno;
  if (std::fclose(f) != 0 && ok) ok = false, err = errno;
  if (!ok)
    throw std::runtime_error("cannot write " + path + ": " +
                             (err ? std::strerror(err) : "write error"));
}

}  // namespace loopd::tools
