#pragma once
// The tokenizer every reader shares: walks a file buffer line by line (`\n` or `\r\n`, the last
// line with or without a newline), skips blank lines and `#` comments, splits a line into
// whitespace-separated fields and parses them as ids or finite numbers. Every failure is a
// DatasetError naming the file and the 1-based line. Internal to the readers.
#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace loopd::io::detail {

/// The whole file in memory; DatasetError(path, 0, OS reason) when it cannot be read.
std::string readWholeFile(const std::string& path);

/// A token for an error message: single-quoted, cut short when long (garbage can be huge).
std::string quoted(std::string_view token);

class LineScanner {
 public:
  /// `text` must outlive the scanner; `path` names the file in errors.
  LineScanner(std::string path, std::string_view text);

  /// Moves to the next line that has fields; false at the end of the text.
  bool next();

  const std::string& path() const { return path_; }
  int line() const { return line_; }
  std::string_view tag() const { return fields_[0]; }
  /// How many fields follow the tag.
  std::size_t count() const { return fields_.size() - 1; }
  /// Throws "TAG expects n numbers after the tag, found m" unless count() == n.
  void expectCount(std::size_t n) const;
  /// Throws unless min ≤ count().
  void expectAtLeast(std::size_t min) const;
  /// Field i after the tag (0-based) as an integer id, 0 to kMaxKeyIndex (what a Key holds).
  std::int64_t id(std::size_t i) const;
  /// Field i after the tag (0-based) as it is written.
  std::string_view field(std::size_t i) const { return fields_[i + 1]; }
  /// Field i after the tag (0-based) as a finite double.
  double number(std::size_t i) const;
  /// Throws DatasetError(path, line, reason).
  [[noreturn]] void fail(const std::string& reason) const;

 private:
  std::string fieldName(std::size_t i) const;

  std::string path_;
  std::string_view text_;
  std::size_t pos_ = 0;
  int line_ = 0;
  std::vector<std::string_view> fields_;  // reused: no allocation per line
};

}  // namespace loopd::io::detail
