#pragma once
// A flat JSON object writer for stats files: keys in insertion order, numbers at full
// precision, non-finite numbers as null (JSON has no NaN).
#include <cstdint>
#include <string>
#include <vector>

namespace loopd::tools {

class JsonObject {
 public:
  JsonObject& add(const std::string& key, double value);
  JsonObject& add(const std::string& key, std::int64_t value);
  JsonObject& add(const std::string& key, int value) { return add(key, std::int64_t{value}); }
  JsonObject& add(const std::string& key, bool value);
  JsonObject& add(const std::string& key, const std::string& value);
  JsonObject& add(const std::string& key, const char* value) {
    return add(key, std::string(value));
  }
  JsonObject& add(const std::string& key, const std::vector<std::int64_t>& values);
  JsonObject& add(const std::string& key, const std::vector<double>& values);
  std::string str() const;
  /// Writes str() to path. Throws std::runtime_error("cannot write PATH: reason") if the file
  /// cannot be opened or any of it cannot be written (checked through the final flush and
  /// close, so a full disk is an error).
  void writeFile(const std::string& path) const;

 private:
  std::vector<std::pair<std::string, std::string>> fields_;
};

std::string jsonEscape(const std::string& s);

/// Writes text to path (replacing it); throws as JsonObject::writeFile does.
void writeTextFile(const std::string& path, const std::string& text);

}  // namespace loopd::tools
