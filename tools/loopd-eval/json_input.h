#pragma once
// Reading what loopd's tools write as JSON (loopd-outliers' truth files, loopd-solve's
// stats), strictly: a text that is not one JSON object is an error, not an empty answer.
#include <cstdint>
#include <string>
#include <vector>

namespace loopd::tools {

/// The integer array under a top-level key of a JSON object (e.g. "outliers", "rejected");
/// empty if the key is absent. Throws std::runtime_error when the text is not one JSON object
/// or the value is not an array of integers that fit 64 bits.
std::vector<std::int64_t> jsonIntArray(const std::string& json, const std::string& key);
/// Whether the JSON object has the top-level key; throws as jsonIntArray for a text that is not
/// one JSON object.
bool jsonHasKey(const std::string& json, const std::string& key);
/// The integer array under key in the JSON file path, which must be there and hold only
/// integers >= minValue. Throws std::runtime_error("PATH: reason"); a missing key's reason
/// ends "(not KIND?)" when kind is given (e.g. "a loopd-outliers truth file").
std::vector<std::int64_t> readIntArray(const std::string& path, const std::string& key,
                                       std::int64_t minValue, const std::string& kind = "");
/// A number (or integer) field; fallback if absent.
double jsonNumber(const std::string& json, const std::string& key, double fallback);
/// Reads a whole file; throws std::runtime_error naming it.
std::string readTextFile(const std::string& path);

}  // namespace loopd::tools
